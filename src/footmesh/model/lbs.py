"""Pure, differentiable functions of the foot model (torch), in the manner of smplx's ``lbs``.

Shapes: B batch, V vertices, K shape components, J = 18 joints, D = 22 rotational DOFs. Lengths in mm,
angles in radians, foot frame (see ``skeleton`` and docs/conventions.md).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from footmesh.model import skeleton as sk

DOF_JOINT = torch.tensor([d.joint for d in sk.DOFS])
"""(D,) the joint each rotational DOF turns (``skeleton.DOFS``)."""
DOF_IS_Z = torch.tensor([d.axis == "z" for d in sk.DOFS])
"""(D,) True for a DOF about the segment's z axis, False for one about y."""


def blend_shapes(shape: torch.Tensor, mean: torch.Tensor, components: torch.Tensor, sd: torch.Tensor) -> torch.Tensor:
    """Shaped rest vertices ``v_shaped = mean + sum_k shape_k * sd_k * components_k``.

    Args:
        shape: (B, K') coefficients in units of each component's SD; K' <= K (missing ones are zero).
        mean: (V, 3) mm. components: (K, V, 3) orthonormal directions. sd: (K,) mm.
    Returns:
        (B, V, 3) mm.
    """
    k = shape.shape[-1]
    offsets = torch.einsum("bk,kvc->bvc", shape * sd[:k], components[:k])
    return mean.unsqueeze(0) + offsets


def rot_y(angle: torch.Tensor) -> torch.Tensor:
    """(...,) radians -> (..., 3, 3); positive turns +x towards -z."""
    c, s = torch.cos(angle), torch.sin(angle)
    z, o = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack([c, z, s, z, o, z, -s, z, c], dim=-1).reshape(*angle.shape, 3, 3)


def rot_z(angle: torch.Tensor) -> torch.Tensor:
    """(...,) radians -> (..., 3, 3); positive turns +x towards +y."""
    c, s = torch.cos(angle), torch.sin(angle)
    z, o = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack([c, -s, z, s, c, z, z, z, o], dim=-1).reshape(*angle.shape, 3, 3)


def local_rotations(
    angles: torch.Tensor,
    dof_joint: torch.Tensor = DOF_JOINT,
    dof_is_z: torch.Tensor = DOF_IS_Z,
    num_joints: int = sk.NUM_JOINTS,
) -> torch.Tensor:
    """Rotation of each segment relative to its parent, ``R = R_y(angle_y) @ R_z(angle_z)``.

    Args:
        angles: (B, D) radians, ``skeleton.DOF_NAMES`` order.
        dof_joint, dof_is_z: (D,) the skeleton's DOFs: the joint each turns and whether about z (default: the
            foot's, ``skeleton.DOFS``). num_joints: J.
    Returns:
        (B, J, 3, 3); identity for the root.
    """
    b = angles.shape[0]
    angle_y = angles.new_zeros(b, num_joints)
    angle_z = angles.new_zeros(b, num_joints)
    dof_joint = dof_joint.to(angles.device)
    is_z = dof_is_z.to(angles.device)
    angle_y = angle_y.index_add(1, dof_joint[~is_z], angles[:, ~is_z])
    angle_z = angle_z.index_add(1, dof_joint[is_z], angles[:, is_z])
    cy, sy = torch.cos(angle_y), torch.sin(angle_y)
    cz, sz = torch.cos(angle_z), torch.sin(angle_z)
    zero = torch.zeros_like(cy)
    # R_y(y) @ R_z(z) written out: one stack instead of two matrices and a batched matmul.
    rows = [cy * cz, -cy * sz, sy, sz, cz, zero, -sy * cz, sy * sz, cy]
    return torch.stack(rows, dim=-1).reshape(b, num_joints, 3, 3)


def forward_kinematics(
    angles: torch.Tensor, rest_joints: torch.Tensor, parents: Sequence[int] = sk.PARENTS
) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward kinematics of all six branches at once.

    Each segment ``p -> c`` turns by its local rotation about the parent joint ``p`` (thesis 3.5.2).

    Args:
        angles: (B, D) radians.
        rest_joints: (B, J, 3) or (J, 3) mm, joint positions in the zero pose.
        parents: (J,) each joint's parent, -1 for the root, parents before children (default: the foot's tree).
    Returns:
        posed_joints: (B, J, 3) mm.
        transforms: (B, J, 3, 4) rigid transform of each segment (column j moves the segment ending at
            joint j; the root's is the identity), mapping rest points to posed points.
    """
    b = angles.shape[0]
    if rest_joints.dim() == 2:
        rest_joints = rest_joints.unsqueeze(0).expand(b, -1, -1)
    local = local_rotations(angles, num_joints=len(parents))
    eye = torch.eye(3, dtype=angles.dtype, device=angles.device).expand(b, 3, 3)
    rotations = [eye]
    translations = [angles.new_zeros(b, 3)]
    # The tree is 18 joints deep at most 4: a Python loop over joints is cheaper than any gather trick.
    for c in range(1, len(parents)):
        p = parents[c]
        rot_p, t_p = rotations[p], translations[p]
        pivot = rest_joints[:, p]
        rot_c = rot_p @ local[:, c]
        # x -> rot_p (R_c (x - pivot) + pivot) + t_p
        t_c = t_p + (rot_p @ pivot.unsqueeze(-1)).squeeze(-1) - (rot_c @ pivot.unsqueeze(-1)).squeeze(-1)
        rotations.append(rot_c)
        translations.append(t_c)
    rot = torch.stack(rotations, dim=1)  # (B, J, 3, 3)
    trans = torch.stack(translations, dim=1)  # (B, J, 3)
    transforms = torch.cat([rot, trans.unsqueeze(-1)], dim=-1)  # (B, J, 3, 4)
    posed_joints = (rot @ rest_joints.unsqueeze(-1)).squeeze(-1) + trans
    return posed_joints, transforms


def skin(vertices: torch.Tensor, transforms: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning ``v' = sum_j w_vj (R_j v + t_j)``.

    Args:
        vertices: (B, V, 3) rest vertices, mm.
        transforms: (B, J, 3, 4) from ``forward_kinematics``.
        weights: (V, J), rows sum to 1.
    Returns:
        (B, V, 3) posed vertices, mm.
    """
    # Blend the transforms' departures from the identity, so that the zero pose returns ``vertices`` bit for
    # bit even though float weights sum to 1 only within rounding.
    eye = torch.eye(3, 4, dtype=transforms.dtype, device=transforms.device)
    blended = torch.einsum("vj,bjrc->bvrc", weights, transforms - eye)  # (B, V, 3, 4)
    return vertices + (blended[..., :3] @ vertices.unsqueeze(-1)).squeeze(-1) + blended[..., 3]


def inverse_skin(posed: torch.Tensor, transforms: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Undo ``skin``: the rest vertices whose skinning gives ``posed`` (per-vertex blended transform inverted).

    Args:
        posed: (B, V, 3) mm. transforms: (B, J, 3, 4). weights: (V, J).
    Returns:
        (B, V, 3) rest vertices, mm.
    """
    eye = torch.eye(3, 4, dtype=transforms.dtype, device=transforms.device)
    blended = eye + torch.einsum("vj,bjrc->bvrc", weights, transforms - eye)  # as in ``skin``
    return torch.linalg.solve(blended[..., :3], (posed - blended[..., 3]).unsqueeze(-1)).squeeze(-1)


def clamp_angles(angles: torch.Tensor) -> torch.Tensor:
    """Clamp (B, D) angles into Table 3.1's limits."""
    lower = angles.new_tensor(sk.DOF_LOWER)
    upper = angles.new_tensor(sk.DOF_UPPER)
    return torch.maximum(torch.minimum(angles, upper), lower)
