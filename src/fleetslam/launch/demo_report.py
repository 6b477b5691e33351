"""The demo's results: what a run measured (:class:`DemoResult`), the files written from it (statistics, processes
and SLAM figures as JSON, trajectories and bandwidth plots) and the report, ``report.md`` and ``report.html``
rendered from one :class:`Report` through Jinja2 templates (``templates/report.{md,html}.j2``)."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.launch.supervisor import ProcessUsage
from fleetslam.middleware.stats_table import StatsRow

log = logging.getLogger(__name__)


@dataclass
class DemoResult:
    """What a demo run measured."""

    out_dir: Path
    duration_s: float
    rows: list[StatsRow]
    """Per topic, publisher and subscriber, every statistics window of the run summed
    (:meth:`~fleetslam.middleware.stats_table.StatsTable.totals`)."""
    history: list[dict[str, Any]] = field(default_factory=list)
    ate: dict[str, float] = field(default_factory=dict)
    """ATE RMSE (m) per robot: its SLAM trajectory as the run ended (``slam/trajectory``: every processed frame on its
    keyframe's optimised pose, as an offline run's) against ground truth."""
    ate_live: dict[str, float] = field(default_factory=dict)
    """ATE RMSE (m) per robot of its poses as SLAM published them during the run (``slam/odom``: each frame's pose
    when it was tracked, before later loop closures corrected it)."""
    plots: list[Path | None] = field(default_factory=list)
    """Extra figures for the report."""
    processes: list[ProcessUsage] = field(default_factory=list)
    """CPU and peak memory of every process over the run, the demo's own first."""
    slam: dict[str, dict[str, str] | None] = field(default_factory=dict)
    """Per robot, the values of its latest SLAM diagnostics (None: it never published any)."""
    placements: dict[str, tuple[float, Any]] = field(default_factory=dict)
    """Per robot its SLAM placed in the fleet frame: seconds after the start, and its latest ``T_fleet_map``."""
    true_placements: dict[str, Any] = field(default_factory=dict)
    """Per robot, the true ``T_fleet_map`` (from the simulator's start poses; evaluation only)."""
    placed_stamps: dict[str, float] = field(default_factory=dict)
    """Per placed robot, the stamp (s) of its first placement: its poses stamped earlier precede it."""
    fleet: FleetTrajectories | None = None
    """The trajectories in the fleet frame (``fleet_trajectories/``) and the fleet ATE, when robots were placed."""

    def per_agent(self) -> dict[str, dict[str, float]]:
        totals: dict[str, dict[str, float]] = {}
        for row in self.rows:
            t = totals.setdefault(row.agent, {"bandwidth_bps": 0.0, "delivered": 0, "dropped": 0})
            t["bandwidth_bps"] += row.bandwidth_bps
            t["delivered"] += row.delivered
            t["dropped"] += row.dropped
        return totals


@dataclass(frozen=True)
class FleetTrajectories:
    """What :func:`write_fleet_trajectories` wrote: per placed robot its poses in the fleet frame and how many of them
    precede its placement, and the fleet ATE."""

    poses: dict[str, int]
    before_placement: dict[str, int]
    ate: float | None
    """ATE RMSE (m) of the placed robots' fleet trajectories concatenated, with one SE(3) alignment for all (COVINS
    style: a wrong placement shows here, while each robot's own alignment hides it); None without ground truth."""


@dataclass(frozen=True)
class Table:
    """A table of the report: column titles, which columns are right-aligned (figures), rows of cell texts."""

    columns: Sequence[str]
    right: Sequence[bool]
    rows: list[list[str]] = field(default_factory=list)


@dataclass(frozen=True)
class Section:
    """A titled section of the report: an optional paragraph, then a table."""

    title: str
    table: Table
    text: str = ""


@dataclass(frozen=True)
class Figure:
    alt: str
    src: str
    """Relative to the report."""


@dataclass(frozen=True)
class Report:
    """What the templates render: the title, the statistics table with its intro, the sections, the figures."""

    title: str
    intro: str
    table: Table
    sections: list[Section]
    figures: list[Figure]


#: The SLAM diagnostics in the report's per-robot table: (column, key of the ``slam`` DiagnosticStatus).
SLAM_COLUMNS = (
    ("frames received", "frames_received"), ("processed", "frames_processed"), ("dropped", "frames_dropped"),
    ("relocalisations", "relocalisations"), ("loop closures", "loop_closures"),
    ("loops retracted", "loops_retracted"), ("keyframes", "keyframes"),
    ("lost frames", "lost_frames"), ("coasting frames", "coasting_frames"), ("odometry ms (mean)", "odometry_ms_mean"),
    ("peer keyframes", "peer_keyframes"), ("peer closures", "peer_closures"),
)  # fmt: skip
MISSING = "—"
STYLE = (
    "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px}"
)
"""The HTML report's style sheet."""


def statistics_table(rows: Sequence[StatsRow]) -> Table:
    """Per topic and subscriber, its statistics (in a demo's report, over the run:
    :meth:`~fleetslam.middleware.stats_table.StatsTable.totals`)."""
    columns = ("agent", "topic", "publisher → subscriber", "kB/s", "Hz", "delivered", "dropped", "age ms (mean ± std)")
    return Table(columns, (False, False, False, True, True, True, True, True), [
        [r.agent, r.topic, f"{r.node_pub} → {r.node_sub}", f"{r.bandwidth_bps / 1e3:.1f}", f"{r.rate_hz:.1f}",
         str(r.delivered), str(r.dropped), f"{r.age_mean_ms:.2f} ± {r.age_std_ms:.2f}"]
        for r in rows
    ])  # fmt: skip


def maps_section(maps: Sequence[Path]) -> Section | None:
    """Node and leaf counts and extent of each map file (None without maps)."""
    if not maps:
        return None
    from fleetslam.mapping.octree import OccupancyOctree

    table = Table(("map", "nodes", "leaves", "occupied leaves", "free leaves", "extent (m)"),
                  (False, True, True, True, True, False))  # fmt: skip
    for path in maps:
        tree = OccupancyOctree.read(path)
        occupied, _ = tree.occupied_centers()
        free, _ = tree.free_centers()
        lo, hi = tree.metric_bounds()
        extent = " × ".join(f"{v:.1f}" for v in (hi - lo))
        table.rows.append([path.name, str(tree.num_nodes()), str(tree.num_leaf_nodes()), str(len(occupied)),
                           str(len(free)), extent])  # fmt: skip
    return Section("Maps", table)


def slam_section(
    slam: Mapping[str, Mapping[str, str] | None], ate: Mapping[str, float], ate_live: Mapping[str, float] | None = None
) -> Section | None:
    """Per robot its latest SLAM diagnostics and its ATE, of the final and of the live trajectory; "—" where a robot
    has no figure (None without robots)."""
    live = ate_live or {}
    robots = sorted(set(slam) | set(ate) | set(live))
    if not robots:
        return None
    columns = (*(c for c, _ in SLAM_COLUMNS), "ATE RMSE (m), final", "ATE RMSE (m), live")
    table = Table(("robot", *columns), (False, *[True] * len(columns)))
    for robot in robots:
        values = slam.get(robot) or {}
        cells = [values.get(key, MISSING) for _, key in SLAM_COLUMNS]
        cells += [f"{figures[robot]:.3f}" if robot in figures else MISSING for figures in (ate, live)]
        table.rows.append([robot, *cells])
    text = ("Counts since the SLAM node started (its latest `slam/diagnostics`). ATE: SLAM against ground truth, "
            "SE(3)-aligned, translation RMSE; *final*: every processed frame on its keyframe's pose after the graph's "
            "last optimisation (`slam/trajectory` as the run ended: `trajectories/`, the figure an offline run and the "
            "benchmarks give); *live*: each pose as SLAM published it when the frame was tracked, before later loop "
            "closures corrected it (`slam/odom`: `trajectories_live/`).")  # fmt: skip
    return Section("SLAM per robot", table, text)


def process_section(processes: Sequence[ProcessUsage]) -> Section | None:
    """CPU (% of one core, averaged over the run) and peak memory of every process (None without processes)."""
    if not processes:
        return None
    table = Table(("process", "pid", "CPU %", "CPU s", "peak RSS (MiB)", "restarts"), (False, *[True] * 5))
    for p in processes:
        table.rows.append([p.label, str(p.pid) if p.pid is not None else MISSING, f"{p.cpu_percent:.1f}",
                           f"{p.cpu_s:.1f}", f"{p.peak_rss_mib:.0f}", str(p.restarts)])  # fmt: skip
    text = ("CPU: % of one core, averaged over each process's life until the end of the run (the demo's own "
            "process: over the run). Peak RSS: the most resident memory it held.")  # fmt: skip
    return Section("Processes", table, text)


def agents_section(result: DemoResult) -> Section:
    """Bandwidth and message counts summed per agent."""
    table = Table(("agent", "kB/s", "delivered", "dropped"), (False, True, True, True))
    for agent, t in sorted(result.per_agent().items()):
        table.rows.append([agent, f"{t['bandwidth_bps'] / 1e3:.1f}", str(int(t["delivered"])), str(int(t["dropped"]))])
    return Section("Per agent", table)


def true_placements(out_dir: Path) -> dict[str, Any]:
    """Per robot, the true ``T_fleet_map`` when the fleet frame is a robot's map frame (``start_poses.yaml`` names
    it): each robot's map frame in the world is where its SLAM trajectory fits its ground truth best (rigidly, by
    position, from ``trajectories/`` and ``ground_truth/``), so a map frame that began after the robot set off is
    placed right. Empty without a reference robot or trajectories (evaluation only)."""
    import yaml

    from fleetslam.fusion.alignment import rigid_fit
    from fleetslam.geometry import invert
    from fleetslam.trajectory import NearestPose, read_tum

    path = out_dir / "start_poses.yaml"
    settings = yaml.safe_load(path.read_text()) if path.is_file() else {}
    reference = settings.get("fleet_frame_of")
    world_from_map: dict[str, Any] = {}
    for robot in settings.get("start_poses") or {}:
        slam_file, truth_file = out_dir / "trajectories" / f"{robot}.txt", out_dir / "ground_truth" / f"{robot}.txt"
        if not slam_file.is_file() or not truth_file.is_file():
            continue
        slam, truth = read_tum(slam_file), read_tum(truth_file)
        nearest = NearestPose(truth, 0.05)
        pairs = [(pose[:3, 3], nearest(stamp)) for stamp, pose in zip(slam.stamps, slam.poses, strict=True)]
        estimated = np.array([p for p, t in pairs if t is not None])
        true = np.array([t[:3, 3] for _, t in pairs if t is not None])
        if len(estimated) >= 3:
            world_from_map[robot] = rigid_fit(estimated, true)
    if reference not in world_from_map:
        return {}
    return {robot: invert(world_from_map[reference]) @ pose for robot, pose in world_from_map.items()}


def fleet_section(result: DemoResult) -> Section | None:
    """When each robot's SLAM placed its map in the fleet frame (no start poses given), and how far that placement
    is from the truth (None when no robot was placed by its SLAM)."""
    if not result.placements:
        return None
    from fleetslam.geometry import invert, rotation_angle

    table = Table(("robot", "placed after (s)", "error (m)", "error (deg)"), (False, True, True, True))
    robots = sorted(set(result.placements) | set(result.true_placements))
    for robot in robots:
        if robot not in result.placements:
            table.rows.append([robot, "not placed", MISSING, MISSING])
            continue
        seconds, placed = result.placements[robot]
        truth = result.true_placements.get(robot)
        if truth is None:
            table.rows.append([robot, f"{seconds:.0f}", MISSING, MISSING])
            continue
        error = invert(truth) @ placed
        table.rows.append([robot, f"{seconds:.0f}", f"{np.linalg.norm(error[:3, 3]):.3f}",
                           f"{np.degrees(rotation_angle(error)):.2f}"])  # fmt: skip
    text = ("Each robot's map frame placed in the fleet frame (the reference robot's map) from inter-agent loop "
            "closures, with no start pose given: by its SLAM, then (`follow_fleet`) by the fleet back-end's joint "
            "optimisation once it has corrected the robot's keyframes; its latest placement, error against the truth "
            "(each map frame where its SLAM trajectory fits the ground truth best).")  # fmt: skip
    return Section("Fleet frame", table, text)


def fleet_trajectory_section(result: DemoResult) -> Section | None:
    """Per robot its poses in the fleet frame (how many precede its placement) and its ATE, and the fleet ATE: one
    alignment over all robots' fleet trajectories (None when no robot was placed)."""
    fleet = result.fleet
    if fleet is None or not fleet.poses:
        return None
    table = Table(("robot", "poses in the fleet frame", "before placement", "ATE RMSE (m), own alignment"),
                  (False, True, True, True))  # fmt: skip
    for robot in sorted(fleet.poses):
        table.rows.append([robot, str(fleet.poses[robot]), str(fleet.before_placement.get(robot, 0)),
                           f"{result.ate[robot]:.3f}" if robot in result.ate else MISSING])  # fmt: skip
    fleet_ate = f"{fleet.ate:.3f}" if fleet.ate is not None else MISSING
    table.rows.append(["fleet (one alignment)", str(sum(fleet.poses.values())),
                       str(sum(fleet.before_placement.values())), fleet_ate])  # fmt: skip
    text = ("`fleet_trajectories/<robot>.txt`: each placed robot's SLAM trajectory (camera optical frame) moved into "
            "the fleet frame by its latest placement; poses stamped before its first placement precede it (its "
            "map frame was placed later, by the same transform). Fleet ATE: the robots' fleet trajectories "
            "concatenated and SE(3)-aligned to the ground truth once, translation RMSE.")  # fmt: skip
    return Section("Fleet trajectories", table, text)


def _robots(result: DemoResult) -> list[str]:
    return sorted(set(result.slam) | set(result.placements))


def pairs_section(result: DemoResult) -> Section | None:
    """Per agent pair: when both were first placed in the fleet frame (their maps merged), and the inter-agent
    closures each agent holds with the other, accepted and rejected (``peer_closures_accepted.<peer>``,
    ``peer_closures_rejected.<peer>`` of its latest diagnostics); None with fewer than two robots or when no robot
    was placed by its SLAM (start poses given, or no SLAM)."""
    robots = _robots(result)
    if len(robots) < 2 or not result.placements:
        return None
    table = Table(("agents", "first merge after (s)", "closures held by", "accepted", "rejected"),
                  (False, True, False, True, True))  # fmt: skip
    for i, a in enumerate(robots):
        for b in robots[i + 1 :]:
            placed = [result.placements[r][0] for r in (a, b) if r in result.placements]
            merged = f"{max(placed):.0f}" if len(placed) == 2 else "not merged"
            for holder, peer in ((a, b), (b, a)):
                values = result.slam.get(holder) or {}
                table.rows.append([f"{a} ↔ {b}", merged, holder, values.get(f"peer_closures_accepted.{peer}", MISSING),
                                   values.get(f"peer_closures_rejected.{peer}", MISSING)])  # fmt: skip
    text = (
        "First merge: seconds after the start when the later of the two was placed in the fleet frame. Closures: "
        "those each agent holds with the other (verified by it or shared by the other, the latest 64); accepted: "
        "the consistent set its placement rests on, rejected: those inconsistent with it (repeated structure)."
    )
    return Section("Agent pairs", table, text)


#: The topics an agent sends its peers (summed for the bytes exchanged per keyframe).
EXCHANGE_TOPICS = ("keyframe_summaries", "graph_updates")


def exchange_section(result: DemoResult) -> Section | None:
    """Per agent and peer: the bytes of its ``keyframe_summaries`` and ``graph_updates`` the peer's SLAM received
    (summed over the statistics windows of the run) and per keyframe the agent made (None without such traffic)."""
    robots = _robots(result)
    received: dict[tuple[str, str, str], int] = {}
    for h in result.history:
        for agent in robots:
            for topic in EXCHANGE_TOPICS:
                if h["topic"] != f"/{agent}/{topic}" or "bytes" not in h:
                    continue
                peer = h["subscriber"].strip("/").split("/")[0]
                if peer in robots and peer != agent and h["subscriber"] == f"/{peer}/slam":
                    received[(agent, peer, topic)] = received.get((agent, peer, topic), 0) + int(h["bytes"])
    if not received:
        return None
    table = Table(("agent", "to", "keyframes", *(f"{t} (kB)" for t in EXCHANGE_TOPICS), "bytes per keyframe"),
                  (False, False, True, True, True, True))  # fmt: skip
    for agent, peer in sorted({(a, p) for a, p, _ in received}):
        keyframes = (result.slam.get(agent) or {}).get("keyframes")
        sent = [received.get((agent, peer, topic), 0) for topic in EXCHANGE_TOPICS]
        per_keyframe = f"{sum(sent) / int(keyframes):.0f}" if keyframes and int(keyframes) > 0 else MISSING
        table.rows.append([agent, peer, keyframes or MISSING, *(f"{b / 1e3:.1f}" for b in sent), per_keyframe])
    text = ("What each agent's peer received of its keyframe summaries and graph updates over the run (from the "
            "peer's `/statistics`), and per keyframe the agent made (its latest diagnostics).")  # fmt: skip
    return Section("Exchange per agent", table, text)


def build_report(result: DemoResult, figures: Sequence[Path | None] = ()) -> Report:
    """The report of a run: its tables (maps read from ``out_dir/maps/*.bt``) and ``figures`` (None: left out)."""
    maps_dir = result.out_dir / "maps"
    maps = sorted(maps_dir.glob("*.bt")) if maps_dir.is_dir() else []
    sections = [maps_section(maps), slam_section(result.slam, result.ate, result.ate_live), fleet_section(result),
                fleet_trajectory_section(result), pairs_section(result), exchange_section(result),
                process_section(result.processes), agents_section(result)]  # fmt: skip
    return Report(
        title="fleetslam demo report",
        intro=(
            f"Run of {result.duration_s:.0f} s. Per topic and subscriber, over the run (every statistics window "
            "it reported; kB/s and Hz over the span from its first window to its last; age pooled over the "
            "messages):"
        ),
        table=statistics_table(result.rows),
        sections=[s for s in sections if s is not None],
        figures=[Figure(plot.stem, plot.name) for plot in figures if plot is not None],
    )


@cache
def _templates() -> Any:
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("fleetslam.launch", "templates"),
        autoescape=jinja2.select_autoescape(["html.j2"]),
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        undefined=jinja2.StrictUndefined,
    )


def render_markdown(report: Report) -> str:
    text: str = _templates().get_template("report.md.j2").render(report=report)
    return text


def render_html(report: Report) -> str:
    """A standalone HTML page (cell texts escaped by the template engine)."""
    text: str = _templates().get_template("report.html.j2").render(report=report, style=STYLE)
    return text


def write_results(result: DemoResult) -> None:
    """statistics.json, processes.json, slam.json, fleet_frame.json (when robots were placed by their SLAM),
    report.md/report.html and the plots in the output folder."""
    out = result.out_dir
    (out / "statistics.json").write_text(json.dumps([r.as_dict() for r in result.rows], indent=1))
    (out / "processes.json").write_text(json.dumps([p.as_dict() for p in result.processes], indent=1))
    (out / "slam.json").write_text(json.dumps(result.slam, indent=1))
    if result.placements:
        placed = {robot: {"placed_after_s": round(seconds, 1), "placed_at_stamp": result.placed_stamps.get(robot),
                          "T_fleet_map": np.asarray(pose).tolist(),
                          "true_T_fleet_map": (np.asarray(result.true_placements[robot]).tolist()
                                               if robot in result.true_placements else None)}
                  for robot, (seconds, pose) in result.placements.items()}  # fmt: skip
        (out / "fleet_frame.json").write_text(json.dumps(placed, indent=1))
    report = build_report(result, [*result.plots, plot_bandwidth(result)])
    (out / "report.md").write_text(render_markdown(report))
    (out / "report.html").write_text(render_html(report))


def write_trajectories(
    trajectories: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]],
    robots: list[str],
    out_dir: Path,
    extrinsics: dict[str, Any],
) -> dict[str, dict[str, float]]:
    """TUM files of every robot's trajectories, ``<robot>/<kind>`` → folder: ``slam`` (final) → ``trajectories/``,
    ``live`` → ``trajectories_live/``, ``truth`` (base_link, moved to the camera by ``extrinsics``) →
    ``ground_truth/``; and the ATE (m) of the estimated ones per kind and robot."""
    from fleetslam.trajectory import Trajectory, write_tum

    ate: dict[str, dict[str, float]] = {"slam": {}, "live": {}}
    for robot in robots:
        tracks = {}
        for kind, folder in (("slam", "trajectories"), ("live", "trajectories_live"), ("truth", "ground_truth")):
            if kind == "live" and f"{robot}/live" not in trajectories:
                continue
            stamps, poses = trajectories.get(f"{robot}/{kind}", (np.zeros(0), np.zeros((0, 4, 4))))
            if kind == "truth" and robot in extrinsics:  # base_link ground truth → camera optical frame
                poses = poses @ extrinsics[robot]
            tracks[kind] = Trajectory.from_lists(stamps.tolist(), list(poses))
            write_tum(out_dir / folder / f"{robot}.txt", tracks[kind])
        for kind in ("slam", "live"):
            if kind in tracks and len(tracks[kind]) >= 3 and len(tracks["truth"]) >= 3:
                try:
                    from fleetslam.eval import ape

                    ate[kind][robot] = float(ape(tracks["truth"], tracks[kind], align=True, max_diff=0.1).rmse)
                except Exception as err:
                    log.warning("ATE of %s (%s): %s", robot, kind, err)
    return ate


def write_fleet_trajectories(
    out_dir: Path, placements: Mapping[str, tuple[float, Any]], placed_stamps: Mapping[str, float]
) -> FleetTrajectories:
    """``fleet_trajectories/<robot>.txt`` (TUM, camera optical frame) of every placed robot: its SLAM trajectory
    (``trajectories/<robot>.txt``) moved by its latest ``T_fleet_map``, with a comment line saying from which
    stamp on it was placed; and the fleet ATE against ``ground_truth/`` (see :class:`FleetTrajectories`)."""
    from fleetslam.trajectory import Trajectory, read_tum, write_tum

    poses: dict[str, int] = {}
    before: dict[str, int] = {}
    estimates: list[Trajectory] = []
    truths: list[Trajectory] = []
    for robot, (_, fleet_from_map) in sorted(placements.items()):
        slam_file, truth_file = out_dir / "trajectories" / f"{robot}.txt", out_dir / "ground_truth" / f"{robot}.txt"
        if not slam_file.is_file():
            continue
        slam = read_tum(slam_file)
        moved = Trajectory(slam.stamps, np.asarray(fleet_from_map) @ slam.poses)
        path = out_dir / "fleet_trajectories" / f"{robot}.txt"
        write_tum(path, moved)
        placed_at = placed_stamps.get(robot)
        poses[robot] = len(moved)
        before[robot] = int(np.sum(moved.stamps < placed_at)) if placed_at is not None else 0
        placed = (f"placed at stamp {placed_at:.6f}: the {before[robot]} poses stamped earlier precede its placement"
                  if placed_at is not None else "stamp of placement unknown")  # fmt: skip
        note = f"# {robot}'s SLAM camera (optical frame) in the fleet frame; {placed}\n"
        path.write_text(note + path.read_text())
        if truth_file.is_file() and len(moved):
            estimates.append(moved)
            truths.append(read_tum(truth_file))
    return FleetTrajectories(poses, before, fleet_ate(estimates, truths))


def fleet_ate(estimates: Sequence[Any], truths: Sequence[Any], max_diff: float = 0.1) -> float | None:
    """ATE RMSE (m) of several robots' trajectories in one frame against their ground truths, with one SE(3)
    alignment for all: each robot's stamps are shifted to a span of their own (the robots' poses share stamps) and
    the trajectories concatenated. None with no trajectories or when they cannot be associated or aligned."""
    from fleetslam.trajectory import Trajectory

    if not estimates:
        return None
    t0 = min(float(np.min(t.stamps)) for t in [*estimates, *truths] if len(t))
    span = max(float(np.max(t.stamps)) for t in [*estimates, *truths] if len(t)) - t0 + 1000.0

    def concatenated(trajectories: Sequence[Any]) -> Trajectory:
        stamps = np.concatenate([t.stamps - t0 + k * span for k, t in enumerate(trajectories)])
        poses = np.concatenate([t.poses for t in trajectories])
        order = np.argsort(stamps, kind="stable")
        return Trajectory(stamps[order], poses[order])

    try:
        from fleetslam.eval import ape

        return float(ape(concatenated(truths), concatenated(estimates), align=True, max_diff=max_diff).rmse)
    except Exception as err:  # as for each robot's ATE: reported missing, not fatal to the report
        log.warning("fleet ATE: %s", err)
        return None


def plot_trajectories(robots: list[str], out_dir: Path) -> Path | None:
    """Ground truth and SLAM paths (SLAM placed by the robots' start poses) over the fleet map's occupied cells."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import yaml

        from fleetslam.geometry import pose_from_xyz_rpy
        from fleetslam.mapping.octree import OccupancyOctree
        from fleetslam.trajectory import read_tum
    except ImportError:
        return None
    fig, ax = plt.subplots(figsize=(9, 6.5), dpi=110)
    # The true start poses (evaluation only: the fleet was not given them without known starts) put the SLAM
    # trajectories and the fleet map in the ground truth's frame; the fleet frame is then the reference agent's map.
    evaluation = out_dir / "start_poses.yaml"
    settings = yaml.safe_load(evaluation.read_text()) if evaluation.is_file() else {}
    starts = settings.get("start_poses", {})
    reference = settings.get("fleet_frame_of")
    fleet_in_world = pose_from_xyz_rpy(*starts[reference]) if reference in starts else np.eye(4)
    fleet_map = out_dir / "maps" / "fleet.bt"
    if fleet_map.is_file():
        centres, _ = OccupancyOctree.read(fleet_map).occupied_centers()
        centres = centres @ fleet_in_world[:3, :3].T + fleet_in_world[:3, 3]
        band = centres[(centres[:, 2] > 0.1) & (centres[:, 2] < 1.5)]
        ax.scatter(band[:, 0], band[:, 1], s=0.3, c="0.6", label="fleet map (occupied, 0.1–1.5 m)")
    for robot in robots:
        truth, slam = out_dir / "ground_truth" / f"{robot}.txt", out_dir / "trajectories" / f"{robot}.txt"
        if not truth.is_file() or not slam.is_file():
            continue
        gt = read_tum(truth).positions
        start = pose_from_xyz_rpy(*starts[robot]) if robot in starts else np.eye(4)
        est = read_tum(slam).poses
        placed = (start @ est)[:, :3, 3] if len(est) else np.zeros((0, 3))
        (line,) = ax.plot(gt[:, 0], gt[:, 1], "--", linewidth=1.2, label=f"{robot} ground truth")
        ax.plot(placed[:, 0], placed[:, 1], "-", color=line.get_color(), linewidth=1.5, label=f"{robot} SLAM")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Trajectories over the fleet map")
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    path = out_dir / "trajectories.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_bandwidth(result: DemoResult) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.warning("matplotlib is not installed: no bandwidth plot (pip install 'fleetslam[eval]')")
        return None
    if not result.history:
        return None
    t0 = min(h["t"] for h in result.history)
    fig, ax = plt.subplots(figsize=(8, 4), dpi=110)
    series: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for h in result.history:
        series.setdefault((h["topic"], h["subscriber"]), []).append((h["t"] - t0, h["bandwidth_bps"] / 1e3))
    for (topic, subscriber), points in sorted(series.items()):
        xs, ys = zip(*points, strict=True)
        ax.plot(xs, ys, label=f"{topic} → {subscriber}", marker=".", linewidth=1)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("bandwidth (kB/s)")
    ax.set_title("Bandwidth per topic (from /statistics)")
    ax.grid(alpha=0.3)
    # Beside the axes, in as many columns as it takes: a fleet's dozens of topic/subscriber pairs inside the axes
    # hid the curves and left tight_layout no room.
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), ncol=1 + len(series) // 24)
    path = result.out_dir / "bandwidth.png"
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path
