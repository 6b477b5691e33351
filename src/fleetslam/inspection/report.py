"""The inspection report of a run (``fleetslam report DIR``): ``report.html`` and ``report.pdf``.

Read from what the run's directory already holds: the findings (``findings/findings.json`` and their photos), the
maps (``maps/*.bt``), the trajectories (``trajectories/``, ``ground_truth/`` in TUM format), where each robot was
placed in the fleet frame (``fleet_frame.json``), SLAM's figures (``slam.json``) and the network's
(``statistics.json``). Anything missing is left out of the report, never invented.

The page holds a map overview with the findings numbered, one section per finding (photo, crop, position in the
fleet frame, robot, time, severity, status, note), the coverage, each robot's accuracy and the network's figures.
The HTML is self-contained (images inline); the PDF is Chromium's print of it (headless, ``--print-to-pdf``).
"""

from __future__ import annotations

import base64
import datetime as dt
import io
import logging
import os
import shutil
import subprocess
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.errors import FleetslamError
from fleetslam.inspection.findings import SEVERITIES, Finding, FindingStore
from fleetslam.inspection.run_folder import load_json, occupied_centres, read_placements, read_trajectories

log = logging.getLogger(__name__)

__all__ = ["InspectionReport", "ReportError", "build_report", "print_pdf", "render_html", "write_inspection_report"]

MISSING = "—"
SIMULATED_CLOCK_BEFORE_NS = 10**18
"""Stamps before this (September 2001) are a simulated clock's, counted from the simulation's start."""
CHROMIUM_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class ReportError(FleetslamError):
    """The report could not be made (no run directory, no browser to print the PDF, the browser failed)."""


@dataclass(frozen=True)
class ReportFinding:
    """A finding as the report shows it."""

    number: int
    finding: Finding
    where: str
    """Position text: in the fleet frame, else in the robot's map (said so), else unknown."""
    time: str
    photo: str
    """``data:`` URL of the photo ("" without one)."""
    crop: str


@dataclass(frozen=True)
class Table:
    columns: Sequence[str]
    rows: list[list[str]] = field(default_factory=list)


@dataclass
class InspectionReport:
    """Everything the report shows, built from a run's directory by :func:`build_report`."""

    title: str
    run: str
    created: str
    findings: list[ReportFinding]
    overview: str
    """``data:`` URL of the map overview PNG ("" when there is nothing to draw or no matplotlib)."""
    summary: Table
    coverage: Table
    accuracy: Table
    network: Table
    notes: list[str] = field(default_factory=list)


def _data_url(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode()}" if data else ""


def _fmt(point: Sequence[float] | NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{c:.2f}" for c in point) + ")"


def _fleet_position(finding: Finding, placements: Mapping[str, NDArray[np.float64]]) -> NDArray[np.float64] | None:
    if finding.fleet_position is not None:
        return np.asarray(finding.fleet_position, dtype=np.float64)
    if finding.position is not None and finding.agent in placements:
        T = placements[finding.agent]
        return np.asarray(T[:3, :3] @ np.asarray(finding.position) + T[:3, 3], dtype=np.float64)
    return None


def levelling_rotation(
    camera_rotations: NDArray[np.float64], positions: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """``R_top_fleet``: the fleet frame turned so that its z is up and its x the cameras' mean heading, for a top-down
    view. The fleet frame is a camera's frame at start (z ahead, y down) and need not be level. "Up" is the normal of
    the plane the cameras moved in when they did (``positions`` spread over a plane: ground robots, whatever their
    cameras' pitch), else the mean of the cameras' −y axes (optical frames: y points down in the image; exact for
    level cameras, a fair guess for hand-held ones). ``camera_rotations``: (N, 3, 3) camera orientations in the fleet
    frame; with none, the optical convention alone (up = −y, ahead = z)."""
    rotations = np.asarray(camera_rotations, dtype=np.float64).reshape(-1, 3, 3)
    up = -rotations[:, :, 1].sum(axis=0) if len(rotations) else np.array([0.0, -1.0, 0.0])
    ahead = rotations[:, :, 2].sum(axis=0) if len(rotations) else np.array([0.0, 0.0, 1.0])
    if np.linalg.norm(up) < 1e-9:
        up = np.array([0.0, -1.0, 0.0])
    up = up / np.linalg.norm(up)
    points = np.asarray(positions, dtype=np.float64).reshape(-1, 3) if positions is not None else np.zeros((0, 3))
    if len(points) >= 10:
        _, spread, axes = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
        spread = spread / np.sqrt(len(points))
        if spread[1] > 0.5 and spread[2] < 0.05 * spread[1]:  # a plane metres wide, centimetres thick
            normal = axes[2]
            up = normal if float(normal @ up) >= 0.0 else -normal
    ahead = ahead - up * float(ahead @ up)
    if np.linalg.norm(ahead) < 1e-9:  # looking straight up or down: any horizontal axis will do
        ahead = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    ahead = ahead / np.linalg.norm(ahead)
    return np.stack([ahead, np.cross(up, ahead), up])


def _overview(
    run: Path,
    numbered: Sequence[tuple[int, Finding, NDArray[np.float64] | None]],
    placements: Mapping[str, NDArray[np.float64]],
    slam: Mapping[str, Any],
) -> bytes:
    """PNG: the fleet map's occupied cells (0.1–1.5 m above the floor), each placed robot's path and the findings,
    numbered, top-down in the fleet frame levelled by :func:`levelling_rotation`."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.warning("matplotlib is not installed: no map overview (pip install 'fleetslam[eval]')")
        return b""
    placed = {robot: t for robot, t in slam.items() if robot in placements and len(t.poses)}
    rotations = [placements[robot][:3, :3] @ t.poses[:, :3, :3] for robot, t in placed.items()]
    positions = [t.positions @ placements[robot][:3, :3].T + placements[robot][:3, 3] for robot, t in placed.items()]
    level = levelling_rotation(
        np.concatenate(rotations) if rotations else np.zeros((0, 3, 3)),
        np.concatenate(positions) if positions else None,
    )
    fleet_map = run / "maps" / "fleet.bt"
    drawn = False
    fig, ax = plt.subplots(figsize=(8, 6), dpi=120)
    if fleet_map.is_file():
        centres = occupied_centres(fleet_map) @ level.T
        if len(centres):  # the floor is the lowest occupied layer (a few stray cells below it aside)
            floor = float(np.percentile(centres[:, 2], 2.0))
            band = centres[(centres[:, 2] > floor + 0.1) & (centres[:, 2] < floor + 1.5)]
            if len(band):
                ax.scatter(band[:, 0], band[:, 1], s=0.4, c="0.55",
                           label="fleet map (occupied, 0.1–1.5 m above the floor)")  # fmt: skip
                drawn = True
    for robot, trajectory in placed.items():
        xy = (trajectory.positions @ placements[robot][:3, :3].T + placements[robot][:3, 3]) @ level.T
        ax.plot(xy[:, 0], xy[:, 1], linewidth=1.2, label=f"{robot} path (SLAM)")
        drawn = True
    colours = {"info": "#4a90c2", "low": "#2e9e5b", "medium": "#d9a400", "high": "#e8612c", "critical": "#d0021b"}
    for number, finding, fleet_point in numbered:
        if fleet_point is None:
            continue
        where = level @ fleet_point
        closed = finding.status == "closed"
        ax.scatter([where[0]], [where[1]], s=140, c="white" if closed else colours.get(finding.severity, "k"),
                   edgecolors="black", linewidths=1.0, zorder=5)  # fmt: skip
        ax.annotate(str(number), (where[0], where[1]), ha="center", va="center", fontsize=7, fontweight="bold",
                    zorder=6)  # fmt: skip
        drawn = True
    if not drawn:
        plt.close(fig)
        return b""
    ax.set_aspect("equal")
    ax.set_xlabel("m (fleet frame, levelled: x along the cameras' mean heading)")
    ax.set_ylabel("m")
    ax.grid(alpha=0.25)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def _coverage(run: Path, slam: Mapping[str, Any]) -> Table:
    table = Table(("map / robot", "occupied voxels", "floor footprint (m²)", "extent x × y (m)", "path (m)"))
    maps = sorted((run / "maps").glob("*.bt")) if (run / "maps").is_dir() else []
    for path in maps:
        try:
            centres = occupied_centres(path)
        except (FleetslamError, OSError, ValueError) as err:
            table.rows.append([path.stem, f"unreadable: {err}", MISSING, MISSING, MISSING])
            continue
        from fleetslam.mapping.octree import OccupancyOctree

        resolution = OccupancyOctree.read(path).resolution
        cells = {tuple(c) for c in np.floor(centres[:, :2] / resolution).astype(np.int64).tolist()}
        extent = np.ptp(centres[:, :2], axis=0) if len(centres) else np.zeros(2)
        trajectory = slam.get(path.stem)
        length = MISSING
        if trajectory is not None and len(trajectory.poses) > 1:
            length = f"{np.linalg.norm(np.diff(trajectory.positions, axis=0), axis=1).sum():.1f}"
        table.rows.append([path.stem, str(len(centres)), f"{len(cells) * resolution**2:.1f}",
                           f"{extent[0]:.1f} × {extent[1]:.1f}", length])  # fmt: skip
    return table


def _accuracy(run: Path, slam: Mapping[str, Any], truth: Mapping[str, Any]) -> Table:
    table = Table(("robot", "ATE RMSE (m)", "keyframes", "loop closures", "peer closures", "placement error (m)"))
    figures = load_json(run / "slam.json") or {}
    placed = load_json(run / "fleet_frame.json") or {}
    for robot in sorted(set(slam) | set(figures)):
        ate = MISSING
        if robot in slam and robot in truth and len(slam[robot].poses) >= 3 and len(truth[robot].poses) >= 3:
            try:
                from fleetslam.eval import ape

                ate = f"{ape(truth[robot], slam[robot], align=True, max_diff=0.1).rmse:.3f}"
            except Exception as err:  # evo raises several kinds (too few matches, degenerate alignment)
                log.warning("ATE of %s: %s", robot, err)
        values = figures.get(robot) or {}
        error = MISSING
        entry = placed.get(robot) or {}
        if entry.get("T_fleet_map") is not None and entry.get("true_T_fleet_map") is not None:
            from fleetslam.geometry import invert

            delta = invert(np.asarray(entry["true_T_fleet_map"])) @ np.asarray(entry["T_fleet_map"])
            error = f"{np.linalg.norm(delta[:3, 3]):.3f}"
        table.rows.append([robot, ate, str(values.get("keyframes", MISSING)), str(values.get("loop_closures", MISSING)),
                           str(values.get("peer_closures", MISSING)), error])  # fmt: skip
    return table


def _network(run: Path) -> Table:
    table = Table(("agent", "kB/s", "delivered", "dropped", "busiest topic"))
    rows = load_json(run / "statistics.json") or []
    per_agent: dict[str, dict[str, Any]] = {}
    for row in rows:
        if not isinstance(row, dict):
            continue
        agent = str(row.get("agent") or "(root)")
        totals = per_agent.setdefault(agent, {"bps": 0.0, "delivered": 0, "dropped": 0, "topics": {}})
        totals["bps"] += float(row.get("bandwidth_bps", 0.0))
        totals["delivered"] += int(row.get("delivered", 0))
        totals["dropped"] += int(row.get("dropped", 0))
        topic = str(row.get("topic", ""))
        totals["topics"][topic] = totals["topics"].get(topic, 0.0) + float(row.get("bandwidth_bps", 0.0))
    for agent, t in sorted(per_agent.items()):
        busiest = max(t["topics"].items(), key=lambda kv: kv[1], default=("", 0.0))
        table.rows.append([agent, f"{t['bps'] / 1e3:.1f}", str(t["delivered"]), str(t["dropped"]),
                           f"{busiest[0]} ({busiest[1] / 1e3:.1f} kB/s)" if busiest[0] else MISSING])  # fmt: skip
    return table


def _time_text(stamp_ns: int) -> str:
    """A stamp as a UTC date, or, before 2001, as a simulated clock's seconds since the simulation started."""
    if stamp_ns < SIMULATED_CLOCK_BEFORE_NS:
        return f"t = {stamp_ns / 1e9:.1f} s (simulated clock)"
    return dt.datetime.fromtimestamp(stamp_ns / 1e9, tz=dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def build_report(run: Path) -> InspectionReport:
    """The inspection report of the run in ``run`` (a directory a demo or a session wrote)."""
    if not run.is_dir():
        raise ReportError(f"{run} is not a run directory")
    store = FindingStore.load(run / "findings")
    placements = read_placements(run)
    slam, truth = read_trajectories(run, "trajectories"), read_trajectories(run, "ground_truth")
    numbered: list[tuple[int, Finding, NDArray[np.float64] | None]] = []
    shown: list[ReportFinding] = []
    for number, finding in enumerate(store.findings, start=1):
        in_fleet = _fleet_position(finding, placements)
        numbered.append((number, finding, in_fleet))
        if in_fleet is not None:
            where = f"{_fmt(in_fleet)} m in the fleet frame"
        elif finding.position is not None:
            where = f"{_fmt(finding.position)} m in {finding.agent}'s map (not placed in the fleet frame)"
        else:
            where = "unknown (its keyframe's pose never arrived)"
        when = _time_text(finding.stamp_ns)
        shown.append(ReportFinding(number, finding, where, when, _data_url(finding.photo, "image/jpeg"),
                                   _data_url(finding.crop, "image/jpeg")))  # fmt: skip
    summary = Table(("severity", "open", "closed"))
    for severity in reversed(SEVERITIES):
        counts = [sum(f.severity == severity and f.status == s for f in store.findings) for s in ("open", "closed")]
        if any(counts):
            summary.rows.append([severity, str(counts[0]), str(counts[1])])
    notes = []
    if not store.findings:
        notes.append("No findings were recorded in this run.")
    return InspectionReport(
        title="Inspection report",
        run=run.resolve().name,
        created=dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        findings=shown,
        overview=_data_url(_overview(run, numbered, placements, slam), "image/png"),
        summary=summary,
        coverage=_coverage(run, slam),
        accuracy=_accuracy(run, slam, truth),
        network=_network(run),
        notes=notes,
    )


@cache
def _templates() -> Any:
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("fleetslam.inspection", "templates"),
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )


def render_html(report: InspectionReport) -> str:
    """The report as one self-contained HTML page (texts escaped by the template engine)."""
    text: str = _templates().get_template("inspection.html.j2").render(report=report)
    return text


def find_chromium() -> str | None:
    """The Chromium (or Chrome) to print with: ``$FLEETSLAM_CHROMIUM``, else the first on the PATH."""
    named = os.environ.get("FLEETSLAM_CHROMIUM")
    if named:
        return named
    for name in CHROMIUM_CANDIDATES:
        found = shutil.which(name)
        if found:
            return found
    return None


def print_pdf(html: Path, pdf: Path, *, chromium: str | None = None, timeout_s: float = 120.0) -> Path:
    """Print ``html`` to ``pdf`` with headless Chromium (A4, no header or footer); ReportError naming what failed."""
    browser = chromium or find_chromium()
    if browser is None:
        raise ReportError("no Chromium to print the PDF with: install it (Debian: apt install chromium) or set "
                          "FLEETSLAM_CHROMIUM; report.html is written")  # fmt: skip
    pdf.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="fleetslam-report-") as profile:
        argv = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--no-first-run", "--disable-background-networking", f"--user-data-dir={profile}",
                "--no-pdf-header-footer", f"--print-to-pdf={pdf.resolve()}", html.resolve().as_uri()]  # fmt: skip
        try:
            done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s, check=False)
        except (OSError, subprocess.TimeoutExpired) as err:
            raise ReportError(f"{browser} could not print {html}: {err}") from err
    if not pdf.is_file() or pdf.stat().st_size == 0:
        raise ReportError(f"{browser} printed no PDF (exit {done.returncode}): {done.stderr.strip()[-400:]}")
    return pdf


def write_inspection_report(run: Path, out_dir: Path | None = None, *, pdf: bool = True) -> tuple[Path, Path | None]:
    """Write ``report.html`` (and ``report.pdf`` with ``pdf``) of the run in ``run`` to ``out_dir`` (default:
    ``run/inspection``, beside the demo's own ``report.html``); returns their paths."""
    report = build_report(run)
    out = out_dir or run / "inspection"
    out.mkdir(parents=True, exist_ok=True)
    html = out / "report.html"
    html.write_text(render_html(report), encoding="utf-8")
    return html, print_pdf(html, out / "report.pdf") if pdf else None
