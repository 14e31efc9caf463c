"""Shared helpers for the registration tests: a small template (the model at FIND's 1,002-vertex level)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

COARSE_VERTICES = 1002


def coarse_faces(fine_faces: np.ndarray, num_coarse: int) -> np.ndarray:
    """Faces of the mesh that one Loop subdivision turned into ``fine_faces`` (original vertices come first).

    Every edge-midpoint vertex (id >= num_coarse) neighbours exactly the two original vertices of its edge; each
    corner triangle (one original vertex a, two midpoints) gives the coarse triangle (a, b, c) in its winding.
    """
    f = np.asarray(fine_faces, dtype=np.int64)
    ends: dict[int, set[int]] = {}
    for tri in f:
        for i in range(3):
            u, v = int(tri[i]), int(tri[(i + 1) % 3])
            if u >= num_coarse > v:
                ends.setdefault(u, set()).add(v)
            if v >= num_coarse > u:
                ends.setdefault(v, set()).add(u)
    out, seen = [], set()
    for tri in f:
        orig = [i for i in range(3) if tri[i] < num_coarse]
        if len(orig) != 1:
            continue
        k = orig[0]
        a, m1, m2 = int(tri[k]), int(tri[(k + 1) % 3]), int(tri[(k + 2) % 3])
        b = next(iter(ends[m1] - {a}))
        c = next(iter(ends[m2] - {a}))
        key = tuple(sorted((a, b, c)))
        if key not in seen:
            seen.add(key)
            out.append((a, b, c))
    return np.array(out, dtype=np.int64)


def coarse_model():
    """The packaged model cut down to its first 1,002 vertices (FIND's level): fast registration tests."""
    from footmesh.model.assets import load_asset

    asset = load_asset()  # shipped: a missing asset fails the test
    n = COARSE_VERTICES
    names = [str(x) for x in asset.landmark_names]
    keep = [i for i, v in enumerate(asset.landmark_vertices) if v < n]
    return replace(
        asset,
        mean_vertices=asset.mean_vertices[:n].astype(np.float64),
        components=asset.components[:, :n].astype(np.float64),
        faces=coarse_faces(asset.faces, n),
        landmark_names=np.array([names[i] for i in keep]),
        landmark_vertices=asset.landmark_vertices[keep],
        joint_regressor=np.zeros((18, n), np.float32),
        skin_weights=np.full((n, 18), 1.0 / 18, np.float32),
    )


def random_shape(model, seed: int, sd_scale: float = 1.0) -> np.ndarray:
    """Model mean + random coefficients (N(0, sd^2)), (V, 3) mm."""
    rng = np.random.default_rng(seed)
    c = rng.standard_normal(model.num_components) * model.component_sd * sd_scale
    return model.mean_vertices + np.tensordot(c, model.components, axes=1)
