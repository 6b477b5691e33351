"""Two demo robots sharing a patrol: the second starts on the first's path, ahead, and drives the same path without
meeting it (the demo's robots must see each other's places for their maps to join the fleet's)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from fleetslam.errors import ConfigError
from fleetslam.launch.demo_plan import SHARED_PATROL_STARTS, sim_config
from fleetslam.robot.autopilot import ROUTES, Autopilot, Route, get_route


def _distance_to_path(point: tuple[float, float], path: list[tuple[float, float]]) -> float:
    best = math.inf
    for (ax, ay), (bx, by) in itertools.pairwise(path):
        dx, dy = bx - ax, by - ay
        t = min(max(((point[0] - ax) * dx + (point[1] - ay) * dy) / max(dx * dx + dy * dy, 1e-12), 0.0), 1.0)
        best = min(best, math.hypot(point[0] - ax - t * dx, point[1] - ay - t * dy))
    return best


@pytest.mark.parametrize("name", sorted(n for n, r in ROUTES.items() if r.closed))
def test_a_closed_route_started_at_any_waypoint_is_the_same_path(name: str) -> None:
    route = ROUTES[name]
    start = (-3.0, 2.0, 0.7)
    lap = route.in_world(start)[:-1]
    for index in range(len(route.waypoints)):
        ahead, (px, py, pyaw) = route.starting_at(index)
        c, s = math.cos(start[2]), math.sin(start[2])
        there = (start[0] + c * px - s * py, start[1] + s * px + c * py, start[2] + pyaw)
        if index:  # the robot standing at waypoint `index` faces the next one: its first leg is straight ahead
            assert ahead.waypoints[0] == (0.0, 0.0) and ahead.waypoints[1][1] == pytest.approx(0.0, abs=1e-9)
            assert ahead.waypoints[1][0] > 0.0
        np.testing.assert_allclose(ahead.in_world(there)[:-1], lap[index:] + lap[:index], atol=1e-8)


def test_the_second_robot_starts_half_a_lap_ahead_unless_they_would_meet_where_the_route_crosses_itself() -> None:
    loop = get_route("loop")
    assert loop.crossing_gaps() == [] and loop.lap_phases()[loop.second_start()] == pytest.approx(0.5)
    eight = get_route("figure_eight")
    # the figure eight crosses itself half a lap apart: a robot half a lap ahead would meet the other there
    assert eight.crossing_gaps() and all(g == pytest.approx(0.5) for g in eight.crossing_gaps())
    assert eight.lap_phases()[eight.second_start()] in (pytest.approx(0.25), pytest.approx(0.75))


def test_an_open_route_has_no_lap_to_start_on_and_a_bad_waypoint_is_named() -> None:
    with pytest.raises(ConfigError, match="'survey' is open"):
        get_route("survey").starting_at(1)
    with pytest.raises(ConfigError, match="no waypoint 9"):
        Route("tri", ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)), closed=True).starting_at(9)
    with pytest.raises(ConfigError, match="no length"):
        Route("dot", ((0.0, 0.0), (0.0, 0.0), (0.0, 0.0)), closed=True).lap_phases()


def test_demo_robots_share_the_figure_eight_in_the_simulator_without_meeting() -> None:
    pytest.importorskip("mujoco")
    from fleetslam.sim.plant import Plant

    route_name = "figure_eight"  # crosses itself: where robots sharing a patrol could meet
    config = sim_config(["c3po", "r2d2"], route=route_name)
    placements = {p.name: p for p in config.robots if p.name in SHARED_PATROL_STARTS}
    route = get_route(route_name)
    pilots = {}
    for name, p in placements.items():
        own = route.starting_at(p.route_start_waypoint)[0]
        pilots[name] = Autopilot.for_route(own, (p.x, p.y, p.yaw), cyclic=True)  # the plant's odometry is world
    driven: dict[str, list[tuple[float, float]]] = {name: [] for name in placements}
    closest = math.inf
    with Plant(config, list(placements.values())) as plant:
        while plant.sim_time < 60.0:
            for name, pilot in pilots.items():
                odometry = plant.robot(name).controller.odometry
                v, omega, _ = pilot.step((odometry.x, odometry.y, odometry.theta), plant.sim_time)
                plant.command(name, v, omega)
            plant.step(0.05)
            at = {name: plant.base_pose(name)[:2, 3] for name in placements}
            closest = min(closest, float(np.linalg.norm(at["c3po"] - at["r2d2"])))
            for name, xy in at.items():
                driven[name].append((float(xy[0]), float(xy[1])))
    # 60 s is more than a lap (the figure eight's 14 m at under 0.5 m/s) for each: both crossings passed by both
    assert closest > 1.5, f"the robots came within {closest:.2f} m of each other"
    # Pure pursuit cuts the corners: compare r2d2 (5-30 s, past its start's transient) with the path c3po drove
    # (0-60 s, which covers that part of the lap).
    off_path = max(_distance_to_path(xy, driven["c3po"]) for xy in driven["r2d2"][100:600])
    # Measured 0.14 m at most (the two pursue the same waypoints from other places on the lap); before the shared
    # start, r2d2's figure eight lay 4.5 m beside c3po's.
    assert off_path < 0.25, f"r2d2 left c3po's path by {off_path:.2f} m"
