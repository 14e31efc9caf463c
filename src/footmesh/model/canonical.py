"""Bring a posed foot mesh back to the canonical pose (all joint angles zero), thesis 3.5.3 and 4.3.

The thesis measures feet "in a canonical pose": inverse kinematics to the joint angles, forward kinematics to
zero angles. Here the posed mesh (model topology, any placement, scale and side) is explained by the foot model
``v = R mirror(s skin(v_shaped(shape), FK(angles))) + t`` (``layer.FootModel.forward``), and the mesh itself --
not the model's fit of it -- is then unposed with the fitted transforms, so that details outside the PCA space
survive into the measurements.

Frames: ``posed_vertices`` in any frame (e.g. OpenCV camera, mm); results in the left-foot frame of the model
(mm, x heel->toe, z up, origin at the heel on the floor; see ``skeleton``) at the foot's true size.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch.func import jacfwd, vmap

from footmesh import optim
from footmesh.geometry.alignment import weighted_procrustes
from footmesh.geometry.rotations import skew
from footmesh.model import ik, lbs
from footmesh.model import skeleton as sk
from footmesh.model.layer import FootModel, side_mask

FIT_ITERATIONS = 40
"""Gauss-Newton / Levenberg-Marquardt iterations of ``canonicalise`` (exact data converges in about 5-10)."""
JOINT_WEIGHT = 1.0
"""Weight of the joint residual (mm per mm) against the vertex residual when posed joints are given."""
CHUNK = 16
"""Items per forward-mode Jacobian evaluation of the shape columns (memory about CHUNK * V * 12 * K doubles)."""
_CONVERGED_MM = 1e-6
"""Stop early once every item's RMS residual (per coordinate) is below this (exact, noise-free input)."""
_RELATIVE_DECREASE = 1e-9
_STALL_DAMPING = 1e-2
"""Also stop once no item's cost falls by more than ``_RELATIVE_DECREASE`` (relative) at a small damping."""
_LM_INITIAL_DAMPING = 1e-4
_LM_DAMPING_DOWN = 1.0 / 3.0
_LM_DAMPING_UP = 4.0
_LM_DAMPING_RANGE = (1e-10, 1e8)
_MIRROR = (1.0, -1.0, 1.0)  # y -> -y turns the left model into a right foot (layer.FootModel.forward)

# Parameter vector of one item: axis-angle rotation increment (3), translation (3, mm), log-scale (1),
# angles (22, radians), shape (K, SD units).
_ROT, _TRANS, _LOG_SCALE, _ANGLES = slice(0, 3), slice(3, 6), 6, slice(7, 7 + sk.NUM_DOFS)
_SHAPE_START = 7 + sk.NUM_DOFS

_DOF_JOINT = lbs.DOF_JOINT
_DOF_PARENT = torch.tensor([sk.PARENTS[d.joint] for d in sk.DOFS])
_DOF_IS_Z = lbs.DOF_IS_Z


def _subtree_matrix() -> torch.Tensor:
    """(D, J) float: 1 where joint j is carried by the DOF's segment (its end joint or a descendant)."""
    out = torch.zeros(sk.NUM_DOFS, sk.NUM_JOINTS, dtype=torch.float64)
    for i, dof in enumerate(sk.DOFS):
        for j in range(sk.NUM_JOINTS):
            k = j
            while k > 0 and k != dof.joint:
                k = sk.PARENTS[k]
            out[i, j] = float(k == dof.joint)
    return out


_SUBTREE = _subtree_matrix()


@dataclass(frozen=True)
class Canonical:
    """A posed foot explained by the model and brought to the zero pose.

    ``model(shape, angles, scale, side, rotation, translation)`` reproduces the posed mesh (to ``residual_mm``).

    Attributes:
        angles: (B, 22) radians, within Table 3.1's limits.
        rotation: (B, 3, 3) model (foot) frame -> input frame, applied after the mirror for right feet.
        translation: (B, 3) mm, input frame.
        scale: (B,) dimensionless, about the heel origin of the foot frame.
        shape: (B, K) PCA coefficients, SD units.
        rest_vertices: (B, V, 3) mm, the input mesh unposed: zero angles, left-foot frame, true size (scale
            applied). A right foot is mirrored into the left frame; mirror y back to show it as a right foot.
        rest_joints: (B, 18, 3) mm, ``joint_regressor @ rest_vertices``.
        residual_mm: (B,) RMS distance between the fitted model and the input vertices, mm.
    """

    angles: torch.Tensor
    rotation: torch.Tensor
    translation: torch.Tensor
    scale: torch.Tensor
    shape: torch.Tensor
    rest_vertices: torch.Tensor
    rest_joints: torch.Tensor
    residual_mm: torch.Tensor


def _exp_so3(w: torch.Tensor) -> torch.Tensor:
    """Rodrigues: (B, 3) axis-angle -> (B, 3, 3)."""
    return torch.linalg.matrix_exp(skew(w))


class _Problem:
    """The fitting residual of one left foot, ``model(params) - data``, in float64 (closure over the model)."""

    def __init__(self, model: FootModel, num_shape: int) -> None:
        f64 = torch.float64
        self.mean = model.mean_vertices.to(f64)
        self.components = model.components[:num_shape].to(f64)
        self.sd = model.component_sd[:num_shape].to(f64)
        self.regressor = model.joint_regressor.to(f64)
        self.weights = model.skin_weights.to(f64)
        self.num_shape = num_shape
        # w_vj restricted to the joints each DOF carries, (V, D, J)
        self.subtree_weights = self.weights.unsqueeze(1) * _SUBTREE.to(self.weights).unsqueeze(0)

    def pose(self, params: torch.Tensor, rot0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One item: params (P,), rot0 (3, 3) -> vertices (V, 3), joints (18, 3) in the (left-mirrored) input frame.

        The rotation is ``exp([w]x) rot0``, expanded to second order: exact in value and first derivative at
        ``w = 0``, where the Jacobian is taken (the update itself uses the exact exponential).
        """
        k = skew(params[_ROT])
        rotation = (torch.eye(3, dtype=params.dtype) + k + 0.5 * k @ k) @ rot0
        shape = params[_SHAPE_START:]
        v_shaped = lbs.blend_shapes(shape.unsqueeze(0), self.mean, self.components, self.sd)  # (1, V, 3)
        rest_joints = torch.einsum("jv,bvc->bjc", self.regressor, v_shaped)
        joints, transforms = lbs.forward_kinematics(params[_ANGLES].unsqueeze(0), rest_joints)
        vertices = lbs.skin(v_shaped, transforms, self.weights)
        s = torch.exp(params[_LOG_SCALE])
        t = params[_TRANS]
        return s * vertices[0] @ rotation.T + t, s * joints[0] @ rotation.T + t

    def residual(
        self, params: torch.Tensor, rot0: torch.Tensor, data: torch.Tensor, data_joints: torch.Tensor | None
    ) -> torch.Tensor:
        """(N,) residual: vertices (3V) then, with joints, ``JOINT_WEIGHT`` * joints (54)."""
        vertices, joints = self.pose(params, rot0)
        res = (vertices - data).reshape(-1)
        if data_joints is not None:
            res = torch.cat([res, JOINT_WEIGHT * (joints - data_joints).reshape(-1)])
        return res

    def batch_pose(self, params: torch.Tensor, rot0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Batched ``pose`` at ``w = 0``: params (B, P), rot0 (B, 3, 3) -> vertices (B, V, 3), joints (B, 18, 3)."""
        v_shaped = lbs.blend_shapes(params[:, _SHAPE_START:], self.mean, self.components, self.sd)
        rest_joints = torch.einsum("jv,bvc->bjc", self.regressor, v_shaped)
        joints, transforms = lbs.forward_kinematics(params[:, _ANGLES], rest_joints)
        vertices = lbs.skin(v_shaped, transforms, self.weights)
        s = torch.exp(params[:, _LOG_SCALE]).reshape(-1, 1, 1)
        t = params[:, _TRANS].unsqueeze(1)
        return s * vertices @ rot0.transpose(1, 2) + t, s * joints @ rot0.transpose(1, 2) + t

    def batch_residual(self, params, rot0, data, data_joints) -> torch.Tensor:
        """(B, N) residual at ``w = 0`` (the rotation increment of ``params`` is ignored)."""
        vertices, joints = self.batch_pose(params, rot0)
        res = (vertices - data).reshape(len(params), -1)
        if data_joints is not None:
            res = torch.cat([res, JOINT_WEIGHT * (joints - data_joints).reshape(len(params), -1)], dim=1)
        return res

    def batch_jacobian(self, params, rot0, data, data_joints) -> tuple[torch.Tensor, torch.Tensor]:
        """Residual (B, N) and its Jacobian (B, N, P).

        Rigid, scale and angle columns in closed form; shape columns by forward-mode autodiff
        (``torch.func.jacfwd``, in chunks of ``CHUNK`` items). A DOF of segment ``p -> c`` turns every point
        carried by the subtree of ``c`` about the axis ``a`` through the posed parent joint ``P_p``, so for a
        vertex ``v`` skinned by weights ``w_vj``: ``dv/dangle = a x sum_{j in subtree(c)} w_vj (T_j v - P_p)``
        (model frame; then times ``s R``). With ``x = s R u + t``: ``dx/dw = -[x - t]x``, ``dx/dt = I``,
        ``dx/dlog s = x - t``.
        """
        b = params.shape[0]
        angles, shape = params[:, _ANGLES], params[:, _SHAPE_START:]
        s = torch.exp(params[:, _LOG_SCALE]).reshape(-1, 1, 1)
        t = params[:, _TRANS].unsqueeze(1)
        v_shaped = lbs.blend_shapes(shape, self.mean, self.components, self.sd)  # (B, V, 3)
        rest_joints = torch.einsum("jv,bvc->bjc", self.regressor, v_shaped)
        joints, transforms = lbs.forward_kinematics(angles, rest_joints)
        rot = transforms[..., :3]  # (B, J, 3, 3)
        per_joint = torch.einsum("bjrc,bvc->bvjr", rot, v_shaped) + transforms[..., 3].unsqueeze(1)  # (B, V, J, 3)
        vertices = torch.einsum("vj,bvjr->bvr", self.weights, per_joint)
        x = s * vertices @ rot0.transpose(1, 2) + t
        xj = s * joints @ rot0.transpose(1, 2) + t

        sub = _SUBTREE.to(params)  # (D, J)
        axis = torch.where(
            _DOF_IS_Z.to(params.device).reshape(1, -1, 1),
            rot[:, _DOF_JOINT, :, 2],
            rot[:, _DOF_PARENT, :, 1],
        )  # (B, D, 3)
        pivot = joints[:, _DOF_PARENT]  # (B, D, 3)
        moved = self.subtree_weights @ per_joint  # (V, D, J) @ (B, V, J, 3) -> (B, V, D, 3)
        carried = self.subtree_weights.sum(-1, keepdim=True)  # (V, D, 1)
        d_vertices = torch.linalg.cross(axis.unsqueeze(1), moved - carried * pivot.unsqueeze(1))  # (B, V, D, 3)
        d_joints = torch.linalg.cross(axis.unsqueeze(1), joints.unsqueeze(2) - pivot.unsqueeze(1))  # (B, J, D, 3)
        d_joints = d_joints * sub.T.unsqueeze(-1)

        def columns(points: torch.Tensor, d_angles: torch.Tensor) -> torch.Tensor:
            """(B, n, 3) data-frame points and (B, n, D, 3) model-frame angle derivatives -> (B, 3n, 7 + D)."""
            n = points.shape[1]
            rel = points - t
            eye = torch.eye(3, dtype=params.dtype, device=params.device).expand(b, n, 3, 3)
            d_rot = -skew(rel)  # (B, n, 3, 3)
            d_angle_world = s.unsqueeze(-1) * torch.einsum("brc,bndc->bnrd", rot0, d_angles)  # (B, n, 3, D)
            cols = torch.cat([d_rot, eye, rel.unsqueeze(-1), d_angle_world], dim=-1)  # (B, n, 3, 7 + D)
            return cols.reshape(b, 3 * n, -1)

        rigid = columns(x, d_vertices)
        residual = (x - data).reshape(b, -1)
        if data_joints is not None:
            rigid = torch.cat([rigid, JOINT_WEIGHT * columns(xj, d_joints)], dim=1)
            residual = torch.cat([residual, JOINT_WEIGHT * (xj - data_joints).reshape(b, -1)], dim=1)
        if self.num_shape == 0:
            return residual, rigid

        def shape_residual(shape_k, fixed, r0, d, dj):
            return self.residual(torch.cat([fixed, shape_k]), r0, d, dj)

        fixed = params[:, :_SHAPE_START]
        if data_joints is None:
            fn = lambda sk_, f, r0, d: shape_residual(sk_, f, r0, d, None)  # noqa: E731
            args = (shape, fixed, rot0, data)
        else:
            fn = shape_residual
            args = (shape, fixed, rot0, data, data_joints)
        jac_fn = vmap(jacfwd(fn))
        d_shape = torch.cat([jac_fn(*(a[i : i + CHUNK] for a in args)) for i in range(0, b, CHUNK)])
        return residual, torch.cat([rigid, d_shape], dim=-1)


def canonicalise(
    posed_vertices: torch.Tensor,
    model: FootModel,
    side: str | Sequence[str] = "left",
    posed_joints: torch.Tensor | None = None,
    iters: int = FIT_ITERATIONS,
    num_shape: int | None = None,
) -> Canonical:
    """Fit the foot model to posed meshes and unpose them (the canonical step of the pipeline, thesis 4.3).

    (a) Mirror right feet (y -> -y) so that only the left model is fitted. Initial similarity transform by
        weighted Procrustes of the model's mean rest vertices onto the input, each vertex weighted by its skinning
        weight on the root (midfoot) segment, which no joint angle moves. Initial angles by
        :func:`ik.angles_from_joints` of the joints regressed from the input brought into the model frame
        (or of ``posed_joints`` when given).
    (b) Levenberg-Marquardt (Gauss-Newton with Marquardt's diagonal damping) over rotation (axis-angle
        increment), translation, log-scale, the 22 angles and the shape coefficients, on ``model - input``
        vertices (plus ``JOINT_WEIGHT`` times the joint residual when ``posed_joints`` are given). Forward-mode
        Jacobian (``torch.func.jacfwd``), float64, batched; angles are projected onto their limits each step.
    (c) The input mesh brought back to the model frame (undo translation, rotation, scale, mirror) is unposed by
        ``lbs.inverse_skin`` with the fitted angles' transforms, then scaled back to its true size.

    Gauge: a global rotation about Y through the midfoot, undone by the same Y angle on all six root-branch DOFs
    (midfoot-ankle and the five metatarsals), moves no vertex except those skinned to the root segment. So only
    the root-weighted vertices fix the split between the global rotation and those six angles: this is why the
    initial alignment uses them alone, and why the fitted global rotation is that of the midfoot.

    Args:
        posed_vertices: (B, V, 3) mm (any consistent unit works; results come back in it), any frame, the
            model's topology.
        model: the foot model (its dtype does not matter; the fit runs in float64).
        side: "left", "right", or one per item.
        posed_joints: optional (B, 18, 3) joints in the same frame as ``posed_vertices``.
        iters: LM iterations.
        num_shape: number of shape components fitted (default all).
    Returns:
        :class:`Canonical` (float64 tensors).
    """
    if posed_vertices.dim() != 3 or posed_vertices.shape[1:] != (model.num_vertices, 3):
        raise ValueError(
            f"posed_vertices must be (B, {model.num_vertices}, 3) on the model's topology, "
            f"got {tuple(posed_vertices.shape)}"
        )
    b = posed_vertices.shape[0]
    if posed_joints is not None and posed_joints.shape != (b, sk.NUM_JOINTS, 3):
        raise ValueError(f"posed_joints must be ({b}, {sk.NUM_JOINTS}, 3), got {tuple(posed_joints.shape)}")
    k = model.num_components if num_shape is None else int(num_shape)
    problem = _Problem(model, k)
    f64 = torch.float64
    right = side_mask(side, b, posed_vertices.device)
    mirror = torch.where(right.unsqueeze(-1), posed_vertices.new_tensor(_MIRROR, dtype=f64), 1.0)  # (B, 3)
    data = posed_vertices.to(f64) * mirror.unsqueeze(1)
    data_joints = None if posed_joints is None else posed_joints.to(f64) * mirror.unsqueeze(1)

    # (a) similarity from the root segment, then angles by closed-form IK in the model frame
    root_weight = problem.weights[:, 0]
    if float(root_weight.sum()) <= 0.0:
        root_weight = torch.ones_like(root_weight)
    rot0, scale0, trans0 = weighted_procrustes(problem.mean, data, root_weight)
    joints_in = data_joints if data_joints is not None else torch.einsum("jv,bvc->bjc", problem.regressor, data)
    joints_model = ((joints_in - trans0.unsqueeze(1)) @ rot0) / scale0.reshape(-1, 1, 1)
    mean_joints = problem.regressor @ problem.mean
    angles0 = ik.angles_from_joints(joints_model, mean_joints)

    params = data.new_zeros(b, _SHAPE_START + k)
    params[:, _TRANS] = trans0
    params[:, _LOG_SCALE] = torch.log(scale0)
    params[:, _ANGLES] = angles0
    lower = data.new_tensor(sk.DOF_LOWER)
    upper = data.new_tensor(sk.DOF_UPPER)
    # the box of every parameter: only the angles have limits
    box_lower = torch.full_like(params[0], -torch.inf)
    box_upper = torch.full_like(params[0], torch.inf)
    box_lower[_ANGLES], box_upper[_ANGLES] = lower, upper

    # (b) projected Levenberg-Marquardt, per item
    damping = data.new_full((b,), _LM_INITIAL_DAMPING)
    res = problem.batch_residual(params, rot0, data, data_joints)
    cost = (res**2).sum(-1)
    for _ in range(iters):
        if bool((cost <= _CONVERGED_MM**2 * res.shape[-1]).all()):
            break
        res, jac = problem.batch_jacobian(params, rot0, data, data_joints)  # (B, N), (B, N, P)
        descent = -(jac.transpose(1, 2) @ res.unsqueeze(-1)).squeeze(-1)  # (B, P)
        held = optim.held_at_bounds(params, descent, box_lower, box_upper)
        step = optim.damped_step(jac, descent, damping, held, floor=1e-9)
        trial = params + step
        trial[:, _ROT] = 0.0
        trial[:, _ANGLES] = torch.minimum(torch.maximum(trial[:, _ANGLES], lower), upper)
        trial_rot0 = _exp_so3(step[:, _ROT]) @ rot0
        trial_cost = (problem.batch_residual(trial, trial_rot0, data, data_joints) ** 2).sum(-1)
        better = trial_cost < cost
        stalled = (cost - trial_cost) <= _RELATIVE_DECREASE * cost  # includes rejected steps
        params = torch.where(better.unsqueeze(-1), trial, params)
        rot0 = torch.where(better.reshape(-1, 1, 1), trial_rot0, rot0)
        cost = torch.where(better, trial_cost, cost)
        damping = optim.next_damping(damping, better, _LM_DAMPING_DOWN, _LM_DAMPING_UP, _LM_DAMPING_RANGE)
        if bool((stalled & (damping < _STALL_DAMPING)).all()):  # converged: only tiny improvements left
            break

    # (c) unpose the input itself with the fitted transforms
    angles = params[:, _ANGLES]
    shape = params[:, _SHAPE_START:]
    scale = torch.exp(params[:, _LOG_SCALE])
    translation = params[:, _TRANS]
    v_shaped = lbs.blend_shapes(shape, problem.mean, problem.components, problem.sd)
    fit_rest_joints = torch.einsum("jv,bvc->bjc", problem.regressor, v_shaped)
    _, transforms = lbs.forward_kinematics(angles, fit_rest_joints)
    in_model = ((data - translation.unsqueeze(1)) @ rot0) / scale.reshape(-1, 1, 1)
    rest_vertices = lbs.inverse_skin(in_model, transforms, problem.weights) * scale.reshape(-1, 1, 1)
    rest_joints = torch.einsum("jv,bvc->bjc", problem.regressor, rest_vertices)
    fitted, _ = problem.batch_pose(params, rot0)
    residual_mm = (fitted - data).norm(dim=-1).pow(2).mean(-1).sqrt()

    # back to the input's side: data' = M data, data' = R' (s skin) + t'  =>  R = M R' M, t = M t'
    flip = torch.diag_embed(mirror)
    rotation = torch.where(right.reshape(-1, 1, 1), flip @ rot0 @ flip, rot0)
    translation = translation * mirror
    return Canonical(angles, rotation, translation, scale, shape, rest_vertices, rest_joints, residual_mm)
