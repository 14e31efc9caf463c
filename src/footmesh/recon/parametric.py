"""The model-based head (issue 24): latent code -> the foot model's parameters -> the foot model's mesh.

    latent (B, C) --linear--> PCA shape (B, 10) SD units, 22 joint angles inside their limits, rotation (6D),
    left/right logit; ``FootModel(shape, angles, side, rotation)`` -> vertices (B, 4002, 3) in the camera's axes

A free 4,002-vertex output has to learn the shape space, the skeleton and the skinning from the images; here
the foot model supplies them and the network only reads ~40 numbers off the image. The placement (the vertex
centroid) comes from ``ReconNet``'s centre heads as for the ISM decoder, and the ISM decoder may add a per-vertex
residual on top (``ReconConfig.residual``).

Rotation: the continuous 6D representation of Zhou et al. (CVPR 2019, "On the continuity of rotation
representations in neural networks"): two 3-vectors made orthonormal by Gram-Schmidt; it has no discontinuity
(unlike Euler angles or quaternions up to sign), which regressing a rotation needs.

Angles: ``lower + (upper - lower) sigmoid(raw)``: inside Table 3.1's limits by construction, differentiable
everywhere; the bias starts each angle at the zero pose where the zero pose is inside its limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from footmesh.model import skeleton as sk
from footmesh.model.layer import FootModel, default_model
from footmesh.recon.decoder import DecoderOutput

NUM_SHAPE = 10
"""PCA components predicted (those the synthetic data draws)."""
ZERO_POSE_MARGIN = 0.05
"""An angle whose limits exclude 0 (or put it on a limit) starts this fraction of its range inside the limit."""


def rotation_from_6d(x: torch.Tensor) -> torch.Tensor:
    """(B, 6) -> (B, 3, 3) rotation matrices whose first two columns are the Gram-Schmidt of the two 3-vectors."""
    a, b = x[:, :3], x[:, 3:]
    e1 = nn.functional.normalize(a, dim=-1)
    e2 = nn.functional.normalize(b - (e1 * b).sum(-1, keepdim=True) * e1, dim=-1)
    e3 = torch.cross(e1, e2, dim=-1)
    return torch.stack([e1, e2, e3], dim=-1)


def rotation_to_6d(rotation: torch.Tensor) -> torch.Tensor:
    """(B, 3, 3) -> (B, 6): the first two columns (the inverse of ``rotation_from_6d`` on rotations)."""
    return torch.cat([rotation[..., 0], rotation[..., 1]], dim=-1)


@dataclass(frozen=True)
class FootParameters:
    """The head's prediction: ``shape`` (B, 10) SD units, ``angles`` (B, 22) rad, ``rotation`` (B, 3, 3) camera
    from foot, ``right_logit`` (B,) > 0 for a right foot."""

    shape: torch.Tensor
    angles: torch.Tensor
    rotation: torch.Tensor
    right_logit: torch.Tensor


@dataclass(frozen=True)
class ModelOutput(DecoderOutput):
    """``DecoderOutput`` (final vertices, centre, levels) plus the foot model's mesh under them and its parameters.

    ``model_vertices`` (B, V, 3) mm, camera frame: the foot model's mesh placed at ``centre``; ``vertices`` adds the
    ISM residual to it (the same when the network has none).
    """

    model_vertices: torch.Tensor
    parameters: FootParameters
    right: torch.Tensor  # (B,) bool: the side the mesh was built for (given, or predicted)


class ParametricHead(nn.Module):
    """Latent (B, C) and the frame's scale [-> ReLU layer (B, hidden)] -> ``FootParameters``; ``mesh`` turns them
    into centred vertices with the foot model.

    The foot model is not a submodule (its buffers would be saved with every network); it is the packaged one.
    """

    def __init__(self, in_features: int, hidden: int = 0) -> None:
        super().__init__()
        self.num_dofs = sk.NUM_DOFS
        inputs = in_features + 1  # the latent and the log of the frame's mm per unit (``forward``)
        # hidden > 0: one ReLU layer first (the rotation and the sigmoid angles are far from linear in the image)
        self.hidden = nn.Sequential(nn.Linear(inputs, hidden), nn.ReLU(inplace=True)) if hidden > 0 else nn.Identity()
        self.linear = nn.Linear(hidden if hidden > 0 else inputs, NUM_SHAPE + sk.NUM_DOFS + 6 + 1)
        lower = torch.tensor(sk.DOF_LOWER)
        upper = torch.tensor(sk.DOF_UPPER)
        self.register_buffer("lower", lower, persistent=False)
        self.register_buffer("range", upper - lower, persistent=False)
        # zero weights: the first prediction is the mean shape, the zero pose, the identity rotation
        nn.init.zeros_(self.linear.weight)
        with torch.no_grad():
            bias = torch.zeros(self.linear.out_features)
            start = ((0.0 - lower) / (upper - lower)).clamp(ZERO_POSE_MARGIN, 1 - ZERO_POSE_MARGIN)
            bias[NUM_SHAPE : NUM_SHAPE + sk.NUM_DOFS] = torch.log(start / (1 - start))
            bias[NUM_SHAPE + sk.NUM_DOFS : NUM_SHAPE + sk.NUM_DOFS + 6] = torch.tensor([1.0, 0, 0, 0, 1, 0])
            self.linear.bias.copy_(bias)

    def forward(self, latent: torch.Tensor, log_mm_per_unit: torch.Tensor) -> FootParameters:
        """(B, C) latent and (B,) log of the mm one lateral unit of the normalised frame spans at the foot
        (``ReconNet``: s f_ref / f_x) -> ``FootParameters``.

        Why the scale: the image reaches the encoder scale-free (depth relative to its median, no focal length),
        so the latent holds the foot's apparent size only; the foot model's shape is in mm (its first components
        are mostly size), which needs this factor. The ISM decoder predicts in the normalised frame instead.
        """
        out = self.linear(self.hidden(torch.cat([latent, log_mm_per_unit[:, None].to(latent.dtype)], dim=1)))
        shape, raw, six, side = out.split([NUM_SHAPE, self.num_dofs, 6, 1], dim=1)
        angles = self.lower.to(out) + self.range.to(out) * torch.sigmoid(raw)
        return FootParameters(shape, angles, rotation_from_6d(six), side[:, 0])

    @staticmethod
    def mesh(
        parameters: FootParameters, right: torch.Tensor, model: FootModel | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Vertices (B, V, 3) and joints (B, 18, 3) mm in the camera's axes, vertex centroid at the origin, for
        the (B,) bool sides ``right``."""
        model = model if model is not None else default_model()
        sides = ["right" if r else "left" for r in right.tolist()]
        out = model(parameters.shape, parameters.angles, side=sides, rotation=parameters.rotation)
        centroid = out.vertices.mean(dim=1, keepdim=True)
        return out.vertices - centroid, out.joints - centroid
