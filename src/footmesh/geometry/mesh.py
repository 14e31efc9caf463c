"""Normals of triangle meshes (faces counter-clockwise seen from outside)."""

from __future__ import annotations

from typing import Any

import numpy as np

EPS = 1e-12


def face_normals(vertices: np.ndarray, faces: np.ndarray, unit: bool = True) -> np.ndarray:
    """(F, 3) face normals of (V, 3) vertices on (F, 3) faces; ``unit=False``: of length twice the face's area."""
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), EPS) if unit else normals


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals (zero for a vertex on no face)."""
    area_normals = face_normals(vertices, faces, unit=False)
    normals = np.zeros_like(vertices, dtype=area_normals.dtype)
    for k in range(3):
        np.add.at(normals, faces[:, k], area_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), EPS)


def batch_vertex_normals(vertices: Any, faces: Any) -> Any:
    """Unit area-weighted vertex normals (B, V, 3) of torch vertices (B, V, 3) on (F, 3) long faces; differentiable."""
    import torch
    import torch.nn.functional as F  # noqa: N812

    f = torch.as_tensor(faces, dtype=torch.long, device=vertices.device)
    v0, v1, v2 = vertices[:, f[:, 0]], vertices[:, f[:, 1]], vertices[:, f[:, 2]]
    area_normals = torch.linalg.cross(v1 - v0, v2 - v0, dim=-1)  # (B, F, 3), length = 2 x area
    normals = torch.zeros_like(vertices)
    for k in range(3):
        normals = normals.index_add(1, f[:, k], area_normals)
    return F.normalize(normals, dim=-1, eps=EPS)
