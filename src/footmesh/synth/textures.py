"""Procedural textures in numpy, evaluated at floor points in mm: floors, background, reference objects.

No image files and no downloads: every texture is a function of the point ``(x, y)`` (mm, scene frame on the
floor plane) and of a few parameters drawn by the scene sampler. Colours are sRGB in 0..1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FLOOR_KINDS = ("wood", "tiles", "carpet", "plain")

A4_MM = (297.0, 210.0)
"""A4 sheet, length x width (ISO 216)."""
CARD_MM = (85.60, 53.98)
"""ID-1 bank card, length x width (ISO/IEC 7810); corners rounded with radius ``CARD_CORNER_MM``."""
CARD_CORNER_MM = 3.18
MARKER_MM = 100.0
"""Printed ArUco marker: side of its black square (the stored corners), mm."""
MARKER_MARGIN_MM = 20.0
"""White paper around the printed marker, mm."""
ARUCO_DICT = "DICT_4X4_50"
ARUCO_ID = 0
# ``cv2.aruco.generateImageMarker(getPredefinedDictionary(DICT_4X4_50), 0, 6) > 0``: 1 = white; the outer ring
# is the black border. Embedded so that OpenCV is not a dependency of the generator.
ARUCO_BITS = np.array(
    [
        [0, 0, 0, 0, 0, 0],
        [0, 1, 0, 1, 1, 0],
        [0, 0, 1, 0, 1, 0],
        [0, 0, 0, 1, 1, 0],
        [0, 0, 0, 1, 0, 0],
        [0, 0, 0, 0, 0, 0],
    ],
    dtype=bool,
)

_WOOD = np.array([[0.55, 0.38, 0.22], [0.70, 0.52, 0.33], [0.42, 0.27, 0.16], [0.80, 0.66, 0.47], [0.33, 0.22, 0.15]])
_TILE = np.array([[0.85, 0.84, 0.80], [0.60, 0.60, 0.62], [0.45, 0.40, 0.36], [0.75, 0.70, 0.62], [0.25, 0.26, 0.28]])
_CARPET = np.array([[0.45, 0.42, 0.40], [0.30, 0.33, 0.40], [0.55, 0.50, 0.42], [0.35, 0.20, 0.20], [0.22, 0.30, 0.24]])
_PLAIN = np.array([[0.70, 0.70, 0.68], [0.55, 0.56, 0.58], [0.80, 0.77, 0.72], [0.40, 0.42, 0.45], [0.62, 0.55, 0.48]])
_CARD = np.array([[0.10, 0.25, 0.55], [0.12, 0.40, 0.25], [0.20, 0.20, 0.22], [0.65, 0.55, 0.30], [0.60, 0.10, 0.12]])


_TABLE_SIZE = 256
_TABLE = np.random.default_rng(20240611).random((_TABLE_SIZE, _TABLE_SIZE))
"""Fixed lattice of random values: the textures' hash (periodic every 256 cells, far beyond any view)."""


def _hash(a: np.ndarray, b: np.ndarray | float = 0.0, salt: float = 0.0) -> np.ndarray:
    """Deterministic pseudo-random numbers in [0, 1) from integer-valued cells ``a``, ``b`` and a salt."""
    s = int(salt * 1000.0)
    ia = (np.asarray(a).astype(np.int64) + s) & (_TABLE_SIZE - 1)
    ib = (np.asarray(b).astype(np.int64) + 7 * s + (s >> 8)) & (_TABLE_SIZE - 1)
    return _TABLE[ia, ib]


def value_noise(x: np.ndarray, y: np.ndarray, cell: float, salt: float) -> np.ndarray:
    """Smooth value noise in [0, 1) with feature size ``cell`` (mm): hashed lattice values, smoothstep blend."""
    gx, gy = x / cell, y / cell
    ix, iy = np.floor(gx), np.floor(gy)
    fx, fy = gx - ix, gy - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    v00, v10 = _hash(ix, iy, salt), _hash(ix + 1, iy, salt)
    v01, v11 = _hash(ix, iy + 1, salt), _hash(ix + 1, iy + 1, salt)
    return (v00 * (1 - fx) + v10 * fx) * (1 - fy) + (v01 * (1 - fx) + v11 * fx) * fy


@dataclass(frozen=True)
class FloorParams:
    """One floor: ``kind`` in FLOOR_KINDS, base colour (sRGB), feature size (mm), direction (rad), salt."""

    kind: str
    colour: tuple[float, float, float]
    size_mm: float
    angle: float
    salt: float
    contrast: float

    @staticmethod
    def sample(rng: np.random.Generator) -> FloorParams:
        kind = FLOOR_KINDS[int(rng.integers(len(FLOOR_KINDS)))]
        palette = {"wood": _WOOD, "tiles": _TILE, "carpet": _CARPET, "plain": _PLAIN}[kind]
        base = palette[int(rng.integers(len(palette)))] * rng.uniform(0.8, 1.15) + rng.normal(0, 0.03, 3)
        size = {"wood": (80.0, 200.0), "tiles": (150.0, 600.0), "carpet": (2.0, 5.0), "plain": (300.0, 900.0)}[kind]
        return FloorParams(
            kind=kind,
            colour=tuple(float(c) for c in np.clip(base, 0.03, 0.97)),
            size_mm=float(rng.uniform(*size)),
            angle=float(rng.uniform(0, np.pi)),
            salt=float(rng.uniform(0, 100)),
            contrast=float(rng.uniform(0.5, 1.0)),
        )


def floor_colour(p: FloorParams, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N,) x, y on the floor (mm) -> (N, 3) sRGB albedo."""
    ca, sa = np.cos(p.angle), np.sin(p.angle)
    u, v = ca * x + sa * y, -sa * x + ca * y  # u along the planks / tile rows
    base = np.asarray(p.colour)
    if p.kind == "wood":
        row = np.floor(v / p.size_mm)
        plank_len = 5.0 * p.size_mm + 400.0
        col = np.floor(u / plank_len + _hash(row, 0.0, p.salt))
        tone = 1.0 + p.contrast * 0.35 * (_hash(row, col, p.salt + 1) - 0.5)
        wobble = value_noise(u * 0.05, v, 4.0, p.salt + 2) * 6.0
        grain = 0.5 + 0.5 * np.sin(2 * np.pi * (v + wobble) / (2.5 + 2 * _hash(row, col, p.salt + 3)))
        fine = value_noise(u, v * 4.0, 30.0, p.salt + 4)
        shade = tone * (0.88 + 0.12 * p.contrast * grain) * (0.93 + 0.14 * fine)
        fv = v / p.size_mm - row
        fu = u / plank_len + _hash(row, 0.0, p.salt) - np.floor(u / plank_len + _hash(row, 0.0, p.salt))
        gap = (fv * p.size_mm < 1.5) | (fu * plank_len < 1.5)
        shade = np.where(gap, 0.45, shade)
    elif p.kind == "tiles":
        gu, gv = u / p.size_mm, v / p.size_mm
        iu, iv = np.floor(gu), np.floor(gv)
        grout_mm = 2.0 + 4.0 * _hash(np.array(p.salt), 1.0)
        du = np.minimum(gu - iu, 1 - (gu - iu)) * p.size_mm
        dv = np.minimum(gv - iv, 1 - (gv - iv)) * p.size_mm
        marble = value_noise(u, v, 60.0, p.salt) * 0.6 + value_noise(u, v, 15.0, p.salt + 1) * 0.4
        shade = (1.0 + p.contrast * 0.12 * (_hash(iu, iv, p.salt) - 0.5)) * (0.92 + 0.16 * p.contrast * marble)
        grout = np.minimum(du, dv) < grout_mm / 2
        out = base[None] * shade[:, None]
        grout_colour = np.where(base.mean() > 0.5, 0.55, 0.8) * np.array([1.0, 0.98, 0.95])
        out[grout] = grout_colour
        return np.clip(out, 0, 1)
    elif p.kind == "carpet":
        fibre = _hash(np.floor(u / p.size_mm), np.floor(v / p.size_mm), p.salt)
        blotch = value_noise(u, v, 80.0, p.salt + 1)
        shade = (0.8 + 0.3 * p.contrast * fibre) * (0.9 + 0.2 * blotch)
    else:  # plain: concrete, vinyl, painted floor
        shade = 0.92 + 0.12 * p.contrast * value_noise(u, v, p.size_mm, p.salt) + 0.04 * value_noise(u, v, 8.0, p.salt)
    return np.clip(base[None] * shade[:, None], 0, 1)


def background_colour(direction_z: np.ndarray, salt: float) -> np.ndarray:
    """(N,) scene-up component of unit view rays -> (N, 3) colour of a distant wall (rays that miss the floor)."""
    tint = 0.6 + 0.3 * np.array([_hash(np.array(salt), k)[()] for k in range(3)])
    return np.clip(tint[None] * (0.85 + 0.25 * np.clip(direction_z, -1, 1))[:, None], 0, 1)


def reference_size(kind: str) -> tuple[float, float]:
    """Length x width (mm) of the rectangle whose corners are stored for a reference object."""
    return {"a4": A4_MM, "card": CARD_MM, "marker": (MARKER_MM, MARKER_MM)}[kind]


def reference_extent(kind: str) -> tuple[float, float, float]:
    """Margin (mm) of the drawn object around the stored rectangle, and its drawn length x width."""
    w, h = reference_size(kind)
    margin = MARKER_MARGIN_MM if kind == "marker" else 0.0
    return margin, w + 2 * margin, h + 2 * margin


def reference_colour(
    kind: str, u: np.ndarray, v: np.ndarray, tint: tuple[float, float, float], salt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Colour of a reference object at local coordinates (mm; origin at stored corner 0, u along its length).

    Returns:
        inside (N,) bool, where the object covers the point, and colour (N, 3) sRGB albedo there.
    """
    w, h = reference_size(kind)
    margin = MARKER_MARGIN_MM if kind == "marker" else 0.0
    inside = (u >= -margin) & (u <= w + margin) & (v >= -margin) & (v <= h + margin)
    paper = np.asarray(tint)[None] * (0.97 + 0.03 * value_noise(u, v, 3.0, salt))[:, None]
    if kind == "a4":
        return inside, paper
    if kind == "marker":
        cell = MARKER_MM / ARUCO_BITS.shape[0]
        iu = np.clip(np.floor(u / cell), 0, ARUCO_BITS.shape[1] - 1).astype(np.int64)
        iv = np.clip(np.floor(v / cell), 0, ARUCO_BITS.shape[0] - 1).astype(np.int64)
        in_marker = (u >= 0) & (u < MARKER_MM) & (v >= 0) & (v < MARKER_MM)
        black = in_marker & ~ARUCO_BITS[iv, iu]
        return inside, np.where(black[:, None], 0.06, paper)
    # card: rounded corners, a base colour, a chip and a stripe
    r = CARD_CORNER_MM
    cu, cv = np.clip(u, r, w - r), np.clip(v, r, h - r)
    inside &= (u - cu) ** 2 + (v - cv) ** 2 <= r * r
    base = _CARD[int(_hash(np.array(salt), 5.0)[()] * len(_CARD))]
    colour = np.broadcast_to(base, (len(u), 3)) * (0.9 + 0.2 * value_noise(u, v, 20.0, salt))[:, None]
    chip = (u > 10) & (u < 22) & (v > 19) & (v < 29)
    stripe = (v > 40) & (v < 44)
    colour = np.where(chip[:, None], np.array([0.80, 0.68, 0.35]), colour)
    colour = np.where(stripe[:, None], np.clip(base * 1.6 + 0.2, 0, 1), colour)
    return inside, colour
