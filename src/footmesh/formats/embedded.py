"""A depth map stored inside a photo file, and how it becomes millimetres of camera z aligned with the photo.

Phones store depth beside the photo in a few containers (the HEIF depth image of iPhones, the GDepth and
Dynamic Depth XMP of Android cameras). Each container's reader (``formats.heif``, ``formats.android``) returns
an :class:`EmbeddedDepth`: the stored samples scaled to 0..1, what they represent and the metric range they
span. :func:`align_depth` turns that into the ``(H, W) float32`` millimetres the pipeline takes, or says why the
depth cannot give millimetres (relative disparity, no metric range, implausible range), in which case the photo
is measured as RGB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

Representation = Literal[
    "uniform_inverse_z",  # HEIF / HEVC type 0: 1/z uniform in [1/z_far, 1/z_near]; the largest sample is nearest
    "uniform_disparity",  # HEIF / HEVC type 1: disparity, relative without a stereo baseline
    "uniform_z",  # HEIF / HEVC type 2: z uniform in [z_near, z_far]; sample 0 is nearest
    "nonuniform_disparity",  # HEIF / HEVC type 3
    "range_linear",  # GDepth / Dynamic Depth RangeLinear: d = near + v (far - near)
    "range_inverse",  # GDepth / Dynamic Depth RangeInverse: d = far near / (far - v (far - near))
]
METRIC_REPRESENTATIONS = ("uniform_inverse_z", "uniform_z", "range_linear", "range_inverse")
"""Representations that give millimetres once the file states their near and far limits."""
NEAR_FAR_RANGE_M = (0.01, 100.0)
"""Near and far limits outside this range (metres) are taken for a broken or non-metric file."""
MIN_CONFIDENCE = 1.0 / 3.0
"""Depth samples whose confidence (scaled to 0..1) is below this are dropped: the lowest third of the scale,
which is ARKit's "low" of low / medium / high."""
MAX_ASPECT_MISMATCH = 0.02
"""An embedded depth map whose aspect ratio differs from the photo's by more than this (2 %) does not cover the
same field of view (a cropped photo) and is not used."""


@dataclass(frozen=True, eq=False)
class EmbeddedDepth:
    """A depth image as a photo file stores it: samples scaled to 0..1, what they represent, and their range.

    ``samples`` and ``confidence`` are as stored (before the photo's EXIF orientation), unless ``upright``.
    """

    samples: np.ndarray  # (h, w) float32 in 0..1: stored value / largest value of its bit depth
    representation: Representation
    near_m: float | None  # the range the samples span, metres (None: the file does not say)
    far_m: float | None
    container: str  # "HEIF depth image", "GDepth XMP", "Dynamic Depth", for people
    bits: int  # bits per stored sample
    measure: Literal["optical_axis", "optic_ray"] = "optical_axis"  # z, or distance along the pixel's ray
    confidence: np.ndarray | None = None  # (hc, wc) float32 in 0..1, 1 = sure; any size, resized to the depth
    upright: bool = False  # the container already applied the photo's orientation

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) px as stored."""
        return self.samples.shape[1], self.samples.shape[0]

    def why_not_metric(self) -> str | None:
        """Why these samples cannot give millimetres, or None when they can."""
        if self.representation not in METRIC_REPRESENTATIONS:
            return (
                f"its {self.container} is {self.representation.replace('_', ' ')}, which is relative (no metric range)"
            )
        if self.near_m is None or self.far_m is None:
            return (
                f"its {self.container} ({self.representation.replace('_', ' ')}) does not state its near and far range"
            )
        lo, hi = NEAR_FAR_RANGE_M
        finite = math.isfinite(self.near_m) and math.isfinite(self.far_m)
        if not (finite and lo <= self.near_m < self.far_m <= hi):
            return (
                f"its {self.container} states a range of {self.near_m:g}-{self.far_m:g} m, which is not a metric "
                f"depth range ({lo:g}-{hi:g} m, near below far)"
            )
        return None

    def metres(self) -> np.ndarray:
        """(h, w) float32 metres as stored, NaN where the sample says nothing; requires ``why_not_metric() is None``."""
        v = self.samples.astype(np.float64)
        near, far = float(self.near_m), float(self.far_m)  # type: ignore[arg-type]
        if self.representation in ("uniform_z", "range_linear"):
            z = near + v * (far - near)
        elif self.representation == "uniform_inverse_z":
            z = near * far / (near + v * (far - near))
        elif self.representation == "range_inverse":
            z = far * near / (far - v * (far - near))
        else:
            raise ValueError(f"{self.representation} is not a metric representation")
        return z.astype(np.float32)


@dataclass(frozen=True)
class DepthSource:
    """Where a photo's depth map came from and what it was, for ``result.json["depth"]``."""

    source: Literal["file", "embedded"]
    container: str  # "depth map file", "HEIF depth image", "GDepth XMP", "Dynamic Depth"
    representation: str  # "millimetres" for a file, else the embedded representation
    near_mm: float | None = None
    far_mm: float | None = None
    bits: int | None = None
    stored_size: tuple[int, int] | None = None  # (width, height) px of the embedded map as stored
    dropped_low_confidence: float | None = None  # fraction of the stored samples dropped for low confidence

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {
            "source": self.source,
            "container": self.container,
            "representation": self.representation,
            "near_mm": self.near_mm,
            "far_mm": self.far_mm,
            "bits": self.bits,
            "stored_size": None if self.stored_size is None else list(self.stored_size),
            "dropped_low_confidence": self.dropped_low_confidence,
        }


def orient(array: np.ndarray, orientation: int) -> np.ndarray:
    """``array`` (h, w[, c]) turned as EXIF orientation 1..8 turns the photo it belongs to (what a viewer shows)."""
    # the transposes of PIL.ImageOps.exif_transpose: 6 = ROTATE_270 (clockwise), 7 = TRANSVERSE, 8 = ROTATE_90
    ops = {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1, :],
        5: lambda a: np.swapaxes(a, 0, 1),
        6: lambda a: np.rot90(a, -1),
        7: lambda a: np.swapaxes(a[::-1, ::-1], 0, 1),
        8: lambda a: np.rot90(a, 1),
    }
    if orientation not in ops:
        raise ValueError(f"EXIF orientation must be 1..8, got {orientation}")
    return np.ascontiguousarray(ops[orientation](array))


def align_depth(
    depth: EmbeddedDepth, orientation: int, photo_size: tuple[int, int], fx: float, fy: float, cx: float, cy: float
) -> tuple[np.ndarray | None, DepthSource | None, str | None]:
    """(depth mm aligned with the upright photo, its DepthSource, None) or (None, None, why it is not used).

    ``orientation``: the EXIF orientation applied to the photo (the depth is turned the same way unless
    ``depth.upright``); ``photo_size`` = (W, H) of the upright photo; fx, fy, cx, cy: its intrinsics (px), used
    only to turn distances along rays into z. Nearest-neighbour upsampling: interpolating across a depth edge would
    invent points between the foot and the floor.
    """
    import cv2  # only photos with embedded depth pay its import

    why = depth.why_not_metric()
    if why is not None:
        return None, None, why
    metres = depth.metres()
    stored = depth.samples.shape
    # the first and last codes hold everything nearer than near or farther than far: clipped, not measured
    clipped = (depth.samples <= 0.0) | (depth.samples >= 1.0)
    keep = np.isfinite(metres) & (metres > 0) & ~clipped
    dropped = None
    if depth.confidence is not None:
        conf = depth.confidence
        if conf.shape != stored:
            conf = cv2.resize(conf.astype(np.float32), (stored[1], stored[0]), interpolation=cv2.INTER_NEAREST)
        low = conf < MIN_CONFIDENCE
        dropped = float(low.mean())
        keep &= ~low
    metres = np.where(keep, metres, 0.0).astype(np.float32)
    W, H = photo_size
    turned = orientation in (5, 6, 7, 8)
    # a quarter turn of a non-square map shows whether the container turned it already (its own irot)
    already_upright = turned and _same_aspect(metres.shape[1], metres.shape[0], W, H) and W != H
    if not (depth.upright or already_upright):
        metres = orient(metres, orientation)
    h, w = metres.shape
    if not _same_aspect(w, h, W, H):
        return (
            None,
            None,
            (
                f"its {depth.container} is {w} x {h} px (upright), another aspect ratio than the {W} x {H} px photo "
                "(a cropped photo?), so it does not cover the same view"
            ),
        )
    mm = cv2.resize(metres * 1000.0, (W, H), interpolation=cv2.INTER_NEAREST)
    if depth.measure == "optic_ray":  # distance along each pixel's ray -> z
        u = (np.arange(W, dtype=np.float32) - cx) / fx
        v = (np.arange(H, dtype=np.float32) - cy) / fy
        mm = mm / np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2)
    source = DepthSource(
        source="embedded",
        container=depth.container,
        representation=depth.representation,
        near_mm=round(float(depth.near_m) * 1000.0, 3),  # type: ignore[arg-type]
        far_mm=round(float(depth.far_m) * 1000.0, 3),  # type: ignore[arg-type]
        bits=depth.bits,
        stored_size=depth.size,
        dropped_low_confidence=None if dropped is None else round(dropped, 4),
    )
    return mm.astype(np.float32), source, None


def _same_aspect(w: int, h: int, W: int, H: int) -> bool:
    return abs((w / h) / (W / H) - 1.0) <= MAX_ASPECT_MISMATCH
