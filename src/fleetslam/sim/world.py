"""The procedural inspection hall as MJCF (generated in code, textures as in-memory PNG assets).

Layout (world frame, metres; the hall spans [-L/2, L/2] × [-W/2, W/2]):

- a west process hall (x < 0) with tanks, pipe runs, a rack, crates and a texture-less white partition;
- a partition wall at x = 0 with three doorways, the middle one opening into a corridor along +x whose
  north wall is plain white and south wall brick;
- a north-east store with racks and crates, a south-east tank farm with a pipe bridge.

Two areas are kept clear for the default robots' routes (see :data:`CLEAR_ZONES`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fleetslam._imports import require
from fleetslam.sim import textures
from fleetslam.sim.config import WorldConfig

CLEAR_ZONES: tuple[tuple[float, float, float, float], ...] = ((-13.6, -8.1, -6.4, -2.9), (2.4, 3.4, 9.6, 8.6))
"""(xmin, ymin, xmax, ymax) areas with no obstacles: the default start areas of c3po and r2d2 and their routes."""


@dataclass
class WorldBuilder:
    """Accumulates textures, materials and static geoms, then emits MJCF."""

    config: WorldConfig
    rng: np.random.Generator = field(init=False)
    assets: dict[str, bytes] = field(default_factory=dict)
    asset_xml: list[str] = field(default_factory=list)
    geom_xml: list[str] = field(default_factory=list)
    _count: int = 0

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.config.seed)

    def material(self, kind: str, *, per_metre: float | None = 0.5, variant: int = 0) -> str:
        """Name of a material with a procedural texture; ``per_metre`` None maps the image once per face."""
        name = f"{kind}_{variant}_{per_metre}"
        if any(f'name="{name}"' in a for a in self.asset_xml):
            return name
        image = textures.make_texture(
            kind, self.rng, self.config.texture_size, photographic=self.config.surfaces == "photographic"
        )
        self.assets[f"{name}.png"] = encode_png(image)
        self.asset_xml.append(f'<texture name="{name}" type="2d" file="{name}.png"/>')
        if per_metre is None:
            self.asset_xml.append(f'<material name="{name}" texture="{name}" texrepeat="1 1" specular="0.1"/>')
        else:
            self.asset_xml.append(
                f'<material name="{name}" texture="{name}" texuniform="true" '
                f'texrepeat="{per_metre} {per_metre}" specular="0.1"/>'
            )
        return name

    def _name(self, prefix: str) -> str:
        self._count += 1
        return f"{prefix}_{self._count}"

    def box(self, center: Sequence[float], half: Sequence[float], material: str, *, yaw_deg: float = 0.0) -> None:
        self.geom_xml.append(
            f'<geom name="{self._name("box")}" type="box" pos="{center[0]} {center[1]} {center[2]}" '
            f'size="{half[0]} {half[1]} {half[2]}" euler="0 0 {yaw_deg}" material="{material}"/>'
        )

    def cylinder(
        self, center: Sequence[float], radius: float, half_length: float, material: str, *, axis: str = "z"
    ) -> None:
        euler = {"z": "0 0 0", "x": "0 90 0", "y": "90 0 0"}[axis]
        self.geom_xml.append(
            f'<geom name="{self._name("cyl")}" type="cylinder" pos="{center[0]} {center[1]} {center[2]}" '
            f'size="{radius} {half_length}" euler="{euler}" material="{material}"/>'
        )

    def wall_x(self, y: float, x0: float, x1: float, material: str, thickness: float = 0.2) -> None:
        """A wall along x at y from x0 to x1."""
        h = self.config.wall_height
        self.box(((x0 + x1) / 2, y, h / 2), ((x1 - x0) / 2, thickness / 2, h / 2), material)

    def wall_y(self, x: float, y0: float, y1: float, material: str, thickness: float = 0.2) -> None:
        """A wall along y at x from y0 to y1."""
        h = self.config.wall_height
        self.box((x, (y0 + y1) / 2, h / 2), (thickness / 2, (y1 - y0) / 2, h / 2), material)

    def tank(self, x: float, y: float, radius: float, height: float) -> None:
        """A vertical tank on a concrete plinth with a hazard band."""
        self.box((x, y, 0.1), (radius + 0.15, radius + 0.15, 0.1), self.material("concrete", per_metre=0.5))
        self.cylinder((x, y, 0.2 + height / 2), radius, height / 2, self.material("metal", variant=int(x * 7 + y) % 3))
        self.cylinder((x, y, 0.2 + 0.35), radius + 0.01, 0.15, self.material("hazard", per_metre=1.0))

    def crate(self, x: float, y: float, half: float, z: float = 0.0, yaw_deg: float = 0.0) -> None:
        variant = int(self.rng.integers(3))
        self.box(
            (x, y, z + half),
            (half, half, half),
            self.material("cardboard", per_metre=None, variant=variant),
            yaw_deg=yaw_deg,
        )

    def rack(self, x0: float, y0: float, length: float, depth: float, levels: int = 3, along_x: bool = True) -> None:
        """A shelving rack with posts, shelves and crates on them."""
        steel = self.material("metal", variant=9)
        hazard = self.material("hazard", per_metre=2.0)
        level_h = 0.7
        lx, ly = (length, depth) if along_x else (depth, length)
        for px in (x0, x0 + lx):
            for py in (y0, y0 + ly):
                self.box((px, py, levels * level_h / 2 + 0.1), (0.04, 0.04, levels * level_h / 2 + 0.1), hazard)
        for k in range(levels):
            z = 0.15 + k * level_h
            self.box((x0 + lx / 2, y0 + ly / 2, z), (lx / 2, ly / 2, 0.02), steel)
            n = int(length / 0.6)
            for i in range(n):
                if self.rng.random() < 0.75:
                    t = (i + 0.5) / n
                    half = 0.15 + 0.08 * self.rng.random()
                    cx = x0 + (t * lx if along_x else lx / 2)
                    cy = y0 + (ly / 2 if along_x else t * ly)
                    self.crate(cx, cy, half, z=z + 0.02, yaw_deg=float(self.rng.uniform(-15, 15)))

    def pipe_run(self, start: Sequence[float], end: Sequence[float], radius: float, supports: int = 4) -> None:
        """A straight horizontal pipe (along x or y) on vertical supports."""
        metal = self.material("metal", variant=5)
        sx, sy, z = start
        ex, ey, _ = end
        axis = "x" if abs(ex - sx) > abs(ey - sy) else "y"
        half = max(abs(ex - sx), abs(ey - sy)) / 2
        self.cylinder(((sx + ex) / 2, (sy + ey) / 2, z), radius, half, metal, axis=axis)
        concrete = self.material("concrete", per_metre=0.5)
        for k in range(supports):
            t = (k + 0.5) / supports
            px, py = sx + t * (ex - sx), sy + t * (ey - sy)
            self.box((px, py, (z - radius) / 2), (0.06, 0.06, (z - radius) / 2), concrete)

    def poster_on_wall(self, center: Sequence[float], half: Sequence[float], kind: str = "poster") -> None:
        self.box(center, half, self.material(kind, per_metre=None, variant=int(self.rng.integers(4))))


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an RGB uint8 image."""
    cv2 = require("cv2", "sim")
    ok, buffer = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise ValueError("PNG encoding failed")
    return buffer.tobytes()


def build_world(config: WorldConfig) -> WorldBuilder:
    """Populate the hall: walls, doorways, corridor, tanks, pipes, racks, crates, posters."""
    b = WorldBuilder(config)
    hx, hy = config.length / 2, config.width / 2
    brick = b.material("bricks", per_metre=0.4)
    concrete = b.material("concrete", per_metre=0.3)
    white = b.material("plain", per_metre=1.0)
    # outer walls
    b.wall_x(-hy - 0.1, -hx - 0.2, hx + 0.2, brick)
    b.wall_x(hy + 0.1, -hx - 0.2, hx + 0.2, concrete)
    b.wall_y(-hx - 0.1, -hy, hy, brick)
    b.wall_y(hx + 0.1, -hy, hy, concrete)
    # partition at x = 0 with three doorways
    for y0, y1 in ((-hy, -8.0), (-6.0, -1.2), (1.2, 6.0), (8.0, hy)):
        b.wall_y(0.0, y0, y1, concrete)
    # corridor from the middle doorway east: plain north wall, brick south wall
    b.wall_x(1.5, 0.1, 12.0, white)
    b.wall_x(-1.5, 0.1, 12.0, brick)
    # west process hall
    b.wall_y(-14.6, -6.5, -1.0, white)  # the texture-less partition seen from the c3po loop
    b.tank(-10.0, 1.0, 1.2, 3.0)
    b.tank(-4.5, 1.5, 0.9, 2.5)
    b.tank(-13.0, 7.0, 1.5, 3.2)
    b.tank(-4.0, -9.0, 1.0, 2.2)
    b.pipe_run((-15.5, 9.8, 0.6), (-1.0, 9.8, 0.6), 0.15, supports=6)
    b.pipe_run((-15.5, 9.3, 1.2), (-1.0, 9.3, 1.2), 0.1, supports=6)
    b.pipe_run((-2.0, -10.5, 2.6), (-2.0, 10.5, 2.6), 0.2, supports=5)
    b.rack(-5.4, -7.8, 3.0, 0.6, along_x=False)
    for k, (x, y) in enumerate(((-10.5, -9.8), (-9.6, -9.9), (-11.6, -9.6), (-8.5, -9.7))):
        b.crate(x, y, 0.3 + 0.05 * k, yaw_deg=10.0 * k)
    b.crate(-10.0, -9.8, 0.25, z=0.6)
    b.crate(-7.5, -1.3, 0.35)
    b.crate(-6.8, -1.6, 0.3, yaw_deg=20)
    for i in range(4):
        b.poster_on_wall((-hx + 0.02, -7.5 + 3.0 * i, 1.6), (0.02, 0.8, 0.6), kind="photo" if i % 2 else "poster")
    b.poster_on_wall((-9.5, -hy + 0.02, 1.5), (1.0, 0.02, 0.7), kind="photo")
    b.poster_on_wall((-6.0, -hy + 0.02, 1.4), (0.8, 0.02, 0.6))
    b.box((-8.0, 4.0, 1.5), (0.2, 0.2, 1.5), b.material("hazard", per_metre=1.0))
    b.box((-3.0, -4.0, 1.5), (0.2, 0.2, 1.5), b.material("hazard", per_metre=1.0))
    # north-east store
    b.rack(11.0, 4.0, 4.0, 0.7, along_x=False)
    b.rack(4.0, 9.8, 6.0, 0.7, along_x=True)
    for k, (x, y) in enumerate(((12.0, 2.6), (13.0, 2.7), (1.2, 9.0), (1.0, 3.0), (14.5, 9.5))):
        b.crate(x, y, 0.3 + 0.04 * k, yaw_deg=7.0 * k)
    b.poster_on_wall((hx - 0.02, 6.0, 1.6), (0.02, 1.0, 0.7), kind="photo")
    b.poster_on_wall((9.9, 1.62, 1.5), (0.5, 0.02, 0.4))
    # south-east tank farm with a pipe bridge
    b.tank(5.0, -6.0, 1.3, 3.0)
    b.tank(10.0, -7.0, 1.0, 2.6)
    b.tank(14.0, -4.5, 0.8, 2.0)
    b.pipe_run((1.0, -3.0, 2.2), (15.5, -3.0, 2.2), 0.18, supports=6)
    b.pipe_run((5.0, -10.5, 0.5), (5.0, -8.0, 0.5), 0.12, supports=2)
    b.crate(8.0, -10.0, 0.4)
    b.crate(2.0, -9.5, 0.35, yaw_deg=30)
    return b


def world_xml(
    builder: WorldBuilder,
    robots_xml: Sequence[str],
    actuators_xml: Sequence[str],
    *,
    timestep: float,
    offscreen: tuple[int, int],
) -> str:
    """The full MJCF document: world geometry, lights, robots and their actuators."""
    floor = builder.material("floor", per_metre=0.5)
    hx, hy = builder.config.length / 2, builder.config.width / 2
    return f"""<mujoco model="fleetslam_plant">
  <statistic extent="20" center="0 0 1"/>
  <option timestep="{timestep}" integrator="implicitfast" cone="elliptic"/>
  <visual>
    <global offwidth="{offscreen[0]}" offheight="{offscreen[1]}"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.25 0.25 0.25" specular="0 0 0"/>
    <quality shadowsize="0" offsamples="0"/>
    <map znear="0.0025" zfar="2.5"/>
  </visual>
  <asset>
    {chr(10).join("    " + a for a in builder.asset_xml)}
  </asset>
  <worldbody>
    <light name="sun" directional="true" pos="0 0 10" dir="-0.3 -0.2 -1" diffuse="0.5 0.5 0.48" castshadow="false"/>
    <light name="fill" directional="true" pos="0 0 10" dir="0.4 0.5 -0.6" diffuse="0.25 0.25 0.28"
           castshadow="false"/>
    <geom name="floor" type="box" pos="0 0 -0.05" size="{hx + 1} {hy + 1} 0.05" material="{floor}"
          friction="1 0.005 0.0001"/>
    {chr(10).join("    " + g for g in builder.geom_xml)}
    {"".join(robots_xml)}
  </worldbody>
  <actuator>{"".join(actuators_xml)}
  </actuator>
</mujoco>
"""
