"""Fit the kinematic foot model to one photo's cues, its depth map and its floor plane (DESIGN.md "fit").

The model ``v = R mirror(skin(v_shaped(shape), FK(angles))) + t`` (``model.layer.FootModel.forward``, scale 1:
size lives in the shape coefficients) is fitted by robust Levenberg-Marquardt to the evidence of one image, all in
the camera frame of that image (OpenCV, mm; pixels with the centre of the top-left pixel at (0, 0)):

==============  ===================================================================================================
term            residual (each whitened by its sigma in ``FitConfig``; robust kernel)
==============  ===================================================================================================
joints          projected model joint - 2D joint, px, weighted by the joint's confidence (Huber)
inside          distance transform of the silhouette's outside at each projected vertex, px: vertices must fall
                inside the silhouette (vertices hidden by the leg, modelled as a cylinder on the ankle cap, skipped)
contour         silhouette contour samples to their nearest projected vertex (of a spread subset, or of the whole
                mesh's rim: vertices seen edge-on), along the contour normal, px (Geman-McClure)
depth           back-projected depth pixels of the eroded silhouette to their nearest camera-facing vertex,
                point-to-plane, mm (Geman-McClure)
free_space      camera-facing vertices must not lie in front of the nearest measured depth around their pixel, mm
                (Huber)
floor_contact   the lowest vertex touches the floor plane, mm (Geman-McClure above the floor: a foot clearly
                lifted is let go; least squares below it: nothing goes through the floor)
sole_contact    only with ``FitConfig.sole_contact``: the lowest vertices of the heel and of the ball touch the floor
                (a foot bearing weight), mm (least squares)
upright         the foot's z axis along the floor normal (a standing foot), radians (Geman-McClure)
camera_above    the camera is above the foot's sole plane (no floor, no depth: removes the mirror-in-depth twin)
distance        no scale evidence: the midfoot stays at the distance of the mean-size foot (``scaled=False``)
shape_prior     shape coefficients ~ N(0, 1) (SD units)
angle_prior     angles ~ N(mean, (f SD)^2) per DOF: everyday poses' spread (``ik.natural_pose_moments``) widened by
                ``angle_prior_sd_factor``
==============  ===================================================================================================

Dense terms are averages over their samples times an *effective number of independent observations*
(``FitConfig.*_count``): neighbouring contour, vertex and depth residuals are strongly correlated, so counting
each as independent evidence would drown the priors and make the covariance far too confident.

Scale comes only from real evidence: depth + intrinsics, or the floor plane of a detected reference object (the
foot stands on it). Without either, a free model scale absorbs size (so that the shape prior judges proportions
only) and the midfoot is held at the distance of a mean-size foot; at the end the scale is moved into the shape
coefficients and ``FootFit.scaled`` is False: only scale-free quantities (ratios, angles) mean anything.

Solver (details and numbers: docs/fit.md): several starts (PnP of the rest-pose joints from different joint
subsets, and with a floor the same starts stood upright), each scaled about the camera centre to the depth or the
floor (the image stays as it is; the size change goes into the shape coefficients), a rigid Levenberg-Marquardt
stage from each, then the best one goes on with every parameter. Data association (nearest vertices,
distance-transform samples, robust weights) is redone at every iteration. Jacobians are forward differences of a
batched model evaluation on ``FitConfig.num_vertices`` vertices spread over the mesh (farthest-point sampling)
plus the few others the terms need. Joint angles stay inside the limits of ``model.skeleton`` (projected steps
with an active set).

Uncertainty: ``FootFit.covariance`` is the Gauss-Newton (Laplace) covariance ``H^-1`` of all parameters at the
optimum, with the cost read as a negative log-likelihood; ``FootFit.sample_shapes`` draws shape coefficients from
it. A refit under perturbed cues, warm-started with ``FitInit.from_fit``, is the other way.
"""

from __future__ import annotations

import functools
import logging
import math
import time
import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, fields, replace

import cv2
import numpy as np
import torch
from scipy import ndimage, sparse
from scipy.spatial.transform import Rotation

from footmesh import optim
from footmesh.cues import Cues
from footmesh.fit import terms
from footmesh.geometry.alignment import weighted_procrustes
from footmesh.geometry.camera import pixel_rays, project, unproject
from footmesh.geometry.rotations import skew
from footmesh.model import anatomy, lbs
from footmesh.model import skeleton as sk
from footmesh.model.ik import natural_pose_moments
from footmesh.model.layer import FootModel, default_model
from footmesh.threads import SOLVER_THREADS, fixed_threads

log = logging.getLogger(__name__)

SIDES = ("left", "right")
CAP_MIN_HEIGHT_MM = 100.0
CAP_NORMAL_Z = 0.8
"""The model's ankle cap (where the leg joins the foot): rest vertices above this height whose normal points up
this much."""
LEG_UPRIGHT = 1.5
"""The leg's axis is the cap's normal plus this much of the foot's z axis, normalised (the shin stays nearer
upright than the cap turns with the ankle)."""
LEG_RADIUS_FACTOR = 1.1
LEG_RANGE_MM = (-10.0, 450.0)
"""The leg occluder: a cylinder of ``LEG_RADIUS_FACTOR`` x the cap's radius over this range along its axis from
the cap's centre."""
RIM_COS = 0.25
"""A vertex is on the rim (seen edge-on) when its normal is within this cosine of perpendicular to its sight line."""
FAR_MM = 1e6
"""Beyond anything a photo of a foot shows (a sight line's far end)."""
FD_STEP = 1e-6
"""Forward-difference step of the Jacobian (radians, mm, SD units alike; float64)."""
MIN_SILHOUETTE_PX = 20
"""A silhouette with fewer foot pixels holds no foot to fit (``fit_foot`` raises; the pipeline refuses first)."""
LM_INITIAL_DAMPING = 1e-2
LM_RETRIES = 5
LM_MIN_DAMPING = 1e-5
LM_RETRY_DAMPING = 1e-3
"""Damping (relative to the diagonal of J^T J) never goes below LM_MIN_DAMPING, and a rejected step is retried
with at least LM_RETRY_DAMPING, growing 4x, 8x, ... so that a few retries reach a short step."""
PNP_MIN_CONFIDENCE = 0.05
FLOOR_START_SCALE = (0.5, 2.0)
"""A start whose contact with the floor needs a size change outside this range is not a plausible start."""
PNP_RANSAC_PX = 8.0
PNP_CORE_JOINTS = np.array([0, 1, 4, 7, 10, 13, 16, 17])
"""Midfoot, the five metatarsophalangeal joints, ankle and heel: where no toe angle moves them."""
PNP_DISTINCT_DEG = 10.0
"""PnP starts closer than this to one already kept are dropped."""
SCALE_SOURCES = ("depth", "floor", "none")
_LOWER = np.asarray(sk.DOF_LOWER)
_UPPER = np.asarray(sk.DOF_UPPER)
_MIRROR = np.array([1.0, -1.0, 1.0])
FREE_SPACE_WINDOW_PX = 2
"""A vertex is in front of the measured depth only if it is in front of every depth pixel within this radius
(a vertex on the outline may round onto a floor pixel)."""

# Parameter vector of the solver: rotation increment (axis-angle, radians), translation (mm), angles (radians),
# shape (SD units).
_ROT, _TRANS, _ANGLES = slice(0, 3), slice(3, 6), slice(6, 6 + sk.NUM_DOFS)
_SHAPE0 = 6 + sk.NUM_DOFS


def parameter_names(num_shape: int) -> tuple[str, ...]:
    """Names of the rows/columns of ``FootFit.covariance``: rotation (3), translation (3), angles (22), shape."""
    return (
        "rotation_x",
        "rotation_y",
        "rotation_z",
        "translation_x",
        "translation_y",
        "translation_z",
        *sk.DOF_NAMES,
        *(f"shape_{k}" for k in range(num_shape)),
    )


# ----------------------------------------------------------------------------------------------------------
# Configuration and results
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FitConfig:
    """Weights, robust scales and solver settings of ``fit_foot`` (sigmas whiten each residual)."""

    joint_sigma_px: float = 3.0
    """Expected 2D error of a confident joint."""
    joint_huber: float = 2.0
    """Huber threshold of the joint term, in sigmas."""
    silhouette_sigma_px: float = 1.0
    silhouette_robust: float = 4.0
    """Geman-McClure scale of the contour term, in sigmas."""
    inside_count: float = 60.0
    contour_count: float = 60.0
    depth_sigma_mm: float = 1.5
    depth_robust: float = 5.0
    depth_count: float = 150.0
    free_space_tolerance_mm: float = 4.0
    free_space_count: float = 30.0
    floor_sigma_mm: float = 1.0
    floor_robust: float = 10.0
    """Geman-McClure scale of the contact term, in sigmas: a foot clearly off the floor is let go."""
    upright_sigma_rad: float = 0.05
    upright_robust: float = 3.0
    sole_contact: bool = False
    """True: the foot bears weight on the floor (``terms.SoleContact``): its heel and its ball both touch it."""
    camera_above_sigma_mm: float = 10.0
    distance_sigma_mm: float = 0.5
    shape_prior_weight: float = 1.0
    """1 = the PCA prior N(0, 1) itself."""
    angle_prior_sd_factor: float = 2.0
    """The pose prior's SD per DOF is this times the spread of everyday poses (``ik.natural_pose_moments``: 0.2
    rad for the midfoot, 0.05 for the ankle's roll and the toes' sideways turn, 0.35 for the toes' flexion). A flat
    0.5 rad for every DOF let the pose make up for the silhouette's errors (the hindfoot swung to shorten or lengthen
    the foot where the heel is hidden): guided photos with a reference, seeds 4242 / 777 / 999 (60 each, two at a
    time), length MAE 4.34 / 6.48 / 4.08 -> 4.46 / 4.99 / 3.40 mm, width 2.83 / 3.62 / 3.19 -> 2.64 / 3.15 / 2.93.
    A first version (the toes' curl centred at 0.27 rad): factors 1.5 / 2 / 2.5 gave 4.40 / 4.14 / 4.36 mm over the
    three seeds, 1 and 3 were worse on 777 (docs/fit.md)."""
    num_vertices: int = 1200
    contour_samples: int = 400
    contour_max_height_mm: float = 70.0
    """Contour samples whose nearest model vertex stands higher than this above the sole (rest pose) are not used:
    up there the outline is the model's cut or the leg (bare skin that the cue network often takes for foot, or
    a trouser's edge), no evidence of the foot's shape (51 synthetic photos with a reference: length MAE 5.4 ->
    3.8 mm; docs/fit.md)."""
    contour_leg_probe_px: float | None = 3.0
    """Contour samples where the pixel this far outside the silhouette (along its outward normal) shows the model's
    leg are not used either, their weight handed to the rest: there the foot's outline is where the leg hides it,
    not the foot's edge, and it pulled the hidden heel in (front views, seeds 4242 / 777: length MAE 6.81 / 7.39
    -> 6.39 / 7.11 mm on the photos measured both ways; docs/fit.md). None: all are used."""
    contour_leg_max_fraction: float = 0.5
    """... unless the leg would hide more than this fraction of the outline: a shin crossing the foot hides a
    stretch of it (13-35 % on front renders), and a pose whose leg points at the camera and hides it all must not
    escape the silhouette that way (two of seven real A4 photos were fitted so, on no outline at all)."""
    depth_samples: int = 800
    depth_erode_px: int = 2
    full_starts: int = 2
    """The stages after the first run from this many of the best starts and the lowest final cost wins: the first
    stage's ranking often puts the right basin second (docs/fit.md)."""
    stages: tuple[tuple[str, int], ...] = (("rigid", 3), ("full", 40))
    """(stage, LM iterations at most): "rigid" = rotation + translation; "pose" adds the angles; "full" the angles
    and the shape. A separate pose stage before the shape was slower and no better on synthetic scenes (the pose
    then bends to make up for the mean shape's size: docs/fit.md)."""
    solver_workers: int = 2
    """The starts (of both sides with side="auto") are fitted this many at a time, one thread each: they are
    independent, and torch and most numpy calls release the GIL (two sides in two threads: about 1.3-1.6x faster
    on two cores). The result does not depend on it."""
    side_tie_ratio: float = 1.15
    """With side="auto", when the two sides' best final costs lie within this ratio, the starts not carried to the
    end yet are, on both sides: on a near tie the wrong side has often only found the better basin (docs/fit.md)."""
    relative_tolerance: float = 1e-3
    """A stage stops when an accepted step lowers the cost by less than this fraction."""


@dataclass(frozen=True)
class FitInit:
    """A starting point, e.g. from a mesh decoder; any field may be None.

    ``cam_from_foot`` (4, 4) places the foot (``vertices_cam = R @ model(shape, angles, side) + t``);
    ``vertices_cam`` (V, 3) mm, a posed mesh of the model's topology in the camera frame (its placement and size
    are taken by a similarity Procrustes fit); ``shape`` (K',) SD units; ``angles`` (22,) radians.
    ``alone``: start from this placement only (a warm start); False: one start more beside the PnP ones, always
    carried through the full stage (a mesh decoder's guess).
    """

    shape: np.ndarray | None = None
    angles: np.ndarray | None = None
    cam_from_foot: np.ndarray | None = None
    vertices_cam: np.ndarray | None = None
    alone: bool = True

    @classmethod
    def from_fit(cls, fit: FootFit) -> FitInit:
        """Start where an earlier fit ended (e.g. to refit under perturbed cues)."""
        return cls(shape=fit.shape, angles=fit.angles, cam_from_foot=fit.cam_from_foot)


def mesh_side_residuals(vertices_cam: np.ndarray, model: FootModel | None = None) -> dict[str, float]:
    """Mean distance (mm) of a mesh (V, 3) of the model's topology, e.g. a decoder's, to the mean foot of each side
    placed on it by a similarity transform: a mirror image cannot be turned into the other side's foot, so the
    true side's residual is far the smaller (RGB-D decoder on 52 guided and random photos: 2-26 mm against
    34-58 mm, every side right)."""
    model = model if model is not None else default_model()
    with torch.no_grad():
        rest = model(torch.zeros(len(SIDES), model.num_components), side=list(SIDES)).vertices.double()  # (2, V, 3)
    target = torch.as_tensor(np.asarray(vertices_cam, dtype=np.float64))[None].expand_as(rest)
    rot, scale, trans = weighted_procrustes(rest, target, torch.ones(rest.shape[1], dtype=torch.float64))
    placed = scale[:, None, None] * rest @ rot.transpose(1, 2) + trans[:, None]
    residuals = (placed - target).norm(dim=2).mean(dim=1)
    return dict(zip(SIDES, residuals.tolist(), strict=True))


@dataclass(frozen=True)
class FitQuality:
    """How well a fit explains the image (unweighted, px / mm), for the pipeline's refusals (``footmesh.refusals``)."""

    contour_within_2px: float
    """Fraction of the silhouette's contour samples within 2 px of the model's outline."""
    vertices_outside_2px: float
    """Fraction of the model's visible vertices more than 2 px outside the silhouette."""
    joint_error_px: float
    """Confidence-weighted mean distance of the model's projected joints from the 2D joints."""
    foot_shown: float
    """Fraction of the model below the ankle that the silhouette shows (``foot_shown``)."""
    depth_median_mm: float | None = None
    """Median |depth residual| of the model's visible surface (None without depth)."""

    def to_dict(self) -> dict[str, float]:
        """result.json ``fit.quality`` (``depth_median_mm`` only with depth)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True, eq=False)
class FootFit:
    """The foot model fitted to one image, camera frame (OpenCV, mm).

    ``vertices_cam = R @ model(shape, angles, scale=1, side) + t`` with ``[R | t] = cam_from_foot[:3]``.
    ``scaled`` is False when there was no scale evidence (no depth, no floor plane): the foot was fitted at the
    distance of a mean-size foot and every millimetre figure (size, position) is arbitrary; only scale-free
    quantities (ratios, angles) mean anything.

    Attributes:
        side: "left" or "right".
        shape: (K,) PCA coefficients, SD units.
        angles: (22,) radians, ``skeleton.DOF_NAMES`` order, inside the limits.
        cam_from_foot: (4, 4) foot frame -> camera.
        vertices_cam: (V, 3) mm. joints_cam: (18, 3) mm.
        scaled: whether millimetres are real. scale_source: "depth", "floor" or "none".
        loss: final total cost (robust, whitened). loss_terms: the cost of each term.
        side_losses: final cost of each side tried ({"left": ..., "right": ...} with side="auto").
        covariance: (6 + 22 + K, 6 + 22 + K) Gauss-Newton covariance of the parameters at the optimum
            (``parameter_names(K)``: rotation increment, translation, angles, shape).
        quality: how well the fit explains the image, to refuse a bad fit (``FitQuality``).
        iterations: LM iterations taken (all sides and starts). seconds: wall time of the whole fit.
    """

    side: str
    shape: np.ndarray
    angles: np.ndarray
    cam_from_foot: np.ndarray
    vertices_cam: np.ndarray
    joints_cam: np.ndarray
    scaled: bool
    scale_source: str
    loss: float
    loss_terms: dict[str, float]
    side_losses: dict[str, float]
    covariance: np.ndarray = field(repr=False)
    quality: FitQuality
    iterations: int = 0
    seconds: float = 0.0

    @property
    def shape_covariance(self) -> np.ndarray:
        """(K, K) covariance of the shape coefficients (SD units^2), marginal over pose and placement."""
        return self.covariance[_SHAPE0:, _SHAPE0:]

    def sample_shapes(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """(n, K) shape coefficients drawn from N(shape, shape_covariance), e.g. to propagate to measurements."""
        rng = np.random.default_rng(rng)
        return rng.multivariate_normal(self.shape, self.shape_covariance, size=n, method="eigh")

    def shape_sigma_points(self) -> np.ndarray:
        """(2, K, K) shape coefficients one SD either way ([0]: +, [1]: -) along each principal axis of
        ``shape_covariance``: a function f of the shape has SD ~ sqrt(sum_k ((f(+k) - f(-k)) / 2)^2), exact when f
        is linear (central differences; 2K evaluations instead of many samples)."""
        variance, axes = np.linalg.eigh(self.shape_covariance)
        steps = (axes * np.sqrt(np.clip(variance, 0.0, None))).T  # (K, K): row k = SD_k * axis_k
        return np.stack([self.shape + steps, self.shape - steps])

    def canonical_vertices(self, model: FootModel | None = None) -> np.ndarray:
        """(V, 3) mm, the fitted shape in the zero pose, foot frame of its side (what ``measure`` takes)."""
        model = model if model is not None else default_model()
        with torch.no_grad():
            out = model(torch.as_tensor(self.shape, dtype=torch.float32)[None], side=self.side)
        return out.vertices[0].double().numpy()

    def __repr__(self) -> str:
        return (
            f"FootFit(side={self.side}, scaled={self.scaled} ({self.scale_source}), loss={self.loss:.3g}, "
            f"iterations={self.iterations}, seconds={self.seconds:.3f})"
        )


# ----------------------------------------------------------------------------------------------------------
# Model arrays for the solver (a vertex subset, float64)
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _ModelArrays:
    """The model's buffers in float64 and the spread subset of vertices that the dense terms use."""

    model: FootModel
    subset: np.ndarray  # (S,) vertex ids
    mean: torch.Tensor  # (V, 3)
    components: torch.Tensor  # (K, V, 3)
    sd: torch.Tensor  # (K,)
    weights: torch.Tensor  # (V, 18)
    joint_mean: torch.Tensor  # (18, 3) joint_regressor @ mean
    joint_basis: torch.Tensor  # (K, 18, 3) joint_regressor @ (sd_k component_k)
    rest_normals: torch.Tensor  # (V, 3) unit normals of the mean rest foot (left)
    cap: np.ndarray  # (C,) vertex ids of the ankle cap, where the leg joins the foot
    sole: tuple[np.ndarray, np.ndarray]  # vertex ids of the heel and the ball, where a standing foot bears weight

    @property
    def num_shape(self) -> int:
        return int(self.sd.shape[0])

    @property
    def num_params(self) -> int:
        """Rotation increment, translation, angles, shape and a log-scale (used only without scale evidence)."""
        return _SHAPE0 + self.num_shape + 1


def farthest_point_subset(points: np.ndarray, n: int) -> np.ndarray:
    """(n,) sorted indices of ``n`` points of (N, 3) spread by farthest-point sampling, starting from point 0."""
    n = min(n, len(points))
    chosen = np.zeros(n, dtype=np.int64)
    dist = np.linalg.norm(points - points[0], axis=1)
    for i in range(1, n):
        chosen[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return np.sort(chosen)


@functools.lru_cache(maxsize=4)
def _model_arrays(model: FootModel, num_vertices: int) -> _ModelArrays:
    dt = torch.float64
    mean = model.mean_vertices.detach().to(dt)
    comps = model.components.detach().to(dt)
    sd = model.component_sd.detach().to(dt)
    jreg = model.joint_regressor.detach().to(dt)
    faces = model.faces_left.numpy()
    mean_np = mean.numpy()
    subset = farthest_point_subset(mean_np, num_vertices)
    # area-weighted vertex normals of the mean rest foot
    fn = np.cross(mean_np[faces[:, 1]] - mean_np[faces[:, 0]], mean_np[faces[:, 2]] - mean_np[faces[:, 0]])
    rows = faces.reshape(-1)
    incidence = sparse.csr_matrix((np.ones(rows.size), (rows, np.repeat(np.arange(len(faces)), 3))))
    normals = incidence @ fn
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return _ModelArrays(
        model=model,
        subset=subset,
        mean=mean,
        components=comps,
        sd=sd,
        weights=model.skin_weights.detach().to(dt),
        joint_mean=jreg @ mean,
        joint_basis=torch.einsum("jv,kvc->kjc", jreg, comps * sd[:, None, None]),
        rest_normals=torch.from_numpy(normals),
        cap=np.flatnonzero((mean_np[:, 2] > CAP_MIN_HEIGHT_MM) & (normals[:, 2] > CAP_NORMAL_Z)),
        sole=(anatomy.heel_region(mean_np), anatomy.ball_region(mean_np)),
    )


def shape_for_scale(model: FootModel, scale: float, shape: np.ndarray | None = None) -> np.ndarray:
    """(K,) shape coefficients whose rest foot best matches ``scale`` x the rest foot of ``shape`` (default mean).

    Least squares in the PCA space (its first components carry foot size), so that a size found as a scale about
    the heel origin is moved into the shape and the model's own ``scale`` can stay 1.
    """
    mean = model.mean_vertices.detach().double().numpy().reshape(-1)
    sd = model.component_sd.detach().double().numpy()
    basis = model.components.detach().double().numpy().reshape(len(sd), -1) * sd[:, None]  # (K, 3V)
    k = len(sd)
    c = np.zeros(k) if shape is None else np.pad(np.asarray(shape, dtype=np.float64), (0, k - len(shape)))
    target = scale * (mean + c @ basis) - mean
    return np.linalg.lstsq(basis.T, target, rcond=None)[0]


def skin_batched(vertices: torch.Tensor, transforms: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """``lbs.skin`` (same result, bit for bit) as one batched matmul: 2-3x faster for the solver's batches.

    Args:
        vertices: (B, N, 3) rest vertices, mm. transforms: (B, J, 3, 4). weights: (N, J).
    Returns:
        (B, N, 3) posed vertices, mm.
    """
    b, n = vertices.shape[:2]
    eye = torch.eye(3, 4, dtype=transforms.dtype, device=transforms.device)
    blended = torch.matmul(weights, (transforms - eye).reshape(b, -1, 12)).reshape(b, n, 3, 4)
    return vertices + (blended[..., :3] @ vertices.unsqueeze(-1)).squeeze(-1) + blended[..., 3]


def _fk_levels() -> tuple[tuple[torch.Tensor, torch.Tensor, torch.Tensor], ...]:
    """The kinematic tree by depth: (children, their parents, the parents' positions among the joints placed
    before), so that forward kinematics takes 3 batched steps instead of 17."""
    depth = [0] * sk.NUM_JOINTS
    for j in range(1, sk.NUM_JOINTS):
        depth[j] = depth[sk.PARENTS[j]] + 1
    order, levels = [0], []
    for d in range(1, max(depth) + 1):
        children = [j for j in range(sk.NUM_JOINTS) if depth[j] == d]
        parents = [sk.PARENTS[j] for j in children]
        levels.append((torch.tensor(children), torch.tensor(parents), torch.tensor([order.index(p) for p in parents])))
        order += children
    return (*levels, (torch.tensor(np.argsort(order)),) * 3)


_FK_LEVELS = _fk_levels()


def forward_kinematics_by_level(angles: torch.Tensor, rest_joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``lbs.forward_kinematics`` (same maths) with the joints of one tree depth at a time: far fewer small ops.

    Args:
        angles: (B, 22) radians. rest_joints: (B, 18, 3) mm.
    Returns:
        posed joints (B, 18, 3) mm, transforms (B, 18, 3, 4).
    """
    b = angles.shape[0]
    local = lbs.local_rotations(angles)
    rot = torch.eye(3, dtype=angles.dtype).expand(b, 1, 3, 3)
    trans = angles.new_zeros(b, 1, 3)
    *levels, (inverse, _, _) = _FK_LEVELS
    for children, parents, placed in levels:
        rot_p, t_p = rot[:, placed], trans[:, placed]
        pivot = rest_joints[:, parents].unsqueeze(-1)
        rot_c = rot_p @ local[:, children]
        # x -> rot_p (R_c (x - pivot) + pivot) + t_p
        t_c = t_p + (rot_p @ pivot).squeeze(-1) - (rot_c @ pivot).squeeze(-1)
        rot, trans = torch.cat([rot, rot_c], 1), torch.cat([trans, t_c], 1)
    rot, trans = rot[:, inverse], trans[:, inverse]
    posed = (rot @ rest_joints.unsqueeze(-1)).squeeze(-1) + trans
    return posed, torch.cat([rot, trans.unsqueeze(-1)], dim=-1)


def _pose_vertices(
    arrays: _ModelArrays, side: str, shape: torch.Tensor, angles: torch.Tensor, ids: torch.Tensor, normals: bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Vertices ``ids`` (B, N, 3), joints (B, 18, 3) and, if asked, vertex normals (B, N, 3), in the foot frame of
    ``side``, mm."""
    v_shaped = lbs.blend_shapes(shape, arrays.mean[ids], arrays.components[:, ids], arrays.sd)
    rest_joints = arrays.joint_mean + torch.einsum("bk,kjc->bjc", shape, arrays.joint_basis)
    joints, transforms = forward_kinematics_by_level(angles, rest_joints)
    weights = arrays.weights[ids]
    vertices = skin_batched(v_shaped, transforms, weights)
    posed_normals = None
    if normals:
        # normals turn with the blended rotations (translations zeroed); the shape barely changes them
        rotations = torch.cat([transforms[..., :3], torch.zeros_like(transforms[..., 3:])], dim=-1)
        rest = arrays.rest_normals[ids].unsqueeze(0).expand_as(vertices)
        posed_normals = skin_batched(rest, rotations, weights)
    if side == "right":
        mirror = torch.tensor(_MIRROR, dtype=vertices.dtype)
        vertices, joints = vertices * mirror, joints * mirror
        posed_normals = posed_normals * mirror if normals else None
    return vertices, joints, posed_normals


# ----------------------------------------------------------------------------------------------------------
# Evidence: the cues turned into what the residuals read
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Evidence:
    K: np.ndarray  # (3, 3)
    size: tuple[int, int]  # (H, W)
    joints: np.ndarray  # (18, 2) px
    joint_weight: np.ndarray  # (18,)
    mask: np.ndarray  # (H, W) bool
    outside_dt: np.ndarray  # (H, W) px from the silhouette's edge, 0 inside
    outside_grad: np.ndarray  # (2, H, W) d/dx, d/dy of outside_dt
    contour: np.ndarray  # (M, 2) px on the silhouette's 0.5 level
    contour_normal: np.ndarray  # (M, 2) unit, pointing out of the silhouette
    depth: np.ndarray | None  # (H, W) mm, 0 = missing
    near_depth: np.ndarray | None  # (H, W) mm, the nearest depth within FREE_SPACE_WINDOW_PX, 0 = none
    depth_points: np.ndarray | None  # (N, 3) mm, camera frame
    floor: np.ndarray | None  # (4,) plane: height above the floor = floor[:3] @ X + floor[3], mm

    @property
    def scale_source(self) -> str:
        return "depth" if self.depth_points is not None else ("floor" if self.floor is not None else "none")


def _check_inputs(cues: Cues, K: np.ndarray, depth_mm, cam_from_floor, side: str) -> None:
    if not isinstance(cues, Cues):
        raise TypeError(f"cues must be footmesh.cues.Cues, got {type(cues).__name__}")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be (3, 3) intrinsics with positive focal lengths in pixels, got {K.tolist()}")
    if not (np.isfinite(cues.joints2d_px).all() and np.isfinite(cues.joint_confidence).all()):
        raise ValueError("cues: joints2d_px and joint_confidence must be finite")
    if not np.isfinite(cues.silhouette).all():
        raise ValueError("cues: silhouette contains NaN or infinite values")
    if depth_mm is not None:
        depth = np.asarray(depth_mm)
        if depth.shape != cues.silhouette.shape:
            raise ValueError(
                f"depth_mm {depth.shape} must match the silhouette {cues.silhouette.shape} pixel for pixel"
            )
        valid = depth[depth > 0]
        if valid.size and (np.median(valid) < 50 or np.median(valid) > 20000):
            raise ValueError(
                f"depth_mm: median depth {np.median(valid):.4g} is not a camera distance in millimetres "
                "(metres? convert to mm)"
            )
    if cam_from_floor is not None:
        t = np.asarray(cam_from_floor, dtype=np.float64)
        if t.shape != (4, 4) or not np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-4):
            raise ValueError("cam_from_floor must be a (4, 4) rigid transform (floor frame z = 0 -> camera, mm)")
    if side not in (*SIDES, "auto"):
        raise ValueError(f"side must be 'left', 'right' or 'auto', got {side!r}")


def silhouette_contour(silhouette: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel points on the 0.5 level of a silhouette and their outward normals.

    Every pair of 4-neighbour pixels across the level contributes the linearly interpolated crossing, so a binary
    mask gives the pixel edges themselves (half a pixel outside the last foot pixel's centre). Edges cut by the
    image border give no points.

    Args:
        silhouette: (H, W) probability (or 0/1).
    Returns:
        points (M, 2) px (x, y), normals (M, 2) unit vectors pointing out of the silhouette.
    """
    p = np.asarray(silhouette, dtype=np.float64)
    smooth = ndimage.gaussian_filter(p, 1.0)
    gy, gx = np.gradient(smooth)
    points, normals = [], []
    for axis in (1, 0):
        a = p[:, :-1] if axis == 1 else p[:-1]
        b = p[:, 1:] if axis == 1 else p[1:]
        rows, cols = np.nonzero((a - 0.5) * (b - 0.5) < 0)
        frac = (0.5 - a[rows, cols]) / (b[rows, cols] - a[rows, cols])
        x = cols + (frac if axis == 1 else 0.0)
        y = rows + (frac if axis == 0 else 0.0)
        points.append(np.stack([x, y], axis=1))
        ri, ci = np.clip(np.rint(y).astype(int), 0, p.shape[0] - 1), np.clip(np.rint(x).astype(int), 0, p.shape[1] - 1)
        g = -np.stack([gx[ri, ci], gy[ri, ci]], axis=1)
        # the crossing's own direction where the smoothed gradient vanishes (thin structures)
        step = np.zeros_like(g)
        step[:, 1 - axis] = np.sign(a[rows, cols] - b[rows, cols])
        g = np.where(np.linalg.norm(g, axis=1, keepdims=True) > 1e-6, g, step)
        normals.append(g / np.linalg.norm(g, axis=1, keepdims=True))
    return np.concatenate(points), np.concatenate(normals)


def _evidence(cues: Cues, K: np.ndarray, depth_mm, cam_from_floor, config: FitConfig) -> _Evidence:
    mask = cues.mask
    if mask.sum() < MIN_SILHOUETTE_PX:
        raise ValueError(f"cues: the silhouette has only {int(mask.sum())} foot pixels; no foot to fit")
    K = np.asarray(K, dtype=np.float64)
    rng = np.random.default_rng(0)  # sample choice only; fixed so that a fit is reproducible
    dt = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64)
    # distance to the pixel edge, not to the last foot pixel's centre
    dt = np.maximum(dt - 0.5, 0.0)
    grad = np.stack(np.gradient(dt)[::-1])
    contour, normal = silhouette_contour(cues.silhouette)
    if len(contour) > config.contour_samples:
        keep = np.sort(rng.choice(len(contour), config.contour_samples, replace=False))
        contour, normal = contour[keep], normal[keep]
    depth = depth_points = near_depth = None
    if depth_mm is not None:
        depth = np.asarray(depth_mm, dtype=np.float64)
        kernel = np.ones((2 * config.depth_erode_px + 1,) * 2, np.uint8)
        inner = cv2.erode(mask.astype(np.uint8), kernel).astype(bool) & (depth > 0)
        rows, cols = np.nonzero(inner)
        if len(rows) < 30:
            warnings.warn(
                f"depth map has only {len(rows)} valid pixels on the foot: depth ignored", RuntimeWarning, stacklevel=3
            )
            depth = None
        else:
            if len(rows) > config.depth_samples:
                keep = np.sort(rng.choice(len(rows), config.depth_samples, replace=False))
                rows, cols = rows[keep], cols[keep]
            z = depth[rows, cols]
            depth_points = unproject(np.stack([cols, rows], axis=-1), z, K)
            size = 2 * FREE_SPACE_WINDOW_PX + 1
            near_depth = ndimage.minimum_filter(np.where(depth > 0, depth, np.inf), size=size, mode="nearest")
            near_depth[~np.isfinite(near_depth)] = 0.0
    floor = None
    if cam_from_floor is not None:
        floor_from_cam = np.linalg.inv(np.asarray(cam_from_floor, dtype=np.float64))
        floor = floor_from_cam[2].copy()
    weight = np.clip(np.asarray(cues.joint_confidence, dtype=np.float64), 0.0, 1.0)
    return _Evidence(
        K=K,
        size=mask.shape,
        joints=np.asarray(cues.joints2d_px, dtype=np.float64),
        joint_weight=weight,
        mask=mask,
        outside_dt=dt,
        outside_grad=grad,
        contour=contour,
        contour_normal=normal,
        depth=depth,
        near_depth=near_depth,
        depth_points=depth_points,
        floor=floor,
    )


def projected_mask(
    vertices_cam: np.ndarray, faces: np.ndarray, K: np.ndarray, size: tuple[int, int]
) -> np.ndarray | None:
    """(H, W) bool: the pixels that the mesh (V, 3) mm, camera frame, covers; None when a vertex is behind the
    camera. OpenCV's polygon fill, not ``synth.raster``: no depth is needed, and no numba compile on a cold start."""
    if not np.all(vertices_cam[:, 2] > 0):
        return None
    uv = (vertices_cam[:, :2] / vertices_cam[:, 2:3]) @ K[:2, :2].T + K[:2, 2]
    raster = np.zeros(size, np.uint8)
    # one triangle at a time: fillPoly fills a list of overlapping polygons even-odd, leaving holes
    for tri in np.round(uv[faces] * 4).astype(np.int32):  # 2 fractional bits
        cv2.fillConvexPoly(raster, tri, 1, lineType=cv2.LINE_8, shift=2)
    return raster > 0


def foot_image(
    vertices_cam: np.ndarray,
    side: str,
    K: np.ndarray,
    size: tuple[int, int],
    model: FootModel | None = None,
    max_height_mm: float | None = None,
) -> np.ndarray | None:
    """(H, W) bool: the pixels that the fitted ``side`` foot (its vertices (V, 3) mm, camera frame) covers below
    the ankle (rest height under ``max_height_mm``, default ``FitConfig.contour_max_height_mm``): the foot without
    its leg cap; None when a vertex is behind the camera."""
    model = model if model is not None else default_model()
    max_height_mm = FitConfig.contour_max_height_mm if max_height_mm is None else max_height_mm
    low = model.mean_vertices[:, 2].detach().numpy() < max_height_mm
    faces = model.faces(side).numpy()
    return projected_mask(vertices_cam, faces[low[faces].all(axis=1)], K, size)


def foot_shown(
    vertices_cam: np.ndarray,
    side: str,
    mask: np.ndarray,
    K: np.ndarray,
    model: FootModel | None = None,
    max_height_mm: float | None = None,
) -> float:
    """Fraction of the fitted ``side`` foot's image (its vertices (V, 3) mm, camera frame) below the ankle (rest
    height under ``max_height_mm``, default ``FitConfig.contour_max_height_mm``) that the photo's silhouette
    (H, W) bool shows: the rest is hidden (by the leg, a trouser, the image's edge)."""
    covered = foot_image(vertices_cam, side, K, mask.shape, model, max_height_mm)
    if covered is None or not covered.any():
        return 0.0
    return float((covered & mask).sum() / covered.sum())


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample (..., H, W) at (N, 2) px (x, y) bilinearly; 0 outside the image."""
    h, w = image.shape[-2:]
    x, y = uv[:, 0], uv[:, 1]
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.minimum(np.floor(x).astype(int), w - 2), np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = x - x0, y - y0
    out = (
        image[..., y0, x0] * (1 - fx) * (1 - fy)
        + image[..., y0, x0 + 1] * fx * (1 - fy)
        + image[..., y0 + 1, x0] * (1 - fx) * fy
        + image[..., y0 + 1, x0 + 1] * fx * fy
    )
    return out * inside


@dataclass(frozen=True)
class LegCylinder:
    """The lower leg as a cylinder: centre (3,) and unit axis (3,) in mm, camera frame, radius mm, and the range of
    heights along the axis from the centre that it covers."""

    centre: np.ndarray
    axis: np.ndarray
    radius: float
    heights: tuple[float, float] = LEG_RANGE_MM


def _leg_cylinder(cap: np.ndarray, cap_normals: np.ndarray, foot_up: np.ndarray) -> LegCylinder:
    """The leg standing on the ankle cap: cap vertices (C, 3) and normals (C, 3), foot z axis (3,), camera frame."""
    centre = cap.mean(axis=0)
    normal = cap_normals.mean(axis=0)
    axis = normal / np.linalg.norm(normal) + LEG_UPRIGHT * foot_up
    axis /= np.linalg.norm(axis)
    offset = cap - centre
    radial = offset - np.outer(offset @ axis, axis)
    return LegCylinder(centre, axis, float(np.linalg.norm(radial, axis=1).max() * LEG_RADIUS_FACTOR))


def _far_along_sight(uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(M, 3) mm: points far along the sight lines through the pixels ``uv`` (M, 2), beyond anything in view."""
    return unproject(uv, np.full(len(uv), FAR_MM), K)


def leg_occludes(points: np.ndarray, leg: LegCylinder, margin_mm: float = 2.0) -> np.ndarray:
    """(N,) bool: the camera's line of sight to each point (N, 3) (camera frame, mm) passes through the leg.

    The sight line ``lam * d`` (0 < lam < |p| - margin) is hidden if some part of it lies inside the infinite
    cylinder and within the leg's height range at once.
    """
    dist = np.linalg.norm(points, axis=1)
    d = points / dist[:, None]
    a, c = leg.axis, leg.centre
    # inside the infinite cylinder: |lam d_perp - c_perp|^2 <= r^2
    d_perp = d - np.outer(d @ a, a)
    c_perp = c - (c @ a) * a
    qa = (d_perp * d_perp).sum(1)
    qb = -(d_perp @ c_perp)
    qc = c_perp @ c_perp - leg.radius**2
    disc = qb * qb - qa * qc
    hit = disc > 0
    root = np.sqrt(np.maximum(disc, 0.0))
    safe = np.maximum(qa, 1e-12)
    lo1, hi1 = (-qb - root) / safe, (-qb + root) / safe
    # within the height range: h(lam) = lam (d . a) - c . a in [h0, h1]
    da = d @ a
    h0, h1 = leg.heights
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (h0 + c @ a) / da, (h1 + c @ a) / da
    lo2, hi2 = np.minimum(t0, t1), np.maximum(t0, t1)
    parallel = np.abs(da) < 1e-12
    inside_range = (h0 <= -(c @ a)) & (-(c @ a) <= h1)
    lo2 = np.where(parallel, np.where(inside_range, -np.inf, np.inf), lo2)
    hi2 = np.where(parallel, np.where(inside_range, np.inf, -np.inf), hi2)
    lo = np.maximum(np.maximum(lo1, lo2), 0.0)
    hi = np.minimum(np.minimum(hi1, hi2), dist - margin_mm)
    return hit & (lo < hi)


# ----------------------------------------------------------------------------------------------------------
# Robust kernels (whitened residual s; cost rho(s), IRLS weight rho'(s) / s)
# ----------------------------------------------------------------------------------------------------------


def _rho(kind: str, s: np.ndarray, k: float) -> np.ndarray:
    if kind == "gm_above":  # Geman-McClure for s > 0, least squares below
        return np.where(s > 0, _rho("gm", s, k), 0.5 * s * s)
    if kind == "huber":
        a = np.abs(s)
        return np.where(a <= k, 0.5 * s * s, k * a - 0.5 * k * k)
    if kind == "gm":  # Geman-McClure: (k^2 / 2) s^2 / (k^2 + s^2)
        return 0.5 * k * k * s * s / (k * k + s * s)
    return 0.5 * s * s


def _irls_weight(kind: str, s: np.ndarray, k: float) -> np.ndarray:
    if kind == "gm_above":
        return np.where(s > 0, _irls_weight("gm", s, k), 1.0)
    if kind == "huber":
        return np.minimum(1.0, k / np.maximum(np.abs(s), 1e-12))
    if kind == "gm":
        return (k * k / (k * k + s * s)) ** 2
    return np.ones_like(s)


# ----------------------------------------------------------------------------------------------------------
# The problem for one side
# ----------------------------------------------------------------------------------------------------------


@dataclass
class _State:
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)
    angles: np.ndarray  # (22,)
    shape: np.ndarray  # (K,)
    log_scale: float = 0.0  # model scale about the heel origin; stays 0 whenever there is scale evidence

    def vector(self) -> np.ndarray:
        return np.concatenate([np.zeros(3), self.translation, self.angles, self.shape, [self.log_scale]])

    def moved(self, step: np.ndarray) -> _State:
        return _State(
            Rotation.from_rotvec(step[_ROT]).as_matrix() @ self.rotation,
            self.translation + step[_TRANS],
            np.clip(self.angles + step[_ANGLES], _LOWER, _UPPER),
            self.shape + step[_SHAPE0:-1],
            self.log_scale + float(step[-1]),
        )

    def scale_into_shape(self, model: FootModel) -> _State:
        """The same foot with its scale moved into the shape coefficients (exact to about 0.03 mm)."""
        if self.log_scale == 0.0:
            return self
        shape = shape_for_scale(model, math.exp(self.log_scale), self.shape)
        return _State(self.rotation, self.translation, self.angles, shape)


@dataclass
class _Association:
    """What the residuals hold fixed between two re-associations (vertex ids, targets, robust weights) and the
    cost at the state where it was made."""

    ids: torch.Tensor  # (N,) vertex ids the residuals read: the spread subset, then the floor terms' extra ones
    blocks: dict[str, dict]  # term -> constants (positions into ``ids``, targets, scale, IRLS sqrt weights)
    terms: dict[str, float]

    @property
    def cost(self) -> float:
        return float(sum(self.terms.values()))


class _SideProblem:
    """Residuals, data association and Levenberg-Marquardt for one side."""

    def __init__(self, ev: _Evidence, arrays: _ModelArrays, side: str, config: FitConfig, distance0: float | None):
        self.ev, self.arrays, self.side, self.config = ev, arrays, side, config
        self.distance0 = distance0  # assumed midfoot distance without scale evidence
        self.k_t = torch.from_numpy(ev.K)
        self.all_ids = torch.arange(arrays.mean.shape[0])
        mean, sd = natural_pose_moments()
        self.angle_mean, self.angle_sd = torch.from_numpy(mean), torch.from_numpy(sd * config.angle_prior_sd_factor)

    # --- model ----------------------------------------------------------------------------------------------

    def evaluate(
        self, state: _State, steps: np.ndarray, ids: torch.Tensor, normals: bool = False
    ) -> dict[str, torch.Tensor]:
        """The model at ``state`` moved by each row of ``steps`` (B, P), camera frame: vertices ``ids`` (B, N, 3)
        mm, their normals, joints (B, 18, 3), rotation (B, 3, 3), translation (B, 3), shape, angles. The rotation
        increment is taken to first order (exact Jacobian at 0; states always carry it as 0)."""
        p = torch.from_numpy(steps)
        q = torch.from_numpy(state.vector()) + p
        shape, angles, scale = q[:, _SHAPE0:-1], q[:, _ANGLES], torch.exp(q[:, -1:, None])
        vertices, joints, vertex_normals = _pose_vertices(self.arrays, self.side, shape, angles, ids, normals)
        vertices, joints = vertices * scale, joints * scale
        rot = (torch.eye(3, dtype=p.dtype) + skew(p[:, _ROT])) @ torch.from_numpy(state.rotation)
        t = q[:, _TRANS]
        rt = rot.transpose(1, 2)
        return {
            "vertices": vertices @ rt + t[:, None],
            "joints": joints @ rt + t[:, None],
            "normals": vertex_normals @ rt if normals else None,
            "rotation": rot,
            "translation": t,
            "shape": shape,
            "angles": angles,
        }

    def project(self, points: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) mm, camera frame -> (B, N, 2) px."""
        return project(points, self.k_t, min_depth=1.0)[0]

    # --- residuals --------------------------------------------------------------------------------------------

    def residuals(self, out: dict[str, torch.Tensor], assoc: _Association) -> dict[str, torch.Tensor]:
        """Whitened residuals (B, m) of each term with the association held fixed (``out`` over ``assoc.ids``)."""
        return terms.residuals(self, out, assoc.blocks)

    # --- association ------------------------------------------------------------------------------------------

    def associate(self, state: _State) -> _Association:
        """Every term's data association at ``state`` (``terms.TERMS``), the robust weights and the cost."""
        t = torch.from_numpy
        subset, cap = self.arrays.subset, self.arrays.cap
        # the whole mesh: the subset, the ankle cap (for the leg), the rim (for the contour), the lowest point (for
        # the floor)
        with torch.no_grad():
            full = self.evaluate(state, np.zeros((1, self.arrays.num_params)), self.all_ids, normals=True)
        v_all, n_all = full["vertices"][0].numpy(), full["normals"][0].numpy()
        v, n = v_all[subset], n_all[subset]
        leg = _leg_cylinder(v_all[cap], n_all[cap], full["rotation"][0].numpy()[:, 2])
        cos_view = np.abs((n_all * v_all).sum(1)) / np.maximum(
            np.linalg.norm(n_all, axis=1) * np.linalg.norm(v_all, axis=1), 1e-12
        )
        frame = terms.Frame(
            vertices=v_all,
            normals=n_all,
            projected=self.project(full["vertices"])[0].numpy(),
            subset=subset,
            hidden=leg_occludes(v, leg),
            facing=np.flatnonzero((n * v).sum(1) < 0),
            rim=np.flatnonzero(cos_view < RIM_COS),
            sample=_bilinear,
            shows_leg=lambda uv: leg_occludes(_far_along_sight(uv, self.ev.K), leg),
        )
        blocks, vertex_ids = terms.associate(self, frame)
        ids = t(vertex_ids)
        assoc = _Association(ids, blocks, {})
        out = dict(full)
        out["vertices"] = full["vertices"][:, ids]
        with torch.no_grad():
            res = self.residuals(out, assoc)
        for name, s in res.items():
            s = s[0].numpy()
            kind, k = terms.kernel(name, self.config)
            scale = blocks[name]["scale"]
            blocks[name]["sqrt_weight"] = t(np.sqrt(scale * _irls_weight(kind, s, k)))
            assoc.terms[name] = float(np.sum(scale * _rho(kind, s, k)))
        return assoc

    # --- Levenberg-Marquardt ------------------------------------------------------------------------------------

    def linearise(self, state: _State, assoc: _Association, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """IRLS-weighted residual r (m,) and its Jacobian (m, len(active)) by forward differences of one batched
        model evaluation."""
        h = FD_STEP
        steps = np.zeros((1 + len(active), self.arrays.num_params))
        steps[np.arange(1, len(active) + 1), active] = h
        with torch.no_grad():
            res = self.residuals(self.evaluate(state, steps, assoc.ids), assoc)
        r, jac = [], []
        for name, s in res.items():
            s = s * assoc.blocks[name]["sqrt_weight"]
            r.append(s[0])
            jac.append(((s[1:] - s[:1]) / h).T)
        return torch.cat(r).numpy(), torch.cat(jac).numpy()

    def solve(self, state: _State, stages: Sequence[tuple[str, int]]) -> tuple[_State, _Association, int]:
        """Levenberg-Marquardt through the stages; returns the final state, its association and the iterations."""
        full = _SHAPE0 + self.arrays.num_shape + (1 if self.distance0 is not None else 0)
        groups = {"rigid": np.r_[0:6], "pose": np.r_[0:_SHAPE0], "full": np.r_[0:full]}
        assoc = self.associate(state)
        iterations = 0
        tol = self.config.relative_tolerance
        for stage, max_iter in stages:
            active = groups[stage]
            damping, grow = LM_INITIAL_DAMPING, 4.0
            for _ in range(max_iter):
                iterations += 1
                r, jac = self.linearise(state, assoc, active)
                hess, grad = jac.T @ jac, jac.T @ r
                done = False
                for _ in range(LM_RETRIES):
                    step = self._step(state, hess, grad, damping, active)
                    d = step[active]
                    predicted = -(grad @ d + 0.5 * d @ hess @ d)
                    if predicted < tol * assoc.cost:  # converged: no step is worth taking
                        done = True
                        break
                    new = state.moved(step)
                    new_assoc = self.associate(new)
                    gain = (assoc.cost - new_assoc.cost) / predicted
                    if gain > 0:
                        break
                    if log.isEnabledFor(logging.DEBUG):
                        change = {k: round(v - assoc.terms.get(k, 0), 2) for k, v in new_assoc.terms.items()}
                        log.debug("%s %s: rejected %.5g (damping %.3g), changes %s", self.side, stage,
                                  new_assoc.cost, damping, change)  # fmt: skip
                    damping, grow = max(damping * grow, LM_RETRY_DAMPING), grow * 2.0
                else:
                    done = True
                if done:
                    break
                decrease = (assoc.cost - new_assoc.cost) / max(assoc.cost, 1e-12)
                log.debug(
                    "%s %s: %.5g -> %.5g (gain %.2f, damping %.3g)",
                    self.side,
                    stage,
                    assoc.cost,
                    new_assoc.cost,
                    gain,
                    damping,
                )
                state, assoc = new, new_assoc
                # Nielsen's update of the damping from the gain ratio
                damping, grow = max(damping * max(1 / 3, 1 - (2 * gain - 1) ** 3), LM_MIN_DAMPING), 4.0
                if decrease < tol:
                    break
        return state, assoc, iterations

    def _step(self, state: _State, hess: np.ndarray, grad: np.ndarray, damping: float, active: np.ndarray):
        """Damped Gauss-Newton step (P,) over ``active`` (``optim.solve_damped``); angles at a limit that the step
        pushes through are held and the step solved again."""
        held = np.zeros(len(active), dtype=bool)
        normal, descent = torch.from_numpy(hess), torch.from_numpy(-grad)
        full = np.zeros(self.arrays.num_params)
        for _ in range(3):
            d = optim.solve_damped(normal, descent, damping, torch.from_numpy(held), absolute_floor=1e-9).numpy()
            full = np.zeros(self.arrays.num_params)
            full[active] = d
            ang = state.angles + full[_ANGLES]
            at_lower, at_upper = state.angles <= _LOWER + 1e-12, state.angles >= _UPPER - 1e-12
            blocked = np.flatnonzero(((ang < _LOWER) & at_lower) | ((ang > _UPPER) & at_upper)) + _ANGLES.start
            newly = np.isin(active, blocked) & ~held
            if not newly.any():
                break
            held |= newly
        return full

    def quality(self, state: _State, assoc: _Association) -> dict[str, float]:
        """How well the fit explains the image (unweighted, in px / mm), each term's figures: for a caller to refuse
        a bad fit (``FitQuality``)."""
        with torch.no_grad():
            res = self.residuals(self.evaluate(state, np.zeros((1, self.arrays.num_params)), assoc.ids), assoc)
        figures = {"vertices_outside_2px": 0.0}  # no vertex outside the silhouette gives the inside term no block
        for name, r in res.items():
            figures.update(terms.BY_NAME[name].quality(self, r[0].numpy()))
        return figures

    def covariance(self, state: _State, assoc: _Association) -> np.ndarray:
        """Gauss-Newton covariance H^-1 (P, P) of every parameter at ``state`` (pseudo-inverse if singular)."""
        _, jac = self.linearise(state, assoc, np.arange(_SHAPE0 + self.arrays.num_shape))
        return np.linalg.pinv(jac.T @ jac, hermitian=True)


# ----------------------------------------------------------------------------------------------------------
# Initialisation
# ----------------------------------------------------------------------------------------------------------


def _rest_joints(arrays: _ModelArrays, shape: np.ndarray, side: str) -> np.ndarray:
    j = arrays.joint_mean.numpy() + np.einsum("k,kjc->jc", shape, arrays.joint_basis.numpy())
    return j * _MIRROR if side == "right" else j


def _full_vertices(arrays: _ModelArrays, state: _State, side: str) -> np.ndarray:
    """(V, 3) camera-frame vertices of the whole mesh at ``state``."""
    model = arrays.model
    with torch.no_grad():
        out = model(
            torch.as_tensor(state.shape, dtype=torch.float32)[None],
            torch.as_tensor(state.angles, dtype=torch.float32)[None],
            None,
            side,
        )
    return out.vertices[0].double().numpy() @ state.rotation.T + state.translation


def _pnp_candidates(ev: _Evidence, rest_joints: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Placements (rotation, translation) of the rest-pose joints from the 2D joints: SQPnP on every joint with any
    confidence, on the joints that toe poses do not move (``PNP_CORE_JOINTS``), on the confident ones, and RANSAC
    PnP; each refined by LM; near-duplicates dropped.

    Hidden joints still carry their position, and the toes alone are close to a plane. On 60 synthetic scenes
    (3 px joint noise) the starts are 12 deg from the truth in the median; 8 % are more than 30 deg off with all
    joints, 3 % with the core joints. Several starts guard against a start in the wrong basin, which no local
    solver recovers from; the first solver stage runs from each and the best goes on.
    """
    order = np.argsort(-ev.joint_weight)
    usable = np.flatnonzero(ev.joint_weight >= PNP_MIN_CONFIDENCE)
    usable = usable if len(usable) >= 6 else order[:6]
    core = np.intersect1d(PNP_CORE_JOINTS, usable)
    subsets = [usable, core, np.flatnonzero(ev.joint_weight >= 0.5)]
    found: list[tuple[np.ndarray, np.ndarray]] = []

    def add(ok: bool, rvec, tvec, use: np.ndarray) -> None:
        if not ok or rvec is None:
            return
        obj, img = rest_joints[use], ev.joints[use]
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, ev.K, None, rvec, tvec)
        rot, t = cv2.Rodrigues(rvec)[0], tvec.reshape(3)
        if ((rest_joints @ rot.T + t)[:, 2] <= 0).any():
            return
        for r, _ in found:
            if np.degrees(np.arccos(np.clip((np.trace(r.T @ rot) - 1) / 2, -1, 1))) < PNP_DISTINCT_DEG:
                return
        found.append((rot, t))

    for use in subsets:
        if len(use) >= 5:
            obj, img = rest_joints[use].astype(np.float64), ev.joints[use].astype(np.float64)
            try:
                ok, rvec, tvec = cv2.solvePnP(obj, img, ev.K, None, flags=cv2.SOLVEPNP_SQPNP)
            except cv2.error:  # joints all but on one point (SQPnP asserts on their spread): no placement
                continue
            add(ok, rvec, tvec, use)
    use = usable
    try:
        ok, rvec, tvec, _ = cv2.solvePnPRansac(
            rest_joints[use].astype(np.float64),
            ev.joints[use].astype(np.float64),
            ev.K,
            None,
            reprojectionError=PNP_RANSAC_PX,
            iterationsCount=100,
            flags=cv2.SOLVEPNP_EPNP,
        )
    except cv2.error:
        ok, rvec, tvec = False, None, None
    add(ok, rvec, tvec, use)
    if not found:
        # a frontal placement at the distance that matches the joints' spread in the image
        spread = np.ptp(ev.joints[use], axis=0).max()
        length = np.ptp(rest_joints[:, 0])
        rot = np.diag([1.0, -1.0, -1.0])
        centre = pixel_rays(ev.joints[use].mean(0), ev.K)
        found.append((rot, centre * ev.K[0, 0] * length / max(spread, 1.0) - rot @ rest_joints.mean(0)))
    return found


def _initial_states(
    ev: _Evidence, arrays: _ModelArrays, side: str, init: FitInit | None
) -> tuple[list[_State], list[_State]]:
    """Starting states, each scaled to the scale evidence: the PnP candidates' (ranked by the rigid stage) and the
    given placement's (carried through every stage). A warm start (``init.alone``) is the only one."""
    if init is not None and not init.alone and (init.vertices_cam is not None or init.cam_from_foot is not None):
        pnp, _ = _initial_states(ev, arrays, side, None)
        given, _ = _initial_states(ev, arrays, side, replace(init, alone=True))
        return pnp, given
    k = arrays.num_shape
    shape = np.zeros(k)
    angles = np.zeros(sk.NUM_DOFS)
    if init is not None and init.shape is not None:
        shape = np.pad(np.asarray(init.shape, dtype=np.float64), (0, k - len(init.shape)))
    if init is not None and init.angles is not None:
        angles = np.clip(np.asarray(init.angles, dtype=np.float64), _LOWER, _UPPER)
    if init is not None and init.cam_from_foot is not None:
        pose = np.asarray(init.cam_from_foot, dtype=np.float64)
        rot, t = pose[:3, :3], pose[:3, 3]
    elif init is not None and init.vertices_cam is not None:
        target = torch.as_tensor(np.asarray(init.vertices_cam, dtype=np.float64))[None]
        state0 = _State(np.eye(3), np.zeros(3), angles, shape)
        source = torch.as_tensor(_full_vertices(arrays, state0, side))
        r, s, tr = weighted_procrustes(source, target, torch.ones(source.shape[0], dtype=torch.float64))
        rot, t = r[0].numpy(), tr[0].numpy()
        shape = shape_for_scale(arrays.model, float(s[0]), shape)
    else:
        placements = _pnp_candidates(ev, _rest_joints(arrays, shape, side))
    if init is not None and (init.cam_from_foot is not None or init.vertices_cam is not None):
        placements = [(rot, t)]
    if ev.floor is not None and not (init is not None and init.cam_from_foot is not None):
        # a foot on the floor stands upright: each start also stood up (its heading kept, its z on the normal)
        rest = _rest_joints(arrays, shape, side)
        stood = [_stood_up(rot, ev.floor[:3]) for rot, _ in placements]
        placements = placements + [(rot, _translation_for(rot, rest, ev)) for rot in stood]
    states = []
    for rot, t in placements:
        state = _State(rot, t, angles, shape)
        alpha = _scale_to_evidence(ev, arrays, state, side)
        if alpha is None:
            continue
        # scaling about the camera centre leaves the image as it is: only size and distance change
        states.append(_State(rot, alpha * t, angles, shape_for_scale(arrays.model, alpha, shape)))
    if not states:
        warnings.warn(
            "floor plane: no start puts the foot on the floor at a plausible size; starting at the mean size",
            RuntimeWarning,
            stacklevel=4,
        )
        states = [_State(rot, t, angles, shape) for rot, t in placements[:1]]
    return states, []


def _translation_for(rotation: np.ndarray, points: np.ndarray, ev: _Evidence) -> np.ndarray:
    """Translation (3,) that best projects ``rotation @ points + t`` ((18, 3) joints) onto the 2D joints: linear
    least squares of the cross product of each joint's ray with its 3D position, confidence-weighted."""
    rays = pixel_rays(ev.joints, ev.K)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    w = np.sqrt(np.maximum(ev.joint_weight, PNP_MIN_CONFIDENCE))[:, None]
    # ray x (R X + t) = 0  ->  skew(ray) t = -(ray x R X)
    a = (w[..., None] * skew(rays)).reshape(-1, 3)
    b = -(w * np.cross(rays, points @ rotation.T)).reshape(-1)
    return np.linalg.lstsq(a, b, rcond=None)[0]


def _stood_up(rotation: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The rotation nearest ``rotation`` (3, 3) whose z axis is ``up`` (3,) and whose x axis keeps its heading."""
    z = up / np.linalg.norm(up)
    x = rotation[:, 0] - (rotation[:, 0] @ z) * z
    if np.linalg.norm(x) < 1e-6:  # looking along the foot's axis: any heading
        x = rotation[:, 1] - (rotation[:, 1] @ z) * z
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _scale_to_evidence(ev: _Evidence, arrays: _ModelArrays, state: _State, side: str) -> float | None:
    """Factor alpha such that the foot scaled by alpha about the camera centre meets the depth or the floor."""
    if ev.depth_points is None and ev.floor is None:
        return 1.0
    v = _full_vertices(arrays, state, side)
    if ev.depth_points is not None:
        uv = v @ ev.K.T
        uv = uv[:, :2] / uv[:, 2:3]
        h, w = ev.size
        col, row = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        seen = (col >= 0) & (col < w) & (row >= 0) & (row < h) & (v[:, 2] > 0)
        depth = np.zeros(len(v))
        depth[seen] = ev.depth[row[seen], col[seen]]
        ok = seen & (depth > 0)
        ok[seen] &= ev.mask[row[seen], col[seen]]
        if ok.sum() >= 10:
            # the nearest third of the vertices on the foot's pixels: mostly the surface the camera sees
            ratio = depth[ok] / v[ok, 2]
            near = v[ok, 2] <= np.quantile(v[ok, 2], 0.33)
            return float(np.median(ratio[near]))
        return float(np.median(ev.depth_points[:, 2]) / np.median(v[:, 2]))
    lowest = float(np.min(v @ ev.floor[:3]))
    alpha = -ev.floor[3] / lowest if lowest < 0 else 0.0
    # a start placed so that no scale puts the foot on the floor plausibly is dropped by the caller
    return alpha if FLOOR_START_SCALE[0] < alpha < FLOOR_START_SCALE[1] else None


# ----------------------------------------------------------------------------------------------------------
# Public entry point
# ----------------------------------------------------------------------------------------------------------


def fit_foot(
    cues: Cues,
    K: np.ndarray,
    depth_mm: np.ndarray | None = None,
    cam_from_floor: np.ndarray | None = None,
    side: str = "auto",
    init: FitInit | None = None,
    config: FitConfig | None = None,
    model: FootModel | None = None,
) -> FootFit:
    """Fit the foot model to one image's cues (and its depth map and floor plane when there are any).

    Args:
        cues: silhouette (H, W), joints2d_px (18, 2) and joint_confidence (18,) of the image.
        K: (3, 3) intrinsics of the image, px.
        depth_mm: (H, W) camera z in mm, 0 = missing, registered to the image; or None.
        cam_from_floor: (4, 4) floor frame (z = 0 on the floor, z up, mm) -> camera, e.g. from a reference
            object; or None.
        side: "left", "right" or "auto" (both are fitted; the lower final cost wins).
        init: optional starting point (e.g. from a mesh decoder).
        config: weights and solver settings.
        model: the foot model (default: the packaged one).
    Returns:
        FootFit in the camera frame; ``scaled`` is False without depth or floor plane.
    """
    start = time.perf_counter()
    config = config if config is not None else FitConfig()
    model = model if model is not None else default_model()
    _check_inputs(cues, K, depth_mm, cam_from_floor, side)
    with fixed_threads(SOLVER_THREADS):
        fit = _fit(cues, K, depth_mm, cam_from_floor, side, init, config, model)
    return replace(fit, seconds=time.perf_counter() - start)


def _fit(cues, K, depth_mm, cam_from_floor, side, init, config, model) -> FootFit:
    ev = _evidence(cues, K, depth_mm, cam_from_floor, config)
    arrays = _model_arrays(model, config.num_vertices)
    sides = SIDES if side == "auto" else (side,)

    def solved(s: str, state: _State) -> tuple[_SideProblem, _State, _Association, int]:
        """The rigid stage from one start of side ``s``."""
        distance0 = None
        if ev.scale_source == "none":
            midfoot = state.rotation @ _rest_joints(arrays, state.shape, s)[0] + state.translation
            distance0 = float(np.linalg.norm(midfoot))
        problem = _SideProblem(ev, arrays, s, config, distance0)
        return problem, *problem.solve(state, config.stages[:1])

    def carried_on(s: str, start: tuple) -> tuple[_SideProblem, _State, _Association, int]:
        """The later stages from a rigid stage's end."""
        problem, state, _, _ = start
        return problem, *problem.solve(state, config.stages[1:])

    # each worker's torch runs on SOLVER_THREADS too (the setting is per thread with OpenMP builds)
    workers = max(config.solver_workers, 1)
    with ThreadPoolExecutor(workers, initializer=torch.set_num_threads, initargs=(SOLVER_THREADS,)) as pool:

        def each(fn, jobs: dict[str, list]) -> dict[str, list]:
            """``fn(side, job)`` of every side's jobs, ``solver_workers`` at a time, in each side's order."""
            futures = {s: [pool.submit(fn, s, job) for job in side_jobs] for s, side_jobs in jobs.items()}
            return {s: [f.result() for f in side_futures] for s, side_futures in futures.items()}

        initial = {s: _initial_states(ev, arrays, s, init) for s in sides}  # (pnp, given) per side
        rigid = each(solved, {s: given + pnp for s, (pnp, given) in initial.items()})
        # the given starts are all carried on, the PnP ones ranked by the rigid stage's cost
        starts = {
            s: (rigid[s][: len(given)], sorted(rigid[s][len(given) :], key=lambda x: x[2].cost))
            for s, (_, given) in initial.items()
        }
        ends = each(carried_on, {s: given + ranked[: config.full_starts] for s, (given, ranked) in starts.items()})
        costs = {s: min(e[2].cost for e in ends[s]) for s in sides}
        if len(sides) > 1 and max(costs.values()) < config.side_tie_ratio * min(costs.values()):
            # a near tie between the sides: the starts left behind may hold a better basin for either
            more = each(carried_on, {s: ranked[config.full_starts :] for s, (_, ranked) in starts.items()})
            ends = {s: ends[s] + more[s] for s in sides}
    fitted = {s: min(ends[s], key=lambda x: x[2].cost) for s in sides}
    iterations = sum(x[3] for s in sides for x in starts[s][0] + starts[s][1] + ends[s])
    best = min(fitted, key=lambda s: fitted[s][2].cost)
    problem, state, assoc, _ = fitted[best]
    covariance = problem.covariance(state, assoc)
    quality = problem.quality(state, assoc)
    if state.log_scale != 0.0:
        # no scale evidence: the fitted scale goes into the shape (c -> s c + const, so shape covariances scale by s^2)
        covariance[_SHAPE0:, _SHAPE0:] *= math.exp(2 * state.log_scale)
        state = state.scale_into_shape(model)
    with torch.no_grad():
        out = model(
            torch.as_tensor(state.shape, dtype=torch.float32)[None],
            torch.as_tensor(state.angles, dtype=torch.float32)[None],
            None,
            best,
        )
    vertices = out.vertices[0].double().numpy() @ state.rotation.T + state.translation
    joints = out.joints[0].double().numpy() @ state.rotation.T + state.translation
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = state.rotation, state.translation
    shown = foot_shown(vertices, best, ev.mask, ev.K, model, config.contour_max_height_mm)
    return FootFit(
        side=best,
        shape=state.shape.copy(),
        angles=state.angles.copy(),
        cam_from_foot=pose,
        vertices_cam=vertices,
        joints_cam=joints,
        scaled=ev.scale_source != "none",
        scale_source=ev.scale_source,
        loss=assoc.cost,
        loss_terms=dict(assoc.terms),
        side_losses={s: fitted[s][2].cost for s in sides},
        covariance=covariance,
        quality=FitQuality(**quality, foot_shown=shown),
        iterations=iterations,
    )


def canonical_measures(shape: np.ndarray, model: FootModel | None = None) -> tuple[float, float]:
    """(stick length, ball width) in mm of the zero-pose foot of ``shape`` (K,) (``measure`` definitions)."""
    from footmesh.model.anatomy import ball_width_mm, stick_length_mm

    model = model if model is not None else default_model()
    with torch.no_grad():
        v = model(torch.as_tensor(shape, dtype=torch.float32)[None]).vertices[0].double().numpy()
    return stick_length_mm(v), ball_width_mm(v)
