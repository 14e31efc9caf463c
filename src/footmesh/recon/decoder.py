"""The Inception Spiral Module mesh decoder of thesis Figure 3.6: latent code -> template vertices in mm.

Layout (levels as in ``hierarchy``: 0 = full template, N-1 = coarsest, ~1/16 of the vertices for N = 5):

    latent (B, C_in) --linear--> features (B, V_{N-1}, c_{N-1})
    layer 1:  [skip 1] -> ISM at level N-1                         -> p_{N-1} = head(x)
    layer k:  up-sample level N-k+1 -> N-k, [skip k] -> ISM         -> p_{N-k} = up(p_{N-k+1}) + head(x)
    vertices_l = centre + shape_scale_mm x (p_l - mean_v p_l);  centre = centre_mean_mm + centre_scale_mm x linear(z)

Coarse-to-fine coordinates (after HandMesh/CMR's per-level heads): each level predicts (B, V_l, 3) normalised
coordinates as the barycentric up-sampling of the coarser level's plus a SpiralConv correction. The coarse levels
carry the overall shape straight to the output (a 252-vertex foot up-sampled is already a foot) and the fine
levels add detail; with a single head on the full level the network must build the whole foot through five
ReLU layers of shared filters, and overfitting one foot took several times as many steps. Every level's mesh is
returned (``DecoderOutput.levels``) for optional deep supervision against ``MeshHierarchy.downsample`` targets.

Skip connections (thesis 3.3.2: the decoder keeps the stacked-hourglass skips of its 2D-cue decoder, where the
first four of five layers concatenate an encoder feature map of matching size): the first
``len(skip_in_channels)`` layers each take one encoder feature, coarsest first, as (B, C_k, H, W) maps
(averaged over the image) or (B, C_k) vectors; a linear map to ``skip_features`` channels (+ ReLU) is broadcast to
every vertex and concatenated to the vertex features before that layer's ISM. A mesh has no image grid to
align a feature map with, so the skip carries global image evidence (e.g. the depth channel's scale) to every
level rather than spatial detail.

Output (why not offsets from the template): vertices are predicted in the camera frame, where the foot turns
freely (views from 140 deg either side of the toes) and right feet are mirror images of the left template, so
offsets from the template would be as large as the foot itself. Instead the network predicts (i) the vertex
centroid (B, 3) mm, as a prior mean plus a scaled correction (the camera looks at the foot from 300-700 mm), and
(ii) centred coordinates in units of ``shape_scale_mm`` (about half a foot length, so they lie within +-1.5),
whose mean over the vertices is removed so that centroid and shape do not compete. Both scales are fixed
constants of the configuration; set them from the training data's statistics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
from torch import nn

from footmesh.recon.hierarchy import MeshHierarchy, Resample, template_hierarchy
from footmesh.recon.spiral import InceptionSpiralModule, SpiralConv

HEAD_INIT_GAIN = 0.1
"""The coordinate heads start at this fraction of Xavier's scale: five levels of random coordinates would otherwise
add up to a first guess ~300 mm off the target instead of ~115 mm (measured on one posed foot)."""


@dataclass(frozen=True)
class OutputScale:
    """How normalised network outputs become millimetres (camera frame, OpenCV axes)."""

    shape_scale_mm: float = 100.0
    """Centred coordinates are multiplied by this."""
    centre_mean_mm: tuple[float, float, float] = (0.0, 0.0, 500.0)
    """Prior mean of the vertex centroid in the camera frame."""
    centre_scale_mm: tuple[float, float, float] = (50.0, 50.0, 150.0)
    """The centroid head's output is multiplied by this before the mean is added."""


@dataclass(frozen=True)
class DecoderConfig:
    """Sizes of ``SpiralDecoder``; ``channels`` and the hierarchy must have the same number of levels."""

    in_features: int = 512
    """Width of the latent code from the image encoder."""
    channels: tuple[int, ...] = (16, 32, 32, 64, 64)
    """Output channels of the ISM at each level, full template (level 0) first, coarsest last."""
    spiral_length: int = 12
    dilation: int = 1
    skip_in_channels: tuple[int, ...] = ()
    """Channels of the encoder features fed to the first layers, coarsest level first (thesis: four)."""
    skip_features: int = 32
    output: OutputScale = field(default_factory=OutputScale)


@dataclass(frozen=True)
class DecoderOutput:
    """What ``SpiralDecoder`` returns."""

    vertices: torch.Tensor  # (B, V_0, 3) mm, camera frame, template vertex order (faces: hierarchy.faces[0])
    centre: torch.Tensor  # (B, 3) mm, the vertices' centroid
    levels: tuple[torch.Tensor, ...]  # (B, V_l, 3) mm per hierarchy level, level 0 (= vertices) first


class CentredOutput(nn.Module):
    """Latent (B, C) -> centroid (B, 3) mm, and normalised coordinates (B, V, 3) -> vertices (B, V, 3) mm."""

    def __init__(self, in_features: int, scale: OutputScale) -> None:
        super().__init__()
        self.shape_scale_mm = float(scale.shape_scale_mm)
        self.centre_head = nn.Linear(in_features, 3)
        # zero start: the first prediction sits at the prior mean and the head learns corrections from there
        nn.init.zeros_(self.centre_head.weight)
        nn.init.zeros_(self.centre_head.bias)
        self.register_buffer("centre_mean", torch.tensor(scale.centre_mean_mm, dtype=torch.float32), persistent=False)
        self.register_buffer("centre_scale", torch.tensor(scale.centre_scale_mm, dtype=torch.float32), persistent=False)

    def centre(self, latent: torch.Tensor) -> torch.Tensor:
        """(B, C) -> predicted centroid (B, 3) mm."""
        return self.centre_mean.to(latent.dtype) + self.centre_scale.to(latent.dtype) * self.centre_head(latent)

    def forward(self, coordinates: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
        """Coordinates (B, V, 3) and centre (B, 3) mm -> vertices (B, V, 3) mm whose centroid is ``centre``."""
        shape = coordinates - coordinates.mean(dim=1, keepdim=True)
        return centre.unsqueeze(1) + self.shape_scale_mm * shape


class SpiralDecoder(nn.Module):
    """Latent code (B, C_in) [+ encoder skips] -> template vertices (B, V, 3) in mm, camera frame.

    Args:
        config: sizes (``DecoderConfig``).
        hierarchy: the template's mesh hierarchy (``template_hierarchy(cache=...)``); built from the packaged
            template when None (a few seconds). Its spirals are rebuilt if their length or dilation differ
            from the configuration's.
    """

    def __init__(self, config: DecoderConfig | None = None, hierarchy: MeshHierarchy | None = None) -> None:
        super().__init__()
        cfg = config if config is not None else DecoderConfig()
        if hierarchy is None:
            hierarchy = template_hierarchy(spiral_length=cfg.spiral_length, dilation=cfg.dilation)
        hierarchy = hierarchy.with_spirals(cfg.spiral_length, cfg.dilation)
        levels = hierarchy.num_levels
        if len(cfg.channels) != levels:
            raise ValueError(f"DecoderConfig.channels has {len(cfg.channels)} entries for {levels} mesh levels")
        if len(cfg.skip_in_channels) > levels:
            raise ValueError(f"at most {levels} skip features for {levels} layers, got {len(cfg.skip_in_channels)}")
        self.config = cfg
        self.num_vertices = hierarchy.num_vertices
        coarsest = levels - 1
        self.register_buffer("faces", torch.as_tensor(hierarchy.faces[0], dtype=torch.long), persistent=False)

        self.project = nn.Linear(cfg.in_features, self.num_vertices[coarsest] * cfg.channels[coarsest])
        self.skip_projections = nn.ModuleList(nn.Linear(c, cfg.skip_features) for c in cfg.skip_in_channels)
        self.upsample = nn.ModuleList()
        self.blocks = nn.ModuleList()
        in_channels = cfg.channels[coarsest]
        for layer, level in enumerate(range(coarsest, -1, -1)):
            if level < coarsest:
                self.upsample.append(Resample(hierarchy.up[level]))
            skip = cfg.skip_features if layer < len(cfg.skip_in_channels) else 0
            self.blocks.append(InceptionSpiralModule(in_channels + skip, cfg.channels[level], hierarchy.spirals[level]))
            in_channels = cfg.channels[level]
        # one coordinate head per level (coarsest first): each level adds detail to the up-sampled coarser shape
        self.heads = nn.ModuleList(
            SpiralConv(cfg.channels[level], 3, hierarchy.spirals[level]) for level in range(coarsest, -1, -1)
        )
        with torch.no_grad():
            for head in self.heads:
                head.linear.weight.mul_(HEAD_INIT_GAIN)
        self.output = CentredOutput(cfg.in_features, cfg.output)

    def forward(
        self, latent: torch.Tensor, skips: Sequence[torch.Tensor] | None = None, centre: torch.Tensor | None = None
    ) -> DecoderOutput:
        """Decode a batch.

        Args:
            latent: (B, in_features) image code.
            skips: ``len(config.skip_in_channels)`` encoder features, coarsest first, each (B, C_k, H, W) or
                (B, C_k); None or empty when the configuration has none.
            centre: (B, 3) the vertices' centroid when the caller places it (e.g. from image evidence); None:
                the centroid head's, from the latent.
        Returns:
            ``DecoderOutput`` with vertices (B, V_0, 3) and centre (B, 3), mm, camera frame.
        """
        cfg = self.config
        if latent.dim() != 2 or latent.shape[1] != cfg.in_features:
            raise ValueError(f"latent must be (B, {cfg.in_features}), got {tuple(latent.shape)}")
        skips = list(skips) if skips is not None else []
        if len(skips) != len(cfg.skip_in_channels):
            raise ValueError(f"expected {len(cfg.skip_in_channels)} skip features, got {len(skips)}")
        b = latent.shape[0]
        x = self.project(latent).reshape(b, self.num_vertices[-1], cfg.channels[-1])
        coordinates = None
        levels = []
        for layer, block in enumerate(self.blocks):
            if layer > 0:
                x = self.upsample[layer - 1](x)
            if layer < len(skips):
                x = torch.cat([x, self._skip(layer, skips[layer], x.shape[1])], dim=-1)
            x = block(x)
            detail = self.heads[layer](x)
            coordinates = detail if coordinates is None else self.upsample[layer - 1](coordinates) + detail
            levels.append(coordinates)
        if centre is None:
            centre = self.output.centre(latent)
        elif centre.shape != (b, 3):
            raise ValueError(f"centre must be (B, 3) = ({b}, 3), got {tuple(centre.shape)}")
        meshes = tuple(self.output(c, centre) for c in reversed(levels))
        return DecoderOutput(meshes[0], centre, meshes)

    def _skip(self, layer: int, feature: torch.Tensor, num_vertices: int) -> torch.Tensor:
        """Encoder feature (B, C, H, W) or (B, C) -> (B, V, skip_features) broadcast over the vertices."""
        want = self.config.skip_in_channels[layer]
        if feature.dim() == 4:
            feature = feature.mean(dim=(2, 3))
        if feature.dim() != 2 or feature.shape[1] != want:
            raise ValueError(f"skip {layer} must be (B, {want}, H, W) or (B, {want}), got {tuple(feature.shape)}")
        s = torch.relu(self.skip_projections[layer](feature))
        return s.unsqueeze(1).expand(-1, num_vertices, -1)

    def extra_repr(self) -> str:
        n = sum(p.numel() for p in self.parameters())
        return f"vertices={list(self.num_vertices)}, parameters={n}"
