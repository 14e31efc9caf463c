"""Anatomy of the foot model that the model itself is built with: what counts as the foot (not the leg), its
length and its ball width (ANSUR definitions, docs/measurements.md).

The model's build (``build_find``), rig and template use these; ``footmesh.measure`` builds the eight
shoe-fitting measurements on them. They live here, under both, so that the model never imports a later stage.
"""

from __future__ import annotations

import numpy as np

BALL_REGION = (0.55, 0.85)
"""Fractions of stick length (from the heel) spanning the ball of the foot, where ball width is taken."""
FOOT_HEIGHT_FRACTION = 0.25
"""Vertices higher than this fraction of the foot's x-extent belong to the leg and are ignored for length."""
HEEL_REGION_FRACTION = 0.2
"""The heel region: vertices within this fraction of the foot's x-extent from its back (``heel_region``)."""


def stick_length_mm(vertices: np.ndarray) -> float:
    """Heel to the tip of the longest toe along the foot axis x (ANSUR "foot length").

    Args:
        vertices: (V, 3) mm, canonical pose, foot frame (x heel->toe, z up, floor at z = 0).
    """
    v = check_vertices(vertices)
    extent = np.ptp(v[:, 0])
    low = v[v[:, 2] <= FOOT_HEIGHT_FRACTION * extent]
    return float(np.ptp(low[:, 0]))


def ball_width_mm(vertices: np.ndarray) -> float:
    """Maximum breadth across the ball, perpendicular to the foot axis (ANSUR "foot breadth, horizontal").

    Taken over the vertices whose x lies in ``BALL_REGION`` of the stick length from the heel.

    Args:
        vertices: (V, 3) mm, canonical pose, foot frame.
    """
    v = check_vertices(vertices)
    length = stick_length_mm(v)
    x = v[:, 0] - heel_x(v)
    band = v[(x >= BALL_REGION[0] * length) & (x <= BALL_REGION[1] * length)]
    return float(np.ptp(band[:, 1]))


def heel_x(v: np.ndarray) -> float:
    """x of the heel: the smallest x among the foot's (not the leg's) vertices, as in ``stick_length_mm``."""
    return float(v[v[:, 2] <= FOOT_HEIGHT_FRACTION * np.ptp(v[:, 0]), 0].min())


def heel_region(vertices: np.ndarray) -> np.ndarray:
    """(H,) ids of the heel region's vertices: those within ``HEEL_REGION_FRACTION`` of the foot's x-extent from its
    back, of (V, 3) vertices in the zero pose, foot frame. A standing foot bears weight there and under its ball."""
    return np.flatnonzero(_x_fraction(vertices) < HEEL_REGION_FRACTION)


def ball_region(vertices: np.ndarray) -> np.ndarray:
    """(B,) ids of the ball region's vertices: those within ``BALL_REGION`` of the foot's x-extent from its back,
    of (V, 3) vertices in the zero pose, foot frame."""
    x = _x_fraction(vertices)
    return np.flatnonzero((x >= BALL_REGION[0]) & (x <= BALL_REGION[1]))


def _x_fraction(vertices: np.ndarray) -> np.ndarray:
    """(V,) each vertex's x as a fraction of the foot's x-extent from its back (0) to its front (1)."""
    v = check_vertices(vertices)
    return (v[:, 0] - v[:, 0].min()) / np.ptp(v[:, 0])


def check_vertices(vertices: np.ndarray) -> np.ndarray:
    """``vertices`` as a finite (V, 3) float64 array with V >= 4 (ValueError otherwise)."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
        raise ValueError(f"expected vertices of shape (V, 3) with V >= 4, got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError("vertices contain NaN or infinite values")
    return v
