"""Synthetic samples in memory at the network's resolution, and batches with augmentation for real photos.

A dataset folder of ``footmesh synth`` is read once into arrays resized to the network's input side and cached
beside it (``cues-cache-<S>/*.npy``, memory-mapped afterwards), because decompressing the chunk files every epoch
would cost more than the network on a 2-core machine. Augmentation runs on whole batches in torch.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812

from footmesh.geometry.camera import rescale_pixels
from footmesh.report import atomic_path

SAMPLE_KEYS = ("rgb", "depth", "silhouette", "joints2d", "joints_visible", "view_id", "side")
"""What the cache keeps of each synthetic sample (and its ``index``)."""
CACHE_KEYS = ("rgb", "depth", "silhouette", "joints2d", "joints_visible", "view_id", "side", "index")


def resize_joints(joints: np.ndarray, src: int, dst: int) -> np.ndarray:
    """Pixel coordinates (centre of the top-left pixel at 0) of a ``src``-side image in a ``dst``-side resize."""
    return rescale_pixels(joints, dst / src)


def resize_sample(sample: dict[str, np.ndarray], size: int) -> dict[str, np.ndarray]:
    """One synthetic sample (``rgb``, ``depth``, ``silhouette``, ``joints2d``...) resized to ``size`` x ``size``.

    RGB by area averaging; depth by nearest neighbour (no blending of missing pixels or across edges); the
    silhouette as its area coverage in [0, 255] (a soft target); joints scaled.
    """
    src = sample["rgb"].shape[0]
    out = dict(sample)
    if src != size:
        out["rgb"] = cv2.resize(sample["rgb"], (size, size), interpolation=cv2.INTER_AREA)
        out["depth"] = cv2.resize(sample["depth"], (size, size), interpolation=cv2.INTER_NEAREST)
        out["joints2d"] = resize_joints(sample["joints2d"], src, size).astype(np.float32)
    sil = sample["silhouette"].astype(np.float32)
    if src != size:
        sil = cv2.resize(sil, (size, size), interpolation=cv2.INTER_AREA)
    out["silhouette"] = np.round(sil * 255).astype(np.uint8)
    return out


@dataclass
class CuesArrays:
    """Samples of one folder at side ``size``: ``rgb`` (N, S, S, 3) uint8, ``depth`` (N, S, S) uint16 mm,
    ``silhouette`` (N, S, S) uint8 coverage x 255, ``joints2d`` (N, 18, 2) px, ``joints_visible`` (N, 18) bool,
    ``view_id`` (N,), ``side`` (N,) int8 (1 = right foot), ``index`` (N,)."""

    rgb: np.ndarray
    depth: np.ndarray
    silhouette: np.ndarray
    joints2d: np.ndarray
    joints_visible: np.ndarray
    view_id: np.ndarray
    side: np.ndarray
    index: np.ndarray
    size: int

    def __len__(self) -> int:
        return len(self.index)

    def subset(self, rows: np.ndarray) -> CuesArrays:
        return CuesArrays(**{k: getattr(self, k)[rows] for k in CACHE_KEYS}, size=self.size)


def load_arrays(folder: str | os.PathLike, size: int, progress: bool = True) -> CuesArrays:
    """The samples of a synthetic dataset folder at side ``size``, from the cache beside it (built if missing)."""
    from footmesh.synth.dataset import SynthDataset

    folder = Path(folder)
    cache = folder / f"cues-cache-{size}"
    dataset = SynthDataset(folder, keys=list(SAMPLE_KEYS))
    chunks = [[f.name, f.stat().st_size, f.stat().st_mtime_ns] for f in dataset.files]
    stamp = {"samples": len(dataset), "size": size, "chunks": chunks, "keys": list(CACHE_KEYS)}
    if not (cache / "stamp.json").is_file() or json.loads((cache / "stamp.json").read_text()) != stamp:
        _build_cache(dataset, cache, size, stamp, progress)
    arrays = {k: np.load(cache / f"{k}.npy", mmap_mode="r") for k in CACHE_KEYS}
    return CuesArrays(**arrays, size=size)


def _build_cache(dataset, cache: Path, size: int, stamp: dict, progress: bool) -> None:
    from tqdm import tqdm

    n = len(dataset)
    cache.mkdir(parents=True, exist_ok=True)
    (cache / "stamp.json").unlink(missing_ok=True)
    out = {
        "rgb": np.zeros((n, size, size, 3), np.uint8),
        "depth": np.zeros((n, size, size), np.uint16),
        "silhouette": np.zeros((n, size, size), np.uint8),
        "joints2d": np.zeros((n, 18, 2), np.float32),
        "joints_visible": np.zeros((n, 18), bool),
        "view_id": np.zeros(n, np.int16),
        "side": np.zeros(n, np.int8),
        "index": np.asarray(dataset.indices, np.int64),
    }
    for i in tqdm(range(n), desc=f"caching {dataset.root.name} at {size} px", disable=not progress, unit="sample"):
        s = resize_sample(dataset[i], size)
        for k in SAMPLE_KEYS:
            out[k][i] = s[k]
    for k, v in out.items():
        with atomic_path(cache / f"{k}.npy") as tmp, open(tmp, "wb") as f:
            np.save(f, v)
    with atomic_path(cache / "stamp.json") as tmp:
        tmp.write_text(json.dumps(stamp))


@dataclass
class Batch:
    """Float tensors of one batch: ``rgb`` (B, 3, S, S) in [0, 1], ``depth`` (B, 1, S, S) mm (0 = missing),
    ``silhouette`` (B, 1, S, S) in [0, 1], ``joints`` (B, 18, 2) px, ``visible`` (B, 18), ``inside`` (B, 18)
    (the joint lies inside the image, so it can be supervised), ``side`` (B,) 1 for a right foot (as seen: a
    mirrored image shows the other side)."""

    rgb: torch.Tensor
    depth: torch.Tensor
    silhouette: torch.Tensor
    joints: torch.Tensor
    visible: torch.Tensor
    inside: torch.Tensor
    side: torch.Tensor | None = None
    """None: the samples carry no side label (the side head is then not trained on them)."""


def make_batch(arrays: CuesArrays, rows: np.ndarray) -> Batch:
    """The rows of ``arrays`` as a ``Batch`` (no augmentation)."""
    rows = np.sort(rows)  # sorted reads are much faster on memory-mapped arrays
    rgb = torch.from_numpy(np.ascontiguousarray(arrays.rgb[rows])).permute(0, 3, 1, 2).float() / 255
    depth = torch.from_numpy(arrays.depth[rows].astype(np.float32))[:, None]
    sil = torch.from_numpy(np.ascontiguousarray(arrays.silhouette[rows])).float()[:, None] / 255
    joints = torch.from_numpy(np.ascontiguousarray(arrays.joints2d[rows]))
    visible = torch.from_numpy(np.ascontiguousarray(arrays.joints_visible[rows])).float()
    side = torch.from_numpy(arrays.side[rows].astype(np.float32))
    return Batch(rgb, depth, sil, joints, visible, inside_image(joints, arrays.size), side)


def inside_image(joints: torch.Tensor, size: int, margin: float = 0.0) -> torch.Tensor:
    """(B, J) float: 1 where the joint lies within the image (pixel centres -0.5 .. size - 0.5)."""
    lo, hi = -0.5 + margin, size - 0.5 - margin
    return ((joints >= lo) & (joints <= hi)).all(-1).float()


@dataclass(frozen=True)
class Augment:
    """Ranges of the augmentation: geometry for every input, photometric changes of phone photos for RGB."""

    scale: tuple[float, float] = (0.8, 1.25)
    rotate_deg: float = 25.0
    shift: float = 0.08
    """Translation, as a fraction of the image side."""
    flip: float = 0.5
    brightness: tuple[float, float] = (0.6, 1.4)
    contrast: tuple[float, float] = (0.7, 1.3)
    saturation: tuple[float, float] = (0.5, 1.4)
    white_balance: float = 0.1
    noise_sd: tuple[float, float] = (0.0, 0.04)
    blur_p: float = 0.3
    jpeg_p: float = 0.4
    jpeg_quality: tuple[int, int] = (30, 95)
    depth_noise_mm: tuple[float, float] = (0.0, 2.0)
    depth_dropout_p: float = 0.3


def augment_batch(batch: Batch, aug: Augment, generator: torch.Generator) -> Batch:
    """A randomly transformed copy of ``batch`` (same transform for image, depth, silhouette and joints)."""
    b, _, size, _ = batch.rgb.shape

    def uniform(lo: float, hi: float, *shape: int) -> torch.Tensor:
        return lo + (hi - lo) * torch.rand(shape or (b,), generator=generator)

    # affine map from output to input normalised coordinates (affine_grid's theta)
    log_s = uniform(math.log(aug.scale[0]), math.log(aug.scale[1]))
    zoom = torch.exp(log_s)  # > 1 enlarges the foot
    angle = torch.deg2rad(uniform(-aug.rotate_deg, aug.rotate_deg))
    flip = torch.where(torch.rand(b, generator=generator) < aug.flip, -1.0, 1.0)
    shift = uniform(-aug.shift, aug.shift, b, 2) * 2
    cos, sin = torch.cos(angle) / zoom, torch.sin(angle) / zoom
    a = torch.stack([torch.stack([cos * flip, -sin], -1), torch.stack([sin * flip, cos], -1)], -2)  # (B, 2, 2)
    theta = torch.cat([a, shift[..., None]], -1)
    grid = F.affine_grid(theta, [b, 1, size, size], align_corners=False)
    rgb = F.grid_sample(batch.rgb, grid, mode="bilinear", padding_mode="border", align_corners=False)
    depth = F.grid_sample(batch.depth, grid, mode="nearest", padding_mode="border", align_corners=False)
    sil = F.grid_sample(batch.silhouette, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    # joints: input px -> normalised -> invert the affine map -> output px
    norm = (2 * batch.joints + 1) / size - 1
    out_norm = torch.linalg.solve(a, (norm - shift[:, None, :]).transpose(1, 2)).transpose(1, 2)
    joints = ((out_norm + 1) * size - 1) / 2

    rgb = _photometric(rgb, aug, generator, uniform)
    depth = _depth_noise(depth, aug, generator, uniform)
    side = batch.side
    if side is not None:
        side = torch.where(flip < 0, 1.0 - side, side)  # a mirror image shows a foot of the other side
    return Batch(rgb, depth, sil, joints, batch.visible, inside_image(joints, size) * batch.inside, side)


def _photometric(rgb: torch.Tensor, aug: Augment, generator: torch.Generator, uniform) -> torch.Tensor:
    b = rgb.shape[0]
    grey = rgb.mean(1, keepdim=True)
    rgb = grey + (rgb - grey) * uniform(*aug.saturation).view(b, 1, 1, 1)
    mean = rgb.mean((1, 2, 3), keepdim=True)
    rgb = mean + (rgb - mean) * uniform(*aug.contrast).view(b, 1, 1, 1)
    rgb = rgb * uniform(*aug.brightness).view(b, 1, 1, 1)
    rgb = rgb * uniform(1 - aug.white_balance, 1 + aug.white_balance, b, 3, 1, 1)
    blur = torch.rand(b, generator=generator) < aug.blur_p
    if blur.any():
        sigma = float(uniform(0.5, 1.2, 1))
        k = torch.exp(-(torch.arange(-2, 3, dtype=rgb.dtype) ** 2) / (2 * sigma**2))
        k = k / k.sum()
        kernel = (k[:, None] * k[None, :]).expand(3, 1, 5, 5)
        blurred = F.conv2d(F.pad(rgb[blur], (2, 2, 2, 2), mode="replicate"), kernel, groups=3)
        rgb = rgb.clone()
        rgb[blur] = blurred
    rgb = rgb + torch.randn(rgb.shape, generator=generator) * uniform(*aug.noise_sd).view(b, 1, 1, 1)
    rgb = rgb.clamp(0, 1)
    jpeg = (torch.rand(b, generator=generator) < aug.jpeg_p).nonzero().flatten().tolist()
    if jpeg:
        quality = torch.randint(aug.jpeg_quality[0], aug.jpeg_quality[1] + 1, (len(jpeg),), generator=generator)
        rgb = rgb.clone()
        for i, q in zip(jpeg, quality.tolist(), strict=True):
            rgb[i] = jpeg_roundtrip(rgb[i], q)
    return rgb


def jpeg_roundtrip(image: torch.Tensor, quality: int) -> torch.Tensor:
    """(3, H, W) in [0, 1] -> the same after JPEG compression at ``quality`` (the artefacts of phone photos)."""
    arr = (image.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", arr[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
        return image
    dec = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return torch.from_numpy(dec[..., ::-1].copy()).permute(2, 0, 1).float() / 255


def _depth_noise(depth: torch.Tensor, aug: Augment, generator: torch.Generator, uniform) -> torch.Tensor:
    b, _, s, _ = depth.shape
    valid = depth > 0
    noisy = depth + torch.randn(depth.shape, generator=generator) * uniform(*aug.depth_noise_mm).view(b, 1, 1, 1)
    # dropout blobs: low-resolution random masks up-sampled, like the holes of a phone's depth sensor
    drop = torch.rand(b, generator=generator) < aug.depth_dropout_p
    blobs = F.interpolate(torch.rand(b, 1, 8, 8, generator=generator), size=(s, s), mode="bilinear") > 0.85
    keep = valid & ~(blobs & drop.view(b, 1, 1, 1))
    return torch.where(keep, noisy.clamp(min=1.0), torch.zeros_like(depth))
