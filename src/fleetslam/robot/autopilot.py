"""Autopilot (pure): named routes followed by a pure-pursuit controller that outputs (v, ω) like an operator.

Routes are waypoint lists in a route frame whose origin is the robot's start pose (x forward, y left), so
they fit any world; :meth:`Route.in_world` places them at a start pose. The simulator may register routes in
plant coordinates with :func:`register_route` (``frame="world"``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from fleetslam.errors import ConfigError
from fleetslam.geometry import normalize_angle

Point = tuple[float, float]


@dataclass(frozen=True)
class Route:
    """A named list of waypoints (m); ``closed`` routes return to their first waypoint."""

    name: str
    waypoints: tuple[Point, ...]
    closed: bool = False
    frame: Literal["start", "world"] = "start"
    """"start": relative to the robot's start pose; "world": already in plant coordinates."""

    def in_world(self, start: tuple[float, float, float]) -> list[Point]:
        """Waypoints in world coordinates for a robot starting at (x, y, θ); closed routes end at the start."""
        points = list(self.waypoints) + ([self.waypoints[0]] if self.closed else [])
        if self.frame == "world":
            return points
        x0, y0, th0 = start
        c, s = math.cos(th0), math.sin(th0)
        return [(x0 + c * px - s * py, y0 + s * px + c * py) for px, py in points]

    def lap_phases(self) -> list[float]:
        """Each waypoint's place on a closed route's lap: the distance driven from the first one, as a fraction of
        the lap (the first 0)."""
        lap = self._lap()
        lengths = [math.dist(a, b) for a, b in itertools.pairwise(lap)]
        total = sum(lengths)
        if total <= 0.0:
            raise ConfigError(f"route {self.name!r}: its lap has no length")
        phases, driven = [], 0.0
        for length in lengths:
            phases.append(driven / total)
            driven += length
        return phases

    def crossing_gaps(self) -> list[float]:
        """Where a closed route crosses itself, the part of a lap between its two passes there (in 0..1): a robot
        that follows another by that much of a lap meets it at the crossing."""
        lap = self._lap()
        phases = [*self.lap_phases(), 1.0]
        gaps = []
        for i in range(len(lap) - 1):
            for j in range(i + 2, len(lap) - 1):
                if i == 0 and j == len(lap) - 2:
                    continue  # the last segment ends where the first begins
                at = _segment_crossing(lap[i], lap[i + 1], lap[j], lap[j + 1])
                if at is not None:
                    on_i = phases[i] + at[0] * (phases[i + 1] - phases[i])
                    on_j = phases[j] + at[1] * (phases[j + 1] - phases[j])
                    gaps.append(on_j - on_i)
        return gaps

    def second_start(self) -> int:
        """The waypoint where a second robot sharing this closed route as a patrol starts: the farthest around the
        lap from the first robot's start and from every gap at which they would meet where the route crosses itself
        (both follow the same path at the same speeds, so the second stays that part of a lap ahead)."""
        avoid = [0.0, *self.crossing_gaps()]
        avoid += [1.0 - g for g in avoid]

        def clearance(phase: float) -> float:
            return min(min(abs(phase - a), 1.0 - abs(phase - a)) for a in avoid)

        phases = self.lap_phases()
        return max(range(len(phases)), key=lambda k: (clearance(phases[k]), -abs(phases[k] - 0.5)))

    def starting_at(self, index: int) -> tuple[Route, tuple[float, float, float]]:
        """The same closed path driven from waypoint ``index``: the route as seen from a robot standing there and
        facing the next waypoint, and that pose (x, y, θ) in this route's frame. A robot placed there with the
        returned route drives this route's path, ``index`` waypoints on. Waypoint 0 is any route's own start."""
        if index == 0:
            return self, (0.0, 0.0, 0.0)
        if not self.closed:
            raise ConfigError(f"route {self.name!r} is open: a robot can start only at its first waypoint")
        if not 0 < index < len(self.waypoints):
            raise ConfigError(f"route {self.name!r} has {len(self.waypoints)} waypoints, no waypoint {index}")
        lap = self._lap()
        (x0, y0), (x1, y1) = lap[index], lap[index + 1]
        th0 = math.atan2(y1 - y0, x1 - x0)
        turned = self.waypoints[index:] + self.waypoints[:index]
        if self.frame == "world":
            return Route(f"{self.name}@{index}", turned, closed=True, frame="world"), (x0, y0, th0)
        c, s = math.cos(th0), math.sin(th0)
        relative = tuple(
            (round(c * (px - x0) + s * (py - y0), 9), round(-s * (px - x0) + c * (py - y0), 9)) for px, py in turned
        )
        return Route(f"{self.name}@{index}", relative, closed=True), (x0, y0, th0)

    def _lap(self) -> list[Point]:
        if not self.closed:
            raise ConfigError(f"route {self.name!r} is open: it has no lap")
        return [*self.waypoints, self.waypoints[0]]


def _segment_crossing(a: Point, b: Point, c: Point, d: Point) -> tuple[float, float] | None:
    """Where segments ab and cd cross, as fractions along each, or None (parallel ones never do)."""
    rx, ry = b[0] - a[0], b[1] - a[1]
    sx, sy = d[0] - c[0], d[1] - c[1]
    denominator = rx * sy - ry * sx
    if abs(denominator) < 1e-12:
        return None
    qx, qy = c[0] - a[0], c[1] - a[1]
    t = (qx * sy - qy * sx) / denominator
    u = (qx * ry - qy * rx) / denominator
    return (t, u) if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0 else None


def _square(side: float) -> tuple[Point, ...]:
    return ((0.0, 0.0), (side, 0.0), (side, side), (0.0, side))


def _survey(length: float, width: float, lanes: int) -> tuple[Point, ...]:
    """A lawn-mower pattern: lanes along x, stepping left by width/(lanes-1)."""
    points: list[Point] = []
    for lane in range(lanes):
        y = width * lane / max(lanes - 1, 1)
        ends = [(0.0, y), (length, y)]
        points.extend(ends if lane % 2 == 0 else ends[::-1])
    return tuple(points)


def _figure_eight(half_height: float, half_width: float, points: int) -> tuple[Point, ...]:
    """A standing figure eight (x = -w·sin 2t, y = h·(1 + sin t), t from -π/2): it starts at the bottom heading
    +x, like a robot at its start pose, and crosses itself at (0, h) twice per lap at ±(atan(h/2w)) off the y
    axis, so the camera sees the crossing from two headings and the lobes' ends from the same one every lap."""
    ts = [-math.pi / 2 + 2 * math.pi * k / points for k in range(points)]
    # round(…, 9): the start is exactly (0, 0), not sin's 1e-16 beside it.
    return tuple((round(-half_width * math.sin(2 * t), 9), round(half_height * (1 + math.sin(t)), 9)) for t in ts)


_LOOP = ((0.0, 0.0), (4.0, 0.0), (5.0, 1.0), (5.0, 3.0), (4.0, 4.0), (0.0, 4.0), (-1.0, 3.0), (-1.0, 1.0))

ROUTES: dict[str, Route] = {
    "square": Route("square", _square(2.0), closed=True),
    "loop": Route("loop", _LOOP, closed=True),
    # The loop, then its first metres again: the camera sees the start from the start's own viewpoint, which
    # a visual loop closure needs (a closed route arrives at the start from the side, looking elsewhere).
    "loop_revisit": Route("loop_revisit", (*_LOOP, (0.0, 0.0), (1.5, 0.0))),
    "survey": Route("survey", _survey(5.0, 3.0, 4)),
    "line": Route("line", ((0.0, 0.0), (3.0, 0.0))),
    # Crosses and revisits itself (4.5 × 3.4 m, about 14 m a lap): fits beside each demo robot's start.
    "figure_eight": Route("figure_eight", _figure_eight(2.25, 1.7, 32), closed=True),
}
"""The route registry: name → route. Extend with :func:`register_route`."""


def register_route(route: Route) -> None:
    """Add or replace a route in :data:`ROUTES`."""
    ROUTES[route.name] = route


def get_route(name: str, routes: Mapping[str, Route] | None = None) -> Route:
    """The route called ``name``; raises ConfigError listing the known ones."""
    table = ROUTES if routes is None else routes
    try:
        return table[name]
    except KeyError as err:
        raise ConfigError(f"route {name!r} is unknown; known routes: {', '.join(sorted(table))}") from err


class Autopilot:
    """Pure pursuit along a polyline of world waypoints.

    Args:
        waypoints: at least one (x, y) point in the odometry/world frame.
        lookahead: distance to the pursued point on the path, m.
        max_speed: cruise speed, m/s.
        max_omega: largest yaw rate commanded, rad/s.
        arrival_tolerance: distance to the last waypoint at which the route is done, m.
        turn_slowdown: speed divides by (1 + turn_slowdown·|curvature|) to slow in turns, m.
        rotate_in_place_angle: if the pursued point is further off the heading than this, turn on the spot.
        cyclic: the waypoints are a closed lap (first point repeated at the end) driven again and again, never
            done: a robot that patrols, and revisits every place once per lap.
    """

    def __init__(
        self,
        waypoints: Sequence[Point],
        *,
        lookahead: float = 0.6,
        max_speed: float = 0.5,
        max_omega: float = 1.2,
        arrival_tolerance: float = 0.15,
        turn_slowdown: float = 1.0,
        rotate_in_place_angle: float = math.radians(75.0),
        cyclic: bool = False,
    ) -> None:
        if not waypoints:
            raise ConfigError("autopilot: the route has no waypoints")
        if lookahead <= 0.0:
            raise ConfigError(f"autopilot: lookahead must be > 0, got {lookahead}")
        self.waypoints = [(float(x), float(y)) for x, y in waypoints]
        self.lookahead = lookahead
        self.max_speed = max_speed
        self.max_omega = max_omega
        self.arrival_tolerance = arrival_tolerance
        self.turn_slowdown = turn_slowdown
        self.rotate_in_place_angle = rotate_in_place_angle
        self.cyclic = cyclic and len(self.waypoints) >= 3
        self._lap = list(self.waypoints)
        self.laps = 0
        """Laps completed (cyclic routes)."""
        self._segment = 0
        self.done = False

    @classmethod
    def for_route(
        cls, route: Route, start: tuple[float, float, float], *, cyclic: bool = False, **options: Any
    ) -> Autopilot:
        """An autopilot following ``route`` placed at the start pose (x, y, θ); ``cyclic`` drives a closed route
        lap after lap (an open route is driven once whatever ``cyclic`` says)."""
        return cls(route.in_world(start), cyclic=cyclic and route.closed, **options)

    def _next_lap(self) -> None:
        """Cyclic routes: keep at least one lap ahead of the robot, and forget the lap behind it."""
        lap = len(self._lap) - 1
        if self._segment >= lap:
            del self.waypoints[:lap]
            self._segment -= lap
            self.laps += 1
        while len(self.waypoints) - 1 - self._segment < lap:
            self.waypoints.extend(self._lap[1:])

    def _advance(self, px: float, py: float) -> None:
        """Move progress forward while the robot is past the end of its current segment."""
        if self.cyclic:
            self._next_lap()
        while self._segment < len(self.waypoints) - 2:
            ax, ay = self.waypoints[self._segment]
            bx, by = self.waypoints[self._segment + 1]
            dx, dy = bx - ax, by - ay
            length2 = dx * dx + dy * dy
            t = ((px - ax) * dx + (py - ay) * dy) / length2 if length2 > 0 else 1.0
            if t < 1.0 and math.hypot(bx - px, by - py) > self.lookahead:
                break
            self._segment += 1

    def _target(self, px: float, py: float) -> Point:
        """The first point on the path from the current segment at distance ≥ lookahead, else the end."""
        for i in range(self._segment, len(self.waypoints) - 1):
            ax, ay = self.waypoints[i]
            bx, by = self.waypoints[i + 1]
            dx, dy = bx - ax, by - ay
            fx, fy = ax - px, ay - py
            a = dx * dx + dy * dy
            if a == 0.0:
                continue
            b = 2.0 * (fx * dx + fy * dy)
            c = fx * fx + fy * fy - self.lookahead**2
            disc = b * b - 4.0 * a * c
            if disc < 0.0:
                continue
            t = (-b + math.sqrt(disc)) / (2.0 * a)
            if 0.0 <= t <= 1.0:
                return ax + t * dx, ay + t * dy
        return self.waypoints[-1]

    def step(self, pose: tuple[float, float, float], now: float) -> tuple[float, float, bool]:
        """(v, ω, done) for the robot at pose (x, y, θ) at time ``now`` (s)."""
        del now  # pure pursuit is memoryless apart from progress; kept for a uniform driver interface
        if self.done:
            return 0.0, 0.0, True
        px, py, theta = pose
        self._advance(px, py)
        end = self.waypoints[-1]
        if self._segment >= len(self.waypoints) - 2 and math.hypot(end[0] - px, end[1] - py) < self.arrival_tolerance:
            self.done = True
            return 0.0, 0.0, True
        tx, ty = self._target(px, py)
        alpha = normalize_angle(math.atan2(ty - py, tx - px) - theta)
        if abs(alpha) > self.rotate_in_place_angle:
            return 0.0, math.copysign(self.max_omega, alpha), False
        distance = max(math.hypot(tx - px, ty - py), 1e-9)
        curvature = 2.0 * math.sin(alpha) / distance
        v = self.max_speed / (1.0 + self.turn_slowdown * abs(curvature))
        # slow down on the final approach so the robot stops on the last waypoint
        to_end = math.hypot(end[0] - px, end[1] - py)
        if self._segment >= len(self.waypoints) - 2:
            v = min(v, max(to_end, 0.1 * self.max_speed))
        omega = curvature * v
        if abs(omega) > self.max_omega:
            omega = math.copysign(self.max_omega, omega)
            v = omega / curvature
        return v, omega, False
