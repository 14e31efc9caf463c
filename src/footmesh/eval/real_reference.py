"""The reference detector on real photos, against sheet corners marked by hand.

The ground truth (``tests/data/real_a4_corners.json``) names each photo of ``../shared/real/a4/photos`` and its
sheet's four corners in px of the photo scaled to ``MARKED_SIDE_PX`` on its longer side. Each photo is searched
the way ``footmesh measure`` does it: at the pipeline's working size, with the first pass's foot silhouette
(dilated) as the excluded region. Two errors are reported: the corners' distance from the marked ones (px at
``MARKED_SIDE_PX``), and the relative error of the camera-to-sheet-centre distance against the pose the marked
corners give, which every millimetre measured through the floor inherits. The photos are also scored turned by
quarter turns (``score_turned``) and cropped so that the photo's edge cuts the sheet (``score_cropped``). These
photos are for evaluation only: nothing here trains or tunes on them.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from footmesh.geometry.camera import rescale_pixels

MARKED_SIDE_PX = 1600
"""The marked corners are in px of the photo scaled to this longer side."""
DILATE_PX = 15
"""The foot's silhouette is dilated by this (px, working size) before it is excluded, as in the pipeline."""


@dataclass(frozen=True)
class RealReferenceScore:
    """One photo: whether an A4 sheet was found (``kind`` what was, or None), its corners' errors (4,) px at
    ``MARKED_SIDE_PX`` in the marked order, the relative error of the distance to the sheet's centre, the relative
    SD the detector gave for its scale, why nothing was taken (``rejected``), and the seconds the search took."""

    photo: str
    kind: str | None
    corner_errors_px: tuple[float, ...]
    centre_distance_error: float
    scale_rel_sd: float
    rejected: str | None
    seconds: float

    @property
    def found(self) -> bool:
        """An A4 sheet was found."""
        return self.kind == "a4"


def read_corners(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Photo name -> (4, 2) marked corners (px at ``MARKED_SIDE_PX``) from a ground-truth JSON file."""
    photos = json.loads(Path(path).read_text())["photos"]
    return {name: np.asarray(corners, dtype=np.float64).reshape(4, 2) for name, corners in photos.items()}


def matched_corner_errors(found_px: np.ndarray, marked_px: np.ndarray) -> np.ndarray:
    """(4,) distances from the marked corners to the found ones, over the found corners' cyclic orders either way
    round (the detector starts where its own convention says)."""
    orders = [np.roll(c, r, axis=0) for c in (found_px, found_px[::-1]) for r in range(4)]
    return min((np.linalg.norm(o - marked_px, axis=1) for o in orders), key=np.max)


def sheet_centre_distance_mm(corners_px: np.ndarray, K: np.ndarray) -> float:
    """Camera-to-centre distance (mm) of an A4 sheet with these image corners (4, 2) in order round it, either
    side first and either way round: the pose (``rectangle_pose``) that reprojects them best."""
    from footmesh.cues.reference import SIZES_MM, rectangle_pose

    length, width = SIZES_MM["a4"]
    best = (float("inf"), float("nan"))
    for order in (corners_px, corners_px[::-1]):
        for start in range(4):
            solved = rectangle_pose(np.roll(order, -start, axis=0), "a4", K)
            if solved is not None:
                pose, reprojection = solved
                centre = pose[:3, :3] @ [length / 2, width / 2, 0.0] + pose[:3, 3]
                best = min(best, (reprojection, float(np.linalg.norm(centre))))
    return best[1]


def pipeline_search(path: str | os.PathLike, intrinsics: str | os.PathLike | None = None):
    """The pipeline's reference search on one photo (working resolution, the feet masked out; ``intrinsics``: its
    K.json, else EXIF or the default): (photo, K of the working image, working-to-photo factor,
    ``ReferenceSearch``, seconds of the search)."""
    import torch

    from footmesh.config import MeasureConfig
    from footmesh.cues.reference import search_reference
    from footmesh.load import load_photo
    from footmesh.pipeline import locate_feet, working_photo

    config = MeasureConfig()
    photo = load_photo(path, intrinsics=intrinsics)
    rgb, _, camera, to_photo = working_photo(photo, config.rgb_working_max_side)
    with torch.inference_mode():
        feet = locate_feet(rgb, None, camera.K, "rgb", config)
    feet_mask = np.any([foot.mask for foot in feet], axis=0).astype(np.uint8)
    exclude = cv2.dilate(feet_mask, np.ones((DILATE_PX, DILATE_PX), np.uint8)) > 0
    start = time.perf_counter()
    focal_prior = config.focal_prior_log_sd[photo.intrinsics.source]
    searched = search_reference(
        rgb,
        camera.K,
        exclude_mask=exclude,
        focal_prior_log_sd=focal_prior,
        distance_prior=config.camera_distance_prior_mm,
    )
    return photo, camera.K, to_photo, searched, time.perf_counter() - start


def false_references(photos_dir: str | os.PathLike) -> list[tuple[str, str]]:
    """(photo, kind) of every photo in a folder of photos *without* any reference object where the pipeline's
    search takes something for one (each such one would give millimetres the photo cannot give)."""
    found = []
    for path in sorted(p for p in Path(photos_dir).iterdir() if p.is_file()):
        searched = pipeline_search(path)[3]
        if searched.found is not None:
            found.append((path.name, searched.found.kind))
    return found


def score_photo(
    path: str | os.PathLike, marked_px: np.ndarray, intrinsics: str | os.PathLike | None = None
) -> RealReferenceScore:
    """Search one photo for its reference the way the pipeline does and score it against the marked corners (all
    four, also those of a sheet beyond the photo's edge; ``intrinsics``: ``pipeline_search``'s)."""
    photo, K, to_photo, searched, seconds = pipeline_search(path, intrinsics)
    found = searched.found
    nan4 = (float("nan"),) * 4
    if found is None:
        return RealReferenceScore(Path(path).name, None, nan4, float("nan"), float("nan"), searched.rejected, seconds)
    to_marked = MARKED_SIDE_PX / max(photo.rgb.shape[:2])
    # pixel centres, not the pixels' corners, are scaled (``rescale_pixels``): a plain product moved every found
    # corner 0.75 px towards the origin at 1600 px
    errors = matched_corner_errors(rescale_pixels(found.corners_px, to_photo * to_marked), marked_px)
    # at the camera the object was found with (its perspective may have corrected a guessed focal length)
    truth = sheet_centre_distance_mm(rescale_pixels(marked_px, 1.0 / (to_photo * to_marked)), found.K)
    return RealReferenceScore(
        photo=Path(path).name,
        kind=found.kind,
        corner_errors_px=tuple(float(e) for e in errors),
        centre_distance_error=found.object_distance_mm / truth - 1.0,
        scale_rel_sd=found.scale_rel_sd,
        rejected=None,
        seconds=seconds,
    )


def score_turned(
    path: str | os.PathLike, marked_px: np.ndarray, quarter_turns: int, folder: str | os.PathLike
) -> RealReferenceScore:
    """``score_photo`` of the photo turned ``quarter_turns`` x 90 deg counter-clockwise (a phone held sideways or
    upside down: the search must not care), against its marked corners turned with it; the turned photo is written
    to ``folder`` (PNG, lossless)."""
    from footmesh.geometry.camera import turned_pixels
    from footmesh.load import load_photo

    rgb = load_photo(path).rgb
    h, w = rgb.shape[:2]
    to_marked = MARKED_SIDE_PX / max(h, w)
    turned_path = Path(folder) / f"{Path(path).stem}_turned{quarter_turns % 4}.png"
    _write_png(turned_path, np.rot90(rgb, quarter_turns))
    pixels = turned_pixels(w, h, quarter_turns)
    turned_px = rescale_pixels(marked_px, 1.0 / to_marked) @ pixels[:2, :2].T + pixels[:2, 2]
    return score_photo(turned_path, rescale_pixels(turned_px, to_marked))


def score_cropped(
    path: str | os.PathLike,
    marked_px: np.ndarray,
    edge: str,
    depth: float,
    folder: str | os.PathLike,
    corners_cut: int = 2,
) -> RealReferenceScore:
    """``score_photo`` of the photo cropped so that its ``edge`` ("top", "bottom", "left" or "right") cuts across the
    sheet and leaves the ``corners_cut`` corners nearest that edge beyond it: the crop's edge crosses ``depth`` of
    the way from the nearest corner left out to the nearest one kept (two: a photo framed on the foot, ``cut``; one:
    a sheet lying askew, its corner cut off, ``finish.finish_beyond``). The crop is
    written to ``folder`` (PNG, lossless) with its intrinsics: the focal length the whole sheet gives the photo
    (its perspective; the photos carry no EXIF) and the photo's principal point, where the crop has it, so that
    only the sheet's far side is missing."""
    photo, K, to_photo, whole, _ = pipeline_search(path)
    if whole.found is None:
        raise ValueError(f"{Path(path).name}: no sheet found in the whole photo to take its focal length from")
    rgb = photo.rgb
    h, w = rgb.shape[:2]
    to_marked = MARKED_SIDE_PX / max(h, w)
    corners = rescale_pixels(marked_px, 1.0 / to_marked)
    axis = 1 if edge in ("top", "bottom") else 0
    signed = corners[:, axis] if edge in ("top", "left") else -corners[:, axis]
    if corners_cut not in (1, 2):
        raise ValueError(f"corners_cut must be 1 or 2, got {corners_cut}")
    first, second = np.sort(signed)[corners_cut - 1 : corners_cut + 1]
    cut = int(round(abs(first + depth * (second - first))))
    start = np.zeros(2, int)
    stop = np.array([w, h])
    if edge in ("top", "left"):
        start[axis] = cut
    else:
        stop[axis] = cut
    corner = "_corner" if corners_cut == 1 else ""
    cropped_name = Path(folder) / f"{Path(path).stem}_{edge}{round(100 * depth)}{corner}"
    image = rgb[start[1] : stop[1], start[0] : stop[0]]
    _write_png(cropped_name.with_suffix(".png"), image)
    focal = float(whole.found.K[0, 0]) * to_photo
    centre = rescale_pixels(K[:2, 2], to_photo) - start
    intrinsics = {"fx": focal, "fy": focal, "cx": float(centre[0]), "cy": float(centre[1])}
    intrinsics |= {"width": float(image.shape[1]), "height": float(image.shape[0])}
    k_path = cropped_name.with_suffix(".K.json")
    k_path.write_text(json.dumps(intrinsics))
    crop_to_marked = MARKED_SIDE_PX / max(image.shape[:2])
    return score_photo(cropped_name.with_suffix(".png"), rescale_pixels(corners - start, crop_to_marked), k_path)


def _write_png(path: Path, rgb: np.ndarray) -> None:
    """An (H, W, 3) uint8 RGB image (any strides) written as a PNG: the turned and cropped photos, losslessly."""
    cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))


def score_set(photos_dir: str | os.PathLike, corners_json: str | os.PathLike) -> list[RealReferenceScore]:
    """``score_photo`` of every photo the ground truth names, in name order."""
    marked = read_corners(corners_json)
    return [score_photo(Path(photos_dir) / name, marked[name]) for name in sorted(marked)]
