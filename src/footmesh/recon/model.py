"""The image -> mesh network (thesis 3.3): a ResNet-style image encoder and the spiral decoder (or EdgeConv).

    image (B, C, S, S) [+ 2 coordinate channels] --stem, 4 ResNet stages (strides 4, 8, 16, 32)-->
    global average of every stage (B, w_k) --concat, linear, ReLU--> latent (B, decoder.in_features)
    SpiralDecoder(latent, skips = stage averages, coarsest first) -> vertices in the *normalised camera frame*
    ``to_camera`` (the intrinsics K, and the depth map's median when there is one) -> vertices, mm, camera frame

Normalised camera frame (why): vertices are wanted in mm in the camera frame, but an image alone fixes only
what a pinhole camera sees: pixel positions ``u - c`` and, with depth, depths. The synthetic cameras' horizontal
field of view spans 60-75 deg, so the focal length varies by +-14 % and a foot's size in mm cannot be read off
its size in pixels without K (10 % of a 260 mm foot is 26 mm, five times the 5 mm target). The decoder
therefore predicts points ``(A, B, C)`` that the image determines, and K turns them into millimetres exactly:

    C = Z / s,   A = (u - c0) C / f_ref,   B = (v - c0) C / f_ref        (c0: the image centre, f_ref = 0.75 S)
    Z = s C,     X = s (f_ref A - (c_x - c0) C) / f_x,   Y = s (f_ref B - (c_y - c0) C) / f_y

with ``s`` the scale the input leaves open: for depth inputs ``s = median depth / 500 mm`` (the depth channel is
fed relative to its median, so scaling the whole scene scales the prediction: depth and size are metric), for
RGB ``s = f_x / f_ref`` (then C is the depth of a camera with focal f_ref: the apparent size of a known object
fixes it, so A4 sheets, cards and markers in the image can give the scale). A principal point off the image
centre (a crop) is handled by the ``c - c0`` terms.

Coordinate channels (CoordConv, Liu et al. 2018): global average pooling forgets where a feature was; two
channels holding the pixel's normalised x and y let the pooled features carry the foot's position in the image,
which the centroid needs (the synthetic cameras look at a point ~15 mm (SD) off the foot's centre).

Spatial centroid (``centre_head="spatial"``): even with coordinate channels, a centroid read off
pooled features stayed ~30 mm off after 700 training steps (most of the vertex error). Instead a 1x1 convolution
of the stride-8 features gives a heat map whose soft-argmax is the centroid's pixel (u, v), as the 2D-cues
network finds joints; the latent gives only its normalised depth C, and ``A = (u - c0) C / f_ref`` (likewise B)
puts the centroid on that pixel's ray exactly.

Anchored centroid (``centre_head="anchored"``, the default): with a depth map the centroid's depth need not be
guessed from pooled features either (the spatial head's RGB-D runs were still 25 mm off after 1,100 steps): a
second heat map over the same stride-8 cells, restricted to cells with measured depth, averages the depth map's
surface depth, and the latent adds only the offset from that surface to the vertex centroid (about half the foot's
thickness). Without depth it is the spatial head.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any

import numpy as np
import torch
from torch import nn

from footmesh.config import INPUT_CHANNELS
from footmesh.cues.inputs import DEPTH_CLIP, normalise_rgb
from footmesh.cues.net import _stage, conv_bn_relu
from footmesh.model.layer import default_model
from footmesh.recon.decoder import CentredOutput, DecoderConfig, DecoderOutput, SpiralDecoder
from footmesh.recon.edgeconv import EdgeConvConfig, EdgeConvGenerator, PointCloudOutput
from footmesh.recon.hierarchy import MeshHierarchy
from footmesh.recon.parametric import ModelOutput, ParametricHead

FOCAL_REF = 0.75
"""Reference focal length f_ref of the normalised frame, as a fraction of the input side (about the middle of the
synthetic 60-75 deg fields of view: 0.87 .. 0.65)."""
DEPTH_REF_MM = 500.0
"""Depth the median of a depth map is mapped to in the normalised frame (the decoder's prior centroid depth)."""
DEPTH_GAIN = 5.0
"""Relative depth ``d / median - 1`` is fed times this: 1 % of the median (5 mm at 500 mm) -> 0.05, the scale of
the 2D-cues network's depth channel (100 mm -> 1) at the typical distance."""
KINDS = ("ism", "edgeconv", "model")
ENCODERS = ("resnet", "efficientnet_lite0")
EFFICIENTNET_WIDTHS = (24, 40, 112, 320)
"""EfficientNet-Lite0's features at strides 4, 8, 16, 32 (``cues.efficientnet.PYRAMID_CHANNELS[1:]``)."""
CENTRE_HEADS = ("anchored", "spatial", "global")
CENTRE_STAGE = 1
"""Encoder stage (stride 8) whose features locate the centroid's pixel."""
LOSSES = {"ism": ("thesis", "structure"), "edgeconv": ("chamfer",), "model": ("structure", "thesis")}
"""The losses each kind can be trained with."""


def _decoder_default() -> DecoderConfig:
    # latent 256 x (252 vertices x 32) = 2.1 M parameters in the projection instead of the default decoder's 8.1 M;
    # 32 channels at the coarse levels: 64 (the decoder's default) costs 50 % more time per training step
    return DecoderConfig(in_features=256, channels=(16, 32, 32, 32, 32), skip_in_channels=(256, 128, 64, 32))


def _edgeconv_default() -> EdgeConvConfig:
    return EdgeConvConfig(in_features=256)


@dataclass(frozen=True)
class ReconConfig:
    """Architecture and loss of ``ReconNet``; the defaults are sized for a 2-core CPU at 128 px."""

    input: str = "rgbd"
    """rgb, rgbd or depth."""
    image_size: int = 128
    widths: tuple[int, ...] = (32, 64, 128, 256)
    """Channels of the encoder stages at strides 4, 8, 16, 32 (ResNet-18: 64, 128, 256, 512). The decoder costs
    ~85 % of a training step on a CPU, so the encoder is wider than the 2D-cues network's at no measurable cost."""
    blocks: tuple[int, ...] = (1, 1, 1, 1)
    """ResNet blocks per stage (``encoder="resnet"`` only)."""
    encoder: str = "resnet"
    """``resnet``: the ResNet-style encoder trained from scratch; ``efficientnet_lite0``: ImageNet-pretrained
    EfficientNet-Lite0 from its PyPI package (``widths`` must be ``EFFICIENTNET_WIDTHS``)."""
    coord_channels: bool = True
    """Append normalised x, y coordinate channels to the input (module docstring)."""
    centre_head: str = "anchored"
    """How the mesh decoder places the vertex centroid: ``anchored`` (``spatial``, and with a depth map its depth
    read off the map plus an offset from the latent), ``spatial`` (its pixel by a soft-argmax over the stride-8
    features, its depth from the latent: module docstring) or ``global`` (all three coordinates from the latent)."""
    centre_refine: bool = False
    """``anchored``/``spatial`` heads: add ``CentrePixelHead`` (a heat map and per-cell offsets from the stride-8,
    16 and 32 features) to the centroid pixel's 1x1 map; its last layer starts at zero, so a network given it starts
    as the one it was initialised from (``train recon --init-from``, ``train_only``)."""
    kind: str = "ism"
    """``ism``: the spiral mesh decoder; ``edgeconv``: the EdgeConv point-cloud baseline; ``model``: the foot
    model's parameters (``recon.parametric``) and, with ``residual``, the spiral decoder's per-vertex residual."""
    residual: bool = True
    """``kind="model"``: add the ISM decoder's per-vertex residual to the foot model's mesh."""
    parametric_hidden: int = 256
    """``kind="model"``: width of the model head's hidden ReLU layer (0: the parameters linear in the latent)."""
    residual_scale_mm: float = 10.0
    """``kind="model"``: the residual decoder's coordinates are multiplied by this (its ``shape_scale_mm``)."""
    loss: str = "thesis"
    """ISM: ``thesis`` (L1 + edge length + 0.1 normal) or ``structure`` (L1 + 0.1 normal + Laplacian); EdgeConv:
    ``chamfer``."""
    decoder: DecoderConfig = field(default_factory=_decoder_default)
    """``in_features`` is the latent width; ``skip_in_channels`` must be ``widths`` reversed (or empty)."""
    edgeconv: EdgeConvConfig = field(default_factory=_edgeconv_default)
    """Used when ``kind == "edgeconv"``; ``in_features`` must equal ``decoder.in_features``."""

    @property
    def in_channels(self) -> int:
        return INPUT_CHANNELS[self.input] + (2 if self.coord_channels else 0)

    @property
    def latent_features(self) -> int:
        return self.decoder.in_features

    @property
    def spiral_decoder(self) -> bool:
        """Whether the network has the ISM spiral decoder (and so needs the mesh hierarchy)."""
        return self.kind == "ism" or (self.kind == "model" and self.residual)

    def __post_init__(self) -> None:
        if self.input not in INPUT_CHANNELS:
            raise ValueError(f"input must be one of {sorted(INPUT_CHANNELS)}, got {self.input!r}")
        if self.centre_head not in CENTRE_HEADS:
            raise ValueError(f"centre_head must be one of {CENTRE_HEADS}, got {self.centre_head!r}")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if self.loss not in LOSSES[self.kind]:
            raise ValueError(
                f"a {self.kind} network is trained with loss {' or '.join(LOSSES[self.kind])}, not {self.loss!r}"
            )
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.encoder == "efficientnet_lite0" and tuple(self.widths) != EFFICIENTNET_WIDTHS:
            raise ValueError(
                f"the EfficientNet-Lite0 encoder's widths are {list(EFFICIENTNET_WIDTHS)}, got {list(self.widths)} "
                "(ReconConfig.for_widths)"
            )
        if self.parametric_hidden < 0:
            raise ValueError(f"parametric_hidden must be >= 0, got {self.parametric_hidden}")
        if self.residual_scale_mm <= 0:
            raise ValueError(f"residual_scale_mm must be positive, got {self.residual_scale_mm}")
        if len(self.widths) != 4 or len(self.blocks) != 4 or min(self.blocks) < 1 or min(self.widths) < 1:
            raise ValueError("widths and blocks need one positive entry per encoder stage (4)")
        if self.image_size % 32 or self.image_size < 64:
            raise ValueError(f"image_size must be a multiple of 32 and at least 64, got {self.image_size}")
        skips = tuple(reversed(self.widths))
        if self.decoder.skip_in_channels not in ((), skips):
            raise ValueError(
                f"decoder.skip_in_channels must be the encoder widths reversed {list(skips)} (or empty for no "
                f"skips), got {list(self.decoder.skip_in_channels)}"
            )
        if self.edgeconv.in_features != self.decoder.in_features:
            raise ValueError(
                f"edgeconv.in_features ({self.edgeconv.in_features}) must equal the latent width "
                f"decoder.in_features ({self.decoder.in_features})"
            )

    @classmethod
    def for_widths(cls, widths: tuple[int, ...], latent: int, **fields: object) -> ReconConfig:
        """A configuration whose decoder and EdgeConv sizes follow the encoder ``widths`` and ``latent`` width."""
        base = cls()
        decoder = fields.pop("decoder", base.decoder)
        edgeconv = fields.pop("edgeconv", base.edgeconv)
        decoder = replace(decoder, in_features=latent, skip_in_channels=tuple(reversed(widths)))
        return cls(widths=tuple(widths), decoder=decoder, edgeconv=replace(edgeconv, in_features=latent), **fields)


def update_config(current, data: dict[str, Any], where: str = "config"):
    """Dataclass ``current`` with the (partial, nested) values of ``data``; unknown keys and wrong types fail.

    Nested dataclasses are updated from their *current* values (``config._from_dict`` starts from the nested
    type's own defaults, which would drop e.g. this module's decoder sizes).
    """
    from footmesh.config import _check_type

    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a JSON object, got {type(data).__name__}")
    known = {f.name for f in fields(current)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown {where} keys {unknown}; known: {sorted(known)}")
    values = {}
    for name, value in data.items():
        now = getattr(current, name)
        if is_dataclass(now):
            values[name] = update_config(now, value, f"{where}.{name}")
        else:
            values[name] = _check_type(value, now, type(current), name, f"{where}.{name}")
    return replace(current, **values)


# --- inputs and the normalised camera frame ---------------------------------------------------------------------


def recon_input(
    input_kind: str, rgb: torch.Tensor | None, depth_mm: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Network input (B, C, S, S) and each depth map's median valid depth (B,) mm (None for RGB).

    Args:
        input_kind: rgb (3 channels), rgbd (4) or depth (1).
        rgb: (B, 3, S, S) in [0, 1] (standardised like the 2D-cues network's).
        depth_mm: (B, 1, S, S) mm, 0 = missing; fed as ``DEPTH_GAIN * (d / median - 1)``, 0 where missing, so
            that a scene scaled by k gives the same input (the median carries the scale).
    Raises:
        ValueError: a needed image is missing, or a depth map has no valid pixel.
    """
    if input_kind not in INPUT_CHANNELS:
        raise ValueError(f"unknown input kind {input_kind!r}; one of {sorted(INPUT_CHANNELS)}")
    parts, ref = [], None
    if input_kind in ("rgb", "rgbd"):
        if rgb is None or rgb.dim() != 4 or rgb.shape[1] != 3:
            raise ValueError(f"{input_kind} input needs an RGB batch (B, 3, S, S)")
        parts.append(normalise_rgb(rgb))
    if input_kind in ("rgbd", "depth"):
        if depth_mm is None or depth_mm.dim() != 4 or depth_mm.shape[1] != 1:
            raise ValueError(f"{input_kind} input needs a depth batch (B, 1, S, S) in mm")
        valid = depth_mm > 0
        if not bool(valid.flatten(1).any(1).all()):
            raise ValueError("a depth map has no valid (> 0) pixel: cannot tell the scale")
        flat = torch.where(valid, depth_mm, torch.nan).flatten(1)
        ref = torch.nanmedian(flat, dim=1).values  # (B,)
        rel = (DEPTH_GAIN * (depth_mm / ref.view(-1, 1, 1, 1) - 1.0)).clamp(-DEPTH_CLIP, DEPTH_CLIP)
        parts.append(torch.where(valid, rel, torch.zeros_like(rel)))
    return torch.cat(parts, dim=1), ref


def frame_scale(input_kind: str, K: torch.Tensor, depth_ref_mm: torch.Tensor | None, size: int) -> torch.Tensor:
    """The scale ``s`` (B,) of the normalised frame (module docstring): median depth / 500 mm, or f_x / f_ref."""
    if input_kind in ("rgbd", "depth"):
        if depth_ref_mm is None:
            raise ValueError(f"{input_kind} input needs the depth maps' medians (recon_input's second output)")
        return depth_ref_mm.to(K.dtype) / DEPTH_REF_MM
    return K[:, 0, 0] / (FOCAL_REF * size)


def to_camera(points: torch.Tensor, K: torch.Tensor, scale: torch.Tensor, size: int) -> torch.Tensor:
    """Normalised-frame points (B, N, 3) -> camera frame (B, N, 3) mm, for intrinsics (B, 3, 3) of the input."""
    c0, f_ref = (size - 1) / 2, FOCAL_REF * size
    s = scale.view(-1, 1)
    a, b, c = points.unbind(-1)
    fx, fy = K[:, 0, 0].view(-1, 1), K[:, 1, 1].view(-1, 1)
    cx, cy = K[:, 0, 2].view(-1, 1), K[:, 1, 2].view(-1, 1)
    x = s * (f_ref * a - (cx - c0) * c) / fx
    y = s * (f_ref * b - (cy - c0) * c) / fy
    return torch.stack([x, y, s * c], dim=-1)


def from_camera(points: torch.Tensor, K: torch.Tensor, scale: torch.Tensor, size: int) -> torch.Tensor:
    """The inverse of ``to_camera``: camera-frame points (B, N, 3) mm -> normalised frame (B, N, 3)."""
    c0, f_ref = (size - 1) / 2, FOCAL_REF * size
    s = scale.view(-1, 1)
    x, y, z = points.unbind(-1)
    c = z / s
    fx, fy = K[:, 0, 0].view(-1, 1), K[:, 1, 1].view(-1, 1)
    cx, cy = K[:, 0, 2].view(-1, 1), K[:, 1, 2].view(-1, 1)
    a = (x * fx / s + (cx - c0) * c) / f_ref
    b = (y * fy / s + (cy - c0) * c) / f_ref
    return torch.stack([a, b, c], dim=-1)


# --- the network ------------------------------------------------------------------------------------------------


class ImageEncoder(nn.Module):
    """ResNet-style encoder of the 2D-cues network: ``(B, C, S, S)`` -> 4 stage outputs at strides 4..32.

    Stem: two stride-2 3x3 convolutions (to stride 4); stages: ``footmesh.cues.net._stage`` (ResNet-18 blocks).
    """

    def __init__(self, in_channels: int, widths: tuple[int, ...], blocks: tuple[int, ...]) -> None:
        super().__init__()
        w = widths
        half = max(w[0] // 2, 16)
        self.stem = nn.Sequential(conv_bn_relu(in_channels, half, stride=2), conv_bn_relu(half, w[0], stride=2))
        self.stages = nn.ModuleList(
            [_stage(w[0], w[0], blocks[0], 1)] + [_stage(w[i - 1], w[i], blocks[i], 2) for i in range(1, 4)]
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, C, S, S) -> [(B, w_k, S / 2^(k+2), S / 2^(k+2)) for k = 0..3], finest first."""
        x = self.stem(x)
        out = []
        for stage in self.stages:
            x = stage(x)
            out.append(x)
        return out


class PretrainedEncoder(nn.Module):
    """EfficientNet-Lite0 (``cues.efficientnet``): ``(B, C, S, S)`` -> its 4 feature maps at strides 4..32 (the
    stride-2 map is dropped: the decoder pools every map and the centre heads read stride 8)."""

    def __init__(self, in_channels: int) -> None:
        super().__init__()
        from footmesh.cues.efficientnet import EfficientNetLite0Features

        self.net = EfficientNetLite0Features(in_channels)

    def load_pretrained(self) -> int:
        """Copy the packaged ImageNet weights in (the extra input channels start at zero); tensors copied."""
        return self.net.load_pretrained()

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, C, S, S) -> [(B, w_k, S / 2^(k+2), S / 2^(k+2)) for k = 0..3], finest first."""
        return self.net(x)[1:]


class CentrePixelHead(nn.Module):
    """A correction of the centroid's pixel: over the stride-8 cells, a heat map added to the centre map's and an
    offset of each cell's point (CenterNet, Zhou et al. 2019), from the stride-8 features, the stride-16 and -32 ones
    brought up to them, the depth channel pooled alike (inputs with depth) and the cells' coordinates. A 1x1 map of
    the stride-8 features alone left the centroid 0.7 px (3.7 mm) off at 128 px, most of the mesh's error."""

    def __init__(self, widths: tuple[int, ...], with_depth: bool, hidden: int = 96) -> None:
        super().__init__()
        inputs = sum(widths[CENTRE_STAGE:]) + 2 + int(with_depth)
        self.mix = nn.Sequential(
            nn.Conv2d(inputs, hidden, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.ReLU(inplace=True),
        )
        self.out = nn.Conv2d(hidden, 3, 1)
        nn.init.zeros_(self.out.weight)  # zero start: no change to the map it corrects
        nn.init.zeros_(self.out.bias)

    def forward(
        self, features: list[torch.Tensor], depth_channel: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Encoder features (finest first) and the (B, 1, S, S) depth channel or None -> the heat map's correction
        (B, 1, h, w) and the cells' offsets (B, 2, h, w) in cells, (x, y), on the stride-8 grid (h, w)."""
        size = features[CENTRE_STAGE].shape[-2:]
        maps = [features[CENTRE_STAGE]]
        maps += [
            nn.functional.interpolate(f, size=size, mode="bilinear", align_corners=False)
            for f in features[CENTRE_STAGE + 1 :]
        ]
        if depth_channel is not None:
            maps.append(nn.functional.adaptive_avg_pool2d(depth_channel, size))
        maps.append(_coordinates(maps[0]))
        out = self.out(self.mix(torch.cat(maps, dim=1)))
        return out[:, :1], out[:, 1:]


class ReconNet(nn.Module):
    """Image (B, C, S, S), intrinsics and depth scale -> mesh (``DecoderOutput``) or points (``PointCloudOutput``).

    Args:
        config: ``ReconConfig``.
        hierarchy: the template's mesh hierarchy (``template_hierarchy(cache=...)``); built when None (ISM only).
    """

    def __init__(self, config: ReconConfig | None = None, hierarchy: MeshHierarchy | None = None) -> None:
        super().__init__()
        cfg = config if config is not None else ReconConfig()
        self.config = cfg
        if cfg.encoder == "efficientnet_lite0":
            self.encoder: nn.Module = PretrainedEncoder(cfg.in_channels)
        else:
            self.encoder = ImageEncoder(cfg.in_channels, cfg.widths, cfg.blocks)
        self.latent = nn.Sequential(nn.Linear(sum(cfg.widths), cfg.latent_features), nn.ReLU(inplace=True))
        self.decoder = None
        if cfg.kind == "ism":
            self.decoder = SpiralDecoder(cfg.decoder, hierarchy)
        elif cfg.spiral_decoder:
            residual = replace(cfg.decoder.output, shape_scale_mm=cfg.residual_scale_mm)
            self.decoder = SpiralDecoder(replace(cfg.decoder, output=residual), hierarchy)
            with torch.no_grad():  # zero start: the first mesh is the foot model's
                for head in self.decoder.heads:
                    head.linear.weight.zero_()
                    head.linear.bias.zero_()
        self.parametric = ParametricHead(cfg.latent_features, cfg.parametric_hidden) if cfg.kind == "model" else None
        # the centroid's prior and latent correction (the ISM decoder has its own)
        self.placement = CentredOutput(cfg.latent_features, cfg.decoder.output) if cfg.kind == "model" else None
        self.centre_map = None
        self.surface_map = None
        if cfg.kind in ("ism", "model") and cfg.centre_head in ("anchored", "spatial"):
            # no bias: a softmax over the map ignores a constant added to it, so a bias would never learn
            self.centre_map = nn.Conv2d(cfg.widths[CENTRE_STAGE], 1, kernel_size=1, bias=False)
            # zero start: a uniform map, the centroid on the ray through the image centre
            nn.init.zeros_(self.centre_map.weight)
            if cfg.centre_head == "anchored" and cfg.input != "rgb":
                # where to read the surface depth (zero start: the mean over the cells with depth)
                self.surface_map = nn.Conv2d(cfg.widths[CENTRE_STAGE], 1, kernel_size=1, bias=False)
                nn.init.zeros_(self.surface_map.weight)
        self.centre_refiner = None
        if self.centre_map is not None and cfg.centre_refine:
            self.centre_refiner = CentrePixelHead(cfg.widths, with_depth=cfg.input != "rgb")
        self.generator = EdgeConvGenerator(cfg.edgeconv) if cfg.kind == "edgeconv" else None
        self.trained_submodules: tuple[str, ...] = ()
        """Set by ``train_only``: the submodules that train, the rest frozen; empty: all of it."""
        self.initialised_from_network = False
        """Set when the weights came from another recon network (``train recon --init-from``): its image parts,
        not only an ImageNet encoder, are then the pretrained ones."""

    def train_only(self, names: tuple[str, ...]) -> None:
        """Train only the submodules ``names``: the other parameters get no gradient, and the other modules stay
        in evaluation mode (batch-norm statistics as loaded) when the network is put in training mode."""
        for name in names:
            if not _has_parameters(self, name):
                raise ValueError(f"train_only: this network has no submodule {name!r} with parameters")
        self.trained_submodules = tuple(names)
        for name, parameter in self.named_parameters():
            parameter.requires_grad_(_within(name, names))
        self.train(self.training)

    def train(self, mode: bool = True) -> ReconNet:
        """``nn.Module.train``, the submodules frozen by ``train_only`` kept in evaluation mode."""
        super().train(mode)
        if self.trained_submodules:
            for name, module in self.named_modules():
                if name and not _within(name, self.trained_submodules):
                    module.training = False  # not .eval(): that would reach the trained modules inside
        return self

    @property
    def pretrained_submodules(self) -> tuple[str, ...]:
        """Submodules that start from pretrained weights (``TrainConfig.pretrained_lr_scale`` applies to them)."""
        if not self.initialised_from_network:
            return ("encoder",) if self.config.encoder == "efficientnet_lite0" else ()
        # the residual decoder's coordinate heads start at zero (copy_matching): new, like the model head
        copied_decoder = ("decoder.project", "decoder.skip_projections", "decoder.blocks")
        names = ("encoder", "latent", "centre_map", "surface_map")
        names += copied_decoder if self.config.kind == "model" else ("decoder",)
        return tuple(n for n in names if _has_parameters(self, n))

    @property
    def faces(self) -> torch.Tensor:
        """(F, 3) faces of the output mesh (left-foot winding; ISM and model only)."""
        if self.config.kind == "edgeconv":
            raise ValueError("the EdgeConv baseline outputs a point cloud, not a mesh")
        return default_model().faces_left if self.decoder is None else self.decoder.faces

    def forward(
        self,
        x: torch.Tensor,
        K: torch.Tensor,
        depth_ref_mm: torch.Tensor | None = None,
        right: torch.Tensor | None = None,
    ) -> DecoderOutput | PointCloudOutput:
        """Reconstruct a batch.

        Args:
            x: (B, C, S, S) from ``recon_input`` (without the coordinate channels).
            K: (B, 3, 3) intrinsics of the input images, px of the S x S input (``geometry.camera``).
            depth_ref_mm: (B,) the depth maps' medians (``recon_input``); None for RGB.
            right: (B,) bool, the side when it is known (training; a side the user gave); None: the network's
                own left/right prediction (``kind="model"`` only; the other kinds ignore it).
        Returns:
            ``DecoderOutput`` (vertices (B, 4002, 3), centre, levels), ``ModelOutput`` (``kind="model"``: also the
            foot model's mesh and parameters) or ``PointCloudOutput`` (points (B, N, 3), centre), mm, camera frame.
        """
        cfg = self.config
        want = INPUT_CHANNELS[cfg.input]
        if x.dim() != 4 or x.shape[1] != want or x.shape[2:] != (cfg.image_size, cfg.image_size):
            raise ValueError(
                f"input must be (B, {want}, {cfg.image_size}, {cfg.image_size}) for {cfg.input}, got {tuple(x.shape)}"
            )
        if K.shape != (x.shape[0], 3, 3):
            raise ValueError(f"K must be (B, 3, 3) = ({x.shape[0]}, 3, 3), got {tuple(K.shape)}")
        scale = frame_scale(cfg.input, K.to(x.dtype), depth_ref_mm, cfg.image_size)
        depth_channel = x[:, -1:] if cfg.input != "rgb" else None  # (recon_input puts the depth channel last)
        if cfg.coord_channels:
            x = torch.cat([x, _coordinates(x)], dim=1)
        features = self.encoder(x)
        pooled = [f.mean(dim=(2, 3)) for f in features]  # (B, w_k), finest first
        latent = self.latent(torch.cat(pooled, dim=1))
        K = K.to(x.dtype)

        def camera(p: torch.Tensor) -> torch.Tensor:
            return to_camera(p, K, scale, cfg.image_size)

        if self.generator is not None:
            out = self.generator(latent)
            return PointCloudOutput(camera(out.points), camera(out.centre[:, None])[:, 0])
        skips = pooled[::-1] if cfg.decoder.skip_in_channels else None
        centre = None
        if self.centre_map is not None:
            centre = self._spatial_centre(features, latent, depth_channel)
        if self.parametric is not None:
            log_mm_per_unit = torch.log(scale * FOCAL_REF * cfg.image_size / K[:, 0, 0])
            return self._model_output(latent, log_mm_per_unit, skips, centre, camera, right)
        out = self.decoder(latent, skips, centre)
        levels = tuple(camera(level) for level in out.levels)
        return DecoderOutput(levels[0], camera(out.centre[:, None])[:, 0], levels)

    def _model_output(self, latent, log_mm_per_unit, skips, centre, camera, right: torch.Tensor | None) -> ModelOutput:
        """The foot model's mesh from the predicted parameters, its centroid at ``centre`` (normalised frame; None:
        from the latent), plus the residual decoder's per-vertex offsets."""
        parameters = self.parametric(latent, log_mm_per_unit)
        if right is None:
            right = parameters.right_logit > 0
        elif right.shape != parameters.right_logit.shape:
            raise ValueError(f"right must be (B,) = ({latent.shape[0]},), got {tuple(right.shape)}")
        right = right.bool()
        centred, _ = ParametricHead.mesh(parameters, right)
        centre = camera((self.placement.centre(latent) if centre is None else centre)[:, None])[:, 0]
        model_vertices = centred + centre[:, None]
        vertices = model_vertices
        if self.decoder is not None:
            zero = torch.zeros_like(centre)
            # to_camera is linear: offsets in the normalised frame become offsets in mm
            vertices = model_vertices + camera(self.decoder(latent, skips, zero).vertices)
        return ModelOutput(vertices, centre, (vertices,), model_vertices, parameters, right)

    def _centre_prior(self, latent: torch.Tensor) -> torch.Tensor:
        """(B, 3) the latent's centroid (normalised frame): the ISM decoder's head, or the model kind's own."""
        return (self.placement if self.placement is not None else self.decoder.output).centre(latent)

    def _spatial_centre(
        self, features: list[torch.Tensor], latent: torch.Tensor, depth_channel: torch.Tensor | None = None
    ) -> torch.Tensor:
        """The centroid (B, 3) in the normalised frame: its pixel by a soft-argmax of ``centre_map`` over the
        stride-8 features (corrected by ``centre_refiner``, when the network has one), its depth C from the
        decoder's centroid head (its A and B outputs unused), or, anchored, the surface depth read off
        ``depth_channel`` (B, 1, S, S) plus that head's offset."""
        size = self.config.image_size
        feature = features[CENTRE_STAGE]
        b, _, h, w = feature.shape
        logits = self.centre_map(feature)
        stride = size / w
        cols = (torch.arange(w, dtype=feature.dtype, device=feature.device) + 0.5) * stride - 0.5
        rows = (torch.arange(h, dtype=feature.dtype, device=feature.device) + 0.5) * stride - 0.5
        u_cells, v_cells = cols.expand(b, h, w), rows[:, None].expand(b, h, w)
        if self.centre_refiner is not None:
            correction, offsets = self.centre_refiner(features, depth_channel)
            logits = logits + correction
            u_cells, v_cells = u_cells + stride * offsets[:, 0], v_cells + stride * offsets[:, 1]
        prob = logits.flatten(1).softmax(dim=1)
        u = (prob * u_cells.flatten(1)).sum(dim=1)
        v = (prob * v_cells.flatten(1)).sum(dim=1)
        depth = self._centre_prior(latent)[:, 2]
        if self.surface_map is not None and depth_channel is not None:
            depth = depth - DEPTH_REF_MM + self._surface_depth(self.surface_map(feature), depth_channel)
        c0, f_ref = (size - 1) / 2, FOCAL_REF * size
        return torch.stack([(u - c0) * depth / f_ref, (v - c0) * depth / f_ref, depth], dim=-1)

    @staticmethod
    def _surface_depth(logits: torch.Tensor, depth_channel: torch.Tensor) -> torch.Tensor:
        """(B,) normalised depth C of the surface: the mean of ``depth_channel``'s measured depth per cell of the
        (B, 1, h, w) ``logits``, weighted by their softmax over the cells that have any."""
        stride = depth_channel.shape[-1] // logits.shape[-1]
        valid = (depth_channel != 0).to(depth_channel.dtype)  # recon_input feeds missing depth as 0
        count = nn.functional.avg_pool2d(valid, stride)
        relative = nn.functional.avg_pool2d(depth_channel * valid, stride) / count.clamp_min(1e-6)
        surface = DEPTH_REF_MM * (1.0 + relative / DEPTH_GAIN)  # C = Z / s, s = median / DEPTH_REF_MM
        weight = logits.masked_fill(count == 0, -1e4).flatten(1).softmax(dim=1)
        return (weight * surface.flatten(1)).sum(dim=1)

    def extra_repr(self) -> str:
        n = sum(p.numel() for p in self.parameters())
        return f"input={self.config.input}, kind={self.config.kind}, parameters={n}"


def _within(name: str, submodules: tuple[str, ...]) -> bool:
    """Whether the parameter or module ``name`` lies in one of ``submodules``."""
    return any(name == s or name.startswith(s + ".") for s in submodules)


def _has_parameters(module: nn.Module, name: str) -> bool:
    try:
        return any(True for _ in module.get_submodule(name).parameters())
    except AttributeError:
        return False


def _coordinates(x: torch.Tensor) -> torch.Tensor:
    """(B, 2, H, W): each pixel's normalised x and y in [-1, 1] (pixel centres)."""
    b, _, h, w = x.shape
    ys = (torch.arange(h, dtype=x.dtype, device=x.device) + 0.5) * (2 / h) - 1
    xs = (torch.arange(w, dtype=x.dtype, device=x.device) + 0.5) * (2 / w) - 1
    grid = torch.stack([xs.view(1, w).expand(h, w), ys.view(h, 1).expand(h, w)])
    return grid.unsqueeze(0).expand(b, -1, -1, -1)


@torch.no_grad()
def predict_batch(
    model: ReconNet,
    rgb: np.ndarray | None,
    depth_mm: np.ndarray | None,
    K: np.ndarray,
    right: np.ndarray | None = None,
    mirror_average: bool = False,
) -> DecoderOutput | PointCloudOutput:
    """Reconstruct a batch already at the network's side: ``rgb`` (B, S, S, 3) uint8, ``depth_mm`` (B, S, S) mm,
    ``K`` (B, 3, 3) px of that side, ``right`` (B,) bool when the sides are known; the images the input kind does
    not use may be None. Outputs in mm.

    ``mirror_average``: the vertices are the average of the network's answer for each image and its answer for the
    mirror image, mirrored back (x -> -x in the camera frame; the mirrored foot is built for the other side); the
    other outputs are the image's own. Meshes only (not EdgeConv's points)."""
    cfg = model.config
    t_rgb = None if rgb is None else torch.from_numpy(np.ascontiguousarray(rgb)).permute(0, 3, 1, 2).float() / 255
    t_depth = None if depth_mm is None else torch.from_numpy(np.asarray(depth_mm, np.float32))[:, None]
    x, ref = recon_input(cfg.input, t_rgb, t_depth)
    sides = None if right is None else torch.as_tensor(np.asarray(right, dtype=bool))
    k = torch.as_tensor(np.asarray(K), dtype=torch.float32)
    out = model(x, k, ref, sides)
    if not mirror_average or isinstance(out, PointCloudOutput):
        return out
    k_mirror = k.clone()
    k_mirror[:, 0, 2] = (x.shape[-1] - 1) - k[:, 0, 2]  # pixel centres: u -> S - 1 - u
    own_sides = out.right if isinstance(out, ModelOutput) else sides
    mirrored = model(x.flip(-1), k_mirror, ref, None if own_sides is None else ~own_sides)
    vertices = 0.5 * (out.vertices + mirrored.vertices * torch.tensor([-1.0, 1.0, 1.0]))
    return replace(out, vertices=vertices, centre=vertices.mean(dim=1))
