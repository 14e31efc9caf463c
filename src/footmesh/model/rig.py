"""Rigging the template: joints grafted by vertex groups, and smooth skinning weights (thesis 3.5.3).

Both are computed once, on the PCA mean foot, by the rules below and stored in the asset; nothing is painted by
hand. All lengths in mm, foot frame (x heel->toe, y to the left, z up, floor z = 0), LEFT foot (big toe on -y).

Joints (thesis: "tips: averages of tip vertices; inner joints interpolated between vertices on opposite
sides"): each joint is a convex combination of small vertex groups (a landmark vertex and its one-ring):
- toe tips and heel: the group around the landmark's vertex;
- ankle: between the lateral and medial malleoli;
- inner joints (midfoot, metatarsophalangeal "proximal" and interphalangeal "distal" joints): a target point
  placed by anatomical proportions (below), then expressed as a non-negative combination of the four surface
  groups that rays from the target hit above, below, medially and laterally. The regressor is linear in the
  vertices, so it follows any shape or pose of the mesh.

Anatomical placement (fractions of stick length L from the heel; metatarsal heads after the metatarsal parabola
in, e.g., Hlavac 1965 and the last-making ball line at 62-73 % of foot length):
- metatarsophalangeal joints 1..5 at x = ``MTP_X_FRACTION``, y = the toe tip's y pulled into the section,
  z = ``MTP_HEIGHT_FRACTION`` of the section's thickness (the heads sit low, near the plantar skin);
- interphalangeal joints on the line MTP -> tip at ``IP_FRACTION`` of the way, centred in the toe's thickness;
- midfoot (Chopart joint, between the calcaneus/talus and the navicular/cuboid) at x = ``MIDFOOT_X_FRACTION``,
  centred in width, at ``MIDFOOT_HEIGHT_FRACTION`` of the thickness.

Skinning weights: bone heat (Baran & Popovic 2007, "Automatic rigging and animation of 3D characters"): solve
``(L + M H) w_j = M H p_j`` on the surface, with L the cotangent Laplacian, M the lumped vertex areas,
p_j = 1 where bone j is the vertex's nearest bone and H = c / d^2 (d = distance to that bone). Column j of the
weights moves with the segment ending at joint j; column 0 (midfoot) stays put.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.optimize import nnls

from footmesh.model import skeleton as sk
from footmesh.model.anatomy import stick_length_mm

MTP_X_FRACTION = (0.725, 0.705, 0.68, 0.655, 0.63)
MTP_HEIGHT_FRACTION = 0.4
IP_FRACTION = (0.5, 0.45, 0.45, 0.45, 0.45)
MIDFOOT_X_FRACTION = 0.42
MIDFOOT_HEIGHT_FRACTION = 0.4
ROOT_BONE_START = 0.35
"""Bones leaving the midfoot start this fraction of the way out, so that the tarsal region around the midfoot
joint belongs to the root (it does not move with any joint angle)."""
ROOT_BONE_RADIUS = 15.0
"""mm taken off every vertex's distance to the root bone, see ``bone_heat_weights``."""
HEAT_CONSTANT = 0.3
MIN_WEIGHT = 0.01
"""Weights below this are dropped (and the rest renormalised) to keep skinning local."""

TIP_LANDMARKS = ("toe1_tip", "toe2_tip", "toe3_tip", "toe4_tip", "toe5_tip")
REQUIRED_LANDMARKS = (*TIP_LANDMARKS, "heel", "malleolus_lateral", "malleolus_medial")


@dataclass(frozen=True)
class Rig:
    """Joint regressor and skinning weights of one template."""

    joint_regressor: np.ndarray  # (18, V), rows non-negative and summing to 1
    skin_weights: np.ndarray  # (V, 18), rows non-negative and summing to 1
    target_joints: np.ndarray  # (18, 3) mm, where the placement rules put the joints on the rigged mesh
    groups: dict[str, np.ndarray] = field(default_factory=dict)  # joint name -> vertex ids it averages


def build_rig(vertices: np.ndarray, faces: np.ndarray, landmarks: dict[str, int]) -> Rig:
    """Graft the 18 joints onto the mesh and compute bone-heat skinning weights.

    Args:
        vertices: (V, 3) mm, zero pose, foot frame, left foot.
        faces: (F, 3) vertex ids, watertight, outward winding.
        landmarks: name -> vertex id; needs ``REQUIRED_LANDMARKS``.
    """
    import trimesh

    missing = [n for n in REQUIRED_LANDMARKS if n not in landmarks]
    if missing:
        raise ValueError(f"build_rig needs landmarks {missing}")
    v = np.asarray(vertices, dtype=np.float64)
    mesh = trimesh.Trimesh(v, np.asarray(faces), process=False)
    neighbours = _one_rings(len(v), mesh.edges_unique)

    regressor = np.zeros((sk.NUM_JOINTS, len(v)))
    groups: dict[str, np.ndarray] = {}
    targets = np.zeros((sk.NUM_JOINTS, 3))

    def set_from_groups(joint: int, group_list: list[np.ndarray], weights: np.ndarray) -> None:
        row = np.zeros(len(v))
        for g, w in zip(group_list, weights, strict=True):
            row[g] += w / len(g)
        regressor[joint] = row / row.sum()
        groups[sk.JOINT_NAMES[joint]] = np.unique(np.concatenate(group_list))
        targets[joint] = regressor[joint] @ v

    def ring(vid: int) -> np.ndarray:
        return np.array(sorted({vid, *neighbours[vid]}))

    heel_x = v[:, 0].min()
    length = stick_length_mm(v)
    # Tips and heel: the landmark's group.
    for k, name in enumerate(TIP_LANDMARKS):
        set_from_groups(sk.TOE_BRANCHES[k][2], [ring(landmarks[name])], np.ones(1))
    set_from_groups(17, [ring(landmarks["heel"])], np.ones(1))
    # Ankle: midway between the malleoli.
    set_from_groups(
        16, [ring(landmarks["malleolus_lateral"]), ring(landmarks["malleolus_medial"])], np.array([0.5, 0.5])
    )

    def inner_joint(joint: int, x: float, y: float, height_fraction: float, centre_y: bool = False) -> None:
        bottom, top = _vertical_hits(mesh, x, y)
        z = bottom[2] + height_fraction * (top[2] - bottom[2])
        medial, lateral = _side_hits(mesh, np.array([x, y, z]))
        if centre_y:
            y = 0.5 * (medial[1] + lateral[1])
            bottom, top = _vertical_hits(mesh, x, y)
            z = bottom[2] + height_fraction * (top[2] - bottom[2])
            medial, lateral = _side_hits(mesh, np.array([x, y, z]))
        target = np.array([x, y, z])
        hit_points = [bottom, top, medial, lateral]
        group_list = [ring(_nearest_vertex(v, p)) for p in hit_points]
        centres = np.stack([v[g].mean(axis=0) for g in group_list])
        weights = _convex_weights(centres, target)
        set_from_groups(joint, group_list, weights)

    inner_joint(0, heel_x + MIDFOOT_X_FRACTION * length, 0.0, MIDFOOT_HEIGHT_FRACTION, centre_y=True)
    for k, (proximal, distal, tip) in enumerate(sk.TOE_BRANCHES):
        tip_point = targets[tip]
        x = heel_x + MTP_X_FRACTION[k] * length
        inner_joint(proximal, x, tip_point[1], MTP_HEIGHT_FRACTION)
        ip = targets[proximal] + IP_FRACTION[k] * (tip_point - targets[proximal])
        inner_joint(distal, ip[0], ip[1], 0.5)

    weights = bone_heat_weights(v, np.asarray(faces), targets)
    return Rig(regressor.astype(np.float32), weights.astype(np.float32), targets, groups)


def bone_segments(joints: np.ndarray, leg_top_z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bones used for the weights: starts (N, 3), ends (N, 3) and the weight column each bone heats (N,).

    Bone j (< 18) is the segment ending at joint j; bones leaving the midfoot start ``ROOT_BONE_START`` out.
    Bone 0 (the root, which no angle moves) runs from the midfoot joint ``ROOT_BONE_START`` of the way towards the
    metatarsophalangeal joints, where the bones leaving the midfoot start. One more bone, the lower leg, runs
    from the ankle straight up to ``leg_top_z`` and moves with the ankle's segment (column 16).
    """
    starts = np.empty_like(joints)
    ends = joints.copy()
    mtp_centre = joints[[b[0] for b in sk.TOE_BRANCHES]].mean(axis=0)
    starts[0] = joints[0]
    ends[0] = joints[0] + ROOT_BONE_START * (mtp_centre - joints[0])
    for c in range(1, sk.NUM_JOINTS):
        p = sk.PARENTS[c]
        start_fraction = ROOT_BONE_START if p == 0 else 0.0
        starts[c] = joints[p] + start_fraction * (joints[c] - joints[p])
    ankle = sk.HEEL_BRANCH[0]
    leg_start = joints[ankle]
    leg_end = np.array([leg_start[0], leg_start[1], max(leg_top_z, leg_start[2])])
    columns = np.append(np.arange(sk.NUM_JOINTS), ankle)
    return np.vstack([starts, leg_start]), np.vstack([ends, leg_end]), columns


def bone_heat_weights(vertices: np.ndarray, faces: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """(V, 18) bone-heat skinning weights (Baran & Popovic 2007), rows summing to 1."""
    starts, ends, columns = bone_segments(joints, float(vertices[:, 2].max()))
    dist = _point_segment_distances(vertices, starts, ends)  # (V, N bones)
    # The tarsal bones are a broad block, not a thin bone: without this the surface around the midfoot would
    # all go to the bones leaving it and nothing would hold the root (and the global pose) in place.
    dist[:, 0] = np.maximum(dist[:, 0] - ROOT_BONE_RADIUS, 1e-3)
    nearest_bone = dist.argmin(axis=1)
    nearest = columns[nearest_bone]
    d = np.maximum(dist[np.arange(len(vertices)), nearest_bone], 1e-3)
    laplacian, areas = _cotangent_laplacian(vertices, faces)
    heat = HEAT_CONSTANT * areas / d**2
    system = (laplacian + sp.diags(heat)).tocsc()
    rhs = np.zeros((len(vertices), sk.NUM_JOINTS))
    rhs[np.arange(len(vertices)), nearest] = heat
    weights = spla.splu(system).solve(rhs)
    weights = np.clip(weights, 0.0, None)
    weights[weights < MIN_WEIGHT] = 0.0
    return weights / weights.sum(axis=1, keepdims=True)


def _cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Positive semi-definite cotangent Laplacian (V, V) and lumped (one third) vertex areas (V,)."""
    n = len(vertices)
    tri = vertices[faces]  # (F, 3, 3)
    rows, cols, vals = [], [], []
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        a = tri[:, j] - tri[:, i]
        b = tri[:, k] - tri[:, i]
        cot = (a * b).sum(axis=1) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-12)
        # the angle at corner i weighs the opposite edge (j, k)
        rows += [faces[:, j], faces[:, k]]
        cols += [faces[:, k], faces[:, j]]
        vals += [0.5 * cot, 0.5 * cot]
    off = sp.coo_matrix((-np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    off = off.tocsr()
    lap = off - sp.diags(np.asarray(off.sum(axis=1)).ravel())
    face_area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    areas = np.bincount(faces.ravel(), weights=np.repeat(face_area / 3.0, 3), minlength=n)
    return lap.tocsr(), areas


def _point_segment_distances(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """(N, S) Euclidean distance from each point to each segment."""
    seg = ends - starts  # (S, 3)
    rel = points[:, None, :] - starts[None]  # (N, S, 3)
    length2 = np.maximum((seg**2).sum(axis=1), 1e-12)
    t = np.clip((rel * seg[None]).sum(axis=2) / length2, 0.0, 1.0)
    closest = starts[None] + t[..., None] * seg[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2)


def _one_rings(n: int, edges: np.ndarray) -> list[set[int]]:
    rings: list[set[int]] = [set() for _ in range(n)]
    for a, b in edges:
        rings[a].add(int(b))
        rings[b].add(int(a))
    return rings


def _nearest_vertex(v: np.ndarray, p: np.ndarray) -> int:
    return int(np.argmin(((v - p) ** 2).sum(axis=1)))


def _ray_hits(mesh, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """All points where the ray meets the surface, sorted by distance (K, 3)."""
    locations, _, _ = mesh.ray.intersects_location(origin[None], direction[None], multiple_hits=True)
    if len(locations) == 0:
        return np.empty((0, 3))
    order = np.argsort((locations - origin) @ direction)
    return locations[order]


def _vertical_hits(mesh, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """Lowest (plantar) and the first surface point above it along the vertical line at (x, y)."""
    top_z = mesh.vertices[:, 2].max() + 10.0
    hits = _ray_hits(mesh, np.array([x, y, top_z]), np.array([0.0, 0.0, -1.0]))
    if len(hits) < 2:
        raise ValueError(f"vertical line at x={x:.1f}, y={y:.1f} mm misses the foot; is it in the foot frame?")
    bottom = hits[-1]
    # the surface right above the sole at this (x, y): the last downward hit before the bottom that enters
    top = hits[-2]
    return bottom, top


def _side_hits(mesh, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest surface points from an interior point towards -y (medial) and +y (lateral)."""
    out = []
    for sign in (-1.0, 1.0):
        hits = _ray_hits(mesh, point, np.array([0.0, sign, 0.0]))
        if len(hits) == 0:
            raise ValueError(f"no surface on the {'medial' if sign < 0 else 'lateral'} side of {point}")
        out.append(hits[0])
    return out[0], out[1]


def _convex_weights(centres: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Non-negative weights summing to 1 whose combination of ``centres`` (G, 3) is nearest ``target`` (3,)."""
    big = 1e3  # enforces sum-to-one as a heavily weighted extra equation
    a = np.vstack([centres.T, big * np.ones(len(centres))])
    b = np.concatenate([target, [big]])
    w, _ = nnls(a, b)
    return w / w.sum()
