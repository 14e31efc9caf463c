"""``footmesh eval real``: the RGB silhouette on real photos with hand-drawn foot masks, and a contact sheet.

A set is a folder with ``labels.json`` (per photo ``{photo, mask, size [w, h], feet: [{side, polygon_px}]}``),
the photos and masks it names (mask pixels: 0 not foot, 1 left foot, 2 right foot), as in
``../shared/real/rafiansyah``. The network runs on the whole photo padded to a square, as the pipeline's first
pass does, and its silhouette (>= 0.5) is compared with the union of the hand-drawn feet. Left/right is scored
per hand-drawn foot: the network sees the square crop the pipeline's second pass would cut around that foot
(``pipeline.crop_around``, ``MeasureConfig.crop_fill``), so the side is judged apart from the first pass's
silhouette; that crop's silhouette is scored too (IoU with the hand-drawn feet inside the crop), as it is the
one the fit sees. These photos are for evaluation only: nothing here trains or tunes on them.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from footmesh.report import atomic_path, write_json

GOOD_IOU = 0.8
"""A photo counts as segmented well from this IoU on (issue 18's share of photos)."""
THUMB_PX = 240
"""Longer side of one contact-sheet tile."""


@dataclass(frozen=True)
class PhotoScore:
    """Silhouette agreement of one photo: ``iou``, ``precision`` (predicted foot pixels that are foot) and
    ``recall`` (foot pixels predicted), each in [0, 1]; ``feet`` the hand-labelled sides; ``predicted_sides``
    the network's side of each of those feet (empty for a network without a left/right head); ``crop_ious`` the
    IoU of the silhouette on the crop around each foot."""

    photo: str
    iou: float
    precision: float
    recall: float
    feet: tuple[str, ...]
    predicted_sides: tuple[str, ...] = ()
    crop_ious: tuple[float, ...] = ()


def mask_scores(predicted: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """IoU, precision and recall of two (H, W) bool masks (1.0 where both are empty, as nothing was missed)."""
    if predicted.shape != truth.shape:
        raise ValueError(f"masks of different sizes: {predicted.shape} and {truth.shape}")
    both = float(np.logical_and(predicted, truth).sum())
    n_pred, n_true = float(predicted.sum()), float(truth.sum())
    union = n_pred + n_true - both
    iou = both / union if union else 1.0
    precision = both / n_pred if n_pred else (1.0 if not n_true else 0.0)
    recall = both / n_true if n_true else 1.0
    return iou, precision, recall


def read_set(folder: str | os.PathLike) -> list[dict]:
    """The entries of a real set's ``labels.json``, with a clear error when it is not one."""
    folder = Path(folder)
    labels = folder / "labels.json"
    if not labels.is_file():
        raise ValueError(f"{folder} is not a real-photo set: it has no labels.json")
    try:
        data = json.loads(labels.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{labels} is not valid JSON ({exc.msg}, line {exc.lineno})") from None
    entries = list(data.values()) if isinstance(data, dict) else data
    for entry in entries:
        missing = {"photo", "mask", "feet"} - set(entry)
        if missing:
            raise ValueError(f"{labels}: an entry lacks {', '.join(sorted(missing))}")
    return entries


MASK_VALUE = {"left": 1, "right": 2}
"""Mask pixel value of each side's hand-drawn foot."""


def evaluate_set(
    folder: str | os.PathLike,
    sheet: str | os.PathLike | None = None,
    progress: bool = True,
    weights: str | os.PathLike | None = None,
) -> list[PhotoScore]:
    """Score every photo of a real set with the shipped RGB network (or the one in ``weights``); write a contact
    sheet of overlays to ``sheet`` (PNG) if given."""
    from tqdm import tqdm

    from footmesh.load import load_image
    from footmesh.pipeline import whole_photo_cues

    folder = Path(folder)
    scores, tiles = [], []
    for entry in tqdm(read_set(folder), desc=f"eval real {folder.name}", disable=not progress):
        rgb, _ = load_image(folder / entry["photo"])
        truth_img = cv2.imread(str(folder / entry["mask"]), cv2.IMREAD_GRAYSCALE)
        if truth_img is None:
            raise ValueError(f"{folder / entry['mask']} is not a readable mask image")
        if truth_img.shape != rgb.shape[:2]:
            raise ValueError(f"{entry['mask']} is {truth_img.shape[::-1]} px but its photo {rgb.shape[1::-1]}")
        predicted = whole_photo_cues("rgb", rgb, None, weights).silhouette >= 0.5
        truth = truth_img > 0
        iou, precision, recall = mask_scores(predicted, truth)
        feet = tuple(f["side"] for f in entry["feet"])
        sides, crop_ious = crop_scores(rgb, truth_img, feet, weights)
        scores.append(PhotoScore(entry["photo"], iou, precision, recall, feet, sides, crop_ious))
        if sheet is not None:
            said = f" L/R {''.join(s[0].upper() for s in sides)}" if sides else ""
            tiles.append(overlay_tile(rgb, predicted, truth, f"IoU {iou:.2f}{said}"))
    if sheet is not None and tiles:
        write_contact_sheet(tiles, sheet)
    return scores


def crop_scores(
    rgb: np.ndarray, mask: np.ndarray, feet: tuple[str, ...], weights: str | os.PathLike | None
) -> tuple[tuple[str, ...], tuple[float, ...]]:
    """The network's side of each hand-drawn foot (``mask`` values ``MASK_VALUE``) from the crop around it (empty
    when the network has no left/right head), and the IoU of that crop's silhouette with the feet in the crop."""
    from footmesh.config import MeasureConfig
    from footmesh.cues.predict import predict_cues
    from footmesh.pipeline import crop_around

    fill = MeasureConfig().crop_fill
    sides, ious = [], []
    for side in feet:
        ys, xs = np.nonzero(mask == MASK_VALUE[side])
        if not len(xs):
            raise ValueError(f"the mask has no pixels of the {side} foot its labels name")
        crop = crop_around(xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1, fill)
        cues = predict_cues("rgb", crop.cut(rgb), weights=weights)
        truth = crop.cut(mask, fill=0) > 0
        ious.append(mask_scores(cues.silhouette >= 0.5, truth)[0])  # predict_cues answers in the crop's pixels
        if cues.right_probability is not None:
            sides.append("right" if cues.right_probability >= 0.5 else "left")
    return tuple(sides) if len(sides) == len(feet) else (), tuple(ious)


def overlay_tile(rgb: np.ndarray, predicted: np.ndarray, truth: np.ndarray, caption: str) -> np.ndarray:
    """A small (h, w, 3) uint8 overlay: predicted foot tinted cyan, hand-drawn outline green, caption on top."""
    tile = rgb.astype(np.float32)
    tile[predicted] = 0.5 * tile[predicted] + 0.5 * np.array([0, 255, 255], np.float32)
    tile = tile.astype(np.uint8)
    contours, _ = cv2.findContours(truth.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    scale = THUMB_PX / max(rgb.shape[:2])
    thick = max(1, int(round(2 / scale)))
    cv2.drawContours(tile, contours, -1, (0, 255, 0), thick)
    tile = cv2.resize(tile, (round(rgb.shape[1] * scale), round(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    cv2.putText(tile, caption, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(tile, caption, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return tile


def write_contact_sheet(tiles: list[np.ndarray], path: str | os.PathLike, columns: int = 10) -> None:
    """Tiles (RGB uint8) in a grid of ``columns``, written atomically as PNG."""
    from PIL import Image

    from footmesh.viz import tile_images

    with atomic_path(path) as tmp:
        Image.fromarray(tile_images(tiles, columns, gap=0, background=32)).save(tmp, format="PNG")


def summarise(scores: list[PhotoScore]) -> dict[str, float]:
    """Mean IoU, precision and recall, the share of photos with IoU >= ``GOOD_IOU``, the mean IoU on the crops
    around the feet and the share of feet whose side the network got right (None without a left/right head)."""
    if not scores:
        raise ValueError("no photos to summarise")
    judged = [(t, p) for s in scores if s.predicted_sides for t, p in zip(s.feet, s.predicted_sides, strict=True)]
    return {
        "photos": len(scores),
        "feet": sum(len(s.feet) for s in scores),
        "mean_iou": float(np.mean([s.iou for s in scores])),
        "mean_precision": float(np.mean([s.precision for s in scores])),
        "mean_recall": float(np.mean([s.recall for s in scores])),
        "share_iou_ge_0.8": float(np.mean([s.iou >= GOOD_IOU for s in scores])),
        "mean_crop_iou": float(np.mean([i for s in scores for i in s.crop_ious])),
        "side_right_share": float(np.mean([t == p for t, p in judged])) if judged else None,
    }


def format_table(name: str, summary: dict[str, float]) -> str:
    """The summary beside issue 18's targets."""
    side = summary["side_right_share"]
    rows = [
        ("mean silhouette IoU", f"{summary['mean_iou']:.3f}", ">= 0.85"),
        ("mean precision", f"{summary['mean_precision']:.3f}", "-"),
        ("mean recall", f"{summary['mean_recall']:.3f}", "-"),
        (f"photos with IoU >= {GOOD_IOU}", f"{100 * summary['share_iou_ge_0.8']:.1f} %", "-"),
        ("mean IoU on the crop per foot", f"{summary['mean_crop_iou']:.3f}", "- (second pass, what the fit sees)"),
        ("side right, per foot", "no left/right head" if side is None else f"{100 * side:.1f} %", ">= 95 %"),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f"real photos: {name} ({summary['photos']} photos, {summary['feet']} feet), RGB network, whole photo"]
    lines += [f"  {what:<{width}}  {ours:<34}  target {target}" for what, ours, target in rows]
    return "\n".join(lines)


def run_eval(
    folder: str | os.PathLike,
    sheet: str | os.PathLike | None,
    json_out: str | None,
    progress: bool,
    weights: str | os.PathLike | None = None,
) -> str:
    """Evaluate a real set; optionally write per-photo scores to ``json_out``; return the printed table."""
    scores = evaluate_set(folder, sheet, progress, weights)
    summary = summarise(scores)
    if json_out:
        write_json(json_out, {"summary": summary, "photos": [asdict(s) for s in scores]})
    return format_table(Path(folder).name, summary)
