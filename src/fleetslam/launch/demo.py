"""`fleetslam demo`: the fleet on one machine, with the operator console and live network statistics.

``mode="sim"`` (the default): a router, the simulated plant with the robots driving autopilot routes, per robot a
SLAM node and a mapping node (its own processes, its own namespace; the SLAM nodes find each other in their maps and
place themselves in the fleet frame), a fleet map node fusing the robots' maps in that frame (or by their known start
poses with ``known_starts``), and the operator console (a process of its own). ``mode="synthetic"``: agents that
only exchange keyframe graphs (``fleetslam.launch.example_agent``), the seed's network experiment, light enough for
any machine.
At the end it writes the results folder: maps (``maps/<agent>.bt``, ``maps/fleet.bt``), trajectories and ground
truth (TUM; the placed robots' also in the fleet frame, ``fleet_trajectories/``), a recording of the key topics
(rosbag2 + MCAP), ``statistics.json``, ``slam.json`` (each robot's latest ``slam/diagnostics``), ``processes.json``
(CPU and peak memory of every process over the run), ``report.md``/``report.html`` (with each robot's SLAM figures
from its latest ``slam/diagnostics``, per agent pair the first merge and the closures accepted and rejected, per agent
the bytes exchanged per keyframe, the fleet ATE), plots, the operator's findings (``findings/``) and the inspection
report (``inspection/report.html``, ``report.pdf``).

The jobs live in one module each: the process plan (:mod:`~fleetslam.launch.demo_plan`), the monitor
(:mod:`~fleetslam.launch.demo_monitor`) and the results and report (:mod:`~fleetslam.launch.demo_report`); this
module runs them (:func:`run_demo`) and re-exports their names.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from pathlib import Path
from typing import TextIO

import numpy as np
from numpy.typing import NDArray

from fleetslam.inspection.node import FindingsNode
from fleetslam.launch.demo_monitor import (
    Monitor,
    OdometryTrack,
    decoded_stamp_pose,
    odometry_stamp_pose,
    slam_values,
)
from fleetslam.launch.demo_plan import (
    GROUND_TRUTH_BASE_DIR,
    ROBOT_CENTERS,
    agent_processes,
    fleet_env,
    sim_processes,
    start_poses,
    station_process,
)
from fleetslam.launch.demo_report import (
    MISSING,
    SLAM_COLUMNS,
    DemoResult,
    build_report,
    plot_bandwidth,
    plot_trajectories,
    render_html,
    render_markdown,
    true_placements,
    write_fleet_trajectories,
    write_results,
    write_trajectories,
)
from fleetslam.launch.router_process import RouterProcess, accepts_connections
from fleetslam.launch.supervisor import ProcessUsage, Supervisor, sample_process
from fleetslam.middleware import Context, Node
from fleetslam.station.access import new_token

__all__ = [
    "MISSING",
    "ROBOT_CENTERS",
    "SLAM_COLUMNS",
    "DemoResult",
    "Monitor",
    "OdometryTrack",
    "agent_processes",
    "build_report",
    "decoded_stamp_pose",
    "fleet_env",
    "odometry_stamp_pose",
    "plot_bandwidth",
    "plot_trajectories",
    "render_html",
    "render_markdown",
    "run_demo",
    "sim_processes",
    "slam_values",
    "start_poses",
    "station_process",
    "write_fleet_trajectories",
    "write_results",
    "write_trajectories",
]

log = logging.getLogger(__name__)


def run_demo(
    *,
    robots: list[str],
    duration_s: float | None,
    out_dir: Path,
    port: int = 8080,
    router_port: int = 7447,
    headless: bool = False,
    mode: str = "sim",
    resolution: str = "320x240",
    camera_hz: float = 10.0,
    route: str = "loop",
    output: TextIO = sys.stdout,
    stop: threading.Event | None = None,
    secure: bool = False,
    console_token: str | None = None,
    known_starts: bool = False,
) -> DemoResult:
    """Run the demo until ``duration_s`` passes (None: until Ctrl-C) or ``stop`` is set, then write the results
    to ``out_dir``. With ``secure``, a keystore is made in ``out_dir/keys`` and every process joins the router by
    mutual TLS under its access control (docs/security.md). The console's WebSocket asks for ``console_token``
    (random when None); its URL, with the token, is printed once the console accepts connections. Simulated robots
    share a patrol and their maps join the fleet map as their SLAM finds them in each other's maps; with
    ``known_starts`` they start apart and the fleet map is given their start poses instead."""
    stop = stop or threading.Event()
    out_dir.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{router_port}"
    security: Path | None = None
    if secure:
        from fleetslam.middleware.context import MAX_MESSAGE_BYTES
        from fleetslam.security.keystore import init_keystore

        security = (out_dir / "keys").resolve()
        init_keystore(security, agents=robots, stations=["station"], router_port=router_port,
                      max_message_bytes=MAX_MESSAGE_BYTES)  # fmt: skip
        endpoint = f"tls/localhost:{router_port}"
        print(f"[demo] secured: keystore in {security}, router on {endpoint}", file=output, flush=True)
    if mode == "sim":
        print("[demo] preparing the simulated plant", file=output, flush=True)
        processes, extrinsics = sim_processes(
            robots, endpoint, out_dir, resolution, camera_hz, route, security, known_starts=known_starts
        )
    else:
        processes, extrinsics = agent_processes(robots, endpoint, security), {}
    own_env = fleet_env(endpoint, security, "station")
    console_url = None
    if not headless:
        token = console_token or new_token()
        processes.append(station_process(own_env, port, token))
        console_url = f"http://127.0.0.1:{port}/?token={token}"
    with RouterProcess(endpoint, security=security) as router:
        log_file = open(out_dir / "processes.log", "w")  # noqa: SIM115
        supervisor = Supervisor(processes, output=log_file)
        with Context(namespace="/", environ={**os.environ, **own_env}) as ctx:
            monitor = Monitor(ctx, robots, out_dir / "recording" if mode == "sim" else None)
            findings = FindingsNode(ctx, out_dir / "findings")  # the operator's findings, served to every console
            start = time.monotonic()
            own_start = sample_process(os.getpid())
            supervisor_thread = threading.Thread(target=supervisor.run, kwargs={"poll_interval_s": 0.2}, daemon=True)
            supervisor_thread.start()
            try:
                while duration_s is None or time.monotonic() - start < duration_s:
                    if stop.wait(1.0):
                        print("[demo] stopping", file=output, flush=True)
                        break
                    if console_url is not None and accepts_connections("127.0.0.1", port):
                        print(f"operator console: {console_url}", file=output, flush=True)
                        console_url = None
                    elapsed = time.monotonic() - start
                    with monitor.lock:
                        totals = monitor.table.per_agent()
                        frames = {k: len(v) for k, v in monitor.tracks.items() if k.endswith("/slam")}
                    summary = ", ".join(
                        f"{agent}: {t['bandwidth_bps'] / 1e3:.1f} kB/s, {int(t['dropped'])} dropped"
                        for agent, t in sorted(totals.items())
                    )
                    poses = ", ".join(f"{k.split('/')[0]} {n} poses" for k, n in sorted(frames.items()))
                    total = f"/{duration_s:.0f}" if duration_s else ""
                    print(f"[demo {elapsed:5.0f}{total} s] {summary or 'waiting for statistics'} {poses}",
                          file=output, flush=True)  # fmt: skip
            except KeyboardInterrupt:
                print("[demo] stopping", file=output, flush=True)
            # The run's figures, before saving the maps and stopping adds work of its own.
            usage = supervisor.usage()
            own_end = sample_process(os.getpid())
            if own_start is not None and own_end is not None:
                usage.insert(0, ProcessUsage.between("demo (monitor)", os.getpid(), own_start, own_end))
            router_usage = router.usage()
            if router_usage is not None:
                usage.insert(1, router_usage)
            final = _final_trajectories(monitor.node, robots, output) if mode == "sim" else {}
            if mode == "sim":
                _save_maps(monitor.node, robots, output)
            supervisor.stop()
            supervisor_thread.join(10)
            log_file.close()
            findings.close()
            monitor.close()
            elapsed = time.monotonic() - start
    with monitor.lock:
        rows = monitor.table.totals()
    result = DemoResult(out_dir, elapsed, rows, monitor.history, processes=usage)
    if mode == "sim":
        live = {key.replace("/slam", "/live"): track for key, track in monitor.trajectories().items()}
        # The final trajectory where SLAM answered, else (with a warning, printed) the live one stands in for it.
        final_tracks = {f"{robot}/slam": final.get(robot, live[f"{robot}/live"]) for robot in robots}
        tracks = {**live, **final_tracks, **simulator_ground_truth(out_dir / GROUND_TRUTH_BASE_DIR, robots)}
        ate = write_trajectories(tracks, robots, out_dir, extrinsics)
        result.ate, result.ate_live = ate["slam"], ate["live"]
        result.plots.append(plot_trajectories(robots, out_dir))
        diagnostics = monitor.slam_diagnostics()
        result.slam = {robot: diagnostics.get(robot) for robot in robots}
        result.placements = monitor.placements()
        result.placed_stamps = monitor.placement_stamps()
        result.true_placements = true_placements(out_dir)
        if result.placements:
            result.fleet = write_fleet_trajectories(out_dir, result.placements, result.placed_stamps)
    write_results(result)
    _write_inspection_report(out_dir, output)
    return result


def simulator_ground_truth(
    folder: Path, robots: list[str]
) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Stamps and 4×4 base_link poses per ``<robot>/truth``, as the simulator wrote them (``sim run
    --ground-truth``); a robot whose file is missing or unreadable is left out, with a warning."""
    from fleetslam.errors import DatasetError
    from fleetslam.trajectory import read_tum

    out = {}
    for robot in robots:
        try:
            truth = read_tum(folder / f"{robot}.txt")
        except DatasetError as err:
            log.warning("no ground truth for %s: %s", robot, err)
            continue
        out[f"{robot}/truth"] = (truth.stamps, truth.poses)
    return out


def _write_inspection_report(out_dir: Path, output: TextIO) -> None:
    """The inspection report (findings, coverage, accuracy, network) in ``out_dir/inspection``: HTML, and a PDF
    where Chromium is installed."""
    from fleetslam.errors import FleetslamError
    from fleetslam.inspection.report import ReportError, write_inspection_report

    try:
        html, pdf = write_inspection_report(out_dir)
    except ReportError as err:
        print(f"[demo] inspection report: {err}", file=output, flush=True)
        return
    except FleetslamError as err:
        print(f"[demo] no inspection report: {err}", file=output, flush=True)
        return
    print(f"[demo] inspection report: {pdf or html}", file=output, flush=True)


def _final_trajectories(
    node: Node, robots: list[str], output: TextIO
) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Per robot, stamps and 4×4 camera poses of its SLAM trajectory as the run ends (``slam/trajectory``); a robot
    whose SLAM does not answer is left out (its live poses stand in, and the output says so)."""
    from fleetslam.msg.conversions import pose_matrix
    from fleetslam.msg.typesys import get_type, ns_from_stamp

    out = {}
    request = get_type("fleetslam_msgs/srv/GetTrajectory_Request")()
    for robot in robots:
        client = node.create_client("fleetslam_msgs/srv/GetTrajectory", f"/{robot}/slam/trajectory")
        try:
            response = client.call(request, timeout=60.0)
        except Exception as err:
            print(f"[demo] {robot}: no final trajectory ({err}); its live poses stand in", file=output, flush=True)
            continue
        if not response.success or not response.trajectory.poses:
            print(f"[demo] {robot}: no final trajectory ({response.message}); its live poses stand in",
                  file=output, flush=True)  # fmt: skip
            continue
        poses = response.trajectory.poses
        stamps = np.array([ns_from_stamp(p.header.stamp) / 1e9 for p in poses])
        out[robot] = (stamps, np.stack([pose_matrix(p.pose) for p in poses]))
        print(f"[demo] {robot}: final trajectory, {response.message}", file=output, flush=True)
    return out


def _save_maps(node: Node, robots: list[str], output: TextIO) -> None:
    """Ask every map node to save its map as ``<name>.bt`` in its maps directory (the demo's ``maps/``)."""
    from fleetslam.msg.typesys import get_type

    request = get_type("fleetslam_msgs/srv/SaveMap_Request")
    for name, service in [*((r, f"/{r}/map/save") for r in robots), ("fleet", "/fleet/map/save")]:
        client = node.create_client("fleetslam_msgs/srv/SaveMap", service)
        client.wait_for_service(10.0)  # a client made now may not see the service yet
        for attempt in (1, 2):  # a node rebuilding its map on a loaded machine may answer after the first timeout
            try:
                response = client.call(request(path=f"{name}.bt"), timeout=30.0)
                print(f"[demo] map {name}: {response.message} -> {response.path}", file=output, flush=True)
                break
            except Exception as err:  # a node that never got data answers late or not at all
                print(f"[demo] map {name} not saved (attempt {attempt}): {err}", file=output, flush=True)
