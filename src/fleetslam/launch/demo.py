"""`fleetslam demo`: the fleet on one machine, with the operator console and live network statistics.

``mode="sim"`` (the default): a router, the simulated plant with the robots driving autopilot routes, per robot a
SLAM node and a mapping node (its own processes, its own namespace), a fleet map node fusing the robots' maps
from their known start poses, and the operator console (a process of its own). ``mode="synthetic"``: agents that
only exchange keyframe graphs (``fleetslam.launch.example_agent``), the seed's network experiment, light enough for
any machine.
At the end it writes the results folder: maps (``maps/<agent>.bt``, ``maps/fleet.bt``), trajectories and ground
truth (TUM), a recording of the key topics (rosbag2 + MCAP), ``statistics.json``, ``slam.json`` (each robot's
latest ``slam/diagnostics``), ``processes.json`` (CPU and peak memory of every process over the run),
``report.md``/``report.html`` (with each robot's SLAM figures from its latest ``slam/diagnostics``) and plots.
"""

from __future__ import annotations

import json
import logging
import os
import struct
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import quat_to_matrix
from fleetslam.launch.description import ProcessSpec, RestartPolicy
from fleetslam.launch.router_process import RouterProcess, accepts_connections
from fleetslam.launch.supervisor import ProcessUsage, Supervisor, sample_process
from fleetslam.middleware import Context, Node
from fleetslam.middleware.recording import BagWriter
from fleetslam.middleware.stats_table import StatsRow, StatsTable
from fleetslam.station.access import new_token
from fleetslam.topics import GRAPH, GROUND_TRUTH_ODOM, ODOM, SLAM_DIAGNOSTICS, SLAM_ODOM, STATISTICS, Topic

log = logging.getLogger(__name__)

#: Where each demo robot drives (centre of its circle), so the two agents' maps sit side by side.
ROBOT_CENTERS = [(0.0, 0.0), (8.0, 0.0), (0.0, 8.0), (8.0, 8.0)]


@dataclass
class DemoResult:
    """What a demo run measured."""

    out_dir: Path
    duration_s: float
    rows: list[StatsRow]
    history: list[dict[str, Any]] = field(default_factory=list)
    ate: dict[str, float] = field(default_factory=dict)
    """ATE RMSE (m) per robot, SLAM against ground truth."""
    plots: list[Path | None] = field(default_factory=list)
    """Extra figures for the report."""
    processes: list[ProcessUsage] = field(default_factory=list)
    """CPU and peak memory of every process over the run, the demo's own first."""
    slam: dict[str, dict[str, str] | None] = field(default_factory=dict)
    """Per robot, the values of its latest SLAM diagnostics (None: it never published any)."""

    def per_agent(self) -> dict[str, dict[str, float]]:
        totals: dict[str, dict[str, float]] = {}
        for row in self.rows:
            t = totals.setdefault(row.agent, {"bandwidth_bps": 0.0, "delivered": 0, "dropped": 0})
            t["bandwidth_bps"] += row.bandwidth_bps
            t["delivered"] += row.delivered
            t["dropped"] += row.dropped
        return totals


def _fleet_env(router: str, security: Path | None, identity: str | None = None) -> dict[str, str]:
    """How a demo process joins: the router's endpoint, and with a keystore its folder and the identity it uses
    (agents default to their own, from FLEETSLAM_AGENT)."""
    if security is None:
        return {"FLEETSLAM_ROUTER": router, "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0"}
    env = {"FLEETSLAM_ROUTER": router, "FLEETSLAM_SECURITY": str(security)}
    return {**env, "FLEETSLAM_IDENTITY": identity} if identity else env


def _agent_processes(robots: list[str], router: str, security: Path | None = None) -> list[ProcessSpec]:
    processes = []
    for i, robot in enumerate(robots):
        peers = [r for r in robots if r != robot]
        cx, cy = ROBOT_CENTERS[i % len(ROBOT_CENTERS)]
        processes.append(
            ProcessSpec(
                label=f"{robot}/agent",
                host="localhost",
                argv=[
                    sys.executable,
                    "-m",
                    "fleetslam.launch.example_agent",
                    "--peers",
                    *peers,
                    "--center",
                    str(cx),
                    str(cy),
                ],
                environment={**_fleet_env(router, security), "FLEETSLAM_AGENT": robot},
                restart=RestartPolicy(initial_backoff_s=1.0),
            )
        )
    return processes


def _fleetslam(*args: str) -> list[str]:
    return [sys.executable, "-m", "fleetslam.cli.main", *args]


def start_poses(robots: list[str]) -> tuple[dict[str, list[float]], dict[str, Any]]:
    """Each robot's camera pose at start in the world, [x, y, z, roll, pitch, yaw] (where its SLAM map sits),
    and its camera extrinsics T_base_link_optical (to compare SLAM camera poses with base ground truth)."""
    from scipy.spatial.transform import Rotation

    from fleetslam.sim.config import SimConfig
    from fleetslam.sim.plant import Plant

    config = SimConfig()
    placements = [p for p in config.robots if p.name in robots]
    poses = {}
    extrinsics = {}
    with Plant(config, placements, controllers=False) as plant:
        for name in plant.robot_names:
            pose = plant.camera_pose(name)
            rpy = Rotation.from_matrix(pose[:3, :3]).as_euler("xyz")
            poses[name] = [*pose[:3, 3].tolist(), *rpy.tolist()]
            extrinsics[name] = plant.camera_extrinsics(name)
    return poses, extrinsics


#: The map nodes' numba kernels on one thread: with seven processes on two cores, a parallel region waits for a
#: thread that another process holds (a 2.5 ms scan took 5-50 ms), and OpenMP's idle threads spin.
_ONE_NUMBA_THREAD = {"NUMBA_NUM_THREADS": "1"}
#: The map nodes yield the CPU to SLAM and the simulated sensors: a map that lags a second costs nothing, a SLAM
#: node starved while they compile their kernels at start dropped frames and drifted through its first lap.
_MAP_NICENESS = 10


def _station_process(env: dict[str, str], port: int, token: str) -> ProcessSpec:
    """The operator console in a process of its own: its encoding and WebSocket traffic are not the monitor's to
    pay for (the report shows each), and a console that fails restarts without stopping the demo (with the same
    token, so an open page reconnects)."""
    return ProcessSpec(label="station", host="localhost", argv=_fleetslam("station", "--port", str(port)),
                       environment={**env, "FLEETSLAM_STATION_TOKEN": token}, restart=RestartPolicy())  # fmt: skip


def _sim_processes(
    robots: list[str],
    router: str,
    out_dir: Path,
    resolution: str,
    camera_hz: float = 10.0,
    route: str = "loop",
    security: Path | None = None,
) -> tuple[list[ProcessSpec], dict[str, Any]]:
    env = _fleet_env(router, security)
    # The fleet map and the simulator (every robot's sensors, /clock) act for the whole fleet: the station's identity.
    fleet_env = _fleet_env(router, security, "station")
    maps_dir = f"maps_dir={(out_dir / 'maps').resolve()}"  # the only place the save services write to
    processes = []
    for robot in robots:
        agent_env = {**env, "FLEETSLAM_AGENT": robot}
        peers = "[" + ",".join(r for r in robots if r != robot) + "]"
        # One BLAS thread: the SLAM node's matrices are small, and on two cores extra threads only contend.
        processes.append(ProcessSpec(label=f"{robot}/slam", host="localhost",
                                     argv=_fleetslam("slam", "node", "--set", f"peers={peers}", "--set", maps_dir),
                                     environment={**agent_env, "OPENBLAS_NUM_THREADS": "1"},
                                     restart=RestartPolicy()))  # fmt: skip
        processes.append(ProcessSpec(label=f"{robot}/mapping", host="localhost",
                                     argv=_fleetslam("map", "node", "--set", maps_dir),
                                     environment={**agent_env, **_ONE_NUMBA_THREAD},
                                     restart=RestartPolicy(), niceness=_MAP_NICENESS))  # fmt: skip
    fleet_config = out_dir / "fleet_map.yaml"
    import yaml

    poses, extrinsics = start_poses(robots)
    fleet_config.write_text(
        yaml.safe_dump({"start_poses": poses, "agents": robots, "maps_dir": str((out_dir / "maps").resolve())})
    )
    processes.append(ProcessSpec(label="fleet_map", host="localhost",
                                 argv=_fleetslam("fleet", "node", "--config", str(fleet_config)),
                                 environment={**fleet_env, **_ONE_NUMBA_THREAD}, restart=RestartPolicy(),
                                 niceness=_MAP_NICENESS))  # fmt: skip
    processes.append(ProcessSpec(label="sim", host="localhost",
                                 argv=_fleetslam("sim", "run", "--robots", ",".join(robots), "--camera-hz",
                                                 f"{camera_hz:g}", "--resolution", resolution, "--autopilot", route,
                                                 "--laps"),
                                 environment={**fleet_env, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")},
                                 restart=RestartPolicy()))  # fmt: skip
    return processes, extrinsics


_STAMP = struct.Struct("<iI")
_LENGTH = struct.Struct("<I")
_POSE = struct.Struct("<7d")


def odometry_stamp_pose(data: bytes) -> tuple[float, NDArray[np.float64]]:
    """Stamp (s) and pose (x, y, z, qx, qy, qz, qw) of a nav_msgs/Odometry in CDR, read where CDR puts them.

    The monitor keeps the ground truth at the physics rate; a full decode (every covariance, every nested message)
    costs some 70 µs, this about 2. Little-endian CDR (what every node sends) is read directly, anything else
    decoded in full. Offsets count from the end of the 4-byte encapsulation header, aligned to each field's size.
    """
    if len(data) < 16 or data[1] != 1:
        return _decoded_stamp_pose(data)
    sec, nanosec = _STAMP.unpack_from(data, 4)
    offset = 8  # header.frame_id: length (with its NUL), characters
    offset += 4 + _LENGTH.unpack_from(data, 4 + offset)[0]
    offset = (offset + 3) & ~3  # child_frame_id
    offset += 4 + _LENGTH.unpack_from(data, 4 + offset)[0]
    offset = (offset + 7) & ~7  # pose.pose: position, orientation (float64)
    if 4 + offset + _POSE.size > len(data):
        return _decoded_stamp_pose(data)
    return sec + nanosec * 1e-9, np.array(_POSE.unpack_from(data, 4 + offset))


def _decoded_stamp_pose(data: bytes) -> tuple[float, NDArray[np.float64]]:
    from fleetslam.msg.typesys import deserialize, ns_from_stamp

    msg = deserialize(data, "nav_msgs/msg/Odometry")
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return ns_from_stamp(msg.header.stamp) / 1e9, np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w])


class _OdometryTrack:
    """Stamps and poses of one nav_msgs/Odometry topic, as compact arrays."""

    def __init__(self) -> None:
        self._stamps: list[float] = []
        self._poses: list[NDArray[np.float64]] = []

    def add(self, data: bytes) -> None:
        stamp, pose = odometry_stamp_pose(data)
        self._stamps.append(stamp)
        self._poses.append(pose)

    def __len__(self) -> int:
        return len(self._stamps)

    def samples(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Stamps (s, arrival order) and 4×4 poses."""
        poses = np.tile(np.eye(4), (len(self._poses), 1, 1))
        if self._poses:
            xyzq = np.stack(self._poses)
            poses[:, :3, :3] = quat_to_matrix(xyzq[:, 3:])
            poses[:, :3, 3] = xyzq[:, :3]
        return np.array(self._stamps), poses


class _Monitor:
    """The demo's own node: statistics, trajectories, each robot's latest SLAM diagnostics and the recording of
    the key topics.

    Built to stay light: one raw subscription per topic; the bytes are recorded as received, only the stamp and pose
    of the odometry are read (:func:`odometry_stamp_pose`), and only the latest diagnostics message is kept, decoded
    when asked for.
    """

    def __init__(self, ctx: Context, robots: list[str], recording: Path | None) -> None:
        self.node = Node("demo_monitor", context=ctx, statistics_period_s=0)
        self.table = StatsTable(stale_s=1e9)
        self.history: list[dict[str, Any]] = []
        self.tracks: dict[str, _OdometryTrack] = {
            f"{r}/{k}": _OdometryTrack() for r in robots for k in ("slam", "truth")
        }
        self._diagnostics: dict[str, bytes] = {}
        self.lock = threading.Lock()
        self.writer = BagWriter(recording) if recording is not None else None
        self.node.create_subscription(
            STATISTICS.type, STATISTICS.name, self._on_statistics, STATISTICS.qos(depth=1000), raw=True
        )
        for robot in robots:
            followed: list[tuple[Topic, _OdometryTrack | None]] = [
                (SLAM_ODOM, self.tracks[f"{robot}/slam"]),
                (GROUND_TRUTH_ODOM, self.tracks[f"{robot}/truth"]),
            ]
            if self.writer is not None:  # recorded only
                followed += [(ODOM, None), (GRAPH, None)]
            for topic, track in followed:
                self.node.create_subscription(topic.type, topic.of(robot), partial(self._on_sample, track),
                                              topic.qos(depth=100), raw=True)  # fmt: skip
            self.node.create_subscription(
                SLAM_DIAGNOSTICS.type, SLAM_DIAGNOSTICS.of(robot), partial(self._on_diagnostics, robot),
                SLAM_DIAGNOSTICS.qos(depth=1), raw=True,
            )  # fmt: skip

    def _on_statistics(self, data: bytes, info: Any) -> None:
        from fleetslam.msg.typesys import deserialize

        msg = deserialize(data, info.type_name)
        with self.lock:
            row = self.table.update(msg)
            self.history.append({"t": time.time(), "agent": row.agent, "topic": row.topic,
                                 "subscriber": row.node_sub, "bandwidth_bps": row.bandwidth_bps})  # fmt: skip
        if self.writer is not None:
            self.writer.write(info.topic, info.type_name, info.received_timestamp_ns, data)

    def _on_sample(self, track: _OdometryTrack | None, data: bytes, info: Any) -> None:
        if self.writer is not None:
            self.writer.write(info.topic, info.type_name, info.received_timestamp_ns, data)
        if track is not None:
            with self.lock:
                track.add(data)

    def _on_diagnostics(self, robot: str, data: bytes, info: Any) -> None:
        with self.lock:
            self._diagnostics[robot] = data

    def trajectories(self) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """Stamps and 4×4 poses per ``<robot>/slam`` and ``<robot>/truth``."""
        with self.lock:
            return {key: track.samples() for key, track in self.tracks.items()}

    def slam_diagnostics(self) -> dict[str, dict[str, str]]:
        """The values of each robot's latest ``slam`` diagnostics status (robots that sent none are absent)."""
        from fleetslam.msg.typesys import deserialize

        with self.lock:
            latest = dict(self._diagnostics)
        out = {}
        for robot, data in latest.items():
            values = slam_values(deserialize(data, "diagnostic_msgs/msg/DiagnosticArray"))
            if values is not None:
                out[robot] = values
        return out

    def close(self) -> None:
        self.node.destroy()
        if self.writer is not None:
            self.writer.close()


def slam_values(msg: Any) -> dict[str, str] | None:
    """Key → value of the DiagnosticStatus named ``slam`` in a diagnostic_msgs/DiagnosticArray (None if absent)."""
    for status in msg.status:
        if status.name == "slam":
            return {kv.key: kv.value for kv in status.values}
    return None


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
) -> DemoResult:
    """Run the demo until ``duration_s`` passes (None: until Ctrl-C) or ``stop`` is set, then write the results
    to ``out_dir``. With ``secure``, a keystore is made in ``out_dir/keys`` and every process joins the router by
    mutual TLS under its access control (docs/security.md). The console's WebSocket asks for ``console_token``
    (random when None); its URL, with the token, is printed once the console accepts connections."""
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
        processes, extrinsics = _sim_processes(robots, endpoint, out_dir, resolution, camera_hz, route, security)
    else:
        processes, extrinsics = _agent_processes(robots, endpoint, security), {}
    own_env = _fleet_env(endpoint, security, "station")
    console_url = None
    if not headless:
        token = console_token or new_token()
        processes.append(_station_process(own_env, port, token))
        console_url = f"http://127.0.0.1:{port}/?token={token}"
    with RouterProcess(endpoint, security=security) as router:
        log_file = open(out_dir / "processes.log", "w")  # noqa: SIM115
        supervisor = Supervisor(processes, output=log_file)
        with Context(namespace="/", environ={**os.environ, **own_env}) as ctx:
            monitor = _Monitor(ctx, robots, out_dir / "recording" if mode == "sim" else None)
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
            if mode == "sim":
                _save_maps(monitor.node, robots, output)
            supervisor.stop()
            supervisor_thread.join(10)
            log_file.close()
            monitor.close()
            elapsed = time.monotonic() - start
    with monitor.lock:
        rows = monitor.table.rows()
    result = DemoResult(out_dir, elapsed, rows, monitor.history, processes=usage)
    if mode == "sim":
        result.ate = _write_trajectories(monitor.trajectories(), robots, out_dir, extrinsics)
        result.plots.append(_plot_trajectories(robots, out_dir))
        diagnostics = monitor.slam_diagnostics()
        result.slam = {robot: diagnostics.get(robot) for robot in robots}
    write_results(result)
    return result


def _save_maps(node: Node, robots: list[str], output: TextIO) -> None:
    """Ask every map node to save its map as ``<name>.bt`` in its maps directory (the demo's ``maps/``)."""
    from fleetslam.msg.typesys import get_type

    request = get_type("fleetslam_msgs/srv/SaveMap_Request")
    for name, service in [*((r, f"/{r}/map/save") for r in robots), ("fleet", "/fleet/map/save")]:
        client = node.create_client("fleetslam_msgs/srv/SaveMap", service)
        try:
            response = client.call(request(path=f"{name}.bt"), timeout=30.0)
            print(f"[demo] map {name}: {response.message} -> {response.path}", file=output, flush=True)
        except Exception as err:  # a node that never got data answers late or not at all
            print(f"[demo] map {name} not saved: {err}", file=output, flush=True)


def _write_trajectories(
    trajectories: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]],
    robots: list[str],
    out_dir: Path,
    extrinsics: dict[str, Any],
) -> dict[str, float]:
    """TUM files of every robot's SLAM and ground-truth camera trajectory, and the ATE (m) of each."""
    from fleetslam.trajectory import Trajectory, write_tum

    ate: dict[str, float] = {}
    for robot in robots:
        tracks = {}
        for kind, folder in (("slam", "trajectories"), ("truth", "ground_truth")):
            stamps, poses = trajectories.get(f"{robot}/{kind}", (np.zeros(0), np.zeros((0, 4, 4))))
            if kind == "truth" and robot in extrinsics:  # base_link ground truth → camera optical frame
                poses = poses @ extrinsics[robot]
            tracks[kind] = Trajectory.from_lists(stamps.tolist(), list(poses))
            write_tum(out_dir / folder / f"{robot}.txt", tracks[kind])
        if len(tracks["slam"]) >= 3 and len(tracks["truth"]) >= 3:
            try:
                from fleetslam.eval import ape

                ate[robot] = float(ape(tracks["truth"], tracks["slam"], align=True, max_diff=0.1).rmse)
            except Exception as err:
                log.warning("ATE of %s: %s", robot, err)
    return ate


#: The SLAM diagnostics in the report's per-robot table: (column, key of the ``slam`` DiagnosticStatus).
SLAM_COLUMNS = (
    ("frames received", "frames_received"), ("processed", "frames_processed"), ("dropped", "frames_dropped"),
    ("relocalisations", "relocalisations"), ("loop closures", "loop_closures"),
    ("loops retracted", "loops_retracted"), ("keyframes", "keyframes"),
    ("lost frames", "lost_frames"), ("coasting frames", "coasting_frames"), ("odometry ms (mean)", "odometry_ms_mean"),
)  # fmt: skip
MISSING = "—"


def slam_table(slam: Mapping[str, Mapping[str, str] | None], ate: Mapping[str, float]) -> list[str]:
    """Report lines: per robot its latest SLAM diagnostics and its ATE; "—" where a robot has no figure."""
    robots = sorted(set(slam) | set(ate))
    if not robots:
        return []
    lines = ["", "## SLAM per robot", "",
             "Counts since the SLAM node started (its latest `slam/diagnostics`); ATE: SLAM against ground truth, "
             "SE(3)-aligned, translation RMSE.", "",
             "| robot | " + " | ".join(c for c, _ in SLAM_COLUMNS) + " | ATE RMSE (m) |",
             "|---|" + "---:|" * (len(SLAM_COLUMNS) + 1)]  # fmt: skip
    for robot in robots:
        values = slam.get(robot) or {}
        cells = [values.get(key, MISSING) for _, key in SLAM_COLUMNS]
        cells.append(f"{ate[robot]:.3f}" if robot in ate else MISSING)
        lines.append(f"| {robot} | " + " | ".join(cells) + " |")
    return lines


def process_table(processes: Sequence[ProcessUsage]) -> list[str]:
    """Report lines: CPU (% of one core, averaged over the run) and peak memory of every process."""
    if not processes:
        return []
    lines = ["", "## Processes", "",
             "CPU: % of one core, averaged over each process's life until the end of the run (the demo's own "
             "process: over the run). Peak RSS: the most resident memory it held.", "",
             "| process | pid | CPU % | CPU s | peak RSS (MiB) | restarts |",
             "|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    for p in processes:
        lines.append(f"| {p.label} | {p.pid if p.pid is not None else MISSING} | {p.cpu_percent:.1f} | "
                     f"{p.cpu_s:.1f} | {p.peak_rss_mib:.0f} | {p.restarts} |")  # fmt: skip
    return lines


def write_results(result: DemoResult) -> None:
    """statistics.json, processes.json, report.md/report.html and the plots in the output folder."""
    out = result.out_dir
    (out / "statistics.json").write_text(json.dumps([r.as_dict() for r in result.rows], indent=1))
    (out / "processes.json").write_text(json.dumps([p.as_dict() for p in result.processes], indent=1))
    (out / "slam.json").write_text(json.dumps(result.slam, indent=1))
    lines = [
        "# fleetslam demo report",
        "",
        f"Run of {result.duration_s:.0f} s. Latest statistics window per topic and subscriber:",
        "",
        "| agent | topic | publisher → subscriber | kB/s | Hz | delivered | dropped | age ms (mean ± std) |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in result.rows:
        lines.append(
            f"| {r.agent} | {r.topic} | {r.node_pub} → {r.node_sub} | {r.bandwidth_bps / 1e3:.1f} | {r.rate_hz:.1f} "
            f"| {r.delivered} | {r.dropped} | {r.age_mean_ms:.2f} ± {r.age_std_ms:.2f} |"
        )
    maps = sorted((out / "maps").glob("*.bt")) if (out / "maps").is_dir() else []
    if maps:
        from fleetslam.mapping.octree import OccupancyOctree

        lines += ["", "## Maps", "", "| map | nodes | leaves | occupied leaves | free leaves | extent (m) |",
                  "|---|---:|---:|---:|---:|---|"]  # fmt: skip
        for path in maps:
            tree = OccupancyOctree.read(path)
            occupied, _ = tree.occupied_centers()
            free, _ = tree.free_centers()
            lo, hi = tree.metric_bounds()
            extent = " × ".join(f"{v:.1f}" for v in (hi - lo))
            lines.append(f"| {path.name} | {tree.num_nodes()} | {tree.num_leaf_nodes()} | {len(occupied)} | "
                         f"{len(free)} | {extent} |")  # fmt: skip
    lines += slam_table(result.slam, result.ate)
    lines += process_table(result.processes)
    lines += ["", "## Per agent", "", "| agent | kB/s | delivered | dropped |", "|---|---:|---:|---:|"]
    for agent, t in sorted(result.per_agent().items()):
        lines.append(f"| {agent} | {t['bandwidth_bps'] / 1e3:.1f} | {int(t['delivered'])} | {int(t['dropped'])} |")
    for plot in [*result.plots, _plot_bandwidth(result)]:
        if plot is not None:
            lines += ["", f"![{plot.stem}]({plot.name})"]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    (out / "report.html").write_text(_markdown_to_html(lines))


def _markdown_to_html(lines: list[str]) -> str:
    """The report's markdown (headings, tables, images, text) as a standalone HTML page."""
    import html

    body: list[str] = []
    in_table = False
    for line in lines:
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if all(set(c) <= set("-:") for c in cells):
                continue
            if not in_table:
                body.append("<table>")
                in_table = True
                body.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in cells) + "</tr>")
            else:
                body.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
            continue
        if in_table:
            body.append("</table>")
            in_table = False
        if line.startswith("## "):
            body.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif line.startswith("# "):
            body.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("!["):
            alt, src = line[2:].split("](", 1)
            body.append(f'<img alt="{html.escape(alt)}" src="{html.escape(src.rstrip(")"))}">')
        elif line:
            body.append(f"<p>{html.escape(line)}</p>")
    if in_table:
        body.append("</table>")
    style = (
        "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 8px}"
    )
    return f"<!doctype html><meta charset=utf-8><title>fleetslam demo</title><style>{style}</style>" + "\n".join(body)


def _plot_trajectories(robots: list[str], out_dir: Path) -> Path | None:
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
    fleet_map = out_dir / "maps" / "fleet.bt"
    if fleet_map.is_file():
        centres, _ = OccupancyOctree.read(fleet_map).occupied_centers()
        band = centres[(centres[:, 2] > 0.1) & (centres[:, 2] < 1.5)]
        ax.scatter(band[:, 0], band[:, 1], s=0.3, c="0.6", label="fleet map (occupied, 0.1–1.5 m)")
    starts = yaml.safe_load((out_dir / "fleet_map.yaml").read_text()).get("start_poses", {})
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


def _plot_bandwidth(result: DemoResult) -> Path | None:
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
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = result.out_dir / "bandwidth.png"
    fig.savefig(path)
    plt.close(fig)
    return path
