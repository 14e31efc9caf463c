"""Template registration by per-vertex affine transforms (Allen, Curless, Popovic 2003; thesis 3.5.1).

Fits a template mesh (fixed topology) to a scan of any topology. Every template vertex ``v_i`` gets its own affine
transform ``T_i`` (3 x 4); the registered vertex is ``T_i [v_i; 1]``. The transforms minimise (thesis eq. 3.10)

    E = alpha * E_data + beta * E_smooth + gamma * E_marker

    E_data   = (1 / V) sum_i w_i dist^2(T_i v_i, S_D)           (thesis eq. 3.7; Allen et al. eq. 1)
    E_smooth = sum_{(i, j) in edges(S_T)} ||T_i - T_j||_F^2      (thesis eq. 3.8; Allen et al. eq. 2)
    E_marker = sum_k ||T_{k_i} v_{k_i} - m_i||^2                 (thesis eq. 3.9; Allen et al. eq. 3)

with scipy's L-BFGS-B and analytic gradients. ``dist(., S_D)`` is the distance to the scan *surface*: the closest
point on the scan's triangles (trimesh's proximity query, rtree), recomputed after every solve (an ICP-style outer
loop; inside one solve the closest points are held fixed, so the energy is quadratic and its gradient exact).
Following Allen et al., ``w_i`` is zero where the closest point is too far, where the normals of template and scan
disagree, or where the closest point lies on the border of a hole; otherwise one.

Frames and units. The solve runs in a *normalised template frame*: the scan is first brought onto the template by
a similarity (rigid + scale; Umeyama from the markers, or principal axes + ICP when there are none), then
template and scan are centred on the template's centroid and divided by its RMS radius, so that the linear part
and the translation of every ``T_i`` have comparable magnitudes in the Frobenius norm of E_smooth. Distances in
:class:`Stage` are in mm of the *scan*; energies reported in :class:`StageReport` are in the normalised frame.
The registered vertices are returned in the scan's frame and units (mm).

Weight schedule (Allen et al. section 4: markers first, data later, smoothness relaxed at the end): see
:func:`default_stages`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize
import scipy.sparse as sp

from footmesh.geometry.alignment import Similarity, umeyama
from footmesh.geometry.mesh import face_normals, vertex_normals
from footmesh.geometry.rotations import skew

log = logging.getLogger(__name__)

MIN_MARKERS_FOR_INIT = 3
"""At least this many named markers shared by template and scan to initialise from them (Umeyama)."""
AXES_TRIAL_ROUNDS = 5
"""Similarity-ICP rounds given to each of the four principal-axes candidates before the best is refined."""
ICP_POINTS = 1000
"""Template vertices (an even subsample) used by the similarity ICP of the initialisation and the shape prior."""
PRIOR_STEP_HALVINGS = 8
"""Shape-prior stage: a Gauss-Newton step that does not lower the (truncated) cost is halved up to this many times.
Undamped, the first round of one scan in 50 jumped along the scale / size-component valley (scale 1.0 -> 1.47, first
coefficient -5.8 sd); its closest-point weights then dropped 40% of the points, and it ended at scale 3.1 and
-13 sd: 90 mm correspondence error."""
PRIOR_STEP_TOL_MM = 0.002
"""The shape-prior stage stops when no (subsampled) vertex moved more than this (scan mm) in a round."""


# --- configuration ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Stage:
    """One stage of the weight schedule (thesis eq. 3.10).

    Attributes:
        name: label for reports.
        alpha: weight of E_data (mean over vertices of the squared distance, normalised units).
        beta: weight of E_smooth (sum over template edges).
        gamma: weight of E_marker (sum over markers); ignored when there are no markers.
        rounds: closest-point updates (each followed by one L-BFGS-B solve).
        max_iter: L-BFGS-B iterations per solve.
        max_distance_mm: data weight zero where the closest scan point is farther (scan mm).
        max_normal_angle_deg: data weight zero where template and scan normals differ by more than this.
    """

    name: str
    alpha: float
    beta: float
    gamma: float
    rounds: int = 3
    max_iter: int = 200
    max_distance_mm: float = 20.0
    max_normal_angle_deg: float = 60.0


def default_stages() -> tuple[Stage, ...]:
    """Allen et al.'s schedule: markers alone first, then data raised while smoothness and markers are lowered
    (to 0.1, not further: see the comment on the last stage).

    The markers-only stage (``alpha = 0``) is skipped when a shape prior is used (see :func:`register`).
    """
    return (
        Stage("markers", alpha=0.0, beta=1.0, gamma=1.0, rounds=1, max_iter=300),
        Stage("coarse", alpha=1e3, beta=1.0, gamma=1.0, rounds=3, max_distance_mm=30.0),
        Stage("medium", alpha=1e3, beta=0.1, gamma=0.1, rounds=4, max_distance_mm=15.0),
        # fine: smoothness kept at 0.1 (Allen et al. go lower): with 0.01 the surface followed the 0.3 mm scan noise
        # (0.02 mm surface distance) and the correspondence error was 0.02-0.04 mm worse (FIND shapes: 0.42 ->
        # 0.38 mm mean over 3 scans; model shapes: 0.32 -> 0.30 mm over 4)
        Stage("fine", alpha=1e3, beta=0.1, gamma=0.1, rounds=5, max_distance_mm=8.0),
    )


@dataclass(frozen=True)
class RegistrationConfig:
    """Settings of :func:`register`.

    Attributes:
        stages: the weight schedule (see :func:`default_stages`).
        init: ``"auto"`` (markers when at least 3 are shared, else principal axes), ``"markers"``,
            ``"axes"`` (principal axes, trying the four proper sign flips), or ``"none"`` (the scan is already in
            the template's frame and units).
        rigid_icp_rounds: similarity-ICP rounds that refine the initial alignment (0 = none).
        lbfgs_memory: L-BFGS-B history size (``maxcor``).
        boundary_eps: barycentric tolerance deciding that a closest point lies on a scan edge.
        solver: ``"lbfgsb"`` (L-BFGS-B on each quadratic subproblem, as Allen et al.) or ``"direct"`` (a sparse
            LU solve of the same subproblem; same minimiser, for checking).
        prior_rounds: closest-point rounds of the shape-prior stage (only with a ``shape_basis``).
        prior_sigma_mm: data noise of the shape-prior stage (mm); the coefficients get a standard-normal prior.
        prior_marker_sigma_mm: marker noise of the shape-prior stage (mm).
        prior_max_distance_mm: data weight zero beyond this distance in the shape-prior stage.
        prior_scale_sd: sd of the log-scale of the shape-prior stage's similarity about the initial one. The
            packaged model's first component changes the size, so scale and that coefficient trade against each
            other almost freely; without this prior the Gauss-Newton walked that valley on 7 of 50 scans of
            ``bench_register.py --build`` (scale 1.0 -> 3-5, first coefficient -10 to -14 sd: 35-130 mm error).
    """

    stages: tuple[Stage, ...] = field(default_factory=default_stages)
    init: str = "auto"
    rigid_icp_rounds: int = 15
    lbfgs_memory: int = 10
    boundary_eps: float = 1e-6
    solver: str = "lbfgsb"
    prior_rounds: int = 100
    prior_sigma_mm: float = 1.0
    prior_marker_sigma_mm: float = 2.0
    prior_max_distance_mm: float = 20.0
    prior_scale_sd: float = 0.02


# --- results ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StageReport:
    """Energies (normalised frame, weights not applied) at the end of one stage."""

    name: str
    alpha: float
    beta: float
    gamma: float
    e_data: float
    e_smooth: float
    e_marker: float
    data_fraction: float
    iterations: int
    seconds: float

    @property
    def total(self) -> float:
        return self.alpha * self.e_data + self.beta * self.e_smooth + self.gamma * self.e_marker


@dataclass(frozen=True)
class RegistrationResult:
    """Result of :func:`register`.

    Attributes:
        vertices: (V, 3) registered template vertices, scan frame, mm.
        faces: (F, 3) the template's faces.
        initial: the similarity template -> scan used to start.
        init_method: ``"markers"``, ``"axes"`` or ``"none"``.
        stages: one :class:`StageReport` per stage.
        mean_distance_mm: mean distance of the registered vertices to the scan surface (those with data weight).
        flipped_faces: faces whose normal turned by more than 90 degrees from the template's (after the
            similarity): folds.
        prior_coefficients: (K,) shape-model coefficients of the shape-prior stage (empty without one).
        seconds: wall time.
    """

    vertices: np.ndarray
    faces: np.ndarray
    initial: Similarity
    init_method: str
    stages: tuple[StageReport, ...]
    mean_distance_mm: float
    flipped_faces: int
    prior_coefficients: np.ndarray
    seconds: float

    def __repr__(self) -> str:
        return (
            f"RegistrationResult(V={len(self.vertices)}, init={self.init_method}, "
            f"mean_distance_mm={self.mean_distance_mm:.3f}, flipped_faces={self.flipped_faces}, "
            f"seconds={self.seconds:.1f})"
        )


# --- sparse operators ---------------------------------------------------------------------------------------


def vertex_operator(vertices: np.ndarray) -> sp.csr_matrix:
    """Sparse A (V, 4V) with ``A @ X`` = the transformed vertices, X (4V, 3) the stacked transposed transforms.

    Row i holds ``[x_i, y_i, z_i, 1]`` in columns ``4i .. 4i+3``, so ``(A X)_i = [v_i, 1] X_i = (T_i [v_i; 1])^T``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    n = len(v)
    data = np.concatenate([v, np.ones((n, 1))], axis=1).ravel()  # (4V,)
    rows = np.repeat(np.arange(n), 4)
    cols = np.arange(4 * n)
    return sp.csr_matrix((data, (rows, cols)), shape=(n, 4 * n))


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges (E, 2), i < j, of a triangle mesh."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], axis=0)
    e.sort(axis=1)
    return np.unique(e, axis=0)


def smoothness_operator(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """Sparse ``G^T G`` (4V, 4V) with G = edge incidence (E, V) kron I_4: ``tr(X^T G^T G X) = E_smooth``."""
    e = mesh_edges(faces)
    m = len(e)
    rows = np.repeat(np.arange(m), 2)
    vals = np.tile([1.0, -1.0], m)
    incidence = sp.csr_matrix((vals, (rows, e.ravel())), shape=(m, num_vertices))
    g = sp.kron(incidence, sp.identity(4, format="csr"), format="csr")
    return (g.T @ g).tocsr()


# --- geometry helpers ---------------------------------------------------------------------------------------


def _area_moments(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-weighted centroid (3,), covariance eigenvalues (3,) descending and eigenvectors (3, 3) columns."""
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    w = area / area.sum()
    cen = tri.mean(axis=1)
    mu = w @ cen
    # covariance of the uniform distribution on the triangles (exact second moment of each triangle)
    d = tri - mu
    second = sum(np.einsum("f,fi,fj->ij", w, d[:, a], d[:, b]) for a in range(3) for b in range(3))
    second = (second + sum(np.einsum("f,fi,fj->ij", w, d[:, a], d[:, a]) for a in range(3))) / 12.0
    evals, evecs = np.linalg.eigh(second)
    order = np.argsort(evals)[::-1]
    return mu, evals[order], evecs[:, order]


# --- closest points and data weights ------------------------------------------------------------------------


class _ScanSurface:
    """The scan in the normalised frame with what the data term needs: closest points, normals, hole borders."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, boundary_eps: float) -> None:
        import trimesh

        self.mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
        self.face_normals = face_normals(self.mesh.vertices, self.mesh.faces)
        self.boundary_eps = boundary_eps
        # border[f, k]: the edge of face f opposite its corner k lies on a hole's border (belongs to one face)
        f = np.asarray(faces, dtype=np.int64)
        opposite = np.stack([f[:, [1, 2]], f[:, [2, 0]], f[:, [0, 1]]], axis=1)  # (F, 3, 2)
        keys = np.sort(opposite, axis=2).reshape(-1, 2)
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        self.border = (counts[inverse.ravel()] == 1).reshape(-1, 3)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest points (P, 3), distances (P,), scan face normals there (P, 3), on-hole-border flags (P,)."""
        import trimesh

        closest, dist, tri = trimesh.proximity.closest_point(self.mesh, points)
        tri = np.asarray(tri, dtype=np.int64)
        bary = trimesh.triangles.points_to_barycentric(self.mesh.triangles[tri], closest)
        on_border = ((bary < self.boundary_eps) & self.border[tri]).any(axis=1)
        return np.asarray(closest), np.asarray(dist), self.face_normals[tri], on_border


# --- initial alignment --------------------------------------------------------------------------------------


def _similarity_icp(
    template: np.ndarray, faces: np.ndarray, surface: _ScanSurface, init: Similarity, rounds: int
) -> tuple[Similarity, float]:
    """Refine a template -> scan similarity by ICP on closest surface points; returns it and the mean distance."""
    sim = init
    normals0 = vertex_normals(template, faces)
    sub = np.arange(0, len(template), max(1, len(template) // ICP_POINTS))  # a subsample is plenty for 7 dof
    template, normals0 = template[sub], normals0[sub]
    dist = np.zeros(len(template))
    previous = np.inf
    for _ in range(max(rounds, 1)):
        moved = sim.apply(template)
        closest, dist, n_scan, border = surface.query(moved)
        n_tmpl = normals0 @ sim.rotation.T
        ok = ((n_tmpl * n_scan).sum(axis=1) > 0.0) & ~border
        cut = np.quantile(dist[ok], 0.9) if ok.sum() > 10 else np.inf
        ok &= dist <= cut
        current = float(dist[ok].mean()) if ok.any() else np.inf
        if ok.sum() < 10 or rounds == 0 or current > (1.0 - 1e-3) * previous:
            break  # nothing to fit, or converged
        previous = current
        sim = umeyama(template[ok], closest[ok])
    moved = sim.apply(template)
    _, dist, _, _ = surface.query(moved)
    return sim, float(dist.mean())


def _init_from_axes(
    template: np.ndarray, faces: np.ndarray, scan_v: np.ndarray, scan_f: np.ndarray, surface: _ScanSurface, rounds
) -> Similarity:
    """Principal axes of template and scan; of the four proper sign choices keep the one ICP fits best.

    The foot's asymmetry (heel vs toes, sole vs instep, big toe side) decides between the flips.
    """
    mu_t, ev_t, ax_t = _area_moments(template, faces)
    mu_s, ev_s, ax_s = _area_moments(scan_v, scan_f)
    scale = float(np.sqrt(ev_s.sum() / ev_t.sum()))
    best: tuple[float, Similarity] | None = None
    for signs in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        flip = np.diag(signs).astype(np.float64)
        axes_s = ax_s @ flip
        rot = axes_s @ ax_t.T
        if np.linalg.det(rot) < 0:  # scan eigenvectors of the other handedness: fix with the last axis
            axes_s[:, 2] *= -1
            rot = axes_s @ ax_t.T
        sim = Similarity(scale, rot, mu_s - scale * rot @ mu_t)
        sim, err = _similarity_icp(template, faces, surface, sim, min(rounds, AXES_TRIAL_ROUNDS))
        log.debug("axes init signs %s: mean distance %.3f", signs, err)
        if best is None or err < best[0]:
            best = (err, sim)
    assert best is not None
    return _similarity_icp(template, faces, surface, best[1], max(rounds - AXES_TRIAL_ROUNDS, 0))[0]


# --- shape prior -------------------------------------------------------------------------------------------


def _fit_shape_prior(
    template: np.ndarray,
    faces: np.ndarray,
    basis: np.ndarray,
    sd: np.ndarray,
    surface: _ScanSurface,
    sim: Similarity,
    marker_ids: np.ndarray,
    marker_pts: np.ndarray,
    cfg: RegistrationConfig,
) -> tuple[np.ndarray, Similarity, np.ndarray]:
    """Fit the coefficients of a linear shape model *and* the similarity to the scan by Gauss-Newton ICP.

    Minimises ``sum_i w_i ||S(mu_i + B_i c) - closest_i||^2 / sigma^2 + sum_m ||S(mu_m + B_m c) - m||^2 /
    sigma_m^2 + sum_k (c_k / sd_k)^2`` over c and the similarity S (scale, rotation, translation) jointly: each
    round fixes the closest points, linearises S about the current one (small rotation, log-scale, translation)
    and solves one (K + 7)-unknown least-squares problem. Solving c and S together matters: a model whose first
    components change the size (the packaged one) is nearly degenerate with S's scale, and alternating between
    the two (c for fixed S, then S by Umeyama) crawls along that valley -- measured on the 1,002-vertex model,
    10 alternating rounds left 2.3 mm correspondence error where the joint solve reaches 0.1-0.2 mm. Point-to-point
    ICP still slides slowly along the surface, hence up to 100 rounds (on about ``ICP_POINTS`` vertices: 40 rounds
    left one 4,002-vertex scan at 0.8 mm, 100 reach 0.09 mm).

    Two safeguards against that same near-degeneracy (scale vs the size component): a prior on the log-scale
    about the initial similarity's (``cfg.prior_scale_sd``), and step halving on the truncated cost
    (:data:`PRIOR_STEP_HALVINGS`). Without them 7 of the 50 scans of ``bench_register.py --build`` walked down the
    valley to scale 3-5 and the first coefficient at -10 to -14 sd, a shrunken foot blown up (35-130 mm error,
    which wrecked the model built from them). The scale prior only decides where along the valley the fit
    lands (how the size splits between the scale and the coefficients), not the fitted surface.

    Returns:
        shape (V, 3) template frame mm, the refined similarity, coefficients (K,).
    """
    k = basis.shape[0]
    c = np.zeros(k)
    inv_sd = 1.0 / np.maximum(np.asarray(sd, dtype=np.float64), 1e-9)
    cos_min = np.cos(np.radians(60.0))
    # K + 7 unknowns need few points: an even subsample, its rows weighted up to stand for every vertex
    sub = np.arange(0, len(template), max(1, len(template) // ICP_POINTS))
    w_data = np.sqrt(len(template) / len(sub)) / cfg.prior_sigma_mm
    w_marker = 1.0 / cfg.prior_marker_sigma_mm
    from scipy.spatial.transform import Rotation

    def advance(c0: np.ndarray, s0: Similarity, d: np.ndarray) -> tuple[np.ndarray, Similarity]:
        # p' = e^ds dR (p - t) + t + dt, p = s R x + t
        dr = Rotation.from_rotvec(d[k + 1 : k + 4]).as_matrix()
        return c0 + d[:k], Similarity(s0.scale * float(np.exp(d[k])), dr @ s0.rotation, s0.translation + d[k + 4 :])

    def cost(c0: np.ndarray, s0: Similarity) -> float:
        # the objective with every data distance truncated at the stage's cut-off: a point cannot lower it by
        # leaving the fit (dropping out of the weights), which is how the undamped iteration escaped
        p = s0.apply(template[sub] + np.tensordot(c0, basis[:, sub], axes=1))
        _, d, _, brd = surface.query(p)
        e = (w_data * np.minimum(d[~brd], cfg.prior_max_distance_mm)) ** 2
        total = (
            float(e.sum()) + float(((c0 * inv_sd) ** 2).sum()) + (np.log(s0.scale / scale0) / cfg.prior_scale_sd) ** 2
        )
        if len(marker_ids):
            pm = s0.apply(template[marker_ids] + np.tensordot(c0, basis[:, marker_ids], axes=1))
            total += float(((w_marker * (pm - marker_pts)) ** 2).sum())
        return total

    cost_now = None
    scale0 = sim.scale
    for _ in range(cfg.prior_rounds):
        shape = template + np.tensordot(c, basis, axes=1)  # (V, 3)
        moved = sim.apply(shape)
        closest, dist, n_scan, border = surface.query(moved[sub])
        n_shape = vertex_normals(moved, faces)[sub]
        ok = (dist <= cfg.prior_max_distance_mm) & ((n_shape * n_scan).sum(axis=1) >= cos_min) & ~border
        log.debug(
            "prior round: scale %.4f, c/sd %s, mean distance %.3f mm, data fraction %.2f",
            sim.scale,
            np.round(c * inv_sd, 2)[:3].tolist(),
            float(dist[ok].mean()) if ok.any() else np.inf,
            ok.mean(),
        )
        if ok.sum() < 10:
            break
        rb = sim.scale * basis @ sim.rotation.T  # (K, V, 3) the basis as seen in the scan frame
        idx = [(sub[ok], closest[ok], w_data)]
        if len(marker_ids):
            idx.append((marker_ids, marker_pts, w_marker))
        rows, rhs = [], []
        for ids, target, w in idx:
            q = moved[ids] - sim.translation  # (P, 3) about the similarity's origin
            # d p = log-scale * q + omega x q + dt + rb dc  (first order in the similarity's increments)
            j_s = q[:, :, None]  # (P, 3, 1)
            j_w = -skew(q)  # omega x q = -[q]x omega
            j_t = np.broadcast_to(np.eye(3), (len(ids), 3, 3))
            j_c = np.moveaxis(rb[:, ids], 0, 2)  # (P, 3, K)
            rows.append(w * np.concatenate([j_c, j_s, j_w, j_t], axis=2).reshape(-1, k + 7))
            rhs.append(w * (target - moved[ids]).ravel())
        rows.append(np.concatenate([np.diag(inv_sd), np.zeros((k, 7))], axis=1))  # prior on c + dc
        rhs.append(-inv_sd * c)
        rows.append(np.eye(1, k + 7, k) / cfg.prior_scale_sd)  # prior on log(scale) + ds about the initial one
        rhs.append(np.array([-np.log(sim.scale / scale0) / cfg.prior_scale_sd]))
        delta = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
        c_old, sim_old = c, sim
        cost_old = cost(c, sim) if cost_now is None else cost_now
        for _ in range(PRIOR_STEP_HALVINGS + 1):
            c, sim = advance(c_old, sim_old, delta)
            cost_now = cost(c, sim)
            if cost_now <= cost_old:
                break
            delta = 0.5 * delta
        else:  # no descent along the Gauss-Newton direction: converged (or stuck); keep the last accepted fit
            c, sim = c_old, sim_old
            break
        step = np.linalg.norm(sim.apply(template[sub] + np.tensordot(c, basis[:, sub], axes=1)) - moved[sub], axis=1)
        if step.max() < PRIOR_STEP_TOL_MM:  # converged: no vertex moved more than this in the last round
            break
    return template + np.tensordot(c, basis, axes=1), sim, c


# --- the solve ----------------------------------------------------------------------------------------------


def _lbfgs(h: sp.csr_matrix, b: np.ndarray, x0: np.ndarray, max_iter: int, memory: int) -> tuple[np.ndarray, int]:
    """Minimise tr(X^T H X) - 2 tr(X^T B) (+ const) over X (4V, 3) with L-BFGS-B; gradient 2 (H X - B)."""
    shape = x0.shape

    def fun(flat: np.ndarray) -> tuple[float, np.ndarray]:
        x = flat.reshape(shape)
        hx = h @ x
        f = float(np.sum(x * hx) - 2.0 * np.sum(x * b))
        return f, (2.0 * (hx - b)).ravel()

    with _single_threaded_blas():
        res = scipy.optimize.minimize(
            fun,
            x0.ravel(),
            jac=True,
            method="L-BFGS-B",
            options={"maxiter": max_iter, "maxcor": memory, "ftol": 1e-12, "gtol": 1e-10},
        )
    return res.x.reshape(shape), int(res.nit)


def _single_threaded_blas():
    """L-BFGS-B's many short vector operations go to BLAS; a multi-threaded OpenBLAS on a busy machine makes them
    ~20x slower (measured: 2 s -> 38 s for one 1,002-vertex registration with two other jobs on two cores). One
    thread is as fast when idle. Uses ``threadpoolctl`` when installed, otherwise does nothing."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        import contextlib

        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def register(
    template_vertices: np.ndarray,
    template_faces: np.ndarray,
    scan,
    template_markers: dict[str, int] | None = None,
    scan_markers: dict[str, np.ndarray] | None = None,
    config: RegistrationConfig | None = None,
    shape_basis: np.ndarray | None = None,
    shape_sd: np.ndarray | None = None,
) -> RegistrationResult:
    """Fit the template to a scan (Allen et al. 2003; thesis 3.5.1, eqs. 3.7-3.10).

    Args:
        template_vertices: (V, 3) mm, any frame (the template's own).
        template_faces: (F, 3) int, counter-clockwise seen from outside.
        scan: ``trimesh.Trimesh`` in mm (any frame, any topology; holes allowed).
        template_markers: marker name -> template vertex id.
        scan_markers: marker name -> (3,) point on the scan (scan frame, mm). Only names present in both
            dictionaries are used.
        config: schedule and options (defaults: :class:`RegistrationConfig`).
        shape_basis: optional (K, V, 3) linear shape model around ``template_vertices`` (e.g. a PCA model's
            components, with the template its mean). When given, a *shape-prior stage* first fits its
            coefficients (and the similarity) to the scan, and the affine stages start from that shape: the
            smoothness term then regularises the departure from the model instead of from the mean. This keeps
            correspondences consistent with the model's where the surface alone cannot tell (sliding along it).
        shape_sd: (K,) standard deviation (mm) of each basis coefficient; required with ``shape_basis``.

    Returns:
        :class:`RegistrationResult` with the registered vertices (V, 3) in the scan's frame, mm.
    """
    t_start = time.perf_counter()
    cfg = config or RegistrationConfig()
    tv = template0 = np.asarray(template_vertices, dtype=np.float64)
    tf = np.asarray(template_faces, dtype=np.int64)
    if tv.ndim != 2 or tv.shape[1] != 3:
        raise ValueError(f"template_vertices must be (V, 3), got {tv.shape}")
    if tf.ndim != 2 or tf.shape[1] != 3 or tf.min() < 0 or tf.max() >= len(tv):
        raise ValueError(f"template_faces of shape {tf.shape} do not index {len(tv)} vertices")
    sv = np.asarray(scan.vertices, dtype=np.float64)
    sf = np.asarray(scan.faces, dtype=np.int64)
    if len(sv) == 0 or len(sf) == 0:
        raise ValueError("the scan has no triangles")

    names = sorted(set(template_markers or {}) & set(scan_markers or {}))
    marker_ids = np.array([int(template_markers[n]) for n in names], dtype=np.int64)  # type: ignore[index]
    marker_pts = np.array([np.asarray(scan_markers[n], dtype=np.float64) for n in names]).reshape(-1, 3)  # type: ignore[index]
    if len(marker_ids) and (marker_ids.min() < 0 or marker_ids.max() >= len(tv)):
        raise ValueError(f"template marker ids must lie in [0, {len(tv)}), got {marker_ids.tolist()}")

    # --- 1. initial similarity template -> scan ---
    method = cfg.init
    if method == "auto":
        method = "markers" if len(names) >= MIN_MARKERS_FOR_INIT else "axes"
    if method == "markers" and len(names) < MIN_MARKERS_FOR_INIT:
        raise ValueError(f"init='markers' needs {MIN_MARKERS_FOR_INIT} shared markers, got {len(names)}")
    raw_surface = _ScanSurface(sv, sf, cfg.boundary_eps)
    if method == "markers":
        sim = umeyama(tv[marker_ids], marker_pts)
        sim, _ = _similarity_icp(tv, tf, raw_surface, sim, min(cfg.rigid_icp_rounds, 3))
        sim_m = umeyama(tv[marker_ids], marker_pts)
        # keep the marker fit unless ICP improved it without moving markers much (noisy markers, good surface)
        resid_icp = np.linalg.norm(sim.apply(tv[marker_ids]) - marker_pts, axis=1).mean()
        resid_m = np.linalg.norm(sim_m.apply(tv[marker_ids]) - marker_pts, axis=1).mean()
        if resid_icp > 2.0 * resid_m + 2.0:
            sim = sim_m
    elif method == "axes":
        sim = _init_from_axes(tv, tf, sv, sf, raw_surface, cfg.rigid_icp_rounds)
    elif method == "none":
        sim = Similarity(1.0, np.eye(3), np.zeros(3))
    else:
        raise ValueError(f"unknown init {cfg.init!r}; use auto, markers, axes or none")

    prior_coefficients = np.zeros(0)
    if shape_basis is not None:
        basis = np.asarray(shape_basis, dtype=np.float64)
        if basis.ndim != 3 or basis.shape[1:] != tv.shape or shape_sd is None or len(shape_sd) != len(basis):
            raise ValueError(
                f"shape_basis must be (K, {len(tv)}, 3) with shape_sd (K,), got {basis.shape} and "
                f"{None if shape_sd is None else np.shape(shape_sd)}"
            )
        tv, sim, prior_coefficients = _fit_shape_prior(
            tv, tf, basis, np.asarray(shape_sd), raw_surface, sim, marker_ids, marker_pts, cfg
        )

    # --- 2. normalised frame: scan mapped onto the template, both centred and scaled by the template ---
    centre = tv.mean(axis=0)
    radius = float(np.sqrt(((tv - centre) ** 2).sum(axis=1).mean()))
    mm_to_unit = 1.0 / (radius * sim.scale)  # one scan mm in normalised units

    def to_unit(p_scan: np.ndarray) -> np.ndarray:
        return (sim.inverse_apply(p_scan) - centre) / radius

    v_hat = (tv - centre) / radius
    surface = _ScanSurface(to_unit(sv), sf, cfg.boundary_eps)
    m_hat = to_unit(marker_pts) if len(names) else np.zeros((0, 3))

    n = len(tv)
    a = vertex_operator(v_hat)  # (V, 4V)
    lap = smoothness_operator(tf, n)  # (4V, 4V)
    am = a[marker_ids] if len(names) else sp.csr_matrix((0, 4 * n))
    x = np.zeros((4 * n, 3))
    x[0::4, 0] = x[1::4, 1] = x[2::4, 2] = 1.0  # identity transforms

    reports = []
    dist = np.zeros(n)
    weights = np.ones(n)
    for stage in cfg.stages:
        t0 = time.perf_counter()
        gamma = stage.gamma if len(names) else 0.0
        if stage.alpha == 0.0 and (gamma == 0.0 or shape_basis is not None):
            # nothing to fit (a markers-only stage without markers), or a shape prior already placed the
            # surface: pulling it onto noisy markers alone would slide it along itself
            continue
        its = 0
        closest = np.zeros((n, 3))
        weights = np.zeros(n)
        for _ in range(stage.rounds):
            p = a @ x  # (V, 3) current registered vertices, normalised frame
            if stage.alpha > 0.0:
                closest, dist, n_scan, border = surface.query(p)
                n_tmpl = vertex_normals(p, tf)
                cos = (n_tmpl * n_scan).sum(axis=1)
                weights = (
                    (dist <= stage.max_distance_mm * mm_to_unit)
                    & (cos >= np.cos(np.radians(stage.max_normal_angle_deg)))
                    & ~border
                ).astype(np.float64)
            wa = (stage.alpha / n) * weights
            h = (a.T @ sp.diags(wa) @ a + stage.beta * lap + gamma * (am.T @ am)).tocsr()
            b = a.T @ (wa[:, None] * closest) + gamma * (am.T @ m_hat)
            if cfg.solver == "direct":
                import scipy.sparse.linalg as spla

                x, it = spla.splu(h.tocsc()).solve(b), 1
            else:
                x, it = _lbfgs(h, b, x, stage.max_iter, cfg.lbfgs_memory)
            its += it
        p = a @ x
        diff = p - closest
        e_data = float((weights * (diff**2).sum(axis=1)).sum() / n) if stage.alpha > 0 else 0.0
        e_smooth = float(np.sum(x * (lap @ x)))
        e_marker = float(((am @ x - m_hat) ** 2).sum()) if len(names) else 0.0
        rep = StageReport(
            stage.name,
            stage.alpha,
            stage.beta,
            gamma,
            e_data,
            e_smooth,
            e_marker,
            float(weights.mean()) if stage.alpha > 0 else 0.0,
            its,
            time.perf_counter() - t0,
        )
        log.debug("%s", rep)
        reports.append(rep)

    p = a @ x
    _, dist, _, _ = surface.query(p)
    ok = weights > 0
    mean_dist = float(dist[ok].mean() / mm_to_unit) if ok.any() else float(dist.mean() / mm_to_unit)
    registered = sim.apply(p * radius + centre)
    flipped = int(((face_normals(registered, tf) * face_normals(sim.apply(template0), tf)).sum(axis=1) < 0).sum())
    return RegistrationResult(
        vertices=registered,
        faces=tf.copy(),
        initial=sim,
        init_method=method,
        stages=tuple(reports),
        mean_distance_mm=mean_dist,
        flipped_faces=flipped,
        prior_coefficients=prior_coefficients,
        seconds=time.perf_counter() - t_start,
    )
