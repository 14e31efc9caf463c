"""Procedural textures evaluated at floor points in mm: floors, background, reference objects.

No image files and no downloads: every texture is a function of the point ``(x, y)`` (mm, scene frame on the
floor plane) and of a few parameters drawn by the scene sampler. Colours are sRGB in 0..1. The per-point code is
compiled (``kernels.floor_albedo``, ``kernels.reference_albedo``); the functions here wrap it for arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from footmesh import references

FLOOR_KINDS = ("wood", "tiles", "carpet", "plain")

CARD_CORNER_MM = 3.18
"""Radius of a card's rounded corners (ISO/IEC 7810 ID-1); the cards' sizes: ``footmesh.references``."""
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
    from footmesh.synth import kernels

    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    flat = kernels.value_noise_many(
        _TABLE, np.ascontiguousarray(x).reshape(-1), np.ascontiguousarray(y).reshape(-1), float(cell), float(salt)
    )
    return flat.reshape(x.shape)


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
    """(N,) x, y on the floor (mm) -> (N, 3) sRGB albedo.

    Wood: planks ``size_mm`` wide and ``5 size_mm + 400`` long, staggered, with a per-plank tone, wavy grain, fine
    noise and 1.5 mm dark gaps. Tiles: ``size_mm`` squares, a per-tile tone, two-scale marble noise, grout 2-6 mm.
    Carpet: fibres of ``size_mm`` with a random tone each, large blotches. Plain: two-scale value noise.
    Evaluated per point by ``kernels.floor_texture``.
    """
    from footmesh.synth import kernels

    return kernels.floor_texture(
        *floor_params(p),
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(y, dtype=np.float64),
    )


def reference_size(kind: str) -> tuple[float, float]:
    """Length x width (mm) of the rectangle whose corners are stored for a reference object."""
    return references.kind(kind).size_mm


def reference_extent(kind: str) -> tuple[float, float, float]:
    """Margin (mm) of the drawn object around the stored rectangle, and its drawn length x width."""
    w, h = reference_size(kind)
    margin = references.kind(kind).margin_mm
    return margin, w + 2 * margin, h + 2 * margin


def reference_colour(
    kind: str, u: np.ndarray, v: np.ndarray, tint: tuple[float, float, float], salt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Colour of a reference object at local coordinates (mm; origin at stored corner 0, u along its length).

    Returns:
        inside (N,) bool, where the object covers the point, and colour (N, 3) sRGB albedo there.
    """
    from footmesh.synth import kernels

    return kernels.reference_texture(
        *reference_params(kind, tint, salt),
        np.ascontiguousarray(u, dtype=np.float64),
        np.ascontiguousarray(v, dtype=np.float64),
    )


def reference_params(kind: str, tint: tuple[float, float, float], salt: float) -> tuple:
    """The arguments of ``kernels.reference_albedo`` before the point: table, bits, kind id, size, margin, colours."""
    ref = references.kind(kind)
    length, width = ref.size_mm
    card = _CARD[int(_hash(np.array(salt), 5.0)[()] * len(_CARD))]
    look = references.LOOKS.index(ref.look) + 1
    return _TABLE, ARUCO_BITS, look, length, width, ref.margin_mm, card, np.asarray(tint, dtype=np.float64), float(salt)


def floor_params(p: FloorParams) -> tuple:
    """The arguments of ``kernels.floor_albedo`` before the point."""
    return (
        _TABLE,
        FLOOR_KINDS.index(p.kind),
        np.asarray(p.colour, dtype=np.float64),
        float(p.size_mm),
        float(p.angle),
        float(p.salt),
        float(p.contrast),
    )


def background_tint(salt: float) -> np.ndarray:
    """(3,) colour of the distant wall (rays that miss the floor) seen level; a ray of scene-up component ``d``
    (unit) sees ``clip(tint (0.85 + 0.25 d), 0, 1)`` (``kernels.floor_shade``)."""
    return 0.6 + 0.3 * np.array([_hash(np.array(salt), k)[()] for k in range(3)])
