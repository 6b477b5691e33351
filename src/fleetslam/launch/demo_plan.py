"""The demo's process plan: which processes `fleetslam demo` starts, with their command lines, environments,
restart policies and niceness (``mode="sim"``: per robot a SLAM and a mapping node, the fleet map, the simulated
plant; ``mode="synthetic"``: the example agents), and where the simulated robots start."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import Any

from fleetslam.launch.description import ProcessSpec, RestartPolicy

#: Where each demo robot drives (centre of its circle), so the two agents' maps sit side by side.
ROBOT_CENTERS = [(0.0, 0.0), (8.0, 0.0), (0.0, 8.0), (8.0, 8.0)]

#: Where the simulated demo robots start (x, y, yaw in the plant), both in the west hall, when they share a patrol:
#: c3po at the route's start; r2d2 on c3po's own path, as far ahead as the route allows (half a lap on a route that
#: does not cross itself, a quarter on the figure eight: :meth:`~fleetslam.robot.autopilot.Route.second_start`), so
#: that each sees what the other mapped and their SLAM finds them in each other's maps (no start pose is given to the
#: fleet). An open route has no lap to share: r2d2 drives it from the hall's other corner, over the same ground the
#: other way. Robots not listed start where the simulator places them.
SHARED_PATROL_STARTS = {"c3po": (-12.0, -7.5, 0.0), "r2d2": (-7.5, -3.5, math.pi)}


def fleet_env(router: str, security: Path | None, identity: str | None = None) -> dict[str, str]:
    """How a demo process joins: the router's endpoint, and with a keystore its folder and the identity it uses
    (agents default to their own, from FLEETSLAM_AGENT)."""
    if security is None:
        return {"FLEETSLAM_ROUTER": router, "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0"}
    env = {"FLEETSLAM_ROUTER": router, "FLEETSLAM_SECURITY": str(security)}
    return {**env, "FLEETSLAM_IDENTITY": identity} if identity else env


def agent_processes(robots: list[str], router: str, security: Path | None = None) -> list[ProcessSpec]:
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
                environment={**fleet_env(router, security), "FLEETSLAM_AGENT": robot},
                restart=RestartPolicy(initial_backoff_s=1.0),
            )
        )
    return processes


def fleetslam_argv(*args: str) -> list[str]:
    return [sys.executable, "-m", "fleetslam.cli.main", *args]


def sim_config(robots: list[str], *, shared_patrol: bool = True, route: str = "loop") -> Any:
    """The simulator's configuration for the demo: with ``shared_patrol``, the robots of
    :data:`SHARED_PATROL_STARTS` share a patrol of ``route``; the others (and all without it) start where the
    simulator places them."""
    from fleetslam.robot.autopilot import get_route
    from fleetslam.sim.config import RobotPlacement, SimConfig

    config = SimConfig()
    if not shared_patrol:
        return config
    placements = {p.name: p for p in config.robots}
    for name, (x, y, yaw) in SHARED_PATROL_STARTS.items():
        if name in robots:
            placements[name] = RobotPlacement(name=name, x=x, y=y, yaw=yaw)
    patrol = get_route(route)
    if "r2d2" in placements and patrol.closed and patrol.frame == "start":
        c3po_start = SHARED_PATROL_STARTS["c3po"]
        ahead = patrol.second_start()
        x, y = patrol.in_world(c3po_start)[ahead]
        yaw = c3po_start[2] + patrol.starting_at(ahead)[1][2]
        placements["r2d2"] = RobotPlacement(name="r2d2", x=x, y=y, yaw=yaw, route_start_waypoint=ahead)
    return config.model_copy(update={"robots": list(placements.values())})


def start_poses(robots: list[str], config: Any = None) -> tuple[dict[str, list[float]], dict[str, Any]]:
    """Each robot's camera pose at start in the world, [x, y, z, roll, pitch, yaw] (where its SLAM map sits),
    and its camera extrinsics T_base_link_optical (to compare SLAM camera poses with base ground truth)."""
    from scipy.spatial.transform import Rotation

    from fleetslam.sim.config import SimConfig
    from fleetslam.sim.plant import Plant

    config = config if config is not None else SimConfig()
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


#: Where the simulator writes each robot's ground truth (base_link in world, TUM) in the results folder: the
#: evaluation reads it there instead of taking 50 samples a second per robot off the network.
GROUND_TRUTH_BASE_DIR = "ground_truth/base_link"
#: The map nodes' numba kernels on one thread: with seven processes on two cores, a parallel region waits for a
#: thread that another process holds (a 2.5 ms scan took 5-50 ms), and OpenMP's idle threads spin.
ONE_NUMBA_THREAD = {"NUMBA_NUM_THREADS": "1"}
#: The map nodes yield the CPU to SLAM and the simulated sensors: a map that lags a second costs nothing, a SLAM
#: node starved while they compile their kernels at start dropped frames and drifted through its first lap.
MAP_NICENESS = 10


def station_process(env: dict[str, str], port: int, token: str) -> ProcessSpec:
    """The operator console in a process of its own: its encoding and WebSocket traffic are not the monitor's to
    pay for (the report shows each), and a console that fails restarts without stopping the demo (with the same
    token, so an open page reconnects)."""
    return ProcessSpec(label="station", host="localhost", argv=fleetslam_argv("station", "--port", str(port)),
                       environment={**env, "FLEETSLAM_STATION_TOKEN": token}, restart=RestartPolicy())  # fmt: skip


def sim_processes(
    robots: list[str],
    router: str,
    out_dir: Path,
    resolution: str,
    camera_hz: float = 10.0,
    route: str = "loop",
    security: Path | None = None,
    known_starts: bool = False,
) -> tuple[list[ProcessSpec], dict[str, Any]]:
    """The simulated fleet's processes. Without ``known_starts`` the robots share a patrol
    (:data:`SHARED_PATROL_STARTS`) and the fleet map is given no start poses: each robot's map joins the fleet map
    when its SLAM has placed it by inter-agent closures. With it, the robots start apart where the simulator places
    them and the fleet map places their maps by their true start poses. The true start poses are written to
    ``start_poses.yaml`` either way, for the report only (the ground truth's frame)."""
    env = fleet_env(router, security)
    # The fleet map and the simulator (every robot's sensors, /clock) act for the whole fleet: the station's identity.
    station_env = fleet_env(router, security, "station")
    maps_dir = f"maps_dir={(out_dir / 'maps').resolve()}"  # the only place the save services write to
    processes = []
    for robot in robots:
        agent_env = {**env, "FLEETSLAM_AGENT": robot}
        peers = "[" + ",".join(r for r in robots if r != robot) + "]"
        # One BLAS thread: the SLAM node's matrices are small, and on two cores extra threads only contend. The
        # robot's place in the fleet frame follows the fleet back-end (below) once it has placed it.
        processes.append(ProcessSpec(label=f"{robot}/slam", host="localhost",
                                     argv=fleetslam_argv("slam", "node", "--set", f"peers={peers}", "--set", maps_dir,
                                                         "--set", "follow_fleet=true"),
                                     environment={**agent_env, "OPENBLAS_NUM_THREADS": "1"},
                                     restart=RestartPolicy()))  # fmt: skip
        # The map follows the fleet back-end's corrections of its keyframes (the back-end runs below): the fleet
        # map lands it by one rigid transform, and a map bent by the robot's own drift would land with doubled walls.
        processes.append(ProcessSpec(label=f"{robot}/mapping", host="localhost",
                                     argv=fleetslam_argv("map", "node", "--set", maps_dir,
                                                         "--set", "follow_fleet=true"),
                                     environment={**agent_env, **ONE_NUMBA_THREAD},
                                     restart=RestartPolicy(), niceness=MAP_NICENESS))  # fmt: skip
    fleet_config = out_dir / "fleet_map.yaml"
    import yaml

    plant_config = sim_config(robots, shared_patrol=not known_starts, route=route)
    (out_dir / "sim.yaml").write_text(yaml.safe_dump(plant_config.model_dump(mode="json")))
    poses, extrinsics = start_poses(robots, plant_config)
    (out_dir / "start_poses.yaml").write_text(
        yaml.safe_dump({"start_poses": poses, "fleet_frame_of": None if known_starts else min(robots)})
    )
    fleet_settings: dict[str, Any] = {"agents": robots, "maps_dir": str((out_dir / "maps").resolve())}
    if known_starts:
        fleet_settings["start_poses"] = poses
    fleet_config.write_text(yaml.safe_dump(fleet_settings))
    processes.append(ProcessSpec(label="fleet_map", host="localhost",
                                 argv=fleetslam_argv("fleet", "node", "--config", str(fleet_config)),
                                 environment={**station_env, **ONE_NUMBA_THREAD}, restart=RestartPolicy(),
                                 niceness=MAP_NICENESS))  # fmt: skip
    # The joint optimisation of every agent's graph and the closures between them (docs/collaboration.md): its
    # placements are what the fleet map and the console land the agents' maps by. On the robots' own two cores it
    # solves once a second within 5 % of a core (its defaults are for a fleet server's core of its own).
    backend_settings = [f"agents=[{','.join(robots)}]", "rate=1.0", "max_load=0.05"]
    backend_argv = fleetslam_argv("fleet", "backend", *(a for s in backend_settings for a in ("--set", s)))
    processes.append(ProcessSpec(label="fleet_backend", host="localhost", argv=backend_argv,
                                 environment={**station_env}, restart=RestartPolicy(),
                                 niceness=MAP_NICENESS))  # fmt: skip
    processes.append(ProcessSpec(label="sim", host="localhost",
                                 argv=fleetslam_argv("sim", "run", "--config", str(out_dir / "sim.yaml"),
                                                 "--robots", ",".join(robots), "--camera-hz",
                                                 f"{camera_hz:g}", "--resolution", resolution, "--autopilot", route,
                                                 "--laps", "--ground-truth",
                                                 str(out_dir / GROUND_TRUTH_BASE_DIR)),
                                 environment={**station_env, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")},
                                 restart=RestartPolicy()))  # fmt: skip
    return processes, extrinsics
