"""The foot model as one stateless layer: ``vertices, joints = foot_model(shape, angles, scale, side)``.

Like smplx's ``SMPLLayer``: the module only holds the asset's arrays as buffers; the caller owns every parameter.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from footmesh.model import lbs
from footmesh.model import skeleton as sk
from footmesh.model.assets import FootModelAsset, load_asset

Side = str  # "left" or "right"


@dataclass(frozen=True)
class FootOutput:
    """What the foot model returns; lengths in mm in the frame described by ``FootModel.forward``."""

    vertices: torch.Tensor  # (B, V, 3)
    joints: torch.Tensor  # (B, J, 3)
    rest_vertices: torch.Tensor  # (B, V, 3) shaped, zero pose, unscaled, left-foot frame
    rest_joints: torch.Tensor  # (B, J, 3)
    transforms: torch.Tensor  # (B, J, 3, 4) segment transforms of the left-foot frame (before scale/mirror)
    right: torch.Tensor  # (B,) bool, True where the foot was mirrored to a right foot


def side_mask(side: Side | Sequence[Side], batch: int, device: torch.device | None = None) -> torch.Tensor:
    """``"left"``/``"right"`` (one for all, or one per item) -> (B,) bool, True for right feet."""
    sides = [side] * batch if isinstance(side, str) else list(side)
    if len(sides) != batch:
        raise ValueError(f"got {len(sides)} sides for a batch of {batch}")
    bad = {s for s in sides if s not in ("left", "right")}
    if bad:
        raise ValueError(f"side must be 'left' or 'right', got {sorted(bad)}")
    return torch.tensor([s == "right" for s in sides], dtype=torch.bool, device=device)


def mirror_faces(faces: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """Reverse the winding of (F, 3) faces, as needed after a mirror so that normals still point outwards."""
    return faces[:, [0, 2, 1]]


class FootModel(nn.Module):
    """Stateless foot model layer holding the PCA shape space, joint regressor and skinning weights."""

    def __init__(self, asset: FootModelAsset | None = None, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        asset = asset if asset is not None else load_asset()
        self.asset = asset
        self.register_buffer("mean_vertices", torch.as_tensor(asset.mean_vertices, dtype=dtype))
        self.register_buffer("components", torch.as_tensor(asset.components, dtype=dtype))
        self.register_buffer("component_sd", torch.as_tensor(asset.component_sd, dtype=dtype))
        self.register_buffer("joint_regressor", torch.as_tensor(asset.joint_regressor, dtype=dtype))
        weights = torch.as_tensor(asset.skin_weights, dtype=dtype)
        # renormalised in the working precision: rows of the float32 asset sum to 1 only within 1e-7
        self.register_buffer("skin_weights", weights / weights.sum(dim=1, keepdim=True))
        self.register_buffer("faces_left", torch.as_tensor(asset.faces.astype(np.int64)))

    @property
    def num_components(self) -> int:
        return int(self.component_sd.shape[0])

    @property
    def num_vertices(self) -> int:
        return int(self.mean_vertices.shape[0])

    def faces(self, side: Side = "left") -> torch.Tensor:
        """(F, 3) faces with outward winding for ``side``."""
        return self.faces_left if side == "left" else mirror_faces(self.faces_left)

    def forward(
        self,
        shape: torch.Tensor | None = None,
        angles: torch.Tensor | None = None,
        scale: torch.Tensor | float | None = None,
        side: Side | Sequence[Side] = "left",
        rotation: torch.Tensor | None = None,
        translation: torch.Tensor | None = None,
    ) -> FootOutput:
        """Pose and place feet.

        ``v = rotation @ (mirror(scale * skin(v_shaped, FK(angles)))) + translation``: shape and pose in the
        left-foot frame, uniform scale about the heel origin, mirror y -> -y for right feet, then an optional
        rigid placement (e.g. into a camera frame).

        Args:
            shape: (B, K') PCA coefficients in SD units (K' <= K); None = mean shape.
            angles: (B, 22) radians in ``skeleton.DOF_NAMES`` order; None = zero pose.
            scale: (B,) or scalar, dimensionless; None = 1.
            side: "left", "right", or one per item.
            rotation: (B, 3, 3) rotation matrices; None = identity.
            translation: (B, 3) mm; None = zero.
        Returns:
            FootOutput with vertices (B, V, 3) and joints (B, 18, 3) in mm.
        """
        batch = _batch_size(shape, angles, scale, rotation, translation)
        ref = self.mean_vertices
        if shape is None:
            shape = ref.new_zeros(batch, 0)
        if angles is None:
            angles = ref.new_zeros(batch, sk.NUM_DOFS)
        # parameters follow the model's precision (float32 for speed, float64 for fitting and gradcheck)
        shape, angles = shape.to(ref.dtype), angles.to(ref.dtype)
        if shape.dim() != 2 or shape.shape[1] > self.num_components:
            raise ValueError(f"shape must be (B, K<={self.num_components}), got {tuple(shape.shape)}")
        if angles.shape != (batch, sk.NUM_DOFS):
            raise ValueError(f"angles must be (B, {sk.NUM_DOFS}), got {tuple(angles.shape)}")

        v_shaped = lbs.blend_shapes(shape, self.mean_vertices, self.components, self.component_sd)
        rest_joints = torch.einsum("jv,bvc->bjc", self.joint_regressor, v_shaped)
        joints, transforms = lbs.forward_kinematics(angles, rest_joints)
        vertices = lbs.skin(v_shaped, transforms, self.skin_weights)

        if scale is not None:
            s = torch.as_tensor(scale, dtype=ref.dtype, device=ref.device).reshape(-1, 1, 1)
            vertices, joints = vertices * s, joints * s
        right = side_mask(side, batch, ref.device)
        flip = torch.where(right, -1.0, 1.0).to(ref.dtype).reshape(-1, 1)
        mirror = torch.stack([torch.ones_like(flip), flip, torch.ones_like(flip)], dim=-1)  # (B, 1, 3)
        vertices, joints = vertices * mirror, joints * mirror
        if rotation is not None:
            rotation = rotation.to(ref.dtype)
            vertices = vertices @ rotation.transpose(-1, -2)
            joints = joints @ rotation.transpose(-1, -2)
        if translation is not None:
            translation = translation.to(ref.dtype)
            vertices = vertices + translation.unsqueeze(1)
            joints = joints + translation.unsqueeze(1)
        return FootOutput(vertices, joints, v_shaped, rest_joints, transforms, right)

    def extra_repr(self) -> str:
        return f"V={self.num_vertices}, F={len(self.faces_left)}, K={self.num_components}, J={sk.NUM_JOINTS}"


def _batch_size(*tensors: torch.Tensor | float | None) -> int:
    sizes = {t.shape[0] for t in tensors if isinstance(t, torch.Tensor) and t.dim() > 0}
    if len(sizes) > 1:
        raise ValueError(f"inconsistent batch sizes {sorted(sizes)}")
    return sizes.pop() if sizes else 1


@functools.lru_cache(maxsize=1)
def default_model() -> FootModel:
    """The packaged foot model (float32), loaded once; its arrays are read-only buffers."""
    return FootModel()


def foot_model(
    shape: torch.Tensor | None = None,
    angles: torch.Tensor | None = None,
    scale: torch.Tensor | float | None = None,
    side: Side | Sequence[Side] = "left",
    model: FootModel | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``vertices (B, V, 3), joints (B, 18, 3) = foot_model(shape, angles, scale, side)`` in mm, foot frame.

    Uses the packaged model unless ``model`` is given; see ``FootModel.forward`` for the arguments.
    """
    out = (model if model is not None else default_model())(shape, angles, scale, side)
    return out.vertices, out.joints
