"""The foot template (FIND's mesh subdivided once) and the rule that stands a foot in the foot frame.

Template: FIND's 1,002-vertex template (``template.obj``, metres, left foot) subdivided ONCE by Loop subdivision
(4,002 vertices, 8,000 faces). FIND's displacement field is a continuous function of the point, so evaluating it
at the subdivided points gives their true displacements (checked: below the ankle cap the Loop points lie within
0.8 mm, mean 0.15 mm, of the original surface, and the field there differs from the Loop-subdivided deformed
coarse mesh by 0.6 mm on average -- the same as at exact on-surface midpoints, 0.5 mm -- so being slightly off
the surface does not upset it; the field is rough only on the flat leg cap, which is not foot).

Foot frame (DESIGN.md "Conventions"): mm, z up from the floor, x from heel to toe, origin at the heel on the
floor. See :func:`to_foot_frame` for the rule.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from footmesh.geometry.rotations import rotation_between
from footmesh.model import vertex_ids
from footmesh.model.anatomy import FOOT_HEIGHT_FRACTION

FIND_TEMPLATE_NAME = "template.obj"
FIND_NUM_VERTICES = 1002
"""FIND's demo template (and the number of points ``model.onnx`` takes per call)."""
NUM_VERTICES = 4002
NUM_FACES = 8000
SUBDIVISION_ITERATIONS = 1

SUPPORT_MAX_TILT_DEG = 60.0
"""A hull facet can be the sole's support plane only if its outward normal is within this angle of the rough
"down" direction (see :func:`to_foot_frame`)."""


def load_find_template(find_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """FIND's coarse template.

    Returns:
        vertices (1002, 3) float64 metres (FIND frame: x heel->toe, z up, left foot), faces (2000, 3) int64.
    """
    import trimesh

    path = Path(find_dir) / FIND_TEMPLATE_NAME
    if not path.is_file():
        raise FileNotFoundError(f"FIND template not found: {path} (pass the folder holding FIND's files)")
    mesh = trimesh.load(path, process=False, force="mesh")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if vertices.shape != (FIND_NUM_VERTICES, 3):
        raise ValueError(f"{path}: expected {FIND_NUM_VERTICES} vertices, got {vertices.shape[0]}")
    return vertices, faces


def subdivided_template(find_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """FIND's template after one Loop subdivision: the footmesh template.

    Returns:
        vertices (4002, 3) float64 metres (FIND frame), faces (8000, 3) int64, counter-clockwise seen from
        outside (positive volume), watertight.
    """
    import trimesh

    coarse_v, coarse_f = load_find_template(find_dir)
    vertices, faces = trimesh.remesh.subdivide_loop(coarse_v, coarse_f, iterations=SUBDIVISION_ITERATIONS)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if not mesh.is_watertight:
        raise ValueError("subdivided FIND template is not watertight")
    if mesh.volume < 0:  # make the winding counter-clockwise seen from outside
        faces = faces[:, ::-1]
    if vertices.shape != (NUM_VERTICES, 3) or faces.shape != (NUM_FACES, 3):
        raise ValueError(f"unexpected subdivided template: {vertices.shape}, {faces.shape}")
    return np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64)


def support_plane(vertices: np.ndarray, down: np.ndarray) -> tuple[np.ndarray, float]:
    """The facet of the convex hull that a foot rests on when gravity pulls along ``down``.

    Rule: among hull facets whose outward normal lies within ``SUPPORT_MAX_TILT_DEG`` of ``down``, the one that a
    ray from the vertex centroid along ``down`` leaves the hull through.

    Args:
        vertices: (V, 3) any units, any frame.
        down: (3,) rough down direction (need not be unit).

    Returns:
        (normal (3,) unit outward normal of the plane, pointing down; offset) with ``normal @ p + offset = 0`` on
        the plane and ``<= 0`` for every vertex.
    """
    from scipy.spatial import ConvexHull

    v = np.asarray(vertices, dtype=np.float64)
    d = np.asarray(down, dtype=np.float64)
    d = d / np.linalg.norm(d)
    hull = ConvexHull(v)
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]
    centroid = v.mean(axis=0)
    facing = normals @ d
    ok = facing > np.cos(np.radians(SUPPORT_MAX_TILT_DEG))
    if not ok.any():
        raise ValueError("no convex-hull facet faces the given down direction")
    # ray c + t d leaves the hull through the facet with the smallest positive t = -(n.c + off) / (n.d)
    t = -(normals[ok] @ centroid + offsets[ok]) / facing[ok]
    best = int(np.argmin(np.where(t > 0, t, np.inf)))
    return normals[ok][best], float(offsets[ok][best])


def to_foot_frame(vertices: np.ndarray, landmarks: dict[str, int] | None = None) -> np.ndarray:
    """Stand a foot (template topology) in the foot frame; a pure function, invariant to rigid motions of the input.

    Rule (units are kept: pass mm to get mm):

    1. Rough up: from the lower heel landmark to the midpoint of the two malleoli, made perpendicular to the
       rough foot axis (heel -> 2nd toe tip). Uses only the surface, so any rigid motion of the input gives the
       same result.
    2. Floor: the support plane of the sole, i.e. the convex-hull facet that a ray from the centroid straight
       "down" leaves through (:func:`support_plane`); rotate its outward normal onto -z and put it at z = 0.
       (FIND feet are rolled by about 13 degrees, so "lowest z = 0" would not stand them on the floor.)
    3. Yaw about z so that the foot axis, heel landmark -> 2nd toe tip projected on the floor, is +x.
    4. Origin: x = 0 at the rearmost point of the foot below the ankle (vertices with
       ``z <= FOOT_HEIGHT_FRACTION * x-extent``, the same set :func:`footmesh.model.anatomy.stick_length_mm` uses),
       y = 0 at the heel landmark, z = 0 on the floor.

    Args:
        vertices: (V, 3) on the footmesh template (any units, any frame).
        landmarks: landmark name -> vertex id; defaults to :data:`footmesh.model.vertex_ids.LANDMARKS`.

    Returns:
        (V, 3) float64 in the foot frame, same units as the input.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"expected vertices of shape (V, 3), got {v.shape}")
    lm = vertex_ids.LANDMARKS if landmarks is None else landmarks
    if max(lm.values()) >= len(v):
        raise ValueError(f"landmark ids do not fit {len(v)} vertices; is this the footmesh template?")
    heel, toe2 = v[lm["heel"]], v[lm["toe2_tip"]]
    axis = toe2 - heel
    axis /= np.linalg.norm(axis)
    ankle = 0.5 * (v[lm["malleolus_lateral"]] + v[lm["malleolus_medial"]])
    up = ankle - v[lm["heel_low"]]
    up -= (up @ axis) * axis  # step 1
    up /= np.linalg.norm(up)

    normal, offset = support_plane(v, -up)  # step 2
    rot = rotation_between(normal, np.array([0.0, 0.0, -1.0]))
    v = v @ rot.T
    v[:, 2] -= offset  # plane: n.p + offset = 0 with R n = -z  ->  z = offset; every vertex has z >= offset

    a = v[lm["toe2_tip"], :2] - v[lm["heel"], :2]  # step 3
    angle = np.arctan2(a[1], a[0])
    c, s = np.cos(-angle), np.sin(-angle)
    yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    v = v @ yaw.T

    low = v[:, 2] <= FOOT_HEIGHT_FRACTION * np.ptp(v[:, 0])  # step 4
    v[:, 0] -= v[low, 0].min()
    v[:, 1] -= v[lm["heel"], 1]
    return v
