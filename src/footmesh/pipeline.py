"""The whole job on one photo: load -> cues -> fit -> canonical -> measure -> sizes -> report.

``measure_photo(image, out_dir, depth=..., intrinsics=..., side=...)`` writes ``result.json``, ``mesh.obj``,
``mesh.glb``, ``canonical.obj`` and ``overlay.png`` into ``out_dir`` and returns the result dictionary (the JSON
contract of ``footmesh measure``, docs/measure.md). A photo that cannot be measured raises
``footmesh.errors.Refusal`` (what was seen and what to retake; the refusals themselves are ``footmesh.refusals``);
options that cannot be used raise ``InputError``.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import cv2
import numpy as np
import torch

from footmesh import __version__, references, refusals, report, viz
from footmesh.config import MeasureConfig
from footmesh.cues import Cues
from footmesh.cues.floor import depth_floor
from footmesh.cues.predict import average_cues, predict_cues, right_probabilities, turned, turned_back
from footmesh.cues.refine import clear_paper, height_image, refine_silhouette
from footmesh.cues.trim import foot_axes, trim_silhouette
from footmesh.cues.weights import network_for as cues_network
from footmesh.errors import InputError, Refusal
from footmesh.geometry.camera import Camera, pixel_rays, project, rescale_pixels, turned_frame, turned_pixels
from footmesh.load import Photo, load_photo
from footmesh.measure import FootLandmarks, Measurements, measure_foot
from footmesh.model import skeleton as sk
from footmesh.model.layer import default_model
from footmesh.report import request_options
from footmesh.result import FootEntry, MeasureResult
from footmesh.sizes import length_advice, shoe_sizes
from footmesh.threads import PIPELINE_THREADS, fixed_threads, torch_threads
from footmesh.uncertainty import measurement_uncertainty

if TYPE_CHECKING:
    from footmesh.cues.reference import ReferenceObject

log = logging.getLogger("footmesh.pipeline")


@dataclass(frozen=True)
class CropBox:
    """A square window ``[x0, x0 + side) x [y0, y0 + side)`` of an image, px (may reach past its edges)."""

    x0: int
    y0: int
    side: int

    def cut(self, image: np.ndarray, fill: float | None = None) -> np.ndarray:
        """The window of an (H, W[, C]) image; outside the image: edge pixels, or ``fill`` when given."""
        h, w = image.shape[:2]
        pad = max(0, -self.x0, -self.y0, self.x0 + self.side - w, self.y0 + self.side - h)
        if pad:
            widths = ((pad, pad), (pad, pad)) + ((0, 0),) * (image.ndim - 2)
            if fill is None:
                image = np.pad(image, widths, mode="edge")
            else:
                image = np.pad(image, widths, mode="constant", constant_values=fill)
        y, x = self.y0 + pad, self.x0 + pad
        return image[y : y + self.side, x : x + self.side]


@dataclass
class Located:
    """The foot found in a photo: its crop and the cues of the crop mapped to the photo's pixels."""

    crop: CropBox
    cues: Cues
    mask: np.ndarray = field(repr=False)
    quarter_turns: int = 0
    """The photo was shown to the networks turned this many times 90 deg counter-clockwise (``turned_where_needed``)."""


def _cues_in_photo(cues: Cues, crop: CropBox, width: int, height: int) -> Cues:
    """Cues of a crop -> cues in the whole photo's pixels (silhouette 0 outside the crop)."""
    sil = np.zeros((height, width), np.float32)
    x0, y0 = max(crop.x0, 0), max(crop.y0, 0)
    x1, y1 = min(crop.x0 + crop.side, width), min(crop.y0 + crop.side, height)
    if x1 > x0 and y1 > y0:
        sil[y0:y1, x0:x1] = cues.silhouette[y0 - crop.y0 : y1 - crop.y0, x0 - crop.x0 : x1 - crop.x0]
    joints = cues.joints2d_px + np.array([crop.x0, crop.y0], np.float32)
    return replace(cues, silhouette=sil, joints2d_px=joints.astype(np.float32))


def _components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return n, labels, stats


def crop_around(x: int, y: int, width: int, height: int, fill: float) -> CropBox:
    """The square crop centred on a box (px) whose longer side is ``fill`` of the crop's, as the networks were
    trained (``MeasureConfig.crop_fill``)."""
    side = int(math.ceil(max(width, height) / fill))
    cx, cy = x + width / 2, y + height / 2
    return CropBox(int(round(cx - side / 2)), int(round(cy - side / 2)), side)


def whole_photo_cues(
    kind: str,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    weights: str | os.PathLike | None = None,
    image_size: int | None = None,
    window: float = 1.0,
) -> Cues:
    """The first pass: cues of the whole photo (H, W, 3) and/or depth (H, W) mm padded to a square, in its pixels
    (the shipped ``kind`` network, or the one in ``weights``, at ``image_size``: see ``predict_cues``).
    ``window``: the square's side over the photo's longer side (above 1: the photo shrunk inside a wider view,
    its edges carried on outwards)."""
    h, w = (rgb if rgb is not None else depth).shape[:2]
    side = int(round(max(h, w) * window))
    whole = CropBox((w - side) // 2, (h - side) // 2, side)
    first = predict_cues(
        kind,
        None if rgb is None else whole.cut(rgb),
        None if depth is None else whole.cut(depth, fill=0.0),
        weights=weights,
        image_size=image_size,
    )
    return _cues_in_photo(first, whole, w, h)


def locate_foot(
    rgb: np.ndarray | None, depth: np.ndarray | None, K: np.ndarray, kind: str, config: MeasureConfig
) -> Located:
    """The largest foot of the photo (``locate_feet``'s first)."""
    return locate_feet(rgb, depth, K, kind, config)[0]


def locate_feet(
    rgb: np.ndarray | None, depth: np.ndarray | None, K: np.ndarray, kind: str, config: MeasureConfig
) -> list[Located]:
    """Find the feet, largest first (one, or two when a second region is at least ``config.second_foot_ratio``
    of the first, or its foot, cut to its joints, of the first foot: ``config.second_look_ratio``): cues on the
    whole photo (padded square; with RGB-D, where its network finds no foot there, the RGB network's), then again
    on a square crop around each region framed like the training images (the foot's longer side
    ``config.crop_fill`` of the crop; once more framed on the foot found where it filled far less:
    ``_located_in``), the silhouette then cut to where that crop's joints say the foot can be (``cues.trim``) and
    snapped to the photo's edges (or, with a depth map alone, to those of the height above the floor; K (3, 3))."""
    ref = rgb if rgb is not None else depth
    h, w = ref.shape[:2]
    for look, zoom in _first_looks(kind, rgb is not None, config.first_look_zoom):
        stats, areas = _first_pass_regions(look, rgb, depth, zoom)
        refusal = refusals.no_foot(float(areas.max()) if areas.size else 0.0, h * w, config)
        if refusal is None:
            break
    else:
        raise refusal
    seen: dict[int, Located | None] = {}  # second passes already run, by region
    if zoom == 1 and config.wider_look_window is not None:
        stats, areas, seen = _wider_where_better(look, rgb, depth, K, kind, config, stats, areas)
    order = np.argsort(areas)[::-1]
    regions, small_second = [1 + order[0]], None
    if len(order) > 1 and areas[order[1]] >= config.second_foot_ratio * areas[order[0]]:
        regions.append(1 + order[1])
    elif len(order) > 1 and config.second_look_ratio is not None:
        if areas[order[1]] >= config.second_look_ratio * areas[order[0]]:
            regions.append(small_second := 1 + order[1])
    feet, boxes = [], []
    for region in regions:
        located = seen[region] if region in seen else _located_in(rgb, depth, K, kind, config, stats[region, :4])
        if region == small_second and located is not None and feet:
            # the regions took in the shins: the feet, cut to their joints, are compared instead
            if located.mask.sum() < config.second_foot_ratio * feet[0].mask.sum():
                continue
        # the second region's crop may show the first foot again (its joints, and so its silhouette, on it)
        if located is not None and not any(
            _same_foot(located.cues, foot.cues, config.same_foot_joints) for foot in feet
        ):
            feet.append(located)
            boxes.append(_boxes_seen_in(located, stats[region, :4], config))
    if not feet:
        raise refusals.foot_vanished()
    if len(feet) == 1:
        # the region's halves, then (where the closer look found two feet as one) those of what it found
        return next(filter(None, (_two_feet_as_one(rgb, depth, K, kind, config, box) for box in boxes[0])), feet)
    return feet


def _two_feet_as_one(rgb, depth, K, kind: str, config: MeasureConfig, box: np.ndarray) -> list[Located] | None:
    """The two feet (largest first) of the halves of one region's box (x, y, w, h px), split across its width or
    its height, where the left/right head takes them surely for a right and a left foot and their joints lie apart
    (``MeasureConfig.two_feet_min_probability``, ``two_feet_max_overlap``; each pixel of both silhouettes given to
    the nearer foot); else None: the region is one foot."""
    sure = config.two_feet_min_probability
    if sure is None:
        return None
    x, y, w, h = (int(v) for v in box)
    splits = [
        ((x, y, w // 2, h), (x + w // 2, y, w - w // 2, h)),
        ((x, y, w, h // 2), (x, y + h // 2, w, h - h // 2)),
    ]
    crops = [crop_around(*half, config.crop_fill) for split in splits for half in split]
    right = right_probabilities(
        kind,
        None if rgb is None else [crop.cut(rgb) for crop in crops],
        None if depth is None else [crop.cut(depth, fill=0.0) for crop in crops],
    )
    if right is None:
        return None
    # the probability that a split's halves are a right and a left foot (either way round), surest first
    pairs = [max(right[2 * i] * (1 - right[2 * i + 1]), right[2 * i + 1] * (1 - right[2 * i])) for i in range(2)]
    for i in np.argsort(pairs)[::-1]:
        if pairs[i] < sure:
            continue
        feet = [_look_in(rgb, depth, K, kind, config, np.array(half)) for half in splits[i]]
        if feet[0] is None or feet[1] is None or _same_foot(feet[0].cues, feet[1].cues, config.same_foot_joints):
            continue
        hulls = [_joints_hull(foot.cues.joints2d_px, foot.mask.shape) for foot in feet]
        if (hulls[0] & hulls[1]).sum() > config.two_feet_max_overlap * min(int(hull.sum()) for hull in hulls):
            continue
        feet = _apart(feet, hulls)
        if any(foot is None for foot in feet):
            continue
        return sorted(feet, key=lambda foot: -int(foot.mask.sum()))
    return None


def _joints_hull(joints2d_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the convex hull of the joints (18, 2) px."""
    hull = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.round(joints2d_px).astype(np.int32)), 1)
    return hull > 0


def _apart(feet: list[Located], hulls: list[np.ndarray]) -> list[Located | None]:
    """Two located feet whose silhouettes both take in the two (feet touching) with each pixel given to the foot
    whose joints' hull (``hulls``: (H, W) bool each) lies nearer, each keeping the part its joints lie on; None
    for one left without such a part."""
    away = np.stack([cv2.distanceTransform((~hull).astype(np.uint8), cv2.DIST_L2, 3) for hull in hulls])
    apart = []
    for index, foot in enumerate(feet):
        nearer = away[index] < away[1 - index] if index else away[index] <= away[1 - index]  # a tie to the first
        mine = foot.mask & nearer
        n, labels, _ = _components(mine)
        keep = _part_of_the_joints(labels, n, foot.cues) if n > 1 else None
        if keep is None:
            apart.append(None)
            continue
        mask = labels == keep
        silhouette = np.where(mask, foot.cues.silhouette, 0.0).astype(np.float32)
        apart.append(replace(foot, cues=replace(foot.cues, silhouette=silhouette), mask=mask))
    return apart


def _first_looks(kind: str, with_rgb: bool, zoom: int) -> list[tuple[str, int]]:
    """The looks at the whole photo, in turn until one finds a foot region: (network, zoom of its own image side;
    the last one at ``zoom``, ``MeasureConfig.first_look_zoom``).
    A small, far foot: the whole photo's depth (relative to its median) barely shows it where its colours do, and
    at the networks' 128 px a foot 60 px long in a 640-px photo is 12 px (ood renders, seed 4242: 6 of 60 RGB-D
    photos refused as *no foot*, five with the foot in view, and 3 of 60 RGB ones, one in plain view)."""
    looks = [(kind, 1)]
    if kind != "rgb" and with_rgb:
        looks.append(("rgb", 1))
    return [*looks, ("rgb" if with_rgb else kind, zoom)]


def _first_pass_regions(
    kind: str, rgb: np.ndarray | None, depth: np.ndarray | None, zoom: int = 1, window: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """The foot regions of the whole photo as the ``kind`` network sees it at ``zoom`` times its own image side
    (``window``: see ``whole_photo_cues``): their ``cv2.connectedComponentsWithStats`` rows (N + 1, 5), the
    background first, and their areas (N,) px."""
    cues = whole_photo_cues(kind, rgb, depth, image_size=cues_network(kind)[1].image_size * zoom, window=window)
    n, _, stats = _components(cues.silhouette >= 0.5)
    return stats, stats[1:, cv2.CC_STAT_AREA] if n > 1 else np.zeros(0)


def _wider_where_better(
    look: str, rgb, depth, K, kind: str, config: MeasureConfig, stats: np.ndarray, areas: np.ndarray
) -> tuple[np.ndarray, np.ndarray, dict[int, Located | None]]:
    """The regions (``_first_pass_regions``' pair) of a look at the photo shrunk into a wider view
    (``MeasureConfig.wider_look_window``) where its largest region is ``wider_look_min_area_ratio`` times the
    first look's and the closer look at it places the joints more confidently (``wider_look_min_confidence_gain``);
    else the first look's ``stats`` and ``areas``; and the second passes it ran on the regions kept, by region.
    A foot filling the photo, larger than the feet the networks saw whole photos with, was found by its toes
    alone (two toes taken for two feet) and measured as a tiny foot."""
    wide_stats, wide_areas = _first_pass_regions(look, rgb, depth, window=config.wider_look_window)
    if not wide_areas.size or wide_areas.max() < config.wider_look_min_area_ratio * areas.max():
        return stats, areas, {}
    wide_region, first_region = 1 + int(np.argmax(wide_areas)), 1 + int(np.argmax(areas))
    wide = _located_in(rgb, depth, K, kind, config, wide_stats[wide_region, :4])
    if wide is None:
        return stats, areas, {}
    first = _located_in(rgb, depth, K, kind, config, stats[first_region, :4])
    gain = config.wider_look_min_confidence_gain
    if first is None or _surety(wide) >= _surety(first) + gain:
        return wide_stats, wide_areas, {wide_region: wide}
    return stats, areas, {first_region: first}


def _located_in(rgb, depth, K, kind: str, config: MeasureConfig, box: np.ndarray) -> Located | None:
    """``_look_in`` the box, then, where the foot found fills much less of the crop than the networks learnt feet
    at (``MeasureConfig.reframe_below``), again on the crop around that foot, kept where it places the joints no
    less surely: a region of shins and feet framed a foot far smaller than any the networks saw."""
    located = _look_in(rgb, depth, K, kind, config, box)
    if located is None or config.reframe_below is None:
        return located
    found = _mask_box(located.mask)
    if max(found[2:]) >= config.reframe_below * config.crop_fill * located.crop.side:
        return located
    closer = _look_in(rgb, depth, K, kind, config, found)
    if closer is None or _surety(closer) < _surety(located):
        return located
    return closer


def _mask_box(mask: np.ndarray) -> np.ndarray:
    """The box (x, y, w, h px) around a non-empty (H, W) bool mask."""
    return np.array(cv2.boundingRect(mask.astype(np.uint8)))


def _boxes_seen_in(located: Located, box: np.ndarray, config: MeasureConfig) -> list[np.ndarray]:
    """The boxes (x, y, w, h px) the foot located in region ``box`` was seen in: ``box`` and, where
    ``_located_in`` looked again closer, the box of the silhouette that look found."""
    return [box] if located.crop == crop_around(*box, config.crop_fill) else [box, _mask_box(located.mask)]


def _look_in(rgb, depth, K, kind: str, config: MeasureConfig, box: np.ndarray) -> Located | None:
    """The second pass on the crop around one region's box (x, y, w, h px): its cues and silhouette (the part its
    own joints lie on, else the part most inside the box), or None when the region vanishes on the closer look."""
    from footmesh.fit import MIN_SILHOUETTE_PX

    ref = rgb if rgb is not None else depth
    h, w = ref.shape[:2]
    crop = crop_around(*box, config.crop_fill)
    crop_rgb = None if rgb is None else crop.cut(rgb)
    crop_depth = None if depth is None else crop.cut(depth, fill=0.0)
    second = predict_cues(kind, crop_rgb, crop_depth)
    if kind == "rgbd" and config.rgbd_with_depth_network:
        # the depth network's plain answer: averaged with its mirror's it made RGB-D worse (MIRROR_AVERAGED_INPUTS)
        second = average_cues([second, predict_cues("depth", None, crop_depth, mirror_average=False)])
    if config.trim_silhouette:
        second = replace(second, silhouette=trim_silhouette(second.silhouette, second.joints2d_px))
    cues = _cues_in_photo(second, crop, w, h)
    if config.refine_silhouette:
        edges = rgb if rgb is not None else height_image(depth, K, cues.mask)
        if edges is not None:
            cues = replace(cues, silhouette=refine_silhouette(edges, cues.silhouette))
    mask = cues.silhouette >= 0.5
    n, labels, stats = _components(mask)
    if n <= 1:
        return None
    keep = _part_of_the_joints(labels, n, cues, config.min_joints_on_part)
    if keep is None:
        # the part of the region this crop was cut for: the crop may hold more of the other foot than of this one
        x, y, bw, bh = (int(v) for v in box)
        inside = np.bincount(labels[max(y, 0) : y + bh, max(x, 0) : x + bw].ravel(), minlength=n)[1:]
        keep = 1 + (np.argmax(inside) if inside.any() else np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[keep, cv2.CC_STAT_AREA] < MIN_SILHOUETTE_PX:
        return None  # a few pixels: nothing the fit could take for a foot
    mask = labels == keep
    return Located(crop, replace(cues, silhouette=np.where(mask, cues.silhouette, 0.0).astype(np.float32)), mask)


def _same_foot(a: Cues, b: Cues, within: float = MeasureConfig.same_foot_joints) -> bool:
    """Two looks found the same foot: their joints lie within ``within`` of its image size S of each other
    (median over the joints). Not the masks: a mask that takes in both feet (through the legs) holds the other
    foot's mask too."""
    axes = foot_axes(a.joints2d_px)
    if axes is None:
        return False
    return bool(np.median(np.linalg.norm(a.joints2d_px - b.joints2d_px, axis=1)) < within * axes.size)


def _part_of_the_joints(
    labels: np.ndarray, n: int, cues: Cues, least: float = MeasureConfig.min_joints_on_part
) -> int | None:
    """The label (1..n-1) of the silhouette part (labels (H, W)) on which the cues' joints lie, by their confidence;
    None when no part holds ``least`` of them. Of two feet in a crop the network may place the joints on
    one and the region the crop was cut for on the other: the fit needs a silhouette of the joints' foot."""
    h, w = labels.shape
    xy = np.round(cues.joints2d_px).astype(np.int64)
    on = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
    weight = np.bincount(labels[xy[on, 1], xy[on, 0]], weights=cues.joint_confidence[on], minlength=n)[1:]
    if not weight.size or weight.max() < least:
        return None
    return 1 + int(np.argmax(weight))


def decoder_mesh(
    located: Located,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    K: np.ndarray,
    kind: str,
    side: str = "auto",
    decoder: str = "ism",
) -> np.ndarray | None:
    """The shipped ``decoder`` (ism or model) for ``kind`` input: its foot (V, 3) mm, camera frame, from the
    networks' crop of the photo (K (3, 3) of the photo; the images ``kind`` does not use are ignored); None when
    the crop holds no depth to read the scale from. A model-based decoder builds the mesh for ``side`` when it is
    known (not ``auto``)."""
    from footmesh.cues.predict import resize_inputs
    from footmesh.recon.model import predict_batch
    from footmesh.recon.weights import network_for as decoder_network
    from footmesh.recon.weights import packaged_weights

    net, cfg = decoder_network(kind, packaged_weights(kind, decoder))
    crop, quarter_turns = located.crop, located.quarter_turns
    # turned as the cues' networks saw it (``turned_where_needed``): the decoders too learnt the leg rising up
    crop_rgb = None if kind == "depth" else turned(crop.cut(rgb), quarter_turns)
    crop_depth = None if kind == "rgb" else turned(crop.cut(depth, fill=0.0), quarter_turns)
    if crop_depth is not None and not np.any(crop_depth > 0):
        return None
    small_rgb, small_depth = resize_inputs(crop_rgb, crop_depth, cfg.image_size)
    h, w = (rgb if rgb is not None else depth).shape[:2]
    seen = Camera(K, w, h).cropped(crop.x0, crop.y0, crop.side, crop.side)  # the same camera, a padded crop
    K_small = seen.resized(cfg.image_size, cfg.image_size).turned(quarter_turns).K
    out = predict_batch(
        net,
        None if small_rgb is None else small_rgb[None],
        None if small_depth is None else small_depth[None],
        K_small[None],
        None if side == "auto" else np.array([side == "right"]),
    )
    return out.vertices[0].double().numpy() @ turned_frame(quarter_turns)


def decoder_for(kind: str, config: MeasureConfig) -> str:
    """The shipped mesh decoder the pipeline runs for ``kind`` input: ``config.decoder_kind`` where it is shipped
    (the model-based head: RGB-D only), else the ISM decoder."""
    return config.decoder_kind if kind == "rgbd" else "ism"


def joint_sigma_px(crop_side_px: int, config: MeasureConfig) -> float:
    """The fit's expected 2D joint error in working pixels: the networks' error scales with the crop they saw."""
    return max(config.joint_sigma_224_px * crop_side_px / 224.0, 1.0)


def warm_up(config: MeasureConfig | None = None) -> None:
    """Load the foot model and every shipped network the pipeline uses now, once per process (they are cached):
    a server's forkserver calls it (``footmesh.web.warm``) so that each job forked from it starts with them in
    memory instead of loading them. Loading runs on one torch thread: OpenMP's thread team does not survive a
    fork, and a parallel region here (any tensor copy large enough) left every job forked after it hung at its
    first one."""
    from footmesh.recon.weights import network_for as decoder_network
    from footmesh.recon.weights import packaged_weights

    config = config or MeasureConfig()
    with torch_threads(1):  # torch alone: the BLAS's own threads are not touched before the forks
        default_model()
        for kind in ("rgb", "rgbd", "depth"):
            cues_network(kind)
        for kind in sorted(set(config.decoder_start_inputs) | set(config.decoder_side_inputs)):
            decoder_network(kind, packaged_weights(kind, decoder_for(kind, config)))


def working_photo(photo: Photo, max_side: int) -> tuple[np.ndarray, np.ndarray | None, Camera, float]:
    """The photo, its depth and camera at no more than ``max_side`` px (the pipeline's working resolution).

    Returns rgb, depth (mm, nearest neighbour), the camera of that image and the factor from working to photo
    pixels.
    """
    h, w = photo.rgb.shape[:2]
    factor = max(h, w) / max_side if max(h, w) > max_side else 1.0
    if factor == 1.0:
        return photo.rgb, photo.depth_mm, photo.intrinsics.camera, 1.0
    ww, wh = int(round(w / factor)), int(round(h / factor))
    rgb = cv2.resize(photo.rgb, (ww, wh), interpolation=cv2.INTER_AREA)
    depth = None
    if photo.depth_mm is not None:
        depth = cv2.resize(photo.depth_mm, (ww, wh), interpolation=cv2.INTER_NEAREST)
    return rgb, depth, photo.intrinsics.camera.resized(ww, wh), w / ww


def measure_photo(
    image: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    depth: str | os.PathLike | None = None,
    depth_unit: str = "mm",
    intrinsics: str | os.PathLike | None = None,
    side: str = "auto",
    input: str = "auto",
    config: MeasureConfig | None = None,
    embedded_depth: bool = True,
    reference: str = "auto",
) -> dict:
    """Measure the foot in one photo; write the result files into ``out_dir`` and return the result dict.

    ``input``: which networks to use: ``auto`` (RGB-D when a depth map is given, else RGB), or ``rgb``,
    ``rgbd``, ``depth`` (the depth map alone; the photo only serves for the overlay). ``embedded_depth``: use a
    metric depth map stored inside the photo (iPhone HEIC, Android depth JPEG) when no ``depth`` is given.
    ``reference``: the reference object in a plain photo, one of ``references.NAMES`` (only it is looked for), or
    ``auto``: any of them.
    """
    start = time.perf_counter()
    photo = load_photo(image, depth=depth, depth_unit=depth_unit, intrinsics=intrinsics, embedded_depth=embedded_depth)
    request = request_options(side, depth_unit, input, embedded_depth, reference)
    return measure_loaded_photo(photo, out_dir, request, config, started=start)


def measure_loaded_photo(
    photo: Photo,
    out_dir: str | os.PathLike,
    request: dict[str, str | bool],
    config: MeasureConfig | None = None,
    started: float | None = None,
) -> dict:
    """``measure_photo`` of a photo already loaded (``load_photo``; its inputs checked before torch loads), with
    the options ``request`` (``report.request_options``); ``started``: ``time.perf_counter()`` when its loading
    began, for the result's ``seconds``."""
    config = config or MeasureConfig()
    start = time.perf_counter() if started is None else started
    side, input, reference = str(request["side"]), str(request["input"]), str(request["reference"])
    if side not in ("left", "right", "auto"):
        raise InputError(f"side must be left, right or auto, got {side!r}")
    if reference != "auto" and reference not in references.NAMES:
        raise InputError(f"reference must be auto or one of {', '.join(references.NAMES)}, got {reference!r}")
    measured, files = run_pipeline(photo, side, config, input, reference)
    result = replace(measured, request=request, seconds=round(time.perf_counter() - start, 3)).to_dict()
    write_outputs(Path(out_dir), result, files)
    return result


@dataclass
class _Files:
    """What ``write_outputs`` writes besides result.json."""

    vertices_cam: np.ndarray
    canonical_vertices: np.ndarray
    faces: np.ndarray
    canonical_faces: np.ndarray
    overlay: np.ndarray
    mask: np.ndarray  # (H, W) uint8 0/255 in photo pixels
    extra_masks: tuple[tuple[str, np.ndarray], ...] = ()  # (file name, mask) of the other feet in the photo


def run_pipeline(
    photo: Photo, side: str, config: MeasureConfig, input: str = "auto", reference: str = "auto"
) -> tuple[MeasureResult, _Files]:
    """Everything after loading: the typed result (``MeasureResult``) and the arrays of the files to write.

    Each foot found is measured (two when both are in view, ``locate_feet``); the result's own keys are the foot
    asked for with ``side``, else the one measured best, and ``feet`` lists every foot. ``reference``: the kind
    of reference object looked for (``auto``: every kind).
    """
    with fixed_threads(PIPELINE_THREADS):  # the same millimetres on any machine (footmesh.threads)
        return _run_stages(photo, side, config, input, reference)


def _assumed_sheet_note(reference: ReferenceObject, searched_any: bool) -> str:
    """What a sheet whose proportions were not seen (cut by the photo's edge, or a corner hidden) was taken for,
    and how to say otherwise (``searched_any``: every kind was looked for, not the one the user named)."""
    described = references.kind(reference.kind).described
    if reference.beyond_edge:
        seen = f"the photo's edge cuts off one side of {described}: its far corners were placed"
    else:
        seen = f"a corner of {described} is hidden: it was completed"
    note = (
        f"{seen} from its known size and its other sides (scale known to {100 * reference.scale_rel_sd:.1f} %, if it "
        "is one: a sheet of another size looks the same and gives other millimetres)"
    )
    others = [k for k in references.with_detector("sheet") if k != reference.kind]
    if searched_any and others:
        note += "; if it is " + " or ".join(f"{references.kind(k).described}, say so: --reference {k}" for k in others)
    return note + ("; for the best figures photograph all of it" if reference.beyond_edge else "")


def _run_stages(
    photo: Photo, side: str, config: MeasureConfig, input: str, reference_kind: str
) -> tuple[MeasureResult, _Files]:
    from footmesh.cues.reference import search_reference

    timings = {}
    t = time.perf_counter()
    kind = input if input != "auto" else ("rgbd" if photo.depth_mm is not None else "rgb")
    if kind in ("rgbd", "depth") and photo.depth_mm is None:
        raise InputError(f"{kind} input needs a depth map (--depth)")
    max_side = config.rgb_working_max_side if kind == "rgb" else config.working_max_side
    rgb, depth, camera, to_photo = working_photo(photo, max_side)
    K = camera.K
    with torch.inference_mode():
        feet = locate_feet(None if kind == "depth" else rgb, None if kind == "rgb" else depth, K, kind, config)
    timings["cues_s"] = time.perf_counter() - t

    t = time.perf_counter()
    reference = None
    sheet_px = None  # the corners of a sheet found, whose paper is cleared from the feet's silhouettes
    notes = list(photo.info.notes)
    feet_mask = np.any([foot.mask for foot in feet], axis=0)
    if kind == "rgb":
        exclude = cv2.dilate(feet_mask.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
        focal_prior = config.focal_prior_log_sd[photo.intrinsics.source]
        kinds = references.NAMES if reference_kind == "auto" else (reference_kind,)
        searched = search_reference(
            rgb,
            K,
            kinds,
            exclude_mask=exclude,
            focal_prior_log_sd=focal_prior,
            distance_prior=config.camera_distance_prior_mm,
        )
        reference = searched.found
        if reference is None and searched.rejected is not None:
            notes.append(
                f"a sheet-like object ({100 * searched.rejected_area:.0f} % of the photo) was seen but not taken as "
                f"the reference: {searched.rejected}; lay the sheet flat, all of it in view, its sides clear of "
                "clothing and shadows"
            )
        if reference is not None and reference.kind_assumed:
            notes.append(_assumed_sheet_note(reference, reference_kind == "auto"))
        if reference is not None and reference.corner_beyond_edge:
            notes.append(
                f"a corner of {references.kind(reference.kind).described} lies beyond the photo's edge: it was "
                f"placed where the sheet's two sides running there meet (scale known to "
                f"{100 * reference.scale_rel_sd:.1f} %); for the best figures photograph all of it"
            )
        if reference is not None and config.clear_paper and references.kind(reference.kind).detector == "sheet":
            sheet_px = reference.corners_px
            feet = [_off_the_paper(foot, rgb, sheet_px) for foot in feet]
    floor_seen = None  # with depth, the floor the depth shows: what a reference's floor is to a plain photo
    if kind != "rgb" and config.floor_from_depth:
        floor_seen = depth_floor(depth, K, feet_mask)
    floor = (reference.K, reference.cam_from_floor) if reference is not None else None
    if floor_seen is not None:
        floor = (K, floor_seen)
    feet = turned_where_needed(feet, rgb if kind != "depth" else None, depth, camera, kind, config, sheet_px, floor)
    timings["reference_s"] = time.perf_counter() - t

    stood = pair_sides(feet[0].cues.joints2d_px, feet[1].cues.joints2d_px, config) if len(feet) == 2 else None
    if len(feet) > 1 and side != "auto":
        feet, why = _foot_of_side(feet, side, stood)
        notes.append(why)
    # each foot's side to fit and what told it ("auto": the cues, the decoder or the fit tell it)
    if side != "auto":
        sides = [(side, "given")] * len(feet)
    elif stood is not None:
        sides = [(s, "pair") for s in stood]
    else:
        sides = [("auto", "fit")] * len(feet)
    outcomes: list[tuple[MeasureResult, _Files, Located, Any, np.ndarray] | Refusal] = []
    for located, (foot_side, side_source) in zip(feet, sides, strict=True):
        try:
            outcomes.append(
                _measure_located(
                    photo,
                    located,
                    foot_side,
                    side_source,
                    config,
                    kind,
                    rgb,
                    depth,
                    K,
                    to_photo,
                    reference,
                    floor_seen,
                    list(notes),
                    dict(timings),
                )
            )
        except Refusal as exc:
            outcomes.append(exc)
    measured = [o for o in outcomes if not isinstance(o, Refusal)]
    if not measured:
        raise next(o for o in outcomes if isinstance(o, Refusal))
    if len(outcomes) == 1:
        return measured[0][0], measured[0][1]
    return _both_feet(outcomes, reference, side)


def turned_where_needed(
    feet: list[Located],
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    camera: Camera,
    kind: str,
    config: MeasureConfig,
    sheet_px: np.ndarray | None = None,
    floor: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[Located]:
    """The feet ``locate_feet`` found (largest first), or those the networks find in the photo turned, where
    upright they see it as they never learnt to (they learnt feet with the leg rising up the picture):

    - the floor's up not up the picture at the largest foot (``floor``: (K (3, 3), cam_from_floor (4, 4)) of the
      floor a reference object or the depth shows, or None; ``floor_up_turns``): every foot is taken from the
      photo turned so that it is (a phone held sideways or upside down);
    - a floor seen straight down (``seen_straight_down``: its up cannot tell, and no view from the side can be
      either): every foot is taken from the photo turned so that the largest foot's ankle lies above its toes
      (``MeasureConfig.straight_down_ankle_up``), where that look sees it there too;
    - without a floor that tells, the largest foot's ankle below its toes (``MeasureConfig.upside_down_deg``):
      every foot is taken from the photo turned 180 deg, where that look puts the ankle below the toes too
      (photos looking down at one's own feet, the legs entering from the bottom); and whichever way up the
      upright look reads its largest foot, where the turned look's surest foot, its ankle below its toes in the
      photo, has its joints placed surer than that largest foot by ``MeasureConfig.upside_down_min_confidence_gain``
      (the ankle below the toes by less, or a shin taken for the largest foot, upside down or upright);
    - a foot past the photo's edge (``refusals.cut_off``): that foot from the first turn of
      ``MeasureConfig.turned_looks`` (or upright, for a foot of a turned look) that keeps it in view (a photo
      taken straight down or held sideways, the leg across the picture and the heel under the shin read as past
      the edge).

    A turned look's foot is the one whose silhouette overlaps the upright one's most; ``sheet_px``: (4, 2) corners
    of a sheet whose paper is cleared from turned looks' silhouettes (``_off_the_paper``), or None. Two feet that
    are one turned foot are kept once."""
    h, w = (rgb if rgb is not None else depth).shape[:2]
    upright = tuple(feet)

    @functools.cache
    def turned_feet(quarter_turns: int) -> tuple[Located, ...]:
        if quarter_turns == 0:
            return upright  # located already
        try:
            with torch.inference_mode():
                found = locate_feet(
                    turned(rgb, quarter_turns),
                    turned(depth, quarter_turns),
                    camera.turned(quarter_turns).K,
                    kind,
                    config,
                )
        except Refusal:
            return ()
        back = (_turned_back_located(foot, quarter_turns, w, h) for foot in found)
        return tuple(back if sheet_px is None else (_off_the_paper(foot, rgb, sheet_px) for foot in back))

    first = feet[0]

    def agreeing(quarter_turns: int, agrees: Callable[[np.ndarray], bool]) -> list[Located] | None:
        """The feet of the photo turned ``quarter_turns``, where the largest foot is found there and its joints
        (18, 2) px, back in the photo's pixels, ``agrees``; else None (the two looks disagree)."""
        if not quarter_turns:
            return None
        match = _overlapping(first, turned_feet(quarter_turns))
        return list(turned_feet(quarter_turns)) if match is not None and agrees(match.cues.joints2d_px) else None

    def surer_turned(quarter_turns: int, gain: float) -> list[Located] | None:
        """The feet of the photo turned ``quarter_turns`` where its surest foot (mean joint confidence), its ankle
        below its toes back in the photo, has joints placed ``gain`` more confidently than the upright look's
        largest foot; else None."""
        look = turned_feet(quarter_turns)
        if not look:
            return None
        surest = max(look, key=_surety)
        if leg_angle_deg(surest.cues.joints2d_px) <= 90.0:
            return None
        return list(look) if _surety(surest) >= _surety(first) + gain else None

    turned_look = None
    floor_turns = None if floor is None else floor_up_turns(first.mask, *floor, config)
    if floor_turns is not None:
        turned_look = agreeing(floor_turns, lambda joints: True)
    elif floor is not None and config.straight_down_ankle_up and seen_straight_down(first.mask, *floor, config):
        turns = ankle_up_turns(first.cues.joints2d_px)
        turned_look = agreeing(turns, lambda joints: ankle_up_turns(joints) == turns)
    else:
        if config.upside_down_deg is not None and leg_angle_deg(first.cues.joints2d_px) > config.upside_down_deg:
            turned_look = agreeing(2, lambda joints: leg_angle_deg(joints) > 90.0)
        if turned_look is None and config.upside_down_min_confidence_gain is not None:
            # also where the upright look sees its foot upright: a shin taken for a foot can read either way up
            turned_look = surer_turned(2, config.upside_down_min_confidence_gain)
    feet = turned_look or feet
    looks = []
    for foot in feet:
        if refusals.cut_off(foot.mask, foot.cues.joints2d_px, w, h, config) is not None:
            # a foot from a turned look may have been in view upright: that look is tried too
            for quarter_turns in (k for k in (0, *config.turned_looks) if k != foot.quarter_turns):
                again = _overlapping(foot, turned_feet(quarter_turns))
                if (
                    again is not None
                    and refusals.cut_off(again.mask, again.cues.joints2d_px, w, h, config) is None
                    and _size_ratio(again, foot) >= config.turned_min_size_ratio
                ):
                    foot = again
                    break
        looks.append(foot)
    return list({id(foot): foot for foot in looks}.values())


def _surety(located: Located) -> float:
    """How surely the networks placed the foot's joints: their mean confidence."""
    return float(located.cues.joint_confidence.mean())


def _size_ratio(located: Located, other: Located) -> float:
    """How large ``located``'s foot is against ``other``'s (their joints' image sizes); 0 where ``located``'s
    joints lie too close together to tell, infinite where only ``other``'s do."""
    a, b = foot_axes(located.cues.joints2d_px), foot_axes(other.cues.joints2d_px)
    if a is None:
        return 0.0
    return math.inf if b is None else a.size / b.size


def _overlapping(located: Located, others: tuple[Located, ...]) -> Located | None:
    """Of ``others``, the foot whose silhouette overlaps ``located``'s most; None where none does."""
    overlap, best = max(
        ((int((o.mask & located.mask).sum()), o) for o in others), key=lambda p: p[0], default=(0, None)
    )
    return best if overlap > 0 else None


def _sight_of_floor(
    mask: np.ndarray, K: np.ndarray, cam_from_floor: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The floor's up (unit (3,), towards the camera), the point of the floor (3,) mm seen at the middle of the
    foot's silhouette ``mask`` (H, W) bool and the angle (deg) between the line of sight to it and straight down;
    None where the silhouette is empty or the floor is not in front of the camera there."""
    ys, xs = np.nonzero(mask)
    if not len(xs):
        return None
    ray = pixel_rays(np.array([xs.mean(), ys.mean()]), K)
    ray /= np.linalg.norm(ray)
    origin, normal = cam_from_floor[:3, 3], cam_from_floor[:3, 2]
    normal = normal if normal @ -origin >= 0 else -normal  # up: towards the camera
    depth = float(normal @ origin) / float(normal @ ray)
    if depth <= 0:
        return None
    return normal, depth * ray, math.degrees(math.acos(min(abs(float(normal @ ray)), 1.0)))


def floor_up_turns(mask: np.ndarray, K: np.ndarray, cam_from_floor: np.ndarray, config: MeasureConfig) -> int | None:
    """How many quarter turns counter-clockwise bring the floor's up (its normal, seen at the middle of the foot's
    silhouette ``mask`` (H, W) bool; K (3, 3), ``cam_from_floor`` (4, 4)) nearest the picture's up: 0 where it lies
    within ``MeasureConfig.floor_up_turn_deg`` of it; None where the floor cannot tell (the line of sight within
    ``MeasureConfig.floor_up_min_tilt_deg`` of straight down, or the floor not in front of the camera, or
    ``MeasureConfig.floor_up_turn_deg`` None)."""
    seen = _sight_of_floor(mask, K, cam_from_floor)
    if seen is None or config.floor_up_turn_deg is None:
        return None
    normal, foot, tilt_deg = seen
    if tilt_deg < config.floor_up_min_tilt_deg:
        return None
    (at, up), _ = project(np.stack([foot, foot + 100.0 * normal]), K)
    return _turns_bringing_up(up - at, config.floor_up_turn_deg)


def seen_straight_down(mask: np.ndarray, K: np.ndarray, cam_from_floor: np.ndarray, config: MeasureConfig) -> bool:
    """Whether the line of sight to the middle of the foot's silhouette ``mask`` lies within ``MeasureConfig.
    floor_up_min_tilt_deg`` of straight down onto the floor (K (3, 3), ``cam_from_floor`` (4, 4))."""
    seen = _sight_of_floor(mask, K, cam_from_floor)
    return seen is not None and seen[2] < config.floor_up_min_tilt_deg


def ankle_up_turns(joints2d_px: np.ndarray) -> int:
    """How many quarter turns counter-clockwise bring the direction from the toe tips' mean to the ankle (joints
    (18, 2) px) nearest the picture's up."""
    return _turns_bringing_up(_toes_to_ankle_px(joints2d_px), 45.0)


def _turns_bringing_up(direction_px: np.ndarray, within_deg: float) -> int:
    """Quarter turns counter-clockwise that bring a picture direction (2,) px nearest the picture's up: 0 where it
    lies within ``within_deg`` of it."""
    angle = math.degrees(math.atan2(direction_px[0], -direction_px[1]))  # from the picture's up, clockwise
    if abs(angle) <= within_deg:
        return 0
    # a counter-clockwise turn takes the picture's right to its top
    return int(round(angle / 90.0)) % 4


def leg_angle_deg(joints2d_px: np.ndarray) -> float:
    """The angle (deg, 0-180) between the image's up and the direction from the toe tips' mean to the ankle, of
    joints (18, 2) px: where the leg rises in the picture. The networks learnt it below ``MeasureConfig.
    upside_down_deg``."""
    v = _toes_to_ankle_px(joints2d_px)
    return float(np.degrees(np.arctan2(abs(v[0]), -v[1])))


def _toes_to_ankle_px(joints2d_px: np.ndarray) -> np.ndarray:
    """(2,) px from the toe tips' mean to the ankle, of joints (18, 2) px."""
    joints = np.asarray(joints2d_px, dtype=np.float64)
    return joints[sk.HEEL_BRANCH[0]] - joints[list(sk.TOE_TIPS)].mean(axis=0)


def _turned_back_located(located: Located, quarter_turns: int, width: int, height: int) -> Located:
    """A foot located in a photo turned ``quarter_turns`` x 90 deg counter-clockwise -> the same foot in the
    ``width`` x ``height`` photo before the turn (its crop: the square the turned one covers)."""
    back = np.linalg.inv(turned_pixels(width, height, quarter_turns))
    side = located.crop.side
    # the turned crop's first and last pixel, back in the photo: the square they span there
    first = np.array([located.crop.x0, located.crop.y0], np.float64)
    ends = np.stack([first, first + side - 1]) @ back[:2, :2].T + back[:2, 2]
    x0, y0 = np.rint(ends.min(axis=0)).astype(int)
    crop = CropBox(int(x0), int(y0), side)
    mask = np.ascontiguousarray(np.rot90(located.mask, -quarter_turns))
    return Located(crop, turned_back(located.cues, quarter_turns), mask, quarter_turns=quarter_turns % 4)


def _off_the_paper(located: Located, rgb: np.ndarray, sheet_px: np.ndarray) -> Located:
    """The foot with the pixels of its silhouette that are the white sheet's (its shadow on it) taken out
    (``cues.refine.clear_paper``)."""
    silhouette = clear_paper(rgb, located.cues.silhouette, sheet_px)
    return replace(located, cues=replace(located.cues, silhouette=silhouette), mask=silhouette >= 0.5)


def _sight_cos(fit, axis: int, point: np.ndarray) -> float:
    """|cos| of the angle between the fitted foot's frame axis ``axis`` (0: heel to toe, 1: lateral) and the line of
    sight to ``point`` (3,), camera frame."""
    return abs(float(fit.cam_from_foot[:3, axis] @ point)) / float(np.linalg.norm(point))


def _end_on(fit) -> float:
    """|cos| of the angle between the fitted foot's heel-to-toe axis and the line of sight to its centre."""
    return _sight_cos(fit, 0, fit.vertices_cam.mean(axis=0))


def _side_cos(fit) -> float:
    """|cos| of the angle between the line of sight to a fitted foot's midfoot and the foot's lateral axis: 0 seen
    from its front, its back or above (the profile of its sole out of sight), 1 seen square from its side."""
    return _sight_cos(fit, 1, fit.joints_cam[0])


def floor_end_on_bound(mask: np.ndarray, K: np.ndarray, cam_from_floor: np.ndarray) -> float:
    """The largest |cos| between the line of sight to the silhouette's centre and any direction in the floor
    plane: how end-on a foot lying on this floor can be seen at most (0 looking straight down, 1 along it)."""
    ys, xs = np.nonzero(mask)
    ray = Camera(K, mask.shape[1], mask.shape[0]).rays(np.array([xs.mean(), ys.mean()]))
    ray /= np.linalg.norm(ray)
    normal = cam_from_floor[:3, 2]
    return math.sqrt(max(0.0, 1.0 - float(ray @ normal) ** 2))


def _foot_of_side(feet: list[Located], side: str, stood: tuple[str, str] | None) -> tuple[list[Located], str]:
    """The foot of two that is ``side``: by where they stand (``stood``: ``pair_sides``, or None), else the one
    the networks take for it (their left/right head); and a message saying so."""
    if stood is not None:
        return [feet[stood.index(side)]], (
            f"two feet in view: measured the {side} one, told by where the two stand (a person's left foot stands "
            "to the left of where the toes point)"
        )
    probabilities = [foot.cues.right_probability for foot in feet]
    if any(p is None for p in probabilities):
        return feet, f"two feet in view: both measured, the {side} one kept (the networks tell no side here)"
    pick = int(np.argmax(probabilities)) if side == "right" else int(np.argmin(probabilities))
    return [feet[pick]], (
        f"two feet in view: measured the one the network takes for the {side} foot "
        f"(p(right) {probabilities[pick]:.2f} against {probabilities[1 - pick]:.2f} for the other)"
    )


def _toes_direction(joints2d_px: np.ndarray) -> np.ndarray | None:
    """The unit direction (2,) in the picture from a foot's midfoot joint to the mean of its toe tips (joints
    (18, 2) px); None where they coincide."""
    joints = np.asarray(joints2d_px, np.float64)
    step = joints[list(sk.TOE_TIPS)].mean(axis=0) - joints[sk.JOINT_INDEX["midfoot"]]
    length = float(np.linalg.norm(step))
    return step / length if length > 1e-6 else None


def pair_sides(joints_a: np.ndarray, joints_b: np.ndarray, config: MeasureConfig) -> tuple[str, str] | None:
    """The sides of two feet standing side by side, from their joints (18, 2) px each: seen from above the floor
    (as any photo of the floor is), a person's left foot stands to the left of where their toes point. None where
    the feet do not point the same way within ``MeasureConfig.pair_side_max_turn_deg`` or stand more one before
    the other than side by side (``MeasureConfig.pair_side_min_lateral``). Where a foot points is read from its
    midfoot to its toe tips, not from its heel: photos looking down at one's own feet hide the heels under the
    shins, and a heel joint placed on the shin turned a foot's heel-to-toe direction by up to 60 deg."""
    axes = [_toes_direction(joints) for joints in (joints_a, joints_b)]
    if config.pair_side_max_turn_deg is None or axes[0] is None or axes[1] is None:
        return None
    if float(axes[0] @ axes[1]) < math.cos(math.radians(config.pair_side_max_turn_deg)):
        return None
    forward = axes[0] + axes[1]
    forward /= np.linalg.norm(forward)
    left = np.array([forward[1], -forward[0]])  # a quarter turn counter-clockwise on the screen (y points down)
    forefeet = [np.asarray(joints, np.float64)[: sk.HEEL_BRANCH[0]].mean(axis=0) for joints in (joints_a, joints_b)]
    step = forefeet[0] - forefeet[1]
    across, along = float(step @ left), float(step @ forward)
    if abs(across) < config.pair_side_min_lateral * abs(along):
        return None
    return ("left", "right") if across > 0 else ("right", "left")


def _both_feet(outcomes: list, reference, requested: str) -> tuple[MeasureResult, _Files]:
    """One result for a photo of two feet: the keys of the foot asked for (``requested`` side) or else of the
    best-measured one, ``feet`` listing both, both drawn on the overlay."""
    measured = [o for o in outcomes if not isinstance(o, Refusal)]

    def rank(outcome) -> tuple:
        result, located = outcome[0], outcome[2]
        u = result.measurements["stick_length"]["uncertainty_mm"]
        u = u if u is not None else math.inf
        # unscaled, no uncertainty tells: the foot the networks place most surely (fit costs of feet of different
        # image sizes do not compare; a charger on the floor, fitted as a tiny foot, cost least)
        surest = -_surety(located)
        return (requested != "auto" and result.side != requested, not result.scaled, u, surest, result.fit["loss"])

    primary = min(measured, key=rank)
    result, files = primary[0], primary[1]
    feet, overlay, masks = [], files.overlay, []
    for index, outcome in enumerate(outcomes):
        if isinstance(outcome, Refusal):
            feet.append(FootEntry(index=index, measured=False, error=str(outcome)))
            continue
        other, other_files, located, fit, fit_K = outcome
        name = "mask.png" if outcome is primary else f"mask_{index}.png"
        feet.append(
            FootEntry(
                index=index,
                measured=True,
                primary=outcome is primary,
                side=other.side,
                side_source=other.side_source,
                scale_source=other.scale_source,
                scaled=other.scaled,
                measurements=other.measurements,
                sizes=other.sizes,
                joints2d_px=other.joints2d_px,
                files={"mask_png": name},
            )
        )
        if outcome is not primary:
            # the reference outlined only where this foot was measured with it (not one it found no adult's foot on)
            used = reference if reference is not None and other.scale_source == reference.kind else None
            overlay = draw_overlay(overlay, located, fit, fit_K, used)
            masks.append((name, other_files.mask))
    result = replace(result, feet=tuple(feet))
    fitted_sides = [foot.side for foot in feet if foot.measured]
    sides = " and ".join(f"a {side}" for side in fitted_sides)
    result = result.with_message(
        f"two feet in view: {sides} foot measured; the result's own keys are the {result.side} foot "
        "(`feet` lists both; --side picks one)"
    )
    if len(fitted_sides) == 2 and fitted_sides[0] == fitted_sides[1]:
        result = result.with_message(
            f"both feet were fitted as {fitted_sides[0]} feet, so one of them is wrong; --side picks the one wanted"
        )
    refused = [foot.error for foot in feet if not foot.measured]
    if refused:
        result = result.with_message(f"the other foot was not measured: {refused[0]}")
    return result, replace(files, overlay=overlay, extra_masks=tuple(masks))


def _measure_located(
    photo: Photo,
    located: Located,
    side: str,
    side_source: str,
    config: MeasureConfig,
    kind: str,
    rgb: np.ndarray,
    depth: np.ndarray | None,
    K: np.ndarray,
    to_photo: float,
    reference,
    floor_seen: np.ndarray | None,
    messages: list[str],
    timings: dict[str, float],
) -> tuple[MeasureResult, _Files, Located, Any, np.ndarray]:
    """Fit, check and measure one located foot: (result dict, files, the located foot, the fit, the K (3, 3) it
    was fitted with: the photo's, or the reference's where its perspective corrected the focal length).
    ``side``: the side to fit, or "auto"; ``side_source``: what told it (``given``: --side; ``pair``: where the two
    feet in view stand, ``pair_sides``; ``fit`` with "auto", unless the cues or the decoder tell it).
    ``floor_seen``: (4, 4) floor frame -> camera that the depth map shows (``cues.floor.depth_floor``), or None;
    the fit stands the foot on it where no reference object gives one."""
    from footmesh.fit import FitConfig, FitInit, canonical_measures, fit_foot, mesh_side_residuals

    h, w = rgb.shape[:2]
    refusal = refusals.cut_off(located.mask, located.cues.joints2d_px, w, h, config)
    if refusal is not None:
        raise refusal
    if located.quarter_turns:
        messages.append(
            f"the foot was read with the photo turned {90 * located.quarter_turns} deg counter-clockwise: the "
            "networks learnt feet with the leg rising up the picture, and this photo was taken another way up"
        )
    t = time.perf_counter()
    init = None
    right = located.cues.right_probability
    if side == "auto" and right is not None and max(right, 1.0 - right) >= config.cues_side_confidence:
        side, side_source = ("right" if right >= 0.5 else "left"), "cues"
    start, tell_side = kind in config.decoder_start_inputs, side == "auto" and kind in config.decoder_side_inputs
    mesh = None
    if start or tell_side:
        with torch.inference_mode():
            mesh = decoder_mesh(located, rgb, depth, K, kind, side, decoder_for(kind, config))
    if mesh is not None and start:
        init = FitInit(vertices_cam=mesh, alone=False)
    if mesh is not None and tell_side:
        residuals = mesh_side_residuals(mesh)
        nearer = min(residuals, key=residuals.get)
        if max(residuals.values()) >= config.decoder_side_ratio * residuals[nearer]:
            side, side_source = nearer, "decoder"  # told plainly: the other side's fit is not needed

    def fitted(on: ReferenceObject | None, hold: Literal["upright", "standing"] | None = None):
        """The fit on the floor of the reference ``on`` (with the camera its pose was solved with), or on none;
        ``hold``: "upright", held upright on that floor (``MeasureConfig.flat_refit_upright_robust``), or
        "standing", held upright and bearing weight on it (its heel and its ball on it: ``FitConfig.sole_contact``)."""
        fit_config = config.held_fit(FitConfig(joint_sigma_px=joint_sigma_px(located.crop.side, config)), hold)
        return fit_foot(
            located.cues,
            K if on is None else on.K,
            depth_mm=None if kind == "rgb" else depth,
            cam_from_floor=floor_seen if on is None else on.cam_from_floor,
            side=side,
            init=init,
            config=fit_config,
        )

    seen_reference = reference  # its floor's orientation stays evidence even if its scale is rejected below
    held_flat = functools.cache(lambda: fitted(seen_reference, "upright"))
    fit, hold = fitted(reference), None
    # a free fit may settle in a worse basin than a fit held upright on the floor finds (the leg hiding the heel
    # lets it tip the foot): the held fit is taken where it matches the photo clearly better
    ratio = config.flat_fit_cost_ratio
    if reference is not None and ratio is not None and held_flat().loss < ratio * fit.loss:
        fit, hold = held_flat(), "upright"
    if (
        reference is not None
        and config.standing_max_side_cos is not None
        and _side_cos(fit) < config.standing_max_side_cos
    ):
        # seen from the front, the back or above, the photo does not show whether the heel and the ball rest on
        # the floor, and a fit free to lift either tips the foot along the line of sight: one standing on it is
        # taken unless it explains the photo far worse
        standing = fitted(reference, "standing")
        if standing.loss <= config.standing_max_cost_ratio * fit.loss:
            fit, hold = standing, "standing"
    length_mm = canonical_measures(fit.shape)[0] if fit.scaled else None
    if reference is None and (refusal := refusals.implausible_length(length_mm, config)) is not None:
        raise refusal
    if reference is not None:

        def contradiction(candidate) -> str | None:
            """Why the fit ``candidate`` says the reference was something else, or None."""
            separation = float(np.linalg.norm(candidate.vertices_cam.mean(axis=0) - reference.centre_mm))
            candidate_mm = canonical_measures(candidate.shape)[0]
            return refusals.contradicted_reference(reference.kind, candidate_mm, candidate.quality, config, separation)

        contradicted = contradiction(fit)
        if contradicted is not None and hold is None and refusals.implausible_length(length_mm, config) is not None:
            # a fit that went wrong is tried again before the object is: held flat on its floor (the leg hiding
            # the heel lets a fit tip the foot and shrink it)
            flat = held_flat()
            if contradiction(flat) is None:
                fit, hold, contradicted = flat, "upright", None
                messages.append(
                    f"the foot was fitted lying flat on the floor that {references.kind(reference.kind).described} "
                    "shows (a first fit made it no adult's length: the heel may be hidden behind the leg)"
                )
        if contradicted is not None:
            messages.append(contradicted)
            reference = None
            fit, hold = fitted(None), None
    # the reference's perspective may have corrected a guessed focal length: the camera the fit used
    photo_K, K = K, (K if reference is None else reference.K)
    if abs(K[0, 0] / photo_K[0, 0] - 1.0) > 0.05:
        messages.append(
            f"the focal length was estimated from the perspective of {references.kind(reference.kind).described} "
            "and how far a phone is usually held from it: "
            f"{K[0, 0] / photo_K[0, 0]:.2f}x the {photo.intrinsics.source} one (known to "
            f"{100 * reference.focal_log_sd:.0f} %); pass --intrinsics for exact figures"
        )
    floor = None
    if seen_reference is not None:
        # the floor the reference shows, not the fit, says how end-on a foot lying on it can be seen
        floor = (seen_reference.kind, floor_end_on_bound(located.mask, seen_reference.K, seen_reference.cam_from_floor))
    if (
        reference is not None
        and floor is not None
        and hold is None
        and refusals.heel_hidden(_end_on(fit), floor[1], floor[0], config)
    ):
        # the fit lifted the foot off the floor the reference shows (as when the leg hides the heel): before
        # refusing, fit again held upright on it (the photo guide asks for the foot flat on the floor)
        flat = held_flat()
        if refusals.fitted_foot(flat.quality, _end_on(flat), kind, config, floor, scaled=flat.scaled) is None:
            fit, hold = flat, "upright"
            messages.append(
                f"the foot was fitted lying flat on the floor that {references.kind(reference.kind).described} shows "
                "(a first fit lifted it off that floor: the heel may be hidden behind the leg); for the best figures "
                "photograph the foot from the side and above, with the heel in view"
            )
    if hold == "standing":
        messages.append(
            f"the foot was fitted standing on the floor that {references.kind(reference.kind).described} shows, its "
            "heel and its ball on it: seen from the front, the back or above, a photo does not show whether either is "
            "lifted"
        )
    timings["fit_s"] = time.perf_counter() - t
    refusal = refusals.fitted_foot(fit.quality, _end_on(fit), kind, config, floor, scaled=fit.scaled)
    if refusal is not None:
        raise refusal
    end_on_note = None if fit.scaled else refusals.end_on_note(_end_on(fit), kind, config)
    if end_on_note is not None:
        messages.append(end_on_note)

    t = time.perf_counter()
    model = default_model()
    canonical, faces, measured = _measured_fit(fit, model)
    scale_source = "depth" if kind != "rgb" else (reference.kind if reference is not None else "none")
    if not fit.scaled:  # the fit could not use the evidence: say so rather than name a source it did not use
        scale_source = "none"
    if fit.scaled:
        focal_effect = None
        if reference is not None and reference.focal_log_sd >= config.focal_uncertainty_min_log_sd:
            focal_effect = _focal_effect_mm(reference, measured, lambda on: fitted(on, hold), model)
        measured = measured.with_uncertainties(
            measurement_uncertainty(fit, measured, scale_source, reference, model, config, focal_effect)
        )
        sizes = shoe_sizes(measured.stick_length.value_mm, measured.ball_width.value_mm)
        if (advice := length_advice(measured.stick_length.uncertainty_mm, config.length_advice_mm)) is not None:
            messages.append(advice)
    else:
        measured = measured.as_unscaled()
        sizes = shoe_sizes(None)
        messages.append(
            "unscaled: no depth map and no reference object found, so millimetres and shoe sizes are not given; "
            f"put {references.described_choices()} on the floor beside the foot, or use a depth photo"
        )
    timings["measure_s"] = time.perf_counter() - t

    joints2d_photo = rescale_pixels(located.cues.joints2d_px, to_photo)
    located = replace(located, mask=_measured_foot_mask(located.mask, fit, K, config))
    overlay = draw_overlay(rgb, located, fit, K, reference)
    result = MeasureResult(
        version=__version__,
        input_sha256=dict(photo.input_sha256),
        image={"width": int(photo.rgb.shape[1]), "height": int(photo.rgb.shape[0])},
        intrinsics=_intrinsics_dict(photo, reference, photo_K),
        depth=None if photo.depth_source is None or kind == "rgb" else photo.depth_source.to_dict(),
        input=kind,
        side=fit.side,
        side_losses={k: float(v) for k, v in fit.side_losses.items()},
        side_source=side_source,
        scale_source=scale_source,
        scaled=bool(fit.scaled),
        reference=None if reference is None else _reference_dict(reference, to_photo),
        measurements=measured.to_dict(),
        ratios={} if end_on_note is not None else measured.ratios(),
        sizes=sizes.to_dict(),
        joints2d_px=joints2d_photo.round(2).tolist(),
        joint_confidence=np.round(located.cues.joint_confidence, 3).tolist(),
        joints3d_mm=np.round(fit.joints_cam, 2).tolist() if fit.scaled else None,
        angles=dict(zip(sk.DOF_NAMES, np.round(fit.angles, 4).tolist(), strict=True)),
        shape=np.round(fit.shape, 4).tolist(),
        fit={
            "loss": float(fit.loss),
            "iterations": int(fit.iterations),
            "terms": fit.loss_terms,
            "quality": fit.quality.to_dict(),
        },
        timings_s={k: round(v, 3) for k, v in timings.items()},
        messages=messages,
        units="mm" if fit.scaled else "unscaled (mesh in arbitrary units)",
        files={
            "result_json": "result.json",
            "mesh_obj": "mesh.obj",
            "mesh_glb": "mesh.glb",
            "canonical_obj": "canonical.obj",
            "overlay_png": "overlay.png",
            "mask_png": "mask.png",
        },
    )
    # the measured foot in photo pixels: nearest-neighbour, so it stays a 0/1 decision
    mask = cv2.resize(located.mask.astype(np.uint8) * 255, photo.rgb.shape[1::-1], interpolation=cv2.INTER_NEAREST)
    files = _Files(fit.vertices_cam, canonical, model.faces(fit.side).numpy(), faces, overlay, mask)
    return result, files, located, fit, K


def _focal_effect_mm(reference: ReferenceObject, measured: Measurements, refit, model) -> dict[str, float] | None:
    """How much each measurement moves when the foot is fitted again (``refit(reference)``) with the reference's
    estimated focal length one SD longer; None when that fit cannot be measured. Seen from above, the foot's relief
    makes the length move with the focal length (20-60 mm per unit of its log on the real A4 photos)."""
    from footmesh.cues.reference import seen_with
    from footmesh.cues.reference.focal import with_focal_scale

    longer_K = with_focal_scale(reference.K, math.exp(reference.focal_log_sd))
    longer = seen_with(reference, longer_K, reference.focal_log_sd)
    if longer is None:
        return None
    # from every start: a warm start stays in the first fit's basin and shows a fraction of the change
    other = refit(longer)
    if not other.scaled:
        return None
    try:
        other_mm = _measured_fit(other, model)[2].values_mm()
    except Refusal:  # unmeasurable there: the focal length's share stays unknown
        return None
    return {name: abs(value - other_mm[name]) for name, value in measured.values_mm().items()}


def _measured_fit(fit, model) -> tuple[np.ndarray, np.ndarray, Measurements]:
    """The fitted foot in its canonical pose (V, 3), its faces (F, 3) and its measurements; a shape far outside
    the population (a failed fit) has none well-defined: refused as unmeasurable."""
    canonical = fit.canonical_vertices(model)
    with torch.no_grad():
        rest = model(torch.as_tensor(fit.shape, dtype=torch.float32)[None], side=fit.side)
    faces = model.faces(fit.side).numpy()
    try:
        measured = measure_foot(
            canonical, faces, FootLandmarks.from_joints(rest.joints[0].double().numpy()), side=fit.side
        )
    except ValueError as exc:
        # measure_foot's words are for a caller's own mesh (its frame, its units); the model's mesh breaks its
        # checks only where the fitted shape lies far outside the population
        far = float(np.abs(fit.shape).max())
        raise refusals.unmeasurable(
            f"the fit ended in a shape {far:.0f} SD from the average foot along one of its components: a fit that "
            "went wrong"
        ) from exc
    return canonical, faces, measured


def _intrinsics_dict(photo: Photo, reference: ReferenceObject | None, photo_K: np.ndarray) -> dict:
    """The photo's intrinsics as result.json gives them: its own, or with the focal length the reference object's
    perspective gave (source ``reference``; ``photo_K``: the working photo's own camera, before that)."""
    own = photo.intrinsics.to_dict()
    if reference is None:
        return own
    factor = float(reference.K[0, 0]) / float(photo_K[0, 0])
    if abs(factor - 1.0) < 1e-9:
        return own
    return {
        **own,
        "fx": own["fx"] * factor,
        "fy": own["fy"] * factor,
        "source": "reference",
        "note": (
            f"focal length from the perspective of {references.kind(reference.kind).described} and a phone's usual "
            f"distance from it: {factor:.2f}x the "
            f"{own['source']} one ({own['fx']:.0f} px), known to {100 * reference.focal_log_sd:.0f} %"
        ),
    }


def _reference_dict(reference, to_photo: float) -> dict:
    return {
        "kind": reference.kind,
        "corners_px": rescale_pixels(np.asarray(reference.corners_px), to_photo).round(2).tolist(),
        "size_mm": list(reference.size_mm),
        "scale_rel_sd": float(reference.scale_rel_sd),
        "kind_assumed": bool(reference.kind_assumed),
    }


def _measured_foot_mask(mask: np.ndarray, fit, K: np.ndarray, config: MeasureConfig) -> np.ndarray:
    """(H, W) bool: the silhouette ``mask``'s pixels within ``config.measured_mask_margin`` of the fitted foot's image
    below the ankle (``fit.foot_image``): the foot measured, without the shin the network also took for foot; the
    whole silhouette where the fitted foot has no image."""
    from footmesh.fit import foot_image

    covered = foot_image(fit.vertices_cam, fit.side, K, mask.shape)
    if covered is None or not covered.any():
        return mask
    rows, cols = np.nonzero(covered)
    reach = max(int(round(config.measured_mask_margin * max(np.ptp(rows), np.ptp(cols)))), 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
    return mask & (cv2.dilate(covered.astype(np.uint8), kernel) > 0)


def draw_overlay(rgb: np.ndarray, located: Located, fit, K: np.ndarray, reference) -> np.ndarray:
    """``viz.draw_overlay`` of one fitted foot: its silhouette, the fitted mesh's outline, joints and reference."""
    from footmesh.fit import projected_mask

    h, w = rgb.shape[:2]
    model_mask = projected_mask(fit.vertices_cam, default_model().faces(fit.side).numpy(), K, (h, w))
    corners = None if reference is None else np.asarray(reference.corners_px)
    return viz.draw_overlay(rgb, located.mask, located.cues.joints2d_px, model_mask, corners)


def write_outputs(out: Path, result: dict, files: _Files) -> None:
    """Write the meshes, the overlay and result.json (last, so a result.json means a complete folder)."""
    import trimesh

    out.mkdir(parents=True, exist_ok=True)
    report.write_mesh(out / "mesh.obj", files.vertices_cam, files.faces)
    report.write_mesh(out / "canonical.obj", files.canonical_vertices, files.canonical_faces)
    mesh = trimesh.Trimesh(files.vertices_cam, files.faces, process=False)
    with report.atomic_path(out / "mesh.glb") as tmp:
        tmp.write_bytes(mesh.export(file_type="glb"))
    for name, image in (("overlay.png", files.overlay[..., ::-1]), ("mask.png", files.mask), *files.extra_masks):
        with report.atomic_path(out / name) as tmp:
            ok, buf = cv2.imencode(".png", image)
            tmp.write_bytes(buf.tobytes())
    report.write_json(out / "result.json", result)
