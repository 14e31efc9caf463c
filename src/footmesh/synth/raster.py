"""A small vectorised z-buffer triangle rasteriser in numpy (exact depth, perspective-correct barycentrics).

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

EDGE_TOLERANCE = 1e-9
"""Barycentric slack (dimensionless) that keeps samples on a shared edge from falling between two triangles."""


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
    xy = np.asarray(xy, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    face_out = np.full(height * width, -1, dtype=np.int64)
    depth_out = np.full(height * width, np.inf)
    bary_out = np.zeros((height * width, 3))

    p0, p1, p2 = xy[faces[:, 0]], xy[faces[:, 1]], xy[faces[:, 2]]  # (F, 2) each
    # twice the signed area; > 0 for counter-clockwise on a y-down screen, seen as clockwise in y-up maths
    area = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])
    keep = area < 0 if cull_back else area != 0
    lo = np.ceil(np.minimum(np.minimum(p0, p1), p2))  # bounding box in whole samples
    hi = np.floor(np.maximum(np.maximum(p0, p1), p2))
    lo = np.maximum(lo, 0.0)
    hi = np.minimum(hi, [width - 1.0, height - 1.0])
    keep &= np.all(hi >= lo, axis=1)
    if perspective:
        keep &= np.all(z[faces] > 0, axis=1)
    ids = np.flatnonzero(keep)
    if len(ids) == 0:
        return _fragments(face_out, depth_out, bary_out, height, width)

    lo_i, hi_i = lo[ids].astype(np.int64), hi[ids].astype(np.int64)
    box_w = hi_i[:, 0] - lo_i[:, 0] + 1
    counts = box_w * (hi_i[:, 1] - lo_i[:, 1] + 1)
    # one candidate per (triangle, sample in its bounding box)
    cand_face = np.repeat(np.arange(len(ids)), counts)  # (C,) index into ids
    start = np.cumsum(counts) - counts
    local = np.arange(counts.sum()) - np.repeat(start, counts)
    bw = box_w[cand_face]
    px = lo_i[cand_face, 0] + local % bw
    py = lo_i[cand_face, 1] + local // bw

    # screen-space barycentrics as affine functions of (x, y): w_k = a_k x + b_k y + c_k; w_2 = 1 - w_0 - w_1.
    # Tested one at a time so that later ones are computed only for the candidates still inside.
    q0, q1, q2 = p0[ids], p1[ids], p2[ids]
    inv = 1.0 / area[ids]
    coef = []
    for qa, qb in ((q1, q2), (q2, q0)):
        coef.append(
            (
                (qa[:, 1] - qb[:, 1]) * inv,
                (qb[:, 0] - qa[:, 0]) * inv,
                (qa[:, 0] * qb[:, 1] - qb[:, 0] * qa[:, 1]) * inv,
            )
        )
    fx, fy = px.astype(np.float64), py.astype(np.float64)
    a0, b0, c0 = coef[0]
    w0 = a0[cand_face] * fx + b0[cand_face] * fy + c0[cand_face]
    keep0 = w0 >= -EDGE_TOLERANCE
    w0, cand_face, px, py, fx, fy = w0[keep0], cand_face[keep0], px[keep0], py[keep0], fx[keep0], fy[keep0]
    a1, b1, c1 = coef[1]
    w1 = a1[cand_face] * fx + b1[cand_face] * fy + c1[cand_face]
    w2 = 1.0 - w0 - w1
    inside = (w1 >= -EDGE_TOLERANCE) & (w2 >= -EDGE_TOLERANCE)
    w = np.stack([w0[inside], w1[inside], w2[inside]], axis=1)  # (C, 3)
    cand_face, px, py = cand_face[inside], px[inside], py[inside]

    zf = z[faces[ids]][cand_face]  # (C, 3)
    if perspective:
        wz = w / zf
        inv_z = wz.sum(axis=1)
        depth = 1.0 / inv_z
        bary = wz * depth[:, None]
    else:
        depth = (w * zf).sum(axis=1)
        bary = w
    pix = py * width + px
    np.minimum.at(depth_out, pix, depth)
    win = depth == depth_out[pix]
    # ties (shared edges at equal depth): the later candidate wins, deterministically
    face_out[pix[win]] = ids[cand_face[win]]
    bary_out[pix[win]] = bary[win]
    return _fragments(face_out, depth_out, bary_out, height, width)


def _fragments(face: np.ndarray, depth: np.ndarray, bary: np.ndarray, height: int, width: int) -> Fragments:
    return Fragments(face.reshape(height, width), depth.reshape(height, width), bary.reshape(height, width, 3))


def project(points: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection of camera-frame points (N, 3) mm -> pixels (N, 2) and depth z (N,) mm."""
    z = points[:, 2]
    uv = (points @ k.T)[:, :2] / z[:, None]
    return uv, z
