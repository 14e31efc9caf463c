"""The synthetic samples' IK poses, compiled: ``model.ik.sample_poses(method="ik")`` for one foot at a time.

``model.ik.solve_branch_ik`` is batched torch code; for one foot its ~1,500 small tensor calls cost about
35-45 ms, most of it call overhead, and its bits depend on the batch (torch's vectorised sin/cos/atan2 give
other bits in the body of an array than in its scalar tail), so samples cannot share a batch. This is the same
algorithm for one foot in plain scalar loops (numba, no ``fastmath``, no ``parallel``; about 0.2 ms): the
closed-form seeds of every metatarsal angle and both roots of the distal bend, then projected Levenberg-Marquardt
with Marquardt's scaling, an adaptive damping per branch, and a step kept per branch only where it lowers that
branch's error. It reaches the same poses (tests: within 1e-9 rad of the torch solver on most feet, the tips as
close to their targets), though rounding differs (libm's sin/cos, an explicit 4 x 4 solve instead of LAPACK's),
so a rare foot whose solve sits on a knife edge lands on the other nearby solution.

Angles are (22,) radians, ``skeleton.DOF_NAMES`` order; joints (18, 3) mm, the left foot's frame (``model.ik``).
"""

from __future__ import annotations

import math

import numpy as np

from footmesh.model import ik
from footmesh.model import skeleton as sk
from footmesh.synth.kernels import _jit

_PARENTS = np.array(sk.PARENTS, dtype=np.int64)
_Y_DOF = np.array(ik._Y_DOF, dtype=np.int64)  # per joint: its DOF about Y (-1: none)
_Z_DOF = np.array(ik._Z_DOF, dtype=np.int64)  # per joint: its DOF about Z (-1: none)
_LOWER = np.array(sk.DOF_LOWER, dtype=np.float64)
_UPPER = np.array(sk.DOF_UPPER, dtype=np.float64)
_TIPS = np.array(sk.TIP_JOINTS, dtype=np.int64)
_BRANCH_DOFS = np.array(ik._BRANCH_DOFS, dtype=np.int64)  # (6, 4), padded with 0
_BRANCH_NDOF = ik._BRANCH_DOF_MASK.sum(dim=1).numpy().astype(np.int64)  # (6,)
_BRANCH_JOINTS = np.full((len(sk.BRANCHES), 3), -1, dtype=np.int64)  # (6, 3) joints moved by each branch, -1 pad
for _b, _chain in enumerate(sk.BRANCHES):
    _BRANCH_JOINTS[_b, : len(_chain)] = _chain
_DOF_JOINT = ik._DOF_JOINT.numpy().astype(np.int64)
_DOF_PARENT = ik._DOF_PARENT.numpy().astype(np.int64)
_DOF_IS_Z = ik._DOF_IS_Z.numpy()
_METATARSAL_DOFS = np.array(ik._METATARSAL_DOFS, dtype=np.int64)
_SEED_METATARSAL = np.array(ik._SEED_METATARSAL, dtype=np.float64)
_LM = np.array(
    [
        ik._LM_INITIAL_DAMPING,
        ik._LM_DAMPING_DOWN,
        ik._LM_DAMPING_UP,
        ik._LM_DAMPING_RANGE[0],
        ik._LM_DAMPING_RANGE[1],
        1e-6 * ik._BRANCH_WIDTH,  # Marquardt's scale floor (``optim.damped_step``'s relative floor)
        1e-12,  # ``optim.solve_damped``'s absolute floor
    ]
)


def sample_ik_angles(rest_joints: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(22,) float64 radians: ``model.ik.sample_poses(rest_joints, rng, 1, method="ik")[0]``, compiled.

    Draws the same 22 uniforms from ``rng`` (angles uniform within the limits), poses the joints, and solves for
    the branch ends (``solve_branch_ik``).

    Args:
        rest_joints: (18, 3) mm, the shaped foot's zero-pose joints (left foot frame).
        rng: the sample's pose stream.
    """
    drawn = _LOWER + (_UPPER - _LOWER) * rng.random((1, sk.NUM_DOFS))[0]
    return solve_branch_ik(np.ascontiguousarray(rest_joints, dtype=np.float64), drawn)


def solve_branch_ik(
    rest: np.ndarray, drawn: np.ndarray, iters: int = ik.SOLVE_ITERATIONS, tolerance_mm: float = ik.SOLVE_TOLERANCE_MM
) -> np.ndarray:
    """(22,) angles bringing each branch end to where the angles ``drawn`` (22,) put it (from the zero pose)."""
    return _solve(rest, drawn, iters, tolerance_mm)


@_jit
def _rot_y(a, out):  # pragma: no cover
    c, s = math.cos(a), math.sin(a)
    out[0, 0], out[0, 1], out[0, 2] = c, 0.0, s
    out[1, 0], out[1, 1], out[1, 2] = 0.0, 1.0, 0.0
    out[2, 0], out[2, 1], out[2, 2] = -s, 0.0, c


@_jit
def _fk(angles, rest, rot, posed):  # pragma: no cover
    """Forward kinematics (``lbs.forward_kinematics``): segment rotations (18, 3, 3) and posed joints (18, 3)."""
    trans = np.zeros((18, 3))
    local = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            rot[0, i, j] = 1.0 if i == j else 0.0
        posed[0, i] = rest[0, i]
    for c in range(1, _PARENTS.shape[0]):
        p = _PARENTS[c]
        ay = angles[_Y_DOF[c]] if _Y_DOF[c] >= 0 else 0.0
        az = angles[_Z_DOF[c]] if _Z_DOF[c] >= 0 else 0.0
        cy, sy, cz, sz = math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
        # R_y(y) @ R_z(z)
        local[0, 0], local[0, 1], local[0, 2] = cy * cz, -cy * sz, sy
        local[1, 0], local[1, 1], local[1, 2] = sz, cz, 0.0
        local[2, 0], local[2, 1], local[2, 2] = -sy * cz, sy * sz, cy
        for i in range(3):
            for j in range(3):
                rot[c, i, j] = rot[p, i, 0] * local[0, j] + rot[p, i, 1] * local[1, j] + rot[p, i, 2] * local[2, j]
        # x -> rot_p (R_c (x - pivot) + pivot) + t_p
        for i in range(3):
            rp = rot[p, i, 0] * rest[p, 0] + rot[p, i, 1] * rest[p, 1] + rot[p, i, 2] * rest[p, 2]
            rc = rot[c, i, 0] * rest[p, 0] + rot[c, i, 1] * rest[p, 1] + rot[c, i, 2] * rest[p, 2]
            trans[c, i] = trans[p, i] + rp - rc
        for i in range(3):
            posed[c, i] = (
                rot[c, i, 0] * rest[c, 0] + rot[c, i, 1] * rest[c, 1] + rot[c, i, 2] * rest[c, 2] + trans[c, i]
            )


@_jit
def _tip_costs(posed, targets, cost):  # pragma: no cover
    for b in range(_TIPS.shape[0]):
        t = _TIPS[b]
        dx, dy, dz = targets[b, 0] - posed[t, 0], targets[b, 1] - posed[t, 1], targets[b, 2] - posed[t, 2]
        cost[b] = dx * dx + dy * dy + dz * dz


@_jit
def _keep_better(angles, rot, posed, cost, trial, rest, targets, t_rot, t_posed, t_cost):  # pragma: no cover
    """Per branch, take ``trial`` (22,) where it brings the branch end closer (``ik._keep_better``); returns
    which branches improved (6,)."""
    _fk(trial, rest, t_rot, t_posed)
    _tip_costs(t_posed, targets, t_cost)
    better = np.zeros(_TIPS.shape[0], dtype=np.bool_)
    for b in range(_TIPS.shape[0]):
        if not t_cost[b] < cost[b]:
            continue
        better[b] = True
        cost[b] = t_cost[b]
        for k in range(_BRANCH_NDOF[b]):
            angles[_BRANCH_DOFS[b, k]] = trial[_BRANCH_DOFS[b, k]]
        for m in range(_BRANCH_JOINTS.shape[1]):
            j = _BRANCH_JOINTS[b, m]
            if j < 0:
                continue
            for i in range(3):
                posed[j, i] = t_posed[j, i]
                for q in range(3):
                    rot[j, i, q] = t_rot[j, i, q]
    return better


@_jit
def _wrap(a):  # pragma: no cover
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@_jit
def _clamp(a, lo, hi):  # pragma: no cover
    return min(max(a, lo), hi)


@_jit
def _rotation_onto(r, d, y_dof, z_dof):  # pragma: no cover
    """(y, z) radians of ``R_y(y) [@ R_z(z)]`` turning ``r`` (3,) towards ``d`` (3,), clamped
    (``ik._rotation_onto``)."""
    rx, ry, rz = r[0], r[1], r[2]
    angle_z = 0.0
    if z_dof >= 0:
        r_norm = math.sqrt(rx * rx + ry * ry + rz * rz)
        d_norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        d_y = d[1] * r_norm / max(d_norm, 1e-12)
        rho = max(math.hypot(rx, ry), 1e-12)
        phi = math.atan2(ry, rx)
        angle_z = _clamp(_wrap(math.asin(_clamp(d_y / rho, -1.0, 1.0)) - phi), _LOWER[z_dof], _UPPER[z_dof])
        c, s = math.cos(angle_z), math.sin(angle_z)
        rx, ry = c * rx - s * ry, s * rx + c * ry
    angle_y = _clamp(_wrap(math.atan2(rz, rx) - math.atan2(d[2], d[0])), _LOWER[y_dof], _UPPER[y_dof])
    return angle_y, angle_z


@_jit
def _bend_for_distance(r_a, r_b, distance, y_dof, root):  # pragma: no cover
    """The Y bend within its limits making ``|r_a + R_y(t) r_b|`` closest to ``distance``
    (``ik._bend_for_distance``)."""
    big_a = r_a[0] * r_b[0] + r_a[2] * r_b[2]
    big_b = r_a[0] * r_b[2] - r_a[2] * r_b[0]
    sq_a = r_a[0] * r_a[0] + r_a[1] * r_a[1] + r_a[2] * r_a[2]
    sq_b = r_b[0] * r_b[0] + r_b[1] * r_b[1] + r_b[2] * r_b[2]
    rhs = 0.5 * (distance * distance - sq_a - sq_b) - r_a[1] * r_b[1]
    amplitude = max(math.hypot(big_a, big_b), 1e-12)
    psi = math.atan2(big_b, big_a)
    spread = math.acos(_clamp(rhs / amplitude, -1.0, 1.0))
    lo, hi = _LOWER[y_dof], _UPPER[y_dof]
    first = _clamp(_wrap(psi + spread), lo, hi)
    second = _clamp(_wrap(psi - spread), lo, hi)
    small, large = min(first, second), max(first, second)
    return small if root == 0 else large


@_jit
def _seed_branches(rest, targets, init, root, out):  # pragma: no cover
    """Closed-form start (``ik._seed_branches``): ``init``'s metatarsal angles, the two-link chain below solved."""
    for q in range(init.shape[0]):
        out[q] = init[q]
    frame = np.empty((3, 3))
    rot_b = np.empty((3, 3))
    pivot = np.empty(3)
    r_a = np.empty(3)
    r_b = np.empty(3)
    d = np.empty(3)
    v = np.empty(3)
    for branch in range(_TIPS.shape[0]):
        if _BRANCH_JOINTS[branch, 2] >= 0:  # toe: metatarsal (Y), proximal phalanx (Y, Z), distal phalanx (Y)
            proximal, first, bend = _BRANCH_JOINTS[branch, 0], _BRANCH_JOINTS[branch, 1], _BRANCH_JOINTS[branch, 2]
            _rot_y(init[_Y_DOF[proximal]], frame)
            for i in range(3):
                pivot[i] = rest[0, i] + (
                    frame[i, 0] * (rest[proximal, 0] - rest[0, 0])
                    + frame[i, 1] * (rest[proximal, 1] - rest[0, 1])
                    + frame[i, 2] * (rest[proximal, 2] - rest[0, 2])
                )
                r_a[i] = rest[first, i] - rest[proximal, i]
                r_b[i] = rest[bend, i] - rest[first, i]
        else:  # heel: midfoot-ankle (Y), ankle (Y)
            first, bend = _BRANCH_JOINTS[branch, 0], _BRANCH_JOINTS[branch, 1]
            for i in range(3):
                for j in range(3):
                    frame[i, j] = 1.0 if i == j else 0.0
                pivot[i] = rest[0, i]
                r_a[i] = rest[first, i] - rest[0, i]
                r_b[i] = rest[bend, i] - rest[first, i]
        for i in range(3):  # d = frame^T (tip - pivot)
            d[i] = (
                frame[0, i] * (targets[branch, 0] - pivot[0])
                + frame[1, i] * (targets[branch, 1] - pivot[1])
                + frame[2, i] * (targets[branch, 2] - pivot[2])
            )
        y_bend = _Y_DOF[bend]
        distance = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        angle_bend = _bend_for_distance(r_a, r_b, distance, y_bend, root)
        _rot_y(angle_bend, rot_b)
        for i in range(3):
            v[i] = r_a[i] + rot_b[i, 0] * r_b[0] + rot_b[i, 1] * r_b[1] + rot_b[i, 2] * r_b[2]
        angle_y, angle_z = _rotation_onto(v, d, _Y_DOF[first], _Z_DOF[first])
        out[y_bend] = angle_bend
        out[_Y_DOF[first]] = angle_y
        if _Z_DOF[first] >= 0:
            out[_Z_DOF[first]] = angle_z


@_jit
def _solve4(a, b, out):  # pragma: no cover
    """Solve the 4 x 4 system ``a x = b`` (Gaussian elimination with partial pivoting; ``a``, ``b`` overwritten)."""
    n = 4
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(a[r, col]) > abs(a[piv, col]):
                piv = r
        if piv != col:
            for q in range(n):
                a[col, q], a[piv, q] = a[piv, q], a[col, q]
            b[col], b[piv] = b[piv], b[col]
        for r in range(col + 1, n):
            f = a[r, col] / a[col, col]
            for q in range(col, n):
                a[r, q] -= f * a[col, q]
            b[r] -= f * b[col]
    for r in range(n - 1, -1, -1):
        acc = b[r]
        for q in range(r + 1, n):
            acc -= a[r, q] * out[q]
        out[r] = acc / a[r, r]


@_jit
def _solve(rest, drawn, iters, tolerance_mm):  # pragma: no cover
    """``ik.solve_branch_ik`` of the branch ends that ``drawn`` reaches, from the zero pose, one foot."""
    n_dofs = drawn.shape[0]
    n_branch = _TIPS.shape[0]
    rot = np.empty((18, 3, 3))
    posed = np.empty((18, 3))
    _fk(drawn, rest, rot, posed)
    targets = np.empty((n_branch, 3))
    for b in range(n_branch):
        for i in range(3):
            targets[b, i] = posed[_TIPS[b], i]
    angles = np.zeros(n_dofs)
    cost = np.empty(n_branch)
    _fk(angles, rest, rot, posed)
    _tip_costs(posed, targets, cost)
    t_rot = np.empty((18, 3, 3))
    t_posed = np.empty((18, 3))
    t_cost = np.empty(n_branch)
    start = np.empty(n_dofs)
    seed = np.empty(n_dofs)
    # the seeds in ``ik.solve_branch_ik``'s order: the zero pose's metatarsal angles, then each of _SEED_METATARSAL
    for m in range(-1, _SEED_METATARSAL.shape[0]):
        for q in range(n_dofs):
            start[q] = 0.0
        if m >= 0:
            for q in range(_METATARSAL_DOFS.shape[0]):
                start[_METATARSAL_DOFS[q]] = _SEED_METATARSAL[m]
        for root in range(2):
            _seed_branches(rest, targets, start, root, seed)
            _keep_better(angles, rot, posed, cost, seed, rest, targets, t_rot, t_posed, t_cost)
    damping = np.full(n_branch, _LM[0])
    jac = np.empty((3, 4))
    normal = np.empty((4, 4))
    descent = np.empty(4)
    rhs = np.empty(4)
    step = np.empty(4)
    x = np.empty(4)
    held = np.empty(4, dtype=np.bool_)
    trial = np.empty(n_dofs)
    tol2 = tolerance_mm * tolerance_mm
    for _ in range(iters):
        done = True
        for b in range(n_branch):
            if cost[b] > tol2:
                done = False
        if done:
            break
        for q in range(n_dofs):
            trial[q] = angles[q]
        for b in range(n_branch):  # one projected LM step per branch (``ik._lm_step``)
            tip = _TIPS[b]
            nk = _BRANCH_NDOF[b]
            for k in range(4):
                if k < nk:
                    dof = _BRANCH_DOFS[b, k]
                    joint, parent = _DOF_JOINT[dof], _DOF_PARENT[dof]
                    if _DOF_IS_Z[dof]:
                        ax, ay, az = rot[joint, 0, 2], rot[joint, 1, 2], rot[joint, 2, 2]
                    else:
                        ax, ay, az = rot[parent, 0, 1], rot[parent, 1, 1], rot[parent, 2, 1]
                    ox = posed[tip, 0] - posed[parent, 0]
                    oy = posed[tip, 1] - posed[parent, 1]
                    oz = posed[tip, 2] - posed[parent, 2]
                    jac[0, k] = ay * oz - az * oy
                    jac[1, k] = az * ox - ax * oz
                    jac[2, k] = ax * oy - ay * ox
                    x[k] = angles[dof]
                else:
                    jac[0, k] = jac[1, k] = jac[2, k] = 0.0
                    x[k] = 0.0
            ex = targets[b, 0] - posed[tip, 0]
            ey = targets[b, 1] - posed[tip, 1]
            ez = targets[b, 2] - posed[tip, 2]
            for k in range(4):
                descent[k] = jac[0, k] * ex + jac[1, k] * ey + jac[2, k] * ez
                if k < nk:
                    dof = _BRANCH_DOFS[b, k]
                    lo, hi = _LOWER[dof], _UPPER[dof]
                    held[k] = (x[k] <= lo and descent[k] < 0) or (x[k] >= hi and descent[k] > 0)
                else:
                    held[k] = True
            for k in range(4):  # J^T J of the free DOFs
                for q in range(4):
                    if held[k] or held[q]:
                        normal[k, q] = 0.0
                    else:
                        normal[k, q] = jac[0, k] * jac[0, q] + jac[1, k] * jac[1, q] + jac[2, k] * jac[2, q]
            mean = (normal[0, 0] + normal[1, 1] + normal[2, 2] + normal[3, 3]) / 4.0
            for k in range(4):
                scale = normal[k, k] + _LM[5] * mean + _LM[6]
                normal[k, k] += damping[b] * scale + (1.0 if held[k] else 0.0)
                rhs[k] = 0.0 if held[k] else descent[k]
            _solve4(normal, rhs, step)
            for k in range(nk):
                dof = _BRANCH_DOFS[b, k]
                value = x[k] + (0.0 if held[k] else step[k])
                trial[dof] = min(max(value, _LOWER[dof]), _UPPER[dof])
        better = _keep_better(angles, rot, posed, cost, trial, rest, targets, t_rot, t_posed, t_cost)
        for b in range(n_branch):
            damping[b] = _clamp(damping[b] * (_LM[1] if better[b] else _LM[2]), _LM[3], _LM[4])
    return angles
