"""The eight shoe-fitting measurements (thesis Table 2.1) of a foot mesh: canonical pose, foot frame, mm.

Definitions, sources and figures: docs/measurements.md. Summary (L = stick length, x measured from the heel):

==============  ==========================================================================================
stick_length    heel to the tip of the longest toe along x (ISO 7250-1 / ANSUR II "foot length")
ball_width      y-extent of the vertices between 55 % and 85 % of L (ANSUR II "foot breadth, horizontal")
heel_width      y-extent of the vertical section x = 18 % of L, below ``HEEL_WIDTH_MAX_HEIGHT`` of the ankle
toe_height      highest point of the section x = big-toe interphalangeal joint, within 5 % of L of it in y
arch_height     lowest surface point on the vertical line (x = midfoot joint, y = first MTP joint)
instep_height   highest point of the vertical section x = 50 % of L
ball_girth      convex perimeter of the vertical section through the first and fifth MTP joints
instep_girth    convex perimeter of the vertical section x = 50 % of L
==============  ==========================================================================================

Sections are cut off at ``LEG_CUT_FACTOR`` x the ankle joint's height (``FootLandmarks.ankle[2]``): what lies
above belongs to the leg. The mesh must be in the foot frame of docs/conventions.md (x heel->toe, z up, floor
z = 0); ``measure_foot`` checks what it can (floor, units, the long axis) and does not re-align a moved foot.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Literal

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from footmesh.model.anatomy import (
    FOOT_HEIGHT_FRACTION,
    ball_width_mm,
    check_vertices,
    heel_x,
    stick_length_mm,
)
from footmesh.model.skeleton import JOINT_INDEX, NUM_JOINTS

HEEL_WIDTH_FRACTION = 0.18
"""Heel width is taken in the vertical section at this fraction of stick length from the heel (last-making
practice places it at 16-20 % of foot length; docs/measurements.md)."""
HEEL_WIDTH_MAX_HEIGHT = 0.5
"""Heel width only counts the section below this fraction of the ankle joint's height: the heel, not the
malleoli (ANSUR II measures heel breadth below the malleoli)."""
INSTEP_FRACTION = 0.5
"""Instep height and instep girth are taken in the vertical section at this fraction of stick length."""
TOE_HALF_WIDTH_FRACTION = 0.05
"""Toe height only counts section points within this fraction of stick length (in y) of the big toe's
interphalangeal joint, so that the second toe cannot be taken for the big toe."""
LENGTH_RANGE_MM = (50.0, 500.0)
"""A stick length outside this range is not a foot in millimetres (metres? centimetres? not a foot?)."""
FLOOR_TOLERANCE_MM = 5.0
"""The lowest vertex must lie within this distance of the floor z = 0 (foot frame)."""
LEG_CUT_FACTOR = 1.25
"""Sections in front of the heel keep only what lies below this multiple of the ankle joint's height; above
it is the leg. Chosen so that the instep (about 0.8-0.9 x the ankle height at 50 % of length) is never
truncated while the plane at 50 % of length stays in front of the shin in the canonical pose
(docs/measurements.md)."""

MEASUREMENT_NAMES: tuple[str, ...] = (
    "stick_length",
    "ball_width",
    "heel_width",
    "toe_height",
    "arch_height",
    "instep_height",
    "ball_girth",
    "instep_girth",
)
"""The eight measurements of thesis Table 2.1 (Dr. Orvitz), in the order of every table and JSON file."""

RATIO_DEFINITIONS: tuple[tuple[str, str], ...] = (
    ("ball_width", "stick_length"),
    ("heel_width", "stick_length"),
    ("heel_width", "ball_width"),
    ("toe_height", "stick_length"),
    ("arch_height", "stick_length"),
    ("instep_height", "stick_length"),
    ("ball_girth", "stick_length"),
    ("instep_girth", "stick_length"),
    ("instep_girth", "ball_girth"),
)
"""(numerator, denominator) of each scale-free ratio; its key is ``"numerator/denominator"``."""

Side = Literal["left", "right"]


# ----------------------------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Measurement:
    """One measurement in mm; ``None`` when unknown (unscaled foot, or no uncertainty estimate)."""

    value_mm: float | None
    uncertainty_mm: float | None = None

    def to_dict(self) -> dict[str, float | None]:
        return {"value_mm": self.value_mm, "uncertainty_mm": self.uncertainty_mm}


@dataclass(frozen=True)
class Measurements:
    """The eight measurements of a foot (mm, canonical pose).

    An *unscaled* result (no real scale evidence, DESIGN.md) has every ``value_mm`` None and keeps only the
    scale-free ratios, in ``unscaled_ratios``; build it with :meth:`as_unscaled`.
    """

    stick_length: Measurement
    ball_width: Measurement
    heel_width: Measurement
    toe_height: Measurement
    arch_height: Measurement
    instep_height: Measurement
    ball_girth: Measurement
    instep_girth: Measurement
    unscaled_ratios: Mapping[str, float] | None = field(default=None, compare=False)

    @property
    def scaled(self) -> bool:
        return self.unscaled_ratios is None

    def values_mm(self) -> dict[str, float | None]:
        """Name -> value in mm (None when unscaled)."""
        return {name: getattr(self, name).value_mm for name in MEASUREMENT_NAMES}

    def to_dict(self) -> dict[str, dict[str, float | None]]:
        """The JSON contract: ``{"stick_length": {"value_mm": ..., "uncertainty_mm": ...}, ...}``."""
        return {name: getattr(self, name).to_dict() for name in MEASUREMENT_NAMES}

    def ratios(self) -> dict[str, float]:
        """Scale-free ratios ``{"ball_width/stick_length": ..., ...}`` (``RATIO_DEFINITIONS``); a ratio whose
        denominator is zero is left out."""
        if self.unscaled_ratios is not None:
            return dict(self.unscaled_ratios)
        values = self.values_mm()
        out = {}
        for num, den in RATIO_DEFINITIONS:
            a, b = values[num], values[den]
            if a is not None and b is not None and b != 0:
                out[f"{num}/{den}"] = float(a / b)
        return out

    def as_unscaled(self) -> Measurements:
        """Copy with every value and uncertainty None, keeping the ratios (for a result without scale)."""
        ratios = self.ratios()
        empty = {name: Measurement(None, None) for name in MEASUREMENT_NAMES}
        return Measurements(**empty, unscaled_ratios=ratios)

    def with_uncertainties(self, uncertainty_mm: Mapping[str, float]) -> Measurements:
        """Copy with the given uncertainties (mm, one standard deviation) attached; unknown names raise."""
        unknown = set(uncertainty_mm) - set(MEASUREMENT_NAMES)
        if unknown:
            raise ValueError(f"unknown measurement names {sorted(unknown)}; expected some of {MEASUREMENT_NAMES}")
        changes = {}
        for name, u in uncertainty_mm.items():
            m = getattr(self, name)
            changes[name] = Measurement(m.value_mm, None if m.value_mm is None else float(u))
        return replace(self, **changes)


# ----------------------------------------------------------------------------------------------------------
# Landmarks
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FootLandmarks:
    """The anatomical points the definitions need, each (3,) in mm in the foot frame.

    Attributes:
        midfoot: joint 0, root of the skeleton (arch height is taken below it).
        mtp1: first metatarsophalangeal joint, joint 1 ``toe1_proximal`` (ball girth plane).
        toe1_distal: interphalangeal joint of the big toe, joint 2 (toe height).
        mtp5: fifth metatarsophalangeal joint, joint 13 ``toe5_proximal`` (ball girth plane).
        ankle: joint 16, between the malleoli; its height sets where the leg begins (``LEG_CUT_FACTOR``).
    """

    midfoot: np.ndarray
    mtp1: np.ndarray
    toe1_distal: np.ndarray
    mtp5: np.ndarray
    ankle: np.ndarray

    JOINTS = {"midfoot": "midfoot", "mtp1": "toe1_proximal", "toe1_distal": "toe1_distal",
              "mtp5": "toe5_proximal", "ankle": "ankle"}  # fmt: skip
    """Landmark -> name in ``skeleton.JOINT_NAMES``."""

    def __post_init__(self) -> None:
        for f in fields(self):
            p = np.asarray(getattr(self, f.name), dtype=np.float64).reshape(-1)
            if p.shape != (3,):
                raise ValueError(f"landmark {f.name} must be a 3D point (3,), got shape {p.shape}")
            if not np.isfinite(p).all():
                raise ValueError(f"landmark {f.name} contains NaN or infinite values: {p}")
            p.setflags(write=False)
            object.__setattr__(self, f.name, p)

    @classmethod
    def from_joints(cls, joints: np.ndarray) -> FootLandmarks:
        """Pick the landmarks from the 18 joints (``skeleton.JOINT_NAMES`` order), (18, 3) mm, foot frame."""
        j = np.asarray(joints, dtype=np.float64)
        if j.shape != (NUM_JOINTS, 3):
            raise ValueError(f"expected joints of shape ({NUM_JOINTS}, 3), got {j.shape}")
        return cls(**{name: j[JOINT_INDEX[joint]] for name, joint in cls.JOINTS.items()})

    def mirrored(self) -> FootLandmarks:
        """The mirror image y -> -y (left <-> right foot)."""
        flip = np.array([1.0, -1.0, 1.0])
        return FootLandmarks(**{f.name: getattr(self, f.name) * flip for f in fields(self)})

    def __repr__(self) -> str:
        pts = ", ".join(f"{f.name}={np.round(getattr(self, f.name), 1).tolist()}" for f in fields(self))
        return f"FootLandmarks({pts})"


# ----------------------------------------------------------------------------------------------------------
# Length and width from vertices (used by the shape model too: keep signatures and definitions)
# ----------------------------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------------------------
# Plane sections
# ----------------------------------------------------------------------------------------------------------


def plane_section(
    mesh: trimesh.Trimesh, origin: np.ndarray, normal: np.ndarray, z_max: float | None = None
) -> np.ndarray:
    """Segments where a plane cuts the mesh, optionally cut off above ``z_max`` (the leg).

    Args:
        mesh: the foot, mm, foot frame.
        origin: (3,) a point of the plane, mm.
        normal: (3,) the plane's normal (any length).
        z_max: keep only what lies at or below this height, mm; segments crossing it are clipped.

    Returns:
        (S, 2, 3) segment end points, mm (S may be 0).
    """
    normal, origin = np.asarray(normal, dtype=np.float64), np.asarray(origin, dtype=np.float64)
    # only the faces with a vertex on the plane or on both sides of it (by trimesh's own dot products and
    # tolerance) are handed over: the same segments in the same order, a quarter faster (the uncertainty takes
    # about 100 sections a photo)
    dots = np.dot(mesh.vertices - origin, normal)
    side = np.zeros(len(dots), np.int8)
    side[dots < -trimesh.tol.merge] = -1
    side[dots > trimesh.tol.merge] = 1
    a, b, c = side[mesh.faces[:, 0]], side[mesh.faces[:, 1]], side[mesh.faces[:, 2]]
    crossing = np.flatnonzero((a != b) | (b != c) | (a == 0))
    segments = trimesh.intersections.mesh_plane(
        mesh, plane_normal=normal, plane_origin=origin, local_faces=crossing, cached_dots=dots
    )
    segments = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
    if z_max is not None:
        segments = clip_segments(segments, np.array([0.0, 0.0, 1.0]), z_max)
    return segments


def clip_segments(segments: np.ndarray, direction: np.ndarray, limit: float) -> np.ndarray:
    """Keep the parts of segments (S, 2, 3) where ``p @ direction <= limit``; the crossing ends are moved onto
    the boundary."""
    s = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
    d = s @ direction  # (S, 2)
    s = s[(d <= limit).any(axis=1)]
    d = s @ direction
    over = d > limit  # (S, 2); at most one end per kept segment
    if over.any():
        rows, ends = np.nonzero(over)
        other = 1 - ends
        t = (limit - d[rows, other]) / (d[rows, ends] - d[rows, other])  # in [0, 1)
        s = s.copy()
        s[rows, ends] = s[rows, other] + t[:, None] * (s[rows, ends] - s[rows, other])
    return s


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3) in-plane axes (u, v) of a vertical plane: u horizontal (``z x n``), v = +z (up)."""
    n = np.asarray(normal, dtype=np.float64)
    u = np.cross([0.0, 0.0, 1.0], n)
    norm = np.linalg.norm(u)
    if norm < 1e-9:
        raise ValueError("plane_basis expects a vertical plane (a horizontal normal)")
    return np.stack([u / norm, [0.0, 0.0, 1.0]])


def convex_perimeter(points_2d: np.ndarray, what: str = "section") -> float:
    """Perimeter of the convex hull of (N, 2) points: what a tape around them measures."""
    p = np.unique(np.round(np.asarray(points_2d, dtype=np.float64), 9), axis=0)
    if len(p) < 3:
        raise ValueError(f"{what}: only {len(p)} distinct points, cannot take a girth")
    try:
        hull = ConvexHull(p)
    except QhullError as err:
        raise ValueError(f"{what}: the section is degenerate (collinear points), cannot take a girth") from err
    return float(hull.area)  # in 2D, ConvexHull.area is the perimeter


def _require(segments: np.ndarray, what: str, where: str) -> np.ndarray:
    if len(segments) == 0:
        raise ValueError(
            f"cannot measure {what}: the section {where} does not cut the foot (empty section); "
            "is the mesh in the foot frame (x heel->toe, z up, floor z = 0) "
            "and are the landmarks on the foot?"
        )
    return segments


# ----------------------------------------------------------------------------------------------------------
# The eight measurements
# ----------------------------------------------------------------------------------------------------------


def measure_foot(
    vertices: np.ndarray, faces: np.ndarray, landmarks: FootLandmarks, side: Side = "left"
) -> Measurements:
    """The eight measurements of a foot mesh in the canonical pose (definitions: docs/measurements.md).

    Args:
        vertices: (V, 3) mm, foot frame: x from heel to toe, z up, floor at z = 0. The mesh is measured
            where it is: a foot that was moved or turned is not brought back into the frame (the floor and the
            long axis are checked; a small turn about z is not detected and changes the result).
        faces: (F, 3) int triangles indexing ``vertices``.
        landmarks: anatomical points in the same frame and units (``FootLandmarks.from_joints``).
        side: "left" (the model's side, big toe on -y) or "right" (the mirror image, big toe on +y); both
            measure the same for mirror-image feet.

    Returns:
        ``Measurements`` with values in mm and no uncertainty (``Measurements.with_uncertainties``).

    Raises:
        ValueError: bad shapes, NaN, a foot not in millimetres or not in the foot frame, landmarks on the
            wrong side, or a section that does not cut the foot.
    """
    v = check_vertices(vertices)
    f = _check_faces(faces, len(v))
    if not isinstance(landmarks, FootLandmarks):
        raise ValueError(f"landmarks must be a FootLandmarks (FootLandmarks.from_joints), got {type(landmarks)}")
    if side not in ("left", "right"):
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    if side == "right":  # measure the mirror image, a left foot (docs/conventions.md)
        v = v * np.array([1.0, -1.0, 1.0])
        f = f[:, ::-1]
        landmarks = landmarks.mirrored()
    _check_frame(v, landmarks, side)

    mesh = trimesh.Trimesh(vertices=v, faces=f, process=False)
    length = stick_length_mm(v)
    heel_start = heel_x(v)
    ankle_z = float(landmarks.ankle[2])
    leg_z = LEG_CUT_FACTOR * ankle_z
    x_axis = np.array([1.0, 0.0, 0.0])
    y_axis = np.array([0.0, 1.0, 0.0])

    # Heel width: y-extent of the section x = 18 % L, below the malleoli.
    x_heel = heel_start + HEEL_WIDTH_FRACTION * length
    heel = plane_section(mesh, np.array([x_heel, 0.0, 0.0]), x_axis, HEEL_WIDTH_MAX_HEIGHT * ankle_z)
    heel = _require(heel, "heel width", f"x = {x_heel:.1f} mm below z = {HEEL_WIDTH_MAX_HEIGHT * ankle_z:.1f} mm")
    heel_width = float(np.ptp(heel[..., 1]))

    # Toe height: highest point of the section through the big toe's IP joint, near that joint in y.
    ip = landmarks.toe1_distal
    toe = plane_section(mesh, ip, x_axis, leg_z)
    half = TOE_HALF_WIDTH_FRACTION * length
    toe = clip_segments(clip_segments(toe, y_axis, ip[1] + half), -y_axis, -(ip[1] - half))
    toe = _require(toe, "toe height", f"x = {ip[0]:.1f} mm within {half:.1f} mm of the big toe (y = {ip[1]:.1f})")
    toe_height = float(toe[..., 2].max())

    # Arch height: lowest surface point on the vertical line x = midfoot, y = first MTP joint.
    mid = landmarks.midfoot
    arch = _require(plane_section(mesh, mid, x_axis, leg_z), "arch height", f"x = {mid[0]:.1f} mm")
    arch_height = _lowest_on_vertical_line(arch, float(landmarks.mtp1[1]), f"x = {mid[0]:.1f} mm")

    # Instep height and girth: the section x = 50 % L.
    x_instep = heel_start + INSTEP_FRACTION * length
    instep = plane_section(mesh, np.array([x_instep, 0.0, 0.0]), x_axis, leg_z)
    instep = _require(instep, "instep height and girth", f"x = {x_instep:.1f} mm")
    instep_height = float(instep[..., 2].max())
    if instep_height >= leg_z - 1e-6:
        warnings.warn(
            f"the instep section at x = {x_instep:.1f} mm reaches the leg cut z = {leg_z:.1f} mm "
            f"({LEG_CUT_FACTOR} x ankle height): instep height and girth may be truncated; "
            "check the ankle landmark",
            stacklevel=2,
        )
    instep_girth = convex_perimeter(instep.reshape(-1, 3) @ plane_basis(x_axis).T, "instep girth")

    # Ball girth: the vertical plane through both MTP joints.
    across = landmarks.mtp5 - landmarks.mtp1
    normal = np.cross(across * np.array([1.0, 1.0, 0.0]), [0.0, 0.0, 1.0])
    if np.linalg.norm(normal) < 1e-6:
        raise ValueError("mtp1 and mtp5 coincide in plan view: cannot place the ball girth plane")
    ball = _require(plane_section(mesh, landmarks.mtp1, normal, leg_z), "ball girth", "through mtp1 and mtp5")
    ball_girth = convex_perimeter(ball.reshape(-1, 3) @ plane_basis(normal).T, "ball girth")

    values = {
        "stick_length": length,
        "ball_width": ball_width_mm(v),
        "heel_width": heel_width,
        "toe_height": toe_height,
        "arch_height": arch_height,
        "instep_height": instep_height,
        "ball_girth": ball_girth,
        "instep_girth": instep_girth,
    }
    return Measurements(**{name: Measurement(float(values[name])) for name in MEASUREMENT_NAMES})


def _lowest_on_vertical_line(segments: np.ndarray, y0: float, where: str) -> float:
    """Lowest z where the section (segments in a plane x = const) crosses the vertical line y = y0."""
    y = segments[..., 1]  # (S, 2)
    z = segments[..., 2]
    lo, hi = y.min(axis=1), y.max(axis=1)
    hit = (lo <= y0) & (hi >= y0)
    if not hit.any():
        raise ValueError(
            f"cannot measure arch height: the section {where} does not reach y = {y0:.1f} mm (the first MTP "
            "joint's y); are the landmarks on this foot?"
        )
    y, z = y[hit], z[hit]
    dy = y[:, 1] - y[:, 0]
    flat = np.abs(dy) < 1e-12
    t = np.where(flat, 0.0, (y0 - y[:, 0]) / np.where(flat, 1.0, dy))
    z_hit = np.where(flat, z.min(axis=1), z[:, 0] + t * (z[:, 1] - z[:, 0]))
    return float(z_hit.min())


# ----------------------------------------------------------------------------------------------------------
# Input checks
# ----------------------------------------------------------------------------------------------------------


def _check_faces(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"expected faces of shape (F, 3) with F >= 1, got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        if not (np.isfinite(f).all() and np.all(f == np.round(f))):
            raise ValueError("faces must be integer vertex indices")
        f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= num_vertices:
        raise ValueError(f"faces index vertices outside [0, {num_vertices - 1}]: min {f.min()}, max {f.max()}")
    return f.astype(np.int64)


def _check_frame(v: np.ndarray, landmarks: FootLandmarks, side: Side) -> None:
    """Units, floor and long axis of a (left, after mirroring) foot; landmarks on the foot and side."""
    length = stick_length_mm(v)
    lo, hi = LENGTH_RANGE_MM
    if not lo <= length <= hi:
        hint = " It looks like metres: multiply by 1000." if length < 1.0 else ""
        hint = " It looks like centimetres: multiply by 10." if 10.0 <= length < lo else hint
        raise ValueError(
            f"foot length {length:.4g} is outside [{lo:.0f}, {hi:.0f}] mm: "
            "the mesh is not a foot in millimetres." + hint
        )
    floor = float(v[:, 2].min())
    if abs(floor) > FLOOR_TOLERANCE_MM:
        raise ValueError(
            f"the lowest point is at z = {floor:.1f} mm, not on the floor z = 0: "
            "the mesh is not in the foot frame (x heel->toe, z up, floor z = 0); "
            "bring it to the canonical pose and frame first"
        )
    low = v[v[:, 2] <= FOOT_HEIGHT_FRACTION * np.ptp(v[:, 0])]
    if np.ptp(low[:, 1]) > np.ptp(low[:, 0]):
        raise ValueError("the foot is wider (y) than long (x): the mesh is not in the foot frame (x heel->toe)")
    pts = np.stack([getattr(landmarks, f.name) for f in fields(landmarks)])
    margin = 0.1 * length
    if (pts < v.min(axis=0) - margin).any() or (pts > v.max(axis=0) + margin).any():
        raise ValueError(
            "landmarks lie outside the mesh's bounding box: they must be in the mesh's frame and units (mm)"
        )
    if landmarks.mtp1[1] > landmarks.mtp5[1]:
        other = "right" if side == "left" else "left"
        raise ValueError(
            f"the first MTP joint lies lateral of the fifth for a {side} foot (big toe on the wrong side): "
            f"is it a {other} foot? pass side={other!r}"
        )
