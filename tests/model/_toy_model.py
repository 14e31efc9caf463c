"""A small hand-made foot model for the model tests, used while (or where) the packaged asset is missing.

Built from FIND's coarse template (1,002 vertices, metres -> mm, heel at x = 0, sole at z = 0) with a
hand-placed skeleton, a joint regressor of nearest-vertex groups, skinning weights from inverse distance to the
segments, and smooth orthonormal shape components (polynomial displacement fields). It has the packaged asset's
keys and conventions, so every test runs on either.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from footmesh.model import skeleton as sk
from footmesh.model.assets import FootModelAsset, load_asset

FIND_TEMPLATE = Path("/work/shared/find/template.obj")

# Hand-placed rest joints of the toy skeleton, mm, foot frame of the shifted template (left foot: big toe on -y).
_TOY_JOINTS = np.array(
    [
        [110.0, 8.0, 42.0],  # midfoot
        [192.0, -8.0, 22.0],  # toe1 proximal
        [235.0, -8.0, 18.0],  # toe1 distal
        [266.0, -6.0, 14.0],  # toe1 tip
        [190.0, 11.0, 20.0],
        [226.0, 12.0, 15.0],
        [255.0, 13.0, 11.0],
        [182.0, 22.0, 18.0],
        [214.0, 23.0, 13.0],
        [242.0, 24.0, 10.0],
        [173.0, 32.0, 16.0],
        [202.0, 33.0, 12.0],
        [230.0, 34.0, 9.0],
        [162.0, 41.0, 14.0],
        [190.0, 43.0, 11.0],
        [214.0, 45.0, 9.0],
        [55.0, 2.0, 78.0],  # ankle
        [8.0, 2.0, 28.0],  # heel
    ]
)
_GROUP_SIZE = 6
_SKIN_POWER = 4.0
_SKIN_KEEP = 3
_ROOT_RADIUS = 40.0
_TOY_SD = np.array([300.0, 200.0, 150.0, 120.0, 90.0, 70.0, 50.0, 40.0])


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)


def toy_asset() -> FootModelAsset:
    """The hand-made model (deterministic)."""
    import trimesh

    mesh = trimesh.load(FIND_TEMPLATE, process=False, force="mesh")
    v = np.asarray(mesh.vertices, dtype=np.float64) * 1000.0
    v -= [v[:, 0].min(), 0.0, v[:, 2].min()]
    faces = np.asarray(mesh.faces, dtype=np.int32)
    n = len(v)

    # Joint regressor: the nearest-vertex group of each hand-placed joint, equal weights.
    regressor = np.zeros((sk.NUM_JOINTS, n))
    for j, p in enumerate(_TOY_JOINTS):
        near = np.argsort(np.linalg.norm(v - p, axis=1))[:_GROUP_SIZE]
        regressor[j, near] = 1.0 / _GROUP_SIZE
    joints = regressor @ v

    # Skinning: inverse distance to each segment (parent -> joint); the root is a ball around the midfoot.
    dist = np.empty((n, sk.NUM_JOINTS))
    dist[:, 0] = np.maximum(np.linalg.norm(v - joints[0], axis=1) - _ROOT_RADIUS, 0.0)
    for c in range(1, sk.NUM_JOINTS):
        dist[:, c] = _segment_distance(v, joints[sk.PARENTS[c]], joints[c])
    w = 1.0 / (dist + 1.0) ** _SKIN_POWER
    w[w < np.sort(w, axis=1)[:, -_SKIN_KEEP][:, None]] = 0.0
    w /= w.sum(axis=1, keepdims=True)

    # Smooth shape components: polynomial displacement fields, orthonormalised (no pure translation).
    u = (v - v.mean(axis=0)) / v.std(axis=0)
    monomials = [u[:, 0], u[:, 1], u[:, 2], u[:, 0] ** 2, u[:, 0] * u[:, 1], u[:, 2] ** 2, u[:, 1] ** 2]
    fields = []
    for axis in (0, 1, 2):
        for m in monomials:
            f = np.zeros((n, 3))
            f[:, axis] = m
            fields.append(f.reshape(-1))
    q, _ = np.linalg.qr(np.stack(fields, axis=1))
    k = len(_TOY_SD)
    rng = np.random.default_rng(0)
    mix, _ = np.linalg.qr(rng.standard_normal((q.shape[1], q.shape[1])))
    components = (q @ mix)[:, :k].T.reshape(k, n, 3)

    landmarks = np.array(["heel", "toe1_tip"])
    return FootModelAsset(
        mean_vertices=v.astype(np.float32),
        components=components.astype(np.float32),
        component_sd=_TOY_SD.astype(np.float32),
        explained_variance_ratio=(_TOY_SD**2 / (_TOY_SD**2).sum()).astype(np.float32),
        faces=faces,
        landmark_names=landmarks,
        landmark_vertices=np.array([int(np.argmin(v[:, 0])), int(np.argmax(v[:, 0]))], dtype=np.int32),
        joint_regressor=regressor.astype(np.float32),
        skin_weights=w.astype(np.float32),
        provenance="toy model for tests (FIND template, hand-placed skeleton)",
    )


def model_asset() -> FootModelAsset:
    """The packaged asset when it exists, else the toy model."""
    try:
        return load_asset()
    except (FileNotFoundError, ValueError):
        return toy_asset()
