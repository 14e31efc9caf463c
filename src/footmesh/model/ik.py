"""Inverse kinematics of the 18-joint foot model and random poses inside Table 3.1's limits.

Thesis 3.5.2 (last paragraph): "each branch could be handled separately", which makes IK simple; thesis 3.5.3:
"For random poses for the training data, we randomly choose a reachable position for the end of each branch of
the kinematic foot model and compute the joints' angle to accommodate the pose."

Everything here works in the foot frame of the LEFT model (mm, x heel->toe, y to the little toe, z up; see
``skeleton``) with no global motion: the midfoot (root) segment never turns. Angles are (B, 22) radians in
``skeleton.DOF_NAMES`` order and never leave ``[skeleton.DOF_LOWER, skeleton.DOF_UPPER]``.

Two solvers:

- :func:`angles_from_joints`: closed-form, segment by segment, when all 18 posed joints are known (the pose step
  of the pipeline; exact on forward-kinematics output).
- :func:`solve_branch_ik`: damped least squares (Levenberg-Marquardt) when only the six branch ends are given
  (how the thesis makes random poses), projected onto the limits at every step.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from footmesh import optim
from footmesh.model import lbs
from footmesh.model import skeleton as sk

SOLVE_TOLERANCE_MM = 1e-4
"""``solve_branch_ik`` stops once every tip of every item is this close to its target."""
SOLVE_ITERATIONS = 60
"""Default Levenberg-Marquardt iterations of ``solve_branch_ik`` (reachable targets need about 10-30)."""
_LM_INITIAL_DAMPING = 1e-3
_LM_DAMPING_DOWN = 1.0 / 3.0
_LM_DAMPING_UP = 4.0
_LM_DAMPING_RANGE = (1e-9, 1e9)
_SEED_METATARSAL = (0.0, 0.025, 0.05, 0.075, 0.1)
"""Metatarsal angles (radians, Table 3.1 range [0, 0.1]) tried, after ``init``'s own, for the closed-form seed."""

# Per joint c: index of the DOF turning its segment about Y and about Z (-1 where there is none).
_Y_DOF = [-1] * sk.NUM_JOINTS
_Z_DOF = [-1] * sk.NUM_JOINTS
for _i, _d in enumerate(sk.DOFS):
    (_Y_DOF if _d.axis == "y" else _Z_DOF)[_d.joint] = _i

# DOFs of each branch (toes 1-5, then heel; the order of ``skeleton.TIP_JOINTS``), padded to 4 with a mask.
_BRANCH_WIDTH = 4
_BRANCH_DOFS: list[list[int]] = []
for _chain in sk.BRANCHES:
    _dofs = [i for i, d in enumerate(sk.DOFS) if d.joint in _chain]
    _BRANCH_DOFS.append(_dofs + [0] * (_BRANCH_WIDTH - len(_dofs)))
_BRANCH_DOF_INDEX = torch.tensor(_BRANCH_DOFS)  # (6, 4)
_BRANCH_DOF_MASK = torch.tensor([[i < sum(d.joint in c for d in sk.DOFS) for i in range(4)] for c in sk.BRANCHES])
_TIPS = torch.tensor(sk.TIP_JOINTS)
_DOF_JOINT = lbs.DOF_JOINT
_DOF_PARENT = torch.tensor([sk.PARENTS[d.joint] for d in sk.DOFS])
_DOF_IS_Z = lbs.DOF_IS_Z
_METATARSAL_DOFS = [_Y_DOF[proximal] for proximal, _, _ in sk.TOE_BRANCHES]


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    """Wrap radians into [-pi, pi)."""
    return torch.remainder(angle + math.pi, 2.0 * math.pi) - math.pi


def _batched_rest(rest_joints: torch.Tensor, batch: int) -> torch.Tensor:
    if rest_joints.dim() == 2:
        rest_joints = rest_joints.unsqueeze(0).expand(batch, -1, -1)
    if rest_joints.shape != (batch, sk.NUM_JOINTS, 3):
        raise ValueError(
            f"rest_joints must be ({sk.NUM_JOINTS}, 3) or (B, {sk.NUM_JOINTS}, 3) with B={batch}, "
            f"got {tuple(rest_joints.shape)}"
        )
    return rest_joints


def angles_from_joints(posed_joints: torch.Tensor, rest_joints: torch.Tensor) -> torch.Tensor:
    """Joint angles from posed joints, in closed form, one segment at a time (analytic per-branch IK).

    Walks every branch from the midfoot. For the segment ``p -> c``, the posed segment vector
    ``d = G_p^T (P_c - P_p)`` is expressed in the parent's posed frame ``G_p`` (the accumulated rotation of the
    already solved, clamped parent) and compared with the rest vector ``r = J_c - J_p``:

    - one DOF (Y): ``R_y(a) r ~ d``; ``R_y`` turns the (x, z) plane by ``-a``, so
      ``a = atan2(r_z, r_x) - atan2(d_z, d_x)`` (the y components are ignored);
    - two DOFs (``R = R_y(y) @ R_z(z)``, the proximal phalanges): ``R_y`` keeps the y component, so
      ``(R_z(z) r)_y = d_y`` (with ``d`` rescaled to ``|r|``), i.e. ``rho sin(z + phi) = d_y`` with
      ``rho, phi`` the polar form of ``(r_x, r_y)``, solved on the branch near zero; then ``y`` as above from
      ``u = R_z(z) r`` to ``d``.

    Each angle is clamped into Table 3.1's limits before its children are solved, so children compensate for a
    clamped parent as far as they can. The midfoot's (root) orientation is taken as the foot frame: remove any
    global motion before calling. Exact on forward-kinematics output of in-limit angles (to float precision);
    with noisy joints each segment gets the rotation closest to its own direction, independent of errors in
    the segment lengths.

    Args:
        posed_joints: (B, 18, 3) mm, foot frame of the left model (no global rotation or translation).
        rest_joints: (B, 18, 3) or (18, 3) mm, the same foot's joints in the zero pose.
    Returns:
        (B, 22) radians, ``skeleton.DOF_NAMES`` order, inside the limits.
    """
    if posed_joints.dim() != 3 or posed_joints.shape[1:] != (sk.NUM_JOINTS, 3):
        raise ValueError(f"posed_joints must be (B, {sk.NUM_JOINTS}, 3), got {tuple(posed_joints.shape)}")
    b = posed_joints.shape[0]
    rest = _batched_rest(rest_joints.to(posed_joints), b)
    lower = posed_joints.new_tensor(sk.DOF_LOWER)
    upper = posed_joints.new_tensor(sk.DOF_UPPER)
    zero = posed_joints.new_zeros(b)
    angles = [zero] * sk.NUM_DOFS
    frames = [torch.eye(3, dtype=posed_joints.dtype, device=posed_joints.device).expand(b, 3, 3)]
    for c in range(1, sk.NUM_JOINTS):  # parents come before children in JOINT_NAMES
        p = sk.PARENTS[c]
        g_p = frames[p]
        d = (g_p.transpose(-1, -2) @ (posed_joints[:, c] - posed_joints[:, p]).unsqueeze(-1)).squeeze(-1)
        r = rest[:, c] - rest[:, p]
        y_dof, z_dof = _Y_DOF[c], _Z_DOF[c]
        z_limits = (lower[z_dof], upper[z_dof]) if z_dof >= 0 else None
        angle_y, angle_z = _rotation_onto(r, d, (lower[y_dof], upper[y_dof]), z_limits)
        angles[y_dof] = angle_y
        if z_dof >= 0:
            angles[z_dof] = angle_z
        frames.append(g_p @ lbs.rot_y(angle_y) @ lbs.rot_z(angle_z))
    return torch.stack(angles, dim=-1)


def _rotation_onto(
    r: torch.Tensor,
    d: torch.Tensor,
    y_limits: tuple[torch.Tensor, torch.Tensor],
    z_limits: tuple[torch.Tensor, torch.Tensor] | None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Angles of ``R_y(y) [@ R_z(z)]`` turning the vector ``r`` (B, 3) towards ``d`` (B, 3), clamped.

    ``R_y(a)`` turns the (x, z) plane by ``-a``, so ``a = atan2(r_z, r_x) - atan2(d_z, d_x)``. With a Z DOF,
    ``R_y`` keeps the y component, so first ``(R_z(z) r)_y = d_y`` (``d`` rescaled to ``|r|``), i.e.
    ``rho sin(z + phi) = d_y`` with ``(rho, phi)`` the polar form of ``(r_x, r_y)``, on the branch near zero.
    Returns (y, z) radians, (B,) each (z = 0 without a Z DOF).
    """
    angle_z = r.new_zeros(r.shape[0])
    if z_limits is not None:
        d_y = d[:, 1] * r.norm(dim=-1) / d.norm(dim=-1).clamp_min(1e-12)
        rho = torch.hypot(r[:, 0], r[:, 1]).clamp_min(1e-12)
        phi = torch.atan2(r[:, 1], r[:, 0])
        angle_z = _wrap(torch.asin((d_y / rho).clamp(-1.0, 1.0)) - phi).clamp(*z_limits)
        r = (lbs.rot_z(angle_z) @ r.unsqueeze(-1)).squeeze(-1)
    angle_y = _wrap(torch.atan2(r[:, 2], r[:, 0]) - torch.atan2(d[:, 2], d[:, 0])).clamp(*y_limits)
    return angle_y, angle_z


def _bend_for_distance(
    r_a: torch.Tensor, r_b: torch.Tensor, distance: torch.Tensor, limits: tuple[float, float], root: int
) -> torch.Tensor:
    """A Y angle ``t`` within ``limits`` making ``|r_a + R_y(t) r_b|`` equal (or close) to ``distance`` (B,).

    ``|r_a + R_y(t) r_b|^2 = |r_a|^2 + |r_b|^2 + 2 (A cos t + B sin t + a_y b_y)`` with
    ``A = a_x b_x + a_z b_z`` and ``B = a_x b_z - a_z b_x``: two closed-form roots, each clamped
    into the limits; ``root`` 0 returns the smaller, 1 the larger.
    """
    a_x, a_y, a_z = r_a.unbind(-1)
    b_x, b_y, b_z = r_b.unbind(-1)
    big_a = a_x * b_x + a_z * b_z
    big_b = a_x * b_z - a_z * b_x
    rhs = 0.5 * (distance**2 - (r_a**2).sum(-1) - (r_b**2).sum(-1)) - a_y * b_y
    amplitude = torch.hypot(big_a, big_b).clamp_min(1e-12)
    psi = torch.atan2(big_b, big_a)
    spread = torch.acos((rhs / amplitude).clamp(-1.0, 1.0))
    roots = torch.stack([_wrap(psi + spread), _wrap(psi - spread)], dim=-1).clamp(*limits)  # (B, 2)
    roots = roots.sort(dim=-1).values
    return roots[:, root]


def _seed_branches(rest: torch.Tensor, targets: torch.Tensor, init: torch.Tensor, root: int) -> torch.Tensor:
    """Closed-form start for ``solve_branch_ik``: (B, 22) angles putting each tip on (or near) its target.

    Keeps ``init``'s first angle of each toe (the metatarsal Y, the redundant DOF), then solves the two-link
    chain below it: the distal (or ankle) bend from the distance to the target, then the segment rotation
    from its direction (``_bend_for_distance``, ``_rotation_onto``).
    """
    lower, upper = sk.DOF_LOWER, sk.DOF_UPPER
    out = init.clone()
    midfoot = rest[:, 0]
    for branch, chain in enumerate(sk.BRANCHES):
        tip = targets[:, branch]
        if len(chain) == 3:  # toe: metatarsal (Y), proximal phalanx (Y, Z), distal phalanx (Y)
            proximal, distal, end = chain
            frame = lbs.rot_y(init[:, _Y_DOF[proximal]])
            pivot = midfoot + (frame @ (rest[:, proximal] - midfoot).unsqueeze(-1)).squeeze(-1)
            first, bend = distal, end
            r_a, r_b = rest[:, distal] - rest[:, proximal], rest[:, end] - rest[:, distal]
        else:  # heel: midfoot-ankle (Y), ankle (Y)
            ankle, end = chain
            frame = torch.eye(3, dtype=rest.dtype, device=rest.device).expand_as(rest[:, :3])
            pivot = midfoot
            first, bend = ankle, end
            r_a, r_b = rest[:, ankle] - midfoot, rest[:, end] - rest[:, ankle]
        d = (frame.transpose(-1, -2) @ (tip - pivot).unsqueeze(-1)).squeeze(-1)
        y_bend = _Y_DOF[bend]
        angle_bend = _bend_for_distance(r_a, r_b, d.norm(dim=-1), (lower[y_bend], upper[y_bend]), root)
        v = r_a + (lbs.rot_y(angle_bend) @ r_b.unsqueeze(-1)).squeeze(-1)
        y_first, z_first = _Y_DOF[first], _Z_DOF[first]
        z_limits = (lower[z_first], upper[z_first]) if z_first >= 0 else None
        angle_y, angle_z = _rotation_onto(v, d, (lower[y_first], upper[y_first]), z_limits)
        out[:, y_bend] = angle_bend
        out[:, y_first] = angle_y
        if z_first >= 0:
            out[:, z_first] = angle_z
    return out


def _tip_jacobian(posed: torch.Tensor, rotations: torch.Tensor) -> torch.Tensor:
    """d tip / d angle of each branch, (B, 6, 3, 4), from the posed joints and segment rotations.

    A DOF of segment ``p -> c`` turns everything below ``c`` about the world axis ``a`` through the posed
    parent joint ``P_p``, so ``d tip / d angle = a x (tip - P_p)``. With ``R_c = R_p R_y(y) R_z(z)`` the Y axis is
    ``R_p e_y`` and the Z axis ``R_p R_y(y) e_z = R_c e_z``.
    """
    index = _BRANCH_DOF_INDEX.to(posed.device)  # (6, 4)
    joint = _DOF_JOINT.to(posed.device)[index]
    parent = _DOF_PARENT.to(posed.device)[index]
    is_z = _DOF_IS_Z.to(posed.device)[index]
    axis_y = rotations[:, parent, :, 1]  # (B, 6, 4, 3)
    axis_z = rotations[:, joint, :, 2]
    axis = torch.where(is_z.unsqueeze(-1), axis_z, axis_y)
    tips = posed[:, _TIPS.to(posed.device)].unsqueeze(2)  # (B, 6, 1, 3)
    jac = torch.linalg.cross(axis, tips - posed[:, parent])  # (B, 6, 4, 3)
    jac = jac * _BRANCH_DOF_MASK.to(posed.device).unsqueeze(-1)
    return jac.transpose(-1, -2)


def _branch_angles(angles: torch.Tensor) -> torch.Tensor:
    """(B, 22) -> (B, 6, 4), padding with zeros."""
    index = _BRANCH_DOF_INDEX.to(angles.device)
    return angles[:, index] * _BRANCH_DOF_MASK.to(angles.device)


def _scatter_branch_angles(branch: torch.Tensor) -> torch.Tensor:
    """(B, 6, 4) -> (B, 22), dropping the padding."""
    mask = _BRANCH_DOF_MASK.to(branch.device)
    index = _BRANCH_DOF_INDEX.to(branch.device)[mask]
    out = branch.new_zeros(branch.shape[0], sk.NUM_DOFS)
    out[:, index] = branch[:, mask]
    return out


def solve_branch_ik(
    rest_joints: torch.Tensor,
    targets: torch.Tensor,
    init: torch.Tensor | None = None,
    iters: int = SOLVE_ITERATIONS,
    tolerance_mm: float = SOLVE_TOLERANCE_MM,
) -> torch.Tensor:
    """Angles that bring the end of each branch to a target (thesis 3.5.3), inside the limits.

    Per branch, only the DOFs that move its end: the four of each toe (metatarsal Y, proximal phalanx Y and Z,
    distal phalanx Y) and the two of the heel branch (midfoot-ankle Y, ankle Y). Damped least squares
    (Levenberg-Marquardt with Marquardt's diagonal scaling and an adaptive damping per branch) on
    ``|tip(angles) - target|^2``, batched over items and all six branches at once. Every step is projected onto
    the limits: DOFs sitting on a bound that the step would push outwards are held for that step (so the others
    still move), and the result is clamped. A step is kept only where it lowers that branch's error.

    A toe has four DOFs for a three-dimensional target, so the solution is one of a one-parameter family: the one
    the damped iteration reaches from ``init`` (close to it). Unreachable targets give the in-limit angles of a
    local minimum of the distance.

    Args:
        rest_joints: (B, 18, 3) or (18, 3) mm, zero-pose joints (left foot frame).
        targets: (B, 6, 3) mm, targets of the toe tips 1-5 then the heel (``skeleton.TIP_JOINTS`` order), foot
            frame, no global motion.
        init: (B, 22) radians to start from (clamped first); None = zero pose.
        iters: maximum iterations.
        tolerance_mm: stop when every tip is within this distance of its target.
    Returns:
        (B, 22) radians, inside the limits (float64 internally, returned in ``targets``' dtype).
    """
    if targets.dim() != 3 or targets.shape[1:] != (len(sk.TIP_JOINTS), 3):
        raise ValueError(f"targets must be (B, {len(sk.TIP_JOINTS)}, 3), got {tuple(targets.shape)}")
    out_dtype = targets.dtype
    b = targets.shape[0]
    targets = targets.double()
    rest = _batched_rest(rest_joints.to(targets), b)
    angles = targets.new_zeros(b, sk.NUM_DOFS) if init is None else lbs.clamp_angles(init.to(targets))
    lower = _branch_angles(targets.new_tensor(sk.DOF_LOWER).expand(b, -1))
    upper = _branch_angles(targets.new_tensor(sk.DOF_UPPER).expand(b, -1))
    tips = _TIPS.to(targets.device)
    damping = targets.new_full((b, len(sk.TIP_JOINTS)), _LM_INITIAL_DAMPING)
    # Start from the better, per branch, of ``init`` and its closed-form seed (avoids the local minima of
    # a toe that starts straight, e.g. the distal joint held on its lower bound of 0).
    posed, transforms = lbs.forward_kinematics(angles, rest)
    cost = ((targets - posed[:, tips]) ** 2).sum(-1)  # (B, 6)
    # A seed replaces the current angles only where it is strictly better, so among exact seeds the first
    # wins: ``init``'s metatarsal angle, then the smaller distal bend.
    init_angles = angles
    for metatarsal in (None, *_SEED_METATARSAL):
        start = init_angles.clone()
        if metatarsal is not None:
            start[:, _METATARSAL_DOFS] = metatarsal
        for root in (0, 1):
            seed = _seed_branches(rest, targets, start, root)
            angles, posed, transforms, cost = _keep_better(angles, posed, transforms, cost, seed, rest, targets)
    for _ in range(iters):
        active = (cost > tolerance_mm**2).any(dim=-1).nonzero().squeeze(-1)  # iterate only unfinished items
        if active.numel() == 0:
            break
        sub = _lm_step(
            angles[active],
            posed[active],
            transforms[active],
            cost[active],
            damping[active],
            rest[active],
            targets[active],
            lower[active],
            upper[active],
        )
        angles[active], posed[active], transforms[active], cost[active], damping[active] = sub
    return angles.to(out_dtype)


def _lm_step(
    angles: torch.Tensor,
    posed: torch.Tensor,
    transforms: torch.Tensor,
    cost: torch.Tensor,
    damping: torch.Tensor,
    rest: torch.Tensor,
    targets: torch.Tensor,
    lower: torch.Tensor,
    upper: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One projected Levenberg-Marquardt step of every branch; shapes as in ``solve_branch_ik``."""
    err = targets - posed[:, _TIPS.to(targets.device)]  # (B, 6, 3)
    jac = _tip_jacobian(posed, transforms[..., :3])  # (B, 6, 3, 4)
    descent = (jac.transpose(-1, -2) @ err.unsqueeze(-1)).squeeze(-1)  # (B, 6, 4)
    x = _branch_angles(angles)
    # a branch's padding DOFs (fewer than 4) are held like DOFs on a bound
    held = optim.held_at_bounds(x, descent, lower, upper) | ~_BRANCH_DOF_MASK.to(targets.device)
    # Marquardt's scale floor: 1e-6 of the sum of the branch's 4 diagonal entries
    step = optim.damped_step(jac, descent, damping, held, floor=1e-6 * _BRANCH_WIDTH)
    trial = _scatter_branch_angles(torch.minimum(torch.maximum(x + step, lower), upper))
    new = _keep_better(angles, posed, transforms, cost, trial, rest, targets)
    better = new[3] < cost
    damping = optim.next_damping(damping, better, _LM_DAMPING_DOWN, _LM_DAMPING_UP, _LM_DAMPING_RANGE)
    return (*new, damping)


# Branch of each joint (the root's entry is arbitrary: it never moves).
_JOINT_BRANCH = torch.tensor([0] + [next(k for k, c in enumerate(sk.BRANCHES) if j in c) for j in range(1, 18)])
_DOF_BRANCH = _JOINT_BRANCH[_DOF_JOINT]


def _keep_better(
    angles: torch.Tensor,
    posed: torch.Tensor,
    transforms: torch.Tensor,
    cost: torch.Tensor,
    trial: torch.Tensor,
    rest: torch.Tensor,
    targets: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per item and branch, keep ``trial`` (B, 22) where it brings the tip closer; FK is redone only once.

    A branch's joints, transforms and tip depend only on that branch's DOFs, so selecting them branch by branch
    from the two FK results is exact.
    """
    trial_posed, trial_transforms = lbs.forward_kinematics(trial, rest)
    trial_cost = ((targets - trial_posed[:, _TIPS.to(targets.device)]) ** 2).sum(-1)
    better = trial_cost < cost  # (B, 6)
    by_dof = better[:, _DOF_BRANCH.to(better.device)]
    by_joint = better[:, _JOINT_BRANCH.to(better.device)]
    return (
        torch.where(by_dof, trial, angles),
        torch.where(by_joint.unsqueeze(-1), trial_posed, posed),
        torch.where(by_joint.unsqueeze(-1).unsqueeze(-1), trial_transforms, transforms),
        torch.where(better, trial_cost, cost),
    )


def _uniform(shape: tuple[int, ...], generator: torch.Generator | np.random.Generator | int | None) -> torch.Tensor:
    """Uniform [0, 1) float64 draws from a torch or numpy generator (or a seed)."""
    if isinstance(generator, np.random.Generator):
        return torch.from_numpy(generator.random(shape))
    if generator is None or isinstance(generator, int):
        seed = generator
        generator = torch.Generator()
        if seed is None:
            generator.seed()
        else:
            generator.manual_seed(seed)
    return torch.rand(shape, generator=generator, dtype=torch.float64)


def uniform_angles(n: int, generator: torch.Generator | np.random.Generator | int | None = None) -> torch.Tensor:
    """(n, 22) float64 angles drawn independently and uniformly within Table 3.1's limits."""
    lower = torch.tensor(sk.DOF_LOWER, dtype=torch.float64)
    upper = torch.tensor(sk.DOF_UPPER, dtype=torch.float64)
    return lower + (upper - lower) * _uniform((n, sk.NUM_DOFS), generator)


NATURAL_POSE_SD = {
    "midfoot_ankle_y": 0.2,
    "ankle_y": 0.05,
    "toe_flexion_common": 0.35,
    "toe_flexion_individual": 0.05,
    "proximal_z": 0.05,
    "distal_y": 0.15,
    "distal_individual": 0.05,
}
"""Spreads (radians) of ``sample_poses(method="natural")``; see its docstring."""


@functools.lru_cache(maxsize=1)
def natural_pose_moments(samples: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """(22,) mean and (22,) SD, radians, of ``natural_angles`` (a fixed draw): the everyday poses' spread per DOF,
    which the fit's pose prior scales (``fit.FitConfig.angle_prior_sd_factor``)."""
    angles = natural_angles(samples, np.random.default_rng(0)).numpy()
    return angles.mean(axis=0), angles.std(axis=0)


def natural_angles(n: int, generator: torch.Generator | np.random.Generator | int | None = None) -> torch.Tensor:
    """(n, 22) float64 angles of everyday foot poses: see ``sample_poses(method="natural")``."""
    sd = NATURAL_POSE_SD
    u = _uniform((n, 2 * sk.NUM_DOFS + 4), generator)
    # Box-Muller normals from pairs of uniforms (one draw stream for torch and numpy generators alike).
    normal = torch.sqrt(-2.0 * torch.log1p(-u[:, 0::2])) * torch.cos(2.0 * math.pi * u[:, 1::2])  # (n, 24)
    angles = torch.zeros(n, sk.NUM_DOFS, dtype=torch.float64)
    index = {name: i for i, name in enumerate(sk.DOF_NAMES)}
    angles[:, index["midfoot_ankle_y"]] = sd["midfoot_ankle_y"] * normal[:, 0]
    angles[:, index["ankle_y"]] = sd["ankle_y"] * normal[:, 1]
    common = sd["toe_flexion_common"] * normal[:, 2]  # the toes flex together
    # and curl together: FIND's lesser toes touch along their length, so toes moving apart would tear the skin
    common_curl = sd["distal_y"] * normal[:, 23].abs()
    for k in range(1, 6):
        z = normal[:, 3 + 4 * (k - 1) : 7 + 4 * (k - 1)]
        angles[:, index[f"toe{k}_metatarsal_y"]] = 0.05 + 0.025 * z[:, 0]
        angles[:, index[f"toe{k}_proximal_y"]] = common + sd["toe_flexion_individual"] * z[:, 1]
        angles[:, index[f"toe{k}_proximal_z"]] = sd["proximal_z"] * z[:, 2]
        # curled toes: the distal joint bends more when the toe is flexed down
        curl = common_curl + sd["distal_individual"] * z[:, 3]
        angles[:, index[f"toe{k}_distal_y"]] = 0.3 * common.clamp_min(0.0) + curl
    return lbs.clamp_angles(angles)


def sample_poses(
    rest_joints: torch.Tensor,
    generator: torch.Generator | np.random.Generator | int | None,
    n: int,
    method: str = "ik",
) -> torch.Tensor:
    """Random joint angles inside the limits.

    ``method="ik"`` (the thesis' way, 3.5.3): a random reachable position for the end of each branch, then
    :func:`solve_branch_ik` from the zero pose. The positions are the branch ends of forward kinematics of
    angles drawn uniformly within the limits, so they cover each tip's reachable workspace. Once a toe's
    metatarsal angle is fixed its chain is not redundant (the distal bend follows from the distance to the
    target, the proximal Y/Z from its direction), so the result is the uniform distribution again except where
    the solver resolves the redundancy differently: the metatarsal angle (the start's 0 first) and, with it,
    the other root of the distal bend. The heel branch (two DOFs, planar) keeps the uniform angles exactly.
    Measured over 20,000 poses on the tests' toy model (mean +- SD, radians; toes 1-5 ranges):

    ===================  =======================  ================
    DOF                  ``"ik"``                 ``"uniform"``
    ===================  =======================  ================
    midfoot_ankle_y      0.226 +- 0.332           0.225 +- 0.332
    ankle_y              0.000 +- 0.058           0.000 +- 0.058
    toe*_metatarsal_y    0.041-0.047 +- 0.035     0.050 +- 0.029
    toe*_proximal_y      -0.05-0.01 +- 0.81-0.83  0.000 +- 0.808
    toe*_proximal_z      0.000 +- 0.075           0.000 +- 0.075
    toe*_distal_y        0.82-0.88 +- 0.42-0.44   0.800 +- 0.462
    ===================  =======================  ================

    ``method="uniform"``: every DOF independently uniform within its limits.

    ``method="natural"``: everyday poses, not the extremes of Table 3.1: normal spreads
    (``NATURAL_POSE_SD``) around the zero pose, the five toes flexing together (a common proximal flexion plus
    a small individual part), the distal joints curling more when the toes flex down, all clamped into the
    limits. Uniform sampling (and so ``"ik"``) often folds a toe by up to 3 rad (proximal 1.4 + distal 1.6),
    which linear blend skinning cannot render without collapsing faces.

    Measured (20,000 poses): midfoot_ankle_y 0.005 +- 0.193, ankle_y 0.000 +- 0.048, metatarsal_y
    0.050 +- 0.024, proximal_y 0.000 +- 0.360 (toes correlated), proximal_z 0.000 +- 0.050, distal_y
    0.267 +- 0.181.

    Which one for synthetic data: ``"natural"`` for most samples (skinning stays valid: on the toy model 95 %
    of edges within 30 % of their rest length and 0.7 % flipped faces, against 82 % and 7 % for the other
    two); ``"ik"`` (the thesis' procedure; about 2 ms a pose) or ``"uniform"`` (same distribution but the
    metatarsals, and free) for a small share covering the limits.

    Args:
        rest_joints: (18, 3) or (n, 18, 3) mm, zero-pose joints of the foot(s) to pose.
        generator: torch or numpy generator, or an int seed (None: fresh entropy). Deterministic given it.
        n: number of poses.
        method: "ik", "uniform" or "natural".
    Returns:
        (n, 22) float64 radians, ``skeleton.DOF_NAMES`` order.
    """
    if method not in ("ik", "uniform", "natural"):
        raise ValueError(f"method must be 'ik', 'uniform' or 'natural', got {method!r}")
    if method == "natural":
        return natural_angles(n, generator)
    drawn = uniform_angles(n, generator)
    if method == "uniform":
        return drawn
    rest = _batched_rest(torch.as_tensor(rest_joints, dtype=torch.float64), n)
    posed, _ = lbs.forward_kinematics(drawn, rest)
    return solve_branch_ik(rest, posed[:, _TIPS])
