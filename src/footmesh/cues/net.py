"""The 2D-cues network: stacked encoder-decoders (thesis 3.2) giving a silhouette and 18 joints with confidences.

Each stack is a ResNet-style encoder (strides 2 to 16 of the input) and a bilinear decoder with encoder skips
back to stride 2; the stacks refine each other's predictions (intermediate supervision, Newell et al.). Heads:

- ``sigmoid`` (the thesis): 1 + 18 maps, each a per-pixel sigmoid, trained with binary cross-entropy against the
  silhouette and Gaussian bumps; joints are read off as the arg-max and its value is the confidence;
- ``soft_argmax`` (our default): the silhouette as above; per joint a heatmap whose softmax gives the joint as its
  expected position (sub-pixel, differentiable; Sun et al., "Integral human pose regression"), and a visibility
  logit averaged under that distribution, so each joint comes with the probability that it is visible.

``encoder="efficientnet_lite0"`` replaces the stacks by an ImageNet-pretrained EfficientNet-Lite0 and an FPN
decoder (``PretrainedCuesNet``), with the same heads and a left/right logit; ``build_network`` picks the class.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

from footmesh.config import CuesNetConfig

NUM_JOINTS = 18
HEATMAP_STRIDE = 4
"""Input pixels per heatmap pixel."""
SILHOUETTE_STRIDE = 2
"""Input pixels per silhouette-map pixel."""


@dataclass
class CuesOutput:
    """One stack's predictions for a ``(B, C, S, S)`` input.

    ``silhouette_logits`` (B, 1, S/2, S/2); ``heatmap_logits`` (B, 18, S/4, S/4); ``joints`` (B, 18, 2) in input
    pixels (centre of the top-left pixel at 0); ``visibility_logits`` (B, 18).
    """

    silhouette_logits: torch.Tensor
    heatmap_logits: torch.Tensor
    joints: torch.Tensor
    visibility_logits: torch.Tensor
    side_logits: torch.Tensor | None = None
    """(B,) logit that the foot is a right foot; None for networks without a side head."""


def conv_bn_relu(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class BasicBlock(nn.Module):
    """ResNet-18's residual block (He et al. 2016): two 3x3 convolutions and a projected shortcut."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.shortcut = None
        if stride != 1 or cin != cout:
            self.shortcut = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        y = self.bn2(self.conv2(y))
        return F.relu(y + (x if self.shortcut is None else self.shortcut(x)), inplace=True)


def _stage(cin: int, cout: int, blocks: int, stride: int) -> nn.Sequential:
    return nn.Sequential(BasicBlock(cin, cout, stride), *[BasicBlock(cout, cout) for _ in range(blocks - 1)])


class EncoderDecoder(nn.Module):
    """One stack: ``(B, w0, S/4, S/4) -> (B, w0, S/4, S/4)`` features through strides 4..32 and back.

    The encoder is ResNet-18's layout (stages at strides 4, 8, 16, 32); the decoder up-samples bilinearly and adds
    each encoder skip through a 1x1 projection before a 3x3 convolution (FPN-style; concatenating the skips, as the
    thesis does, costs twice the multiply-adds at the finest level for no measured gain on 2 cores).
    """

    def __init__(self, widths: tuple[int, ...], blocks: tuple[int, ...], decoder_convs: int) -> None:
        super().__init__()
        w = widths
        self.enc = nn.ModuleList(
            [_stage(w[0], w[0], blocks[0], 1)] + [_stage(w[i - 1], w[i], blocks[i], 2) for i in range(1, 4)]
        )
        # decoder_convs 3x3 convolutions: one on the deepest features, one after each of the 3 up-samplings, the
        # rest at the output resolution
        self.bottom = conv_bn_relu(w[3], w[3])
        self.project = nn.ModuleList([nn.Conv2d(w[i + 1], w[i], 1) for i in (2, 1, 0)])
        self.up = nn.ModuleList([conv_bn_relu(w[i], w[i]) for i in (2, 1, 0)])
        self.out = nn.Sequential(*[conv_bn_relu(w[0], w[0]) for _ in range(max(decoder_convs - 4, 0))])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for stage in self.enc:
            x = stage(x)
            skips.append(x)
        y = self.bottom(skips[-1])
        for project, conv, skip in zip(self.project, self.up, reversed(skips[:-1]), strict=True):
            y = F.interpolate(project(y), size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = conv(y + skip)
        return self.out(y)


class CuesNet(nn.Module):
    """``forward(x (B, C, S, S)) -> list of CuesOutput``, one per stack; the last is the prediction.

    The stem brings the input to stride 4 (ResNet-18's stem); the stacks work at strides 4..32; joints are read
    from stride-4 heatmaps (sub-pixel by soft-argmax); the silhouette is refined at stride 2 from the stem's first
    features, so that its outline is not limited by the stride-4 maps.
    """

    def __init__(self, config: CuesNetConfig) -> None:
        super().__init__()
        self.config = config
        w0 = config.widths[0]
        half = max(w0 // 2, 16)
        self.stem1 = conv_bn_relu(config.in_channels, half, stride=2)
        self.stem2 = nn.Sequential(conv_bn_relu(half, w0, stride=2), conv_bn_relu(w0, w0))
        self.stacks = nn.ModuleList(
            [EncoderDecoder(config.widths, config.blocks, config.decoder_convs) for _ in range(config.stacks)]
        )
        maps = head_channels(config)
        self.heads = nn.ModuleList([nn.Conv2d(w0, maps, 1) for _ in range(config.stacks)])
        # the next stack sees this stack's features and predictions (Newell et al.'s re-injection)
        self.remap_features = nn.ModuleList([nn.Conv2d(w0, w0, 1) for _ in range(config.stacks - 1)])
        self.remap_maps = nn.ModuleList([nn.Conv2d(maps, w0, 1) for _ in range(config.stacks - 1)])
        self.refine = nn.Sequential(conv_bn_relu(half + 1, half), nn.Conv2d(half, 1, 3, 1, 1))

    def forward(self, x: torch.Tensor) -> list[CuesOutput]:
        fine = self.stem1(x)
        x = self.stem2(fine)
        outputs = []
        for k, (stack, head) in enumerate(zip(self.stacks, self.heads, strict=True)):
            features = stack(x)
            maps = head(features)
            outputs.append(self._decode(maps, fine))
            if k < len(self.stacks) - 1:
                x = x + self.remap_features[k](features) + self.remap_maps[k](maps)
        return outputs

    def _decode(self, maps: torch.Tensor, fine: torch.Tensor) -> CuesOutput:
        return decode_maps(self.config, maps, fine, self.refine)


def head_channels(config: CuesNetConfig) -> int:
    """Channels of the stride-4 output maps: silhouette, joint heatmaps (and visibility logits with soft-argmax)."""
    return 1 + NUM_JOINTS + (NUM_JOINTS if config.head == "soft_argmax" else 0)


def decode_maps(
    config: CuesNetConfig,
    maps: torch.Tensor,
    fine: torch.Tensor,
    refine: nn.Module,
    side_logits: torch.Tensor | None = None,
) -> CuesOutput:
    """Stride-4 ``maps`` and stride-2 ``fine`` features -> silhouette refined at stride 2, joints, visibility."""
    coarse = F.interpolate(maps[:, :1], size=fine.shape[-2:], mode="bilinear", align_corners=False)
    silhouette = coarse + refine(torch.cat([fine, coarse], dim=1))
    heat = maps[:, 1 : 1 + NUM_JOINTS]
    if config.head == "soft_argmax":
        joints, prob = soft_argmax(heat)
        vis = (maps[:, 1 + NUM_JOINTS :] * prob).flatten(2).sum(-1)
    else:
        joints, peak = hard_argmax(heat)
        vis = peak  # the sigmoid map's peak logit is the thesis' confidence
    joints = (joints + 0.5) * HEATMAP_STRIDE - 0.5  # heatmap pixels -> input pixels
    return CuesOutput(silhouette, heat, joints, vis, side_logits)


class PretrainedCuesNet(nn.Module):
    """``forward(x (B, C, S, S)) -> [CuesOutput]``: EfficientNet-Lite0 features at strides 2-32, an FPN decoder
    (Lin et al. 2017: 1x1 laterals added top-down, one 3x3 convolution per level) to stride 4, the cues heads, and
    a left/right logit from the globally pooled stride-32 features.

    ``pretrained=True`` loads the ImageNet weights from the installed package (training from them); a network read
    from a weights file is built with ``pretrained=False`` and gets everything from that file.
    """

    pretrained_submodules = ("encoder",)
    """Parts that start from ImageNet weights (``TrainConfig.pretrained_lr_scale`` applies to them)."""

    def __init__(self, config: CuesNetConfig, pretrained: bool = False) -> None:
        super().__init__()
        from footmesh.cues.efficientnet import PYRAMID_CHANNELS, EfficientNetLite0Features

        self.config = config
        self.encoder = EfficientNetLite0Features(config.in_channels)
        if pretrained:
            self.encoder.load_pretrained()
        width = config.decoder_width
        fine = PYRAMID_CHANNELS[0]
        self.laterals = nn.ModuleList([nn.Conv2d(c, width, 1) for c in PYRAMID_CHANNELS[1:]])
        self.smooth = nn.ModuleList([conv_bn_relu(width, width) for _ in PYRAMID_CHANNELS[1:-1]])
        self.out = nn.Sequential(*[conv_bn_relu(width, width) for _ in range(max(config.decoder_convs - 3, 1))])
        self.head = nn.Conv2d(width, head_channels(config), 1)
        self.refine = nn.Sequential(conv_bn_relu(fine + 1, fine), nn.Conv2d(fine, 1, 3, 1, 1))
        self.side = nn.Linear(PYRAMID_CHANNELS[-1], 1)

    def forward(self, x: torch.Tensor) -> list[CuesOutput]:
        fine, *pyramid = self.encoder(x)
        y = self.laterals[-1](pyramid[-1])
        for lateral, smooth, skip in zip(self.laterals[-2::-1], self.smooth[::-1], pyramid[-2::-1], strict=True):
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = smooth(y + lateral(skip))
        maps = self.head(self.out(y))
        side = self.side(pyramid[-1].mean((2, 3)))[:, 0]
        return [decode_maps(self.config, maps, fine, self.refine, side)]


def build_network(config: CuesNetConfig, pretrained: bool = False) -> nn.Module:
    """The cues network of ``config.encoder`` (``pretrained``: start the pretrained encoder from ImageNet)."""
    if config.encoder == "efficientnet_lite0":
        return PretrainedCuesNet(config, pretrained=pretrained)
    return CuesNet(config)


def _grid(h: int, w: int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    ys = torch.arange(h, dtype=like.dtype, device=like.device)
    xs = torch.arange(w, dtype=like.dtype, device=like.device)
    return xs, ys


def soft_argmax(heat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Expected (x, y) of softmax(heat) per map: ``(B, J, H, W) -> (B, J, 2)`` map pixels, and the softmax."""
    b, j, h, w = heat.shape
    prob = torch.softmax(heat.flatten(2), dim=-1).view(b, j, h, w)
    xs, ys = _grid(h, w, heat)
    x = (prob.sum(2) * xs).sum(-1)
    y = (prob.sum(3) * ys).sum(-1)
    return torch.stack([x, y], dim=-1), prob


def hard_argmax(heat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(x, y) of each map's maximum: ``(B, J, H, W) -> (B, J, 2)`` map pixels, and the maximum (B, J)."""
    b, j, h, w = heat.shape
    peak, idx = heat.flatten(2).max(-1)
    return torch.stack([(idx % w).to(heat.dtype), (idx // w).to(heat.dtype)], dim=-1), peak


def gaussian_targets(joints: torch.Tensor, inside: torch.Tensor, size: int, sigma: float) -> torch.Tensor:
    """Gaussian bumps (peak 1) at ``joints`` (B, J, 2) given in map pixels -> (B, J, size, size); 0 where not inside."""
    xs = torch.arange(size, dtype=joints.dtype, device=joints.device)
    gx = torch.exp(-((xs - joints[..., 0:1]) ** 2) / (2 * sigma**2))  # (B, J, W)
    gy = torch.exp(-((xs - joints[..., 1:2]) ** 2) / (2 * sigma**2))  # (B, J, H)
    return gy[..., :, None] * gx[..., None, :] * inside[..., None, None].to(joints.dtype)


def num_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
