"""Mesh hierarchy of the template for the spiral decoder (thesis 3.3.2): QSLIM levels, resampling, spirals.

Level 0 is the full template (4,002 vertices); each further level has about half the vertices of the one
before, made by quadric-error edge collapses (Garland & Heckbert's QSLIM, via ``fast_simplification``). Between
neighbouring levels ``l`` (fine) and ``l + 1`` (coarse):

- ``down[l]`` (V_{l+1}, V_l): each coarse vertex = the barycentric combination of the fine triangle closest to it
  (QSLIM moves the vertices it keeps, so a coarse vertex is not a fine vertex);
- ``up[l]`` (V_l, V_{l+1}): each fine vertex = the barycentric combination of the coarse triangle closest to it
  (CoMA / Neural3DMM's up-sampling).

Every row holds three non-negative weights summing to 1, stored as sparse COO torch tensors.

Spirals (thesis Algorithm 1, Neural3DMM, SpiralNet++): for every vertex a fixed-length sequence of vertex ids:
the vertex, then its one-ring counter-clockwise (seen from outside), then the next rings outward, each ring
continuing the turn of the one before. The start of the one-ring is fixed geometrically (the neighbour whose
direction in the tangent plane is closest to the projected ``+x`` axis, heel to toe), so that the same spiral
position points the same way all over the mesh, as a CNN kernel's rows do. With dilation ``d`` the spiral is
built ``d`` times longer and every ``d``-th entry kept (SpiralNet++). A spiral that runs out of vertices (only on
tiny meshes) is padded with the centre vertex.

Everything is deterministic; ``MeshHierarchy.save`` writes an ``.npz`` whose bytes depend only on the arrays, and
``template_hierarchy(cache=...)`` reuses it when it was built from the same template and parameters.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from footmesh.geometry.mesh import vertex_normals

FORMAT_VERSION = 1
DEFAULT_LEVELS = 4
"""Levels below the full mesh: 4,002 -> ~2,000 -> ~1,000 -> ~500 -> ~250 vertices (thesis Figure 3.6's five
layers, the first at 1/16 of the template)."""
DEFAULT_SPIRAL_LENGTH = 12
"""The vertex, its one-ring (6 on average) and about the first third of its second ring; the Inception Spiral
Module's filters then see 1, 4, 8 and 12 vertices."""
REFERENCE_AXIS = (1.0, 0.0, 0.0)
"""Spirals start towards this direction (foot frame +x, heel to toe) projected on the tangent plane ..."""
FALLBACK_AXIS = (0.0, 0.0, 1.0)
"""... or towards this one where the surface faces +-x (toe tips, back of the heel)."""
FALLBACK_COSINE = 0.9
"""|normal . REFERENCE_AXIS| above which FALLBACK_AXIS is used."""


@dataclass(frozen=True)
class MeshHierarchy:
    """Meshes of the template from full (level 0) to coarsest, with resampling matrices and spirals.

    Attributes:
        vertices: per level (V_l, 3) float32, mm (the template's frame).
        faces: per level (F_l, 3) int64, counter-clockwise seen from outside.
        down: per level pair (V_{l+1}, V_l) sparse float32, rows of 3 barycentric weights summing to 1.
        up: per level pair (V_l, V_{l+1}) sparse float32, rows of 3 barycentric weights summing to 1.
        spirals: per level (V_l, spiral_length) int64 vertex ids, column 0 = the vertex itself.
        spiral_length: entries per spiral. dilation: spacing of the kept entries along the full spiral.
        ratio: fraction of the faces kept from one level to the next.
        key: hash of the level-0 mesh and the build parameters (checks a cached file is still valid).
    """

    vertices: tuple[np.ndarray, ...]
    faces: tuple[np.ndarray, ...]
    down: tuple[torch.Tensor, ...]
    up: tuple[torch.Tensor, ...]
    spirals: tuple[np.ndarray, ...]
    spiral_length: int
    dilation: int
    ratio: float
    key: str

    def __post_init__(self) -> None:
        n = len(self.vertices)
        if not (len(self.faces) == len(self.spirals) == n and len(self.down) == len(self.up) == n - 1):
            raise ValueError(
                f"MeshHierarchy: {n} vertex levels, {len(self.faces)} face levels, {len(self.spirals)} spiral "
                f"levels, {len(self.down)} down and {len(self.up)} up matrices (want n, n, n, n-1, n-1)"
            )
        for level in range(n - 1):
            fine, coarse = self.num_vertices[level], self.num_vertices[level + 1]
            if tuple(self.down[level].shape) != (coarse, fine) or tuple(self.up[level].shape) != (fine, coarse):
                raise ValueError(f"MeshHierarchy: matrices of level {level} do not map {fine} <-> {coarse} vertices")
        for level, spiral in enumerate(self.spirals):
            if spiral.shape != (self.num_vertices[level], self.spiral_length):
                raise ValueError(f"MeshHierarchy: spirals of level {level} have shape {spiral.shape}")

    @property
    def num_levels(self) -> int:
        """Number of meshes, the full one included."""
        return len(self.vertices)

    @property
    def num_vertices(self) -> tuple[int, ...]:
        return tuple(int(v.shape[0]) for v in self.vertices)

    def downsample(self, x: torch.Tensor, level: int) -> torch.Tensor:
        """Vertex features or positions of the full mesh (B, V_0, C) taken down to ``level``: (B, V_level, C)."""
        if not 0 <= level < self.num_levels:
            raise ValueError(f"level must lie in [0, {self.num_levels}), got {level}")
        for lower in range(level):
            x = resample(self.down[lower], x)
        return x

    def with_spirals(self, spiral_length: int, dilation: int = 1) -> MeshHierarchy:
        """This hierarchy with spirals of another length or dilation (itself when they already match)."""
        if (spiral_length, dilation) == (self.spiral_length, self.dilation):
            return self
        spirals = tuple(
            spiral_sequences(v, f, spiral_length, dilation) for v, f in zip(self.vertices, self.faces, strict=True)
        )
        key = _hierarchy_key(self.vertices[0], self.faces[0], self.num_levels - 1, self.ratio, spiral_length, dilation)
        return replace(self, spirals=spirals, spiral_length=spiral_length, dilation=dilation, key=key)

    def save(self, path: str | os.PathLike) -> None:
        """Write the hierarchy to an ``.npz`` (atomic; same arrays -> same bytes)."""
        from footmesh.report import write_npz

        arrays: dict[str, np.ndarray] = {
            "format_version": np.array(FORMAT_VERSION),
            "num_levels": np.array(self.num_levels),
            "spiral_length": np.array(self.spiral_length),
            "dilation": np.array(self.dilation),
            "ratio": np.array(self.ratio),
            "key": np.array(self.key),
        }
        for level in range(self.num_levels):
            arrays[f"vertices_{level}"] = self.vertices[level]
            arrays[f"faces_{level}"] = self.faces[level]
            arrays[f"spirals_{level}"] = self.spirals[level]
        for level in range(self.num_levels - 1):
            for name, matrix in (("down", self.down[level]), ("up", self.up[level])):
                m = matrix.coalesce()
                arrays[f"{name}_indices_{level}"] = m.indices().numpy()
                arrays[f"{name}_values_{level}"] = m.values().numpy()
                arrays[f"{name}_shape_{level}"] = np.array(m.shape, dtype=np.int64)
        write_npz(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> MeshHierarchy:
        """Read a hierarchy written by ``save``."""
        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"mesh hierarchy not found: {p}")
        with np.load(io.BytesIO(p.read_bytes()), allow_pickle=False) as npz:
            version = int(npz["format_version"]) if "format_version" in npz else -1
            if version != FORMAT_VERSION:
                raise ValueError(f"{p}: mesh hierarchy format {version}, this footmesh reads {FORMAT_VERSION}")
            n = int(npz["num_levels"])

            def matrix(name: str, level: int) -> torch.Tensor:
                return torch.sparse_coo_tensor(
                    torch.from_numpy(npz[f"{name}_indices_{level}"]),
                    torch.from_numpy(npz[f"{name}_values_{level}"]),
                    tuple(int(s) for s in npz[f"{name}_shape_{level}"]),
                    check_invariants=True,
                ).coalesce()

            return cls(
                vertices=tuple(npz[f"vertices_{i}"] for i in range(n)),
                faces=tuple(npz[f"faces_{i}"] for i in range(n)),
                down=tuple(matrix("down", i) for i in range(n - 1)),
                up=tuple(matrix("up", i) for i in range(n - 1)),
                spirals=tuple(npz[f"spirals_{i}"] for i in range(n)),
                spiral_length=int(npz["spiral_length"]),
                dilation=int(npz["dilation"]),
                ratio=float(npz["ratio"]),
                key=str(npz["key"]),
            )

    def __repr__(self) -> str:
        return (
            f"MeshHierarchy(vertices={list(self.num_vertices)}, spiral_length={self.spiral_length}, "
            f"dilation={self.dilation})"
        )


def build_hierarchy(
    vertices: np.ndarray,
    faces: np.ndarray,
    num_levels: int = DEFAULT_LEVELS,
    ratio: float = 0.5,
    spiral_length: int = DEFAULT_SPIRAL_LENGTH,
    dilation: int = 1,
) -> MeshHierarchy:
    """Simplify a mesh ``num_levels`` times by quadric error, keeping ``ratio`` of the faces at each step.

    Args:
        vertices: (V, 3) mm. faces: (F, 3) vertex ids, consistently wound (outward normals).
        num_levels: levels below the full mesh. ratio: fraction of the faces (~ of the vertices) kept per level.
        spiral_length: entries per spiral (>= 1). dilation: keep every ``dilation``-th entry of a longer spiral.
    Returns:
        The hierarchy, level 0 being the input mesh itself.
    """
    try:
        import fast_simplification
    except ImportError as err:  # an optional dependency: only building a hierarchy needs it, loading one does not
        raise ImportError(
            "building a mesh hierarchy needs fast-simplification: pip install fast-simplification "
            "(or load a hierarchy saved with MeshHierarchy.save)"
        ) from err

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3) and faces (F, 3), got {v.shape} and {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces index vertices outside [0, {len(v)})")
    if num_levels < 0 or not 0.0 < ratio < 1.0:
        raise ValueError(f"need num_levels >= 0 and 0 < ratio < 1, got {num_levels} and {ratio}")
    _check_spiral_args(spiral_length, dilation)

    levels_v, levels_f = [v], [f]
    for level in range(num_levels):
        target = int(round(len(levels_f[-1]) * ratio))
        if target < 4:
            raise ValueError(f"level {level + 1} would keep {target} faces; use fewer levels or a larger ratio")
        pts, tri = fast_simplification.simplify(levels_v[-1], levels_f[-1], target_count=target)
        pts, tri = _drop_unused(np.asarray(pts, dtype=np.float64), np.asarray(tri, dtype=np.int64))
        levels_v.append(pts)
        levels_f.append(tri)

    down, up = [], []
    for level in range(num_levels):
        fine_v, fine_f = levels_v[level], levels_f[level]
        coarse_v, coarse_f = levels_v[level + 1], levels_f[level + 1]
        down.append(barycentric_matrix(coarse_v, fine_v, fine_f))
        up.append(barycentric_matrix(fine_v, coarse_v, coarse_f))
    spirals = tuple(
        spiral_sequences(lv, lf, spiral_length, dilation) for lv, lf in zip(levels_v, levels_f, strict=True)
    )
    return MeshHierarchy(
        vertices=tuple(lv.astype(np.float32) for lv in levels_v),
        faces=tuple(levels_f),
        down=tuple(down),
        up=tuple(up),
        spirals=spirals,
        spiral_length=spiral_length,
        dilation=dilation,
        ratio=ratio,
        key=_hierarchy_key(v, f, num_levels, ratio, spiral_length, dilation),
    )


def template_hierarchy(
    cache: str | os.PathLike | None = None,
    num_levels: int = DEFAULT_LEVELS,
    spiral_length: int = DEFAULT_SPIRAL_LENGTH,
    dilation: int = 1,
) -> MeshHierarchy:
    """The hierarchy of the packaged template (``default_model()``'s mean shape, zero pose, left foot frame).

    With ``cache``, a file there built from the same template and parameters is loaded instead of recomputed;
    otherwise the hierarchy is built and written there (the caller asked for it, so this is no hidden side effect).
    """
    from footmesh.model.layer import default_model

    model = default_model()
    vertices = model.mean_vertices.detach().cpu().numpy().astype(np.float64)
    faces = model.faces_left.cpu().numpy()
    key = _hierarchy_key(vertices, faces, num_levels, 0.5, spiral_length, dilation)
    if cache is not None and Path(cache).is_file():
        try:
            cached = MeshHierarchy.load(cache)
        except (ValueError, KeyError):
            cached = None  # an old or foreign file: rebuilt and overwritten below
        if cached is not None and cached.key == key:
            return cached
    hierarchy = build_hierarchy(vertices, faces, num_levels, spiral_length=spiral_length, dilation=dilation)
    if cache is not None:
        hierarchy.save(cache)
    return hierarchy


def barycentric_matrix(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> torch.Tensor:
    """Sparse (P, V) matrix whose row p holds the barycentric weights of the closest point to ``points[p]``.

    Args:
        points: (P, 3) mm. vertices: (V, 3) mm and faces: (F, 3) of the mesh they are projected on.
    Returns:
        (P, V) sparse COO float32 with exactly 3 stored entries per row, non-negative and summing to 1.
    """
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces), process=False)
    closest, _, triangle = trimesh.proximity.closest_point(mesh, np.asarray(points, dtype=np.float64))
    corners = np.asarray(faces)[triangle]  # (P, 3)
    weights = trimesh.triangles.points_to_barycentric(mesh.vertices[corners], closest)
    # the closest point lies in its triangle; clipping only removes rounding outside it
    weights = np.clip(weights, 0.0, None)
    weights /= weights.sum(axis=1, keepdims=True)
    rows = np.repeat(np.arange(len(points)), 3)
    indices = torch.from_numpy(np.stack([rows, corners.ravel()]).astype(np.int64))
    values = torch.from_numpy(weights.ravel().astype(np.float32))
    return torch.sparse_coo_tensor(indices, values, (len(points), len(vertices)), check_invariants=True).coalesce()


def spiral_sequences(
    vertices: np.ndarray,
    faces: np.ndarray,
    length: int = DEFAULT_SPIRAL_LENGTH,
    dilation: int = 1,
    reference_axis: tuple[float, float, float] = REFERENCE_AXIS,
) -> np.ndarray:
    """Spiral of every vertex (thesis Algorithm 1; SpiralNet++ dilation): (V, length) int64 vertex ids.

    Entry 0 is the vertex; entries 1..deg(v) its one-ring counter-clockwise seen from outside, starting at the
    neighbour pointing most along ``reference_axis`` in the tangent plane; then the further rings (see the
    module docstring). With ``dilation`` d, entries 0, d, 2d, ... of the undilated spiral are kept.

    Args:
        vertices: (V, 3). faces: (F, 3), consistently wound with outward normals.
    """
    _check_spiral_args(length, dilation)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    rings = ordered_one_rings(v, f, reference_axis)
    full = length * dilation - (dilation - 1)  # entries needed so that every kept one exists
    out = np.empty((len(v), length), dtype=np.int64)
    for centre in range(len(v)):
        spiral = _spiral(centre, rings, full)
        kept = spiral[::dilation][:length]
        out[centre, : len(kept)] = kept
        out[centre, len(kept) :] = centre  # only where the component has fewer vertices than the spiral needs
    return out


def ordered_one_rings(
    vertices: np.ndarray, faces: np.ndarray, reference_axis: tuple[float, float, float] = REFERENCE_AXIS
) -> list[np.ndarray]:
    """Each vertex's neighbours, counter-clockwise about its outward normal, from the reference direction.

    Uses the faces' winding (for a face (a, b, c), c follows b around a); where the link of a vertex is not one
    chain (non-manifold), the neighbours are sorted by angle in the tangent plane instead. A boundary vertex's
    ring starts at the end of its open chain.

    Returns:
        V arrays of vertex ids.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    normals = vertex_normals(v, f)
    axis = np.asarray(reference_axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    fallback = np.asarray(FALLBACK_AXIS, dtype=np.float64)
    if abs(fallback @ axis) > FALLBACK_COSINE:
        fallback = np.roll(axis, 1)  # a reference axis along z needs another fallback

    # link edges b -> c around each corner a, for every face corner
    corner = f.ravel()
    nxt_from = f[:, [1, 2, 0]].ravel()
    nxt_to = f[:, [2, 0, 1]].ravel()
    order = np.argsort(corner, kind="stable")
    corner, nxt_from, nxt_to = corner[order], nxt_from[order], nxt_to[order]
    bounds = np.searchsorted(corner, np.arange(len(v) + 1))

    rings: list[np.ndarray] = []
    for a in range(len(v)):
        lo, hi = bounds[a], bounds[a + 1]
        src, dst = nxt_from[lo:hi].tolist(), nxt_to[lo:hi].tolist()
        neighbours = sorted(set(src) | set(dst))
        if not neighbours:
            rings.append(np.empty(0, dtype=np.int64))
            continue
        n = normals[a]
        ref = fallback if abs(n @ axis) > FALLBACK_COSINE else axis
        ref_t = ref - (ref @ n) * n
        nxt = dict(zip(src, dst, strict=True))
        manifold = len(nxt) == len(src) and len(set(dst)) == len(dst)
        ring = _follow_link(nxt, neighbours, v, a, ref_t) if manifold else None
        if ring is None:
            ring = _angle_sorted(v, a, neighbours, n, ref_t)
        rings.append(np.asarray(ring, dtype=np.int64))
    return rings


def resample(matrix: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Apply a sparse (V_out, V_in) resampling matrix to batched vertex features (B, V_in, C) -> (B, V_out, C)."""
    if x.dim() != 3 or x.shape[1] != matrix.shape[1]:
        raise ValueError(f"features must be (B, {matrix.shape[1]}, C), got {tuple(x.shape)}")
    b, v_in, c = x.shape
    flat = x.transpose(0, 1).reshape(v_in, b * c)  # (V_in, B*C): one sparse product for the whole batch
    out = torch.sparse.mm(matrix.to(dtype=x.dtype, device=x.device), flat)
    return out.reshape(-1, b, c).transpose(0, 1)


class Resample(nn.Module):
    """A fixed resampling matrix with the same number K of entries in every row (3 for barycentric rows).

    Holds the matrix as dense (V_out, K) index and weight tables (buffers that DDP can broadcast, unlike sparse
    ones), which is also faster than a sparse product for K = 3.

    Shapes:
        (B, V_in, C) -> (B, V_out, C).
    """

    def __init__(self, matrix: torch.Tensor) -> None:
        super().__init__()
        m = matrix.coalesce()
        rows, cols = m.indices()
        counts = torch.bincount(rows, minlength=m.shape[0])
        if counts.numel() == 0 or not bool((counts == counts[0]).all()):
            raise ValueError("Resample needs the same number of stored entries in every row")
        k = int(counts[0])
        self.num_in = int(m.shape[1])
        # coalesced COO indices are sorted by row, so a reshape groups each row's entries
        self.register_buffer("index", cols.reshape(-1, k).clone(), persistent=False)
        self.register_buffer("weight", m.values().reshape(-1, k, 1).clone(), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, V_in, C) -> (B, V_out, C)."""
        if x.dim() != 3 or x.shape[1] != self.num_in:
            raise ValueError(f"features must be (B, {self.num_in}, C), got {tuple(x.shape)}")
        b, _, c = x.shape
        v_out, k = self.index.shape
        gathered = x.index_select(1, self.index.reshape(-1)).reshape(b, v_out, k, c)
        return (gathered * self.weight.to(x.dtype)).sum(dim=2)

    def extra_repr(self) -> str:
        return f"{self.num_in} -> {self.index.shape[0]}, K={self.index.shape[1]}"


def _spiral(centre: int, rings: list[np.ndarray], size: int) -> list[int]:
    """Undilated spiral of ``centre`` with up to ``size`` entries (fewer if its component is smaller)."""
    spiral = [centre]
    seen = {centre}
    frontier = [centre]
    while len(spiral) < size and frontier:
        next_frontier: list[int] = []
        for u in frontier:
            ring = rings[u].tolist()
            if not ring:
                continue
            # walk u's ring counter-clockwise from the first unseen neighbour that follows a seen one, so each
            # new ring continues the turn of the previous one
            k = len(ring)
            start = next((i for i in range(k) if ring[i - 1] in seen and ring[i] not in seen), 0)
            for i in range(k):
                w = ring[(start + i) % k]
                if w not in seen:
                    seen.add(w)
                    spiral.append(w)
                    next_frontier.append(w)
        frontier = next_frontier
    return spiral[:size]


def _follow_link(nxt: dict[int, int], neighbours: list[int], v: np.ndarray, a: int, ref_t: np.ndarray) -> list | None:
    """The link of ``a`` as one counter-clockwise chain or cycle, or None if it is not one."""
    targets = set(nxt.values())
    heads = [b for b in neighbours if b not in targets]
    if len(heads) > 1:
        return None
    if heads:  # boundary vertex: an open chain has only one start
        start = heads[0]
    else:
        start = _best_aligned(v, a, neighbours, ref_t)
    ring = [start]
    while ring[-1] in nxt and nxt[ring[-1]] != start:
        ring.append(nxt[ring[-1]])
        if len(ring) > len(neighbours):
            return None
    return ring if len(ring) == len(neighbours) else None


def _best_aligned(v: np.ndarray, a: int, neighbours: list[int], ref_t: np.ndarray) -> int:
    d = v[neighbours] - v[a]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    # ties (none on real meshes) go to the lowest id: neighbours are sorted
    return neighbours[int(np.argmax(d @ ref_t))]


def _angle_sorted(v: np.ndarray, a: int, neighbours: list[int], n: np.ndarray, ref_t: np.ndarray) -> list[int]:
    e1 = ref_t / max(np.linalg.norm(ref_t), 1e-12)
    e2 = np.cross(n, e1)
    d = v[neighbours] - v[a]
    angle = np.mod(np.arctan2(d @ e2, d @ e1), 2 * np.pi)
    return [neighbours[i] for i in np.lexsort((neighbours, angle))]


def _drop_unused(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used = np.unique(f)
    if len(used) == len(v):
        return v, f
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def _check_spiral_args(length: int, dilation: int) -> None:
    if length < 1 or dilation < 1:
        raise ValueError(f"spiral length and dilation must be >= 1, got {length} and {dilation}")


def _hierarchy_key(
    vertices: np.ndarray, faces: np.ndarray, num_levels: int, ratio: float, spiral_length: int, dilation: int
) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float32).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    params = {"v": FORMAT_VERSION, "levels": num_levels, "ratio": ratio, "length": spiral_length, "dilation": dilation}
    h.update(json.dumps(params, sort_keys=True).encode())
    return h.hexdigest()
