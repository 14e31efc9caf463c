"""A small z-buffer triangle rasteriser (exact depth, perspective-correct barycentrics), compiled with numba.

Renderer choice: our own rasteriser, because it needs no system libraries (EGL/OSMesa are absent here and on a
fresh CI machine), gives exact per-sample depth and face ids for the labels, and is byte-deterministic.

Conventions: sample coordinates are pixel units of the grid being rasterised (x right, y down; sample ``(i, j)``
sits at ``x = j, y = i``). Each triangle covers the samples whose screen-space barycentrics are all >= 0 (a tiny
tolerance closes cracks between neighbours). Depth is camera ``z`` (mm) for perspective rasterisation, where
``1/z`` is affine in screen space, or any affine depth for orthographic rasterisation (shadow maps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from footmesh.synth import kernels
from footmesh.synth.kernels import EDGE_TOLERANCE

__all__ = ["EDGE_TOLERANCE", "Fragments", "rasterize"]


@dataclass(frozen=True)
class Fragments:
    """What the rasteriser returns for an ``(H, W)`` grid.

    face: (H, W) int64, index of the front-most triangle, -1 where none.
    depth: (H, W) float64, its depth (camera z in mm), ``inf`` where none.
    bary: (H, W, 3) float64, perspective-correct barycentrics of the sample in that triangle (0 where none).
    """

    face: np.ndarray
    depth: np.ndarray
    bary: np.ndarray


def rasterize(
    xy: np.ndarray,
    z: np.ndarray,
    faces: np.ndarray,
    height: int,
    width: int,
    perspective: bool = True,
    cull_back: bool = True,
) -> Fragments:
    """Rasterise triangles with a z-buffer.

    Args:
        xy: (N, 2) vertex positions in sample units of the grid.
        z: (N,) vertex depths, > 0 for perspective rasterisation (mm).
        faces: (F, 3) vertex indices; counter-clockwise on screen (x right, y down) means front-facing, i.e. the
            winding of outward faces seen from outside in an OpenCV camera.
        height, width: grid size in samples.
        perspective: interpolate ``1/z`` (perspective camera) or ``z`` (orthographic).
        cull_back: drop back-facing triangles (closed meshes only).
    Returns:
        Fragments of the grid.
    """
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    z = np.ascontiguousarray(z, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    return Fragments(*kernels.rasterize(xy, z, faces, int(height), int(width), bool(perspective), bool(cull_back)))
