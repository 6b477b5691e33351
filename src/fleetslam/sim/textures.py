"""Procedural textures (NumPy images, nothing downloaded): concrete, bricks, hazard stripes, rust, posters.

Every generator returns an (S, S, 3) uint8 RGB image and is deterministic for a given generator state.
Texture-rich surfaces give feature-based SLAM something to track; :func:`plain` gives deliberately
texture-less walls.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require

Image = NDArray[np.uint8]


def _smooth_noise(rng: np.random.Generator, size: int, cells: int) -> NDArray[np.float64]:
    """Value noise in [0, 1]: a random grid of ``cells``² values bilinearly upsampled (tileable)."""
    grid = rng.random((cells, cells))
    coords = np.arange(size) * cells / size
    i0 = np.floor(coords).astype(int)
    t = coords - i0
    t = t * t * (3 - 2 * t)
    i1 = (i0 + 1) % cells
    rows = grid[i0][:, i0] * (1 - t)[None, :] + grid[i0][:, i1] * t[None, :]
    rows_next = grid[i1][:, i0] * (1 - t)[None, :] + grid[i1][:, i1] * t[None, :]
    return rows * (1 - t)[:, None] + rows_next * t[:, None]


def fractal_noise(rng: np.random.Generator, size: int, octaves: int = 5) -> NDArray[np.float64]:
    """Sum of value-noise octaves, normalised to [0, 1]."""
    total = np.zeros((size, size))
    amplitude = 1.0
    for octave in range(octaves):
        cells = min(4 * 2**octave, size)
        total += amplitude * _smooth_noise(rng, size, cells)
        amplitude *= 0.55
    total -= total.min()
    return total / max(float(total.max()), 1e-9)


def _to_image(gray_or_rgb: NDArray[np.float64]) -> Image:
    arr = gray_or_rgb if gray_or_rgb.ndim == 3 else np.repeat(gray_or_rgb[..., None], 3, axis=2)
    return np.clip(arr * 255.0, 0, 255).astype(np.uint8)


def tint(gray: NDArray[np.float64], color: tuple[float, float, float]) -> NDArray[np.float64]:
    """A grey image coloured by ``color`` (RGB in [0, 1])."""
    return gray[..., None] * np.asarray(color)[None, None, :]


def concrete(rng: np.random.Generator, size: int) -> Image:
    """Speckled grey concrete with stains and dark pits."""
    base = 0.45 + 0.3 * fractal_noise(rng, size)
    speckle = rng.random((size, size))
    base = np.where(speckle > 0.985, base * 0.4, base)
    base = np.where(speckle < 0.01, np.minimum(base * 1.5, 1.0), base)
    return _to_image(tint(base, (0.95, 0.93, 0.9)))


def floor_tiles(rng: np.random.Generator, size: int, tiles: int = 4) -> Image:
    """Worn floor tiles with dark grout lines and painted marks."""
    img = tint(0.5 + 0.35 * fractal_noise(rng, size), (0.75, 0.75, 0.7))
    step = size // tiles
    grout = max(size // 128, 1)
    for k in range(tiles):
        img[k * step : k * step + grout, :] *= 0.3
        img[:, k * step : k * step + grout] *= 0.3
    for _ in range(6):
        y, x = rng.integers(0, size - 20, 2)
        h, w = rng.integers(4, 20, 2)
        img[y : y + h, x : x + w] = rng.random(3) * 0.8 + 0.1
    return _to_image(img)


def bricks(rng: np.random.Generator, size: int, rows: int = 8) -> Image:
    """Red bricks of varying shade in light mortar, rows offset by half a brick."""
    img = np.empty((size, size, 3))
    img[:] = (0.82, 0.8, 0.75)
    brick_h = size // rows
    brick_w = 2 * brick_h
    mortar = max(brick_h // 8, 1)
    noise = fractal_noise(rng, size)
    for r in range(rows):
        offset = (brick_w // 2) * (r % 2)
        for c in range(-1, size // brick_w + 1):
            x0 = c * brick_w + offset
            shade = np.array([0.55, 0.22, 0.15]) * (0.7 + 0.6 * rng.random())
            ys = slice(r * brick_h + mortar, (r + 1) * brick_h)
            xs = slice(max(x0 + mortar, 0), min(x0 + brick_w, size))
            img[ys, xs] = shade
    img *= (0.75 + 0.5 * noise)[..., None]
    return _to_image(img)


def hazard_stripes(rng: np.random.Generator, size: int, stripes: int = 8) -> Image:
    """Yellow/black diagonal warning stripes, slightly dirty."""
    yy, xx = np.mgrid[0:size, 0:size]
    band = ((xx + yy) * stripes // size) % 2 == 0
    img = np.where(band[..., None], np.array([0.95, 0.8, 0.1]), np.array([0.08, 0.08, 0.08]))
    img *= (0.8 + 0.2 * fractal_noise(rng, size))[..., None]
    return _to_image(img)


def rusty_metal(rng: np.random.Generator, size: int) -> Image:
    """Painted metal with rust blotches and rivet rows."""
    paint = np.array(rng.choice([(0.2, 0.35, 0.6), (0.25, 0.5, 0.3), (0.6, 0.6, 0.62), (0.7, 0.3, 0.1)]))
    rust = fractal_noise(rng, size) > 0.62
    img = np.where(rust[..., None], np.array([0.45, 0.22, 0.08]), paint)
    img = img * (0.75 + 0.4 * fractal_noise(rng, size))[..., None]
    spacing = size // 8
    yy, xx = np.mgrid[0:size, 0:size]
    rivets = ((yy % spacing - spacing // 2) ** 2 + (xx % spacing - spacing // 2) ** 2) < (spacing // 8) ** 2 + 1
    rivets &= (yy // spacing) % 4 == 0
    img[rivets] = (0.9, 0.9, 0.88)
    return _to_image(img)


def cardboard(rng: np.random.Generator, size: int) -> Image:
    """Brown cardboard with tape and a printed label block of random glyph-like marks."""
    img = tint(0.55 + 0.25 * fractal_noise(rng, size, octaves=3), (0.85, 0.62, 0.38))
    tape = slice(size // 2 - size // 16, size // 2 + size // 16)
    img[tape, :] = (0.8, 0.72, 0.55)
    y0, x0 = size // 8, size // 8
    label = img[y0 : y0 + size // 4, x0 : x0 + size // 3]
    label[:] = 0.95
    marks = rng.random(label.shape[:2]) > 0.7
    label[marks] = 0.1
    return _to_image(img)


def poster(rng: np.random.Generator, size: int) -> Image:
    """A notice board: coloured rectangles, circles and bars (a strongly textured patch)."""
    img = np.empty((size, size, 3))
    img[:] = (0.9, 0.9, 0.85)
    yy, xx = np.mgrid[0:size, 0:size]
    for _ in range(14):
        color = rng.random(3)
        if rng.random() < 0.5:
            y, x = rng.integers(0, size, 2)
            h, w = rng.integers(size // 16, size // 3, 2)
            img[y : y + h, x : x + w] = color
        else:
            cy, cx = rng.integers(0, size, 2)
            r = rng.integers(size // 20, size // 6)
            img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = color
    return _to_image(img)


def photo(rng: np.random.Generator, size: int) -> Image:
    """A photograph from scikit-image's bundled samples (no download), or a poster if unavailable."""
    try:
        from skimage import data
    except ImportError:
        return poster(rng, size)
    sources = [data.astronaut, data.chelsea, data.coffee, data.rocket, data.immunohistochemistry]
    image = sources[int(rng.integers(len(sources)))]()
    ys = np.linspace(0, image.shape[0] - 1, size).astype(int)
    xs = np.linspace(0, image.shape[1] - 1, size).astype(int)
    return np.ascontiguousarray(image[ys][:, xs, :3]).astype(np.uint8)


def plain(rng: np.random.Generator, size: int, color: tuple[float, float, float] = (0.93, 0.93, 0.93)) -> Image:
    """A uniform, texture-less surface (deliberately hard for visual odometry)."""
    del rng
    img = np.empty((size, size, 3))
    img[:] = color
    return _to_image(img)


TextureFn = Callable[[np.random.Generator, int], Image]

GENERATORS: dict[str, TextureFn] = {
    "concrete": concrete,
    "floor": floor_tiles,
    "bricks": bricks,
    "hazard": hazard_stripes,
    "metal": rusty_metal,
    "cardboard": cardboard,
    "poster": poster,
    "photo": photo,
    "plain": plain,
}
"""Texture kinds by name."""


PHOTOGRAPHS: dict[str, tuple[str, ...]] = {
    "concrete": ("gravel", "moon"),
    "floor": ("gravel", "grass"),
    "bricks": ("brick",),
    "hazard": ("coins",),
    "metal": ("coins", "camera"),
    "cardboard": ("page", "text"),
    "poster": ("astronaut", "coffee", "chelsea", "rocket", "hubble_deep_field"),
    "photo": ("astronaut", "coffee", "chelsea", "rocket", "hubble_deep_field"),
}
"""Texture kind → scikit-image sample photographs standing in for it in a photographic world (real surfaces
photographed: brick, gravel, grass; real scenes on the posters). ``plain`` stays texture-less."""


def photograph(kind: str, rng: np.random.Generator, size: int) -> Image:
    """A real photograph (scikit-image's bundled samples, no download) for a surface of the given kind, resampled
    to ``size``² RGB. Raises ImportError without scikit-image."""
    from skimage import data

    cv2 = require("cv2", "sim")

    image = np.asarray(getattr(data, PHOTOGRAPHS[kind][int(rng.integers(len(PHOTOGRAPHS[kind])))])())
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    side = min(image.shape[:2])
    square = np.ascontiguousarray(image[:side, :side, :3])
    # Area averaging when shrinking (no aliasing), bilinear when enlarging a small sample.
    interpolation = cv2.INTER_AREA if side >= size else cv2.INTER_LINEAR
    return np.asarray(cv2.resize(square, (size, size), interpolation=interpolation), np.uint8)


def make_texture(kind: str, rng: np.random.Generator, size: int, *, photographic: bool = False) -> Image:
    """A texture of the named kind; ``photographic`` replaces the procedural ones by real photographs."""
    if photographic and kind in PHOTOGRAPHS:
        return photograph(kind, rng, size)
    return GENERATORS[kind](rng, size)
