"""Foot scans for template registration: loading and checking meshes, marker files, the template's markers.

Scan files: OBJ, PLY, STL (or OFF) holding one triangle mesh of one foot, in millimetres unless told otherwise
(``unit``). What :func:`load_scan` checks, and why it matters to registration:

- readable, a triangle mesh (not a point cloud, not an empty scene), at least ``MIN_FACES`` triangles;
- finite coordinates;
- units: the bounding-box diagonal must lie in ``FOOT_DIAGONAL_MM``; a scan 1000x too small is reported as
  "metres?" (pass ``unit="m"``), 10x too small as "centimetres?"; nothing is ever rescaled silently;
- non-manifold edges (shared by more than two triangles: overlapping sheets, triangle soups) break the normals and
  the hole borders that the data term relies on: more than ``MAX_NONMANIFOLD_EDGE_FRACTION`` of the edges is an
  error, fewer a warning;
- inconsistent winding is repaired (trimesh's ``fix_winding``) and an inward-facing scan (negative signed volume)
  flipped, each with a warning: the data term compares template and scan normals;
- degenerate (zero-area) triangles are dropped, with a warning;
- several pieces: small ones (less than ``MAX_EXTRA_PIECE_AREA_FRACTION`` of the area in all) are dropped with a
  warning; more is an error (two feet, or a foot and a floor, in one file).

Holes are fine (the smoothness term bridges small ones). Marker files: see :func:`load_markers` and
``docs/registration.md``.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from footmesh.errors import InputError

log = logging.getLogger(__name__)

SCAN_SUFFIXES = (".obj", ".ply", ".stl", ".off")
UNIT_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
FOOT_DIAGONAL_MM = (80.0, 1500.0)
"""Accepted bounding-box diagonal of a foot scan in mm (a child's foot to a foot with most of the shank)."""
MIN_FACES = 100
MAX_NONMANIFOLD_EDGE_FRACTION = 0.01
MAX_EXTRA_PIECE_AREA_FRACTION = 0.05
MARKER_SURFACE_TOLERANCE_MM = 30.0
"""A marker farther than this from the scan surface means scan and markers disagree on frame or units."""

MARKER_NAMES: dict[str, str] = {
    "heel": "rearmost point of the heel, at about the height of the heel's bulge",
    "heel_low": "lowest point under the heel (on the sole, below the calcaneus)",
    "toe1_tip": "tip of the big toe (farthest point along the foot axis)",
    "toe2_tip": "tip of the second toe",
    "toe3_tip": "tip of the third toe",
    "toe4_tip": "tip of the fourth toe",
    "toe5_tip": "tip of the little toe",
    "ball_medial": "most medial point over the first metatarsal head (inner end of the ball width)",
    "ball_lateral": "most lateral point over the fifth metatarsal head (outer end of the ball width)",
    "malleolus_medial": "most prominent point of the medial malleolus (inner ankle bone)",
    "malleolus_lateral": "most prominent point of the lateral malleolus (outer ankle bone)",
    "arch_medial": "highest point of the medial arch's skin line, on the inner side (navicular region)",
    "instep": "top of the instep on the dorsum, above the midfoot",
}
"""Named anatomical markers a marker file may use (any subset; at least 3 to initialise from them)."""

TEMPLATE_MARKERS_FILE = "template_markers.json"


class ScanError(InputError):
    """A scan or marker file that cannot be used; the message names the file and the fix."""


@dataclass(frozen=True)
class ScanReport:
    """What :func:`load_scan` found and repaired."""

    path: str
    vertices: int
    faces: int
    diagonal_mm: float
    boundary_edges: int
    warnings: tuple[str, ...]


def load_scan(path: str | os.PathLike, unit: str = "mm") -> tuple[object, ScanReport]:
    """Load and check one foot scan (see the module docstring for every check).

    Args:
        path: OBJ/PLY/STL/OFF file.
        unit: the file's length unit, ``mm``, ``cm`` or ``m``; the mesh is returned in mm.

    Returns:
        (``trimesh.Trimesh`` in mm, :class:`ScanReport`).

    Raises:
        FileNotFoundError: no such file.
        ScanError: unreadable, not a mesh, empty, non-manifold, units off, several large pieces.
    """
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"scan not found: {p}")
    if p.suffix.lower() not in SCAN_SUFFIXES:
        raise ScanError(f"{p}: unsupported scan format {p.suffix!r}; use one of {', '.join(SCAN_SUFFIXES)}")
    if unit not in UNIT_TO_MM:
        raise ScanError(f"unknown unit {unit!r}; use one of {', '.join(UNIT_TO_MM)}")
    try:
        loaded = trimesh.load(p, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types on bad files
        raise ScanError(f"{p}: cannot read it as a mesh ({type(exc).__name__}: {exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh):
        kind = type(loaded).__name__
        raise ScanError(f"{p}: not a triangle mesh (found {kind}); a point cloud must be meshed first")
    return check_scan(loaded, unit=unit, name=str(p))


def check_scan(mesh, unit: str = "mm", name: str = "scan") -> tuple[object, ScanReport]:
    """The checks and repairs of :func:`load_scan` on an in-memory ``trimesh.Trimesh`` (returns a new mesh, mm)."""
    import trimesh

    if unit not in UNIT_TO_MM:
        raise ScanError(f"unknown unit {unit!r}; use one of {', '.join(UNIT_TO_MM)}")
    warnings: list[str] = []
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    if len(f) == 0 or len(v) == 0:
        raise ScanError(f"{name}: the mesh is empty (no triangles)")
    if not np.isfinite(v).all():
        raise ScanError(f"{name}: vertex coordinates contain NaN or infinity")
    if len(f) < MIN_FACES:
        raise ScanError(f"{name}: only {len(f)} triangles; a foot scan needs at least {MIN_FACES}")

    # units, before anything else: a wrong unit makes every later threshold meaningless
    factor = UNIT_TO_MM[unit]
    diag_mm = float(np.linalg.norm(np.ptp(v, axis=0))) * factor
    lo, hi = FOOT_DIAGONAL_MM
    if not lo <= diag_mm <= hi:
        hint = ""
        for other, f_other in UNIT_TO_MM.items():
            d = diag_mm / factor * f_other
            if other != unit and lo <= d <= hi:
                hint = f"; it looks like {other}: pass --unit {other} (unit={other!r}) or rescale the file"
                break
        raise ScanError(
            f"{name}: bounding-box diagonal is {diag_mm:.4g} mm read as {unit}, outside the {lo:g}-{hi:g} mm of a "
            f"foot{hint or '; check the units or that this is a foot scan'}"
        )
    if factor != 1.0:
        log.info("%s: scaled by %g (%s -> mm) as asked", name, factor, unit)
    m = trimesh.Trimesh(v * factor, f, process=True, validate=False)

    # degenerate triangles
    area = m.area_faces
    bad = area <= 1e-12 * max(float(area.max()), 1e-30)
    if bad.any():
        warnings.append(f"dropped {int(bad.sum())} degenerate (zero-area) triangles")
        m.update_faces(~bad)
        m.remove_unreferenced_vertices()

    # non-manifold edges
    edges = np.sort(m.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    nonmanifold = int((counts > 2).sum())
    if nonmanifold > MAX_NONMANIFOLD_EDGE_FRACTION * len(counts):
        raise ScanError(
            f"{name}: {nonmanifold} of {len(counts)} edges are shared by more than two triangles (non-manifold: "
            "overlapping sheets or a triangle soup); registration needs a manifold surface for normals and hole "
            "borders. Repair it (e.g. MeshLab 'Repair non Manifold Edges', or re-mesh the scan) and retry"
        )
    if nonmanifold:
        warnings.append(f"{nonmanifold} non-manifold edges (fewer than {MAX_NONMANIFOLD_EDGE_FRACTION:.0%})")

    # pieces
    pieces = m.split(only_watertight=False)
    if len(pieces) > 1:
        areas = np.array([pc.area for pc in pieces])
        order = np.argsort(areas)[::-1]
        rest = float(areas[order[1:]].sum() / areas.sum())
        if rest > MAX_EXTRA_PIECE_AREA_FRACTION:
            raise ScanError(
                f"{name}: {len(pieces)} separate pieces and the smaller ones hold {rest:.0%} of the area "
                "(two feet, or a foot and the floor?); keep one foot per file"
            )
        warnings.append(f"dropped {len(pieces) - 1} small loose pieces ({rest:.1%} of the area)")
        m = pieces[order[0]]

    # winding and orientation
    if not m.is_winding_consistent:
        trimesh.repair.fix_winding(m)
        warnings.append("triangle winding was inconsistent; repaired")
    if _signed_volume(m.vertices, m.faces) < 0:
        m.invert()
        warnings.append("normals pointed inwards; flipped")

    boundary = int((counts == 1).sum())
    for w in warnings:
        log.warning("%s: %s", name, w)
    report = ScanReport(name, len(m.vertices), len(m.faces), diag_mm, boundary, tuple(warnings))
    return m, report


def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume by the divergence theorem (meaningful for a closed mesh, roughly so for small holes)."""
    tri = np.asarray(vertices)[np.asarray(faces)]
    c = tri.mean(axis=(0, 1))
    tri = tri - c
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


# --- marker files -------------------------------------------------------------------------------------------


def parse_markers(data: object, name: str = "markers") -> dict[str, np.ndarray]:
    """Validate marker-file content: ``{"units": "mm", "markers": {"heel": [x, y, z], ...}}`` -> name -> (3,) mm."""
    if not isinstance(data, dict) or "markers" not in data:
        raise ScanError(f'{name}: expected an object {{"units": "mm", "markers": {{"heel": [x, y, z], ...}}}}')
    unit = data.get("units", "mm")
    if unit not in UNIT_TO_MM:
        raise ScanError(f"{name}: unknown units {unit!r}; use one of {', '.join(UNIT_TO_MM)}")
    markers = data["markers"]
    if not isinstance(markers, dict) or not markers:
        raise ScanError(f"{name}: 'markers' must be a non-empty object name -> [x, y, z]")
    out: dict[str, np.ndarray] = {}
    for key, value in markers.items():
        if key not in MARKER_NAMES:
            raise ScanError(f"{name}: unknown marker {key!r}; known markers: {', '.join(MARKER_NAMES)}")
        arr = np.asarray(value, dtype=np.float64) if _is_triple(value) else None
        if arr is None or not np.isfinite(arr).all():
            raise ScanError(f"{name}: marker {key!r} must be three finite numbers [x, y, z], got {value!r}")
        out[key] = arr * UNIT_TO_MM[unit]
    return out


def _is_triple(value: object) -> bool:
    return (
        isinstance(value, list | tuple)
        and len(value) == 3
        and all(isinstance(x, int | float) and not isinstance(x, bool) for x in value)
    )


def load_markers(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a marker file (JSON; format in ``docs/registration.md``); returns name -> (3,) point in mm."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"marker file not found: {p}")
    try:
        data = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ScanError(f"{p}: not valid JSON ({exc})") from exc
    return parse_markers(data, name=str(p))


def save_markers(path: str | os.PathLike, markers: dict[str, np.ndarray]) -> None:
    """Write a marker file in mm."""
    for key in markers:
        if key not in MARKER_NAMES:
            raise ValueError(f"unknown marker {key!r}; known markers: {', '.join(MARKER_NAMES)}")
    data = {"units": "mm", "markers": {k: [round(float(x), 4) for x in v] for k, v in markers.items()}}
    Path(path).write_text(json.dumps(data, indent=2) + "\n")


def check_markers_on_scan(markers: dict[str, np.ndarray], mesh, name: str = "markers") -> np.ndarray:
    """Distances (mm) of the markers to the scan surface; ScanError when one is implausibly far.

    A marker more than ``MARKER_SURFACE_TOLERANCE_MM`` from the surface means that markers and scan disagree on
    the frame or the units.
    """
    import trimesh

    if not markers:
        return np.zeros(0)
    names = list(markers)
    pts = np.array([markers[k] for k in names])
    _, dist, _ = trimesh.proximity.closest_point(mesh, pts)
    worst = int(np.argmax(dist))
    if dist[worst] > MARKER_SURFACE_TOLERANCE_MM:
        raise ScanError(
            f"{name}: marker {names[worst]!r} lies {dist[worst]:.1f} mm from the scan surface (more than "
            f"{MARKER_SURFACE_TOLERANCE_MM:g} mm): are markers and scan in the same frame and units?"
        )
    return np.asarray(dist)


def template_markers(num_vertices: int | None = None) -> dict[str, int]:
    """The template's own markers (name -> vertex id), shipped as ``model/data/template_markers.json``.

    The ids are vertices of FIND's 1,002-vertex template; Loop subdivision keeps those vertices first, so the same
    ids hold on the footmesh template (4,002 vertices) and its PCA models.

    Args:
        num_vertices: the template's vertex count, to check that every id fits.
    """
    ref = resources.files("footmesh.model").joinpath("data", TEMPLATE_MARKERS_FILE)
    data = json.loads(ref.read_text())
    ids = {str(k): int(v) for k, v in data["markers"].items()}
    if num_vertices is not None and max(ids.values()) >= num_vertices:
        raise ValueError(
            f"template markers index up to vertex {max(ids.values())}, the template has {num_vertices} vertices"
        )
    return ids


FINE_TEMPLATE_VERTICES = 4002
"""Vertices of the footmesh template (:mod:`footmesh.model.vertex_ids`)."""
COARSE_TEMPLATE_VERTICES = 1002
"""Vertices of FIND's template; one Loop subdivision of it (these vertices first) is the 4,002-vertex template."""


def nearest_coarse_vertices(
    fine_vertices: np.ndarray, ids: dict[str, int], num_coarse: int = COARSE_TEMPLATE_VERTICES
) -> dict[str, int]:
    """Move vertex ids of the fine (subdivided) template to the nearest of its first ``num_coarse`` vertices.

    Loop subdivision keeps the coarse mesh's vertices first, so vertex ``i < num_coarse`` of the fine template is
    vertex ``i`` of the coarse one: the returned ids hold on both. Ids already below ``num_coarse`` stay.

    Args:
        fine_vertices: (V_fine, 3) the fine template's vertices (mm), e.g. a model's mean.
        ids: name -> vertex id on the fine template.
        num_coarse: vertices of the coarse template.
    """
    v = np.asarray(fine_vertices, dtype=np.float64)
    out = {}
    for name, i in ids.items():
        i = int(i)
        out[name] = i if i < num_coarse else int(np.argmin(np.linalg.norm(v[:num_coarse] - v[i], axis=1)))
    return out


def template_landmarks(num_vertices: int, fine_vertices: np.ndarray | None = None) -> dict[str, int]:
    """footmesh's landmarks (:data:`footmesh.model.vertex_ids.LANDMARKS`) on a template of ``num_vertices``.

    The one place that says which vertices :func:`footmesh.model.rig.build_rig` and
    :func:`footmesh.model.template.to_foot_frame` get for a template: ``LANDMARKS`` itself on the 4,002-vertex
    template; on FIND's 1,002-vertex template (its first vertices) each landmark moved to the nearest coarse
    vertex (:func:`nearest_coarse_vertices`).

    Args:
        num_vertices: the template's vertex count (4,002 or 1,002).
        fine_vertices: (4002, 3) positions of the fine template to measure "nearest" on; default the packaged
            model's mean.

    Raises:
        ValueError: for any other vertex count.
    """
    from footmesh.model.vertex_ids import LANDMARKS

    if num_vertices == FINE_TEMPLATE_VERTICES:
        return dict(LANDMARKS)
    if num_vertices != COARSE_TEMPLATE_VERTICES:
        raise ValueError(
            f"footmesh landmarks are defined on the {FINE_TEMPLATE_VERTICES:,}-vertex template and its "
            f"{COARSE_TEMPLATE_VERTICES:,}-vertex base, not on a template of {num_vertices:,} vertices"
        )
    if fine_vertices is None:
        from footmesh.model.assets import load_asset

        fine_vertices = load_asset().mean_vertices
    return nearest_coarse_vertices(fine_vertices, LANDMARKS)


# --- synthetic scans (tests and benchmarks) -----------------------------------------------------------------


@dataclass(frozen=True)
class SyntheticScan:
    """A scan made from a known shape, with its ground truth.

    Attributes:
        mesh: ``trimesh.Trimesh`` (scan frame, mm): other topology, noise, holes, posed and scaled.
        markers: name -> (3,) noisy marker point, scan frame, mm.
        true_vertices: (V, 3) the shape on the template's topology, posed and scaled like the scan: the true
            correspondent of every template vertex.
        scale: the scale applied to the shape (the scan is ``scale * R @ shape + t``).
    """

    mesh: object
    markers: dict[str, np.ndarray]
    true_vertices: np.ndarray
    scale: float


def synthetic_scan(
    vertices: np.ndarray,
    faces: np.ndarray,
    marker_ids: dict[str, int],
    seed: int,
    target_vertices: int = 3000,
    noise_mm: float = 0.3,
    holes: int = 3,
    hole_radius_mm: float = 3.0,
    marker_noise_mm: float = 1.0,
    scale_range: tuple[float, float] = (0.9, 1.1),
) -> SyntheticScan:
    """Turn a shape on the template's topology into a realistic scan of another topology, with ground truth.

    Steps: one midpoint subdivision, then quadric decimation to about ``target_vertices`` (``fast_simplification``)
    so no scan vertex is a template vertex; isotropic Gaussian noise of ``noise_mm`` per axis; ``holes`` small
    holes (faces within ``hole_radius_mm`` of random surface points deleted); a random rotation (uniform),
    translation (N(0, 100 mm) per axis) and scale (uniform in ``scale_range``). Markers: the true marker vertices,
    posed, plus ``marker_noise_mm`` Gaussian noise per axis.

    Args:
        vertices: (V, 3) mm, the true shape on the template topology.
        faces: (F, 3) template faces.
        marker_ids: marker name -> template vertex id.
        seed: everything random comes from ``numpy.random.default_rng(seed)``.
    """
    import fast_simplification
    import trimesh
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    sv, sf = trimesh.remesh.subdivide(v, f)
    reduction = float(np.clip(1.0 - target_vertices / len(sv), 0.0, 0.99))
    sv, sf = fast_simplification.simplify(sv.astype(np.float64), sf.astype(np.int64), target_reduction=reduction)
    sv = np.asarray(sv, dtype=np.float64) + rng.normal(0.0, noise_mm, size=(len(sv), 3))
    sf = np.asarray(sf, dtype=np.int64)
    if holes:
        cen = sv[sf].mean(axis=1)
        centres = cen[rng.choice(len(sf), size=holes, replace=False)]
        d = np.linalg.norm(cen[:, None, :] - centres[None], axis=2).min(axis=1)
        sf = sf[d > hole_radius_mm]
    mesh = trimesh.Trimesh(sv, sf, process=True)
    mesh.remove_unreferenced_vertices()

    rot = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
    scale = float(rng.uniform(*scale_range))
    trans = rng.normal(0.0, 100.0, size=3)

    def pose(p: np.ndarray) -> np.ndarray:
        return scale * p @ rot.T + trans

    mesh.vertices = pose(np.asarray(mesh.vertices))
    markers = {k: pose(v[i]) + rng.normal(0.0, marker_noise_mm, size=3) for k, i in marker_ids.items()}
    return SyntheticScan(mesh=mesh, markers=markers, true_vertices=pose(v), scale=scale)
