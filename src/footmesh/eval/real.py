"""``footmesh eval real``: the RGB silhouette on real photos with hand-drawn foot masks, and a contact sheet.

A set is a folder with ``labels.json`` (per photo ``{photo, mask, size [w, h], feet: [{side, polygon_px}]}``),
the photos and masks it names (mask pixels: 0 not foot, 1 left foot, 2 right foot), as in
``../shared/real/rafiansyah``. The network runs on the whole photo padded to a square, as the pipeline's first
pass does, and its silhouette (>= 0.5) is compared with the union of the hand-drawn feet. Left/right is scored
per hand-drawn foot: the network sees the square crop the pipeline's second pass would cut around that foot
(``pipeline.crop_around``, ``MeasureConfig.crop_fill``), so the side is judged apart from the first pass's
silhouette; that crop's silhouette is scored too (IoU with the hand-drawn feet inside the crop). The foot the
fit is given is scored last: the pipeline's own located foot (its framing, the cut to the joints and the snap to
the photo's edges; shipped network only) that best matches each hand-drawn one. These photos are for evaluation
only: nothing here trains or tunes on them.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from footmesh.config import MeasureConfig
from footmesh.report import atomic_path, write_json

if TYPE_CHECKING:
    from footmesh.load import Photo

GOOD_IOU = 0.8
"""A photo counts as segmented well from this IoU on (issue 18's share of photos)."""
OFF_FEET_SHARE = 0.5
"""A measured foot whose mask has less than this share of its pixels on the hand-drawn feet was measured on
something else (a shin, a charger on the floor)."""
THUMB_PX = 240
"""Longer side of one contact-sheet tile."""


@dataclass(frozen=True)
class PhotoScore:
    """Silhouette agreement of one photo: ``iou``, ``precision`` (predicted foot pixels that are foot) and
    ``recall`` (foot pixels predicted), each in [0, 1]; ``feet`` the hand-labelled sides; ``predicted_sides``
    the network's side of each of those feet (empty for a network without a left/right head); ``crop_ious`` the
    IoU of the silhouette on the crop around each foot; ``located_ious`` that of the pipeline's own located foot
    that best matches each hand-drawn one (0 when it found none; ``located_scores``); with ``measure``,
    ``measured_ious`` that of the best-matching ``mask.png`` that ``footmesh measure`` wrote (0 when it refused the
    photo: ``answered`` False), ``measured_sides`` the side its result gives that foot ("" where it measured
    none there), ``off_feet`` how many of its masks lie mostly off every hand-drawn foot (``OFF_FEET_SHARE``)
    and ``primary_off_feet`` whether the result's own keys (the foot measured best) are such a one."""

    photo: str
    iou: float
    precision: float
    recall: float
    feet: tuple[str, ...]
    predicted_sides: tuple[str, ...] = ()
    crop_ious: tuple[float, ...] = ()
    located_ious: tuple[float, ...] = ()
    measured_ious: tuple[float, ...] = ()
    answered: bool | None = None
    measured_sides: tuple[str, ...] = ()
    off_feet: int | None = None
    primary_off_feet: bool | None = None


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
    measure: bool = False,
) -> list[PhotoScore]:
    """Score every photo of a real set with the shipped RGB network (or the one in ``weights``); write a contact
    sheet of overlays to ``sheet`` (PNG) if given (the first pass's silhouette, or with ``measure`` the masks
    ``footmesh measure`` wrote); ``measure``: also run the whole pipeline on each photo and score the masks it
    writes (``measured_ious``; the shipped networks only)."""
    from tqdm import tqdm

    from footmesh.load import load_photo
    from footmesh.pipeline import whole_photo_cues

    folder = Path(folder)
    scores, tiles = [], []
    for entry in tqdm(read_set(folder), desc=f"eval real {folder.name}", disable=not progress):
        photo = load_photo(folder / entry["photo"])
        rgb = photo.rgb
        truth_img = _read_mask(folder, entry, rgb.shape[:2])
        predicted = whole_photo_cues("rgb", rgb, None, weights).silhouette >= 0.5
        truth = truth_img > 0
        iou, precision, recall = mask_scores(predicted, truth)
        feet = tuple(f["side"] for f in entry["feet"])
        sides, crop_ious = crop_scores(rgb, truth_img, feet, weights)
        located = () if weights is not None else located_ious(photo, truth_img, feet)
        answered, measured, shown, caption = None, (), predicted, f"IoU {iou:.2f}"
        measured_sides: tuple[str, ...] = ()
        off_feet, primary_off_feet = None, None
        if measure and weights is None:
            made = measured_ious(photo, truth_img, feet)
            answered, measured, measured_sides, shown = made.answered, made.ious, made.sides, made.union
            off_feet, primary_off_feet = made.off_feet, made.primary_off_feet
            caption = "mask.png " + (" ".join(f"{i:.2f}" for i in measured) if answered else "refused")
        scores.append(
            PhotoScore(
                entry["photo"],
                iou,
                precision,
                recall,
                feet,
                predicted_sides=sides,
                crop_ious=crop_ious,
                located_ious=located,
                measured_ious=measured,
                answered=answered,
                measured_sides=measured_sides,
                off_feet=off_feet,
                primary_off_feet=primary_off_feet,
            )
        )
        if sheet is not None:
            said = f" L/R {''.join(s[0].upper() for s in sides)}" if sides else ""
            tiles.append(overlay_tile(rgb, shown, truth, caption + said))
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


def located_ious(
    photo: Photo, mask: np.ndarray, feet: tuple[str, ...], config: MeasureConfig | None = None
) -> tuple[float, ...]:
    """Per hand-drawn foot (``mask`` values ``MASK_VALUE``): the IoU of the best-matching foot the pipeline
    locates in the photo (``pipeline.locate_feet`` at its working resolution, as ``footmesh measure`` runs it: both
    passes of the shipped RGB network, the cut to the joints and the snap to the photo's edges, and the look at the
    photo turned where upright the networks see the ankle below the toes or the foot past the edge,
    ``pipeline.turned_where_needed``, without a reference object's floor), 0 when it locates none (a refusal, or
    no foot there)."""
    from footmesh.errors import Refusal
    from footmesh.pipeline import locate_feet, turned_where_needed, working_photo

    config = config if config is not None else MeasureConfig()
    rgb, _, camera, _ = working_photo(photo, config.rgb_working_max_side)
    try:
        located = locate_feet(rgb, None, camera.K, "rgb", config)
        found = [foot.mask for foot in turned_where_needed(located, rgb, None, camera, "rgb", config)]
    except Refusal:
        found = []
    return _best_ious(found, cv2.resize(mask, rgb.shape[1::-1], interpolation=cv2.INTER_NEAREST), feet)


@dataclass(frozen=True)
class Measured:
    """What ``footmesh measure`` made of a photo (``measured_ious``): whether it answered, per hand-drawn foot the
    IoU of the best-matching ``mask.png`` it wrote (0 where none) and that foot's side in its result ("" where no
    mask overlaps the foot), the union of its masks (H, W) bool, how many of them lie mostly off every hand-drawn
    foot (``OFF_FEET_SHARE``: a shin, a charger on the floor measured as a foot) and whether the foot its result's
    own keys give is one of those."""

    answered: bool
    ious: tuple[float, ...]
    sides: tuple[str, ...]
    union: np.ndarray
    off_feet: int = 0
    primary_off_feet: bool = False


def measured_ious(photo: Photo, mask: np.ndarray, feet: tuple[str, ...]) -> Measured:
    """``footmesh measure`` (default settings) on one photo, scored against its hand-drawn feet (``mask`` values
    ``MASK_VALUE``; its masks ``mask.png``, ``mask_1.png`` are in photo pixels)."""
    import tempfile

    from footmesh.errors import Refusal
    from footmesh.pipeline import measure_loaded_photo
    from footmesh.report import request_options

    with tempfile.TemporaryDirectory() as out:
        try:
            result = measure_loaded_photo(photo, out, request_options("auto", "mm", "auto"))
        except Refusal:
            return Measured(False, (0.0,) * len(feet), ("",) * len(feet), np.zeros(mask.shape, bool))
        # "feet" lists each foot only where two were in view
        entries = result["feet"] if "feet" in result else [{"measured": True, **result}]
        entries = [entry for entry in entries if entry["measured"]]
        written = [
            (entry["side"], cv2.imread(str(Path(out) / entry["files"]["mask_png"]), cv2.IMREAD_GRAYSCALE) > 0)
            for entry in entries
        ]
        # the result's own keys are the foot measured best, whose mask is mask.png
        primary = [entry["files"]["mask_png"] for entry in entries].index("mask.png")
    ious, sides = [], []
    for side in feet:
        truth = mask == MASK_VALUE[side]
        scored = ((mask_scores(m, truth)[0], s, m) for s, m in written)
        iou, said, best = max(scored, key=lambda entry: entry[0], default=(0.0, "", None))
        ious.append(iou)
        sides.append(said if best is not None and (best & truth).any() else "")
    masks = [m for _, m in written]
    union = np.any(masks, axis=0) if masks else np.zeros(mask.shape, bool)
    off = [(m & (mask > 0)).sum() < OFF_FEET_SHARE * m.sum() for m in masks]
    return Measured(True, tuple(ious), tuple(sides), union, sum(off), off[primary])


def _best_ious(found: list[np.ndarray], mask: np.ndarray, feet: tuple[str, ...]) -> tuple[float, ...]:
    """Per hand-drawn foot of ``mask`` (values ``MASK_VALUE``): the best IoU of any of the ``found`` (H, W) bool
    masks with it, 0 when there is none."""
    return tuple(max((mask_scores(f, mask == MASK_VALUE[side])[0] for f in found), default=0.0) for side in feet)


def located_scores(folder: str | os.PathLike, config: MeasureConfig | None = None) -> list[float]:
    """``located_ious`` of every hand-drawn foot of a real set (``config``: the pipeline's settings)."""
    from footmesh.load import load_photo

    folder = Path(folder)
    ious: list[float] = []
    for entry in read_set(folder):
        photo = load_photo(folder / entry["photo"])
        feet = tuple(f["side"] for f in entry["feet"])
        ious += located_ious(photo, _read_mask(folder, entry, photo.rgb.shape[:2]), feet, config)
    return ious


def _read_mask(folder: Path, entry: dict, shape: tuple[int, int]) -> np.ndarray:
    """The (H, W) uint8 hand-drawn mask of an entry, checked to be readable and of its photo's ``shape``."""
    mask = cv2.imread(str(folder / entry["mask"]), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise ValueError(f"{folder / entry['mask']} is not a readable mask image")
    if mask.shape != shape:
        raise ValueError(f"{entry['mask']} is {mask.shape[::-1]} px but its photo {shape[::-1]}")
    return mask


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
    around the feet, that of the pipeline's located feet (None where not scored) and the share of feet whose side
    the network got right (None without a left/right head)."""
    if not scores:
        raise ValueError("no photos to summarise")
    judged = [(t, p) for s in scores if s.predicted_sides for t, p in zip(s.feet, s.predicted_sides, strict=True)]
    located = [i for s in scores for i in s.located_ious]
    measured = [i for s in scores for i in s.measured_ious]
    measured_sides = [(t, p) for s in scores for t, p in zip(s.feet, s.measured_sides, strict=False) if p]
    answered = [s for s in scores if s.answered]
    return {
        "photos": len(scores),
        "feet": sum(len(s.feet) for s in scores),
        "mean_iou": float(np.mean([s.iou for s in scores])),
        "mean_precision": float(np.mean([s.precision for s in scores])),
        "mean_recall": float(np.mean([s.recall for s in scores])),
        "share_iou_ge_0.8": float(np.mean([s.iou >= GOOD_IOU for s in scores])),
        "mean_crop_iou": float(np.mean([i for s in scores for i in s.crop_ious])),
        "mean_located_iou": float(np.mean(located)) if located else None,
        "mean_measured_iou": float(np.mean(measured)) if measured else None,
        "answered": sum(bool(s.answered) for s in scores) if measured else None,
        "side_right_share": float(np.mean([t == p for t, p in judged])) if judged else None,
        "measured_feet": len(measured_sides) if measured else None,
        "measured_side_right_share": float(np.mean([t == p for t, p in measured_sides])) if measured_sides else None,
        "measured_off_feet": sum(s.off_feet for s in answered) if measured else None,
        "primary_off_feet": sum(bool(s.primary_off_feet) for s in answered) if measured else None,
    }


def format_table(name: str, summary: dict[str, float]) -> str:
    """The summary beside issue 18's targets."""
    side = summary["side_right_share"]
    rows = [
        ("mean silhouette IoU", f"{summary['mean_iou']:.3f}", ">= 0.85"),
        ("mean precision", f"{summary['mean_precision']:.3f}", "-"),
        ("mean recall", f"{summary['mean_recall']:.3f}", "-"),
        (f"photos with IoU >= {GOOD_IOU}", f"{100 * summary['share_iou_ge_0.8']:.1f} %", "-"),
        ("mean IoU on the crop per foot", f"{summary['mean_crop_iou']:.3f}", "- (second pass, framed on the foot)"),
        ("mean IoU of the located foot", _or_dash(summary["mean_located_iou"]), "- (what the fit sees)"),
        ("mean IoU of the measured foot's mask.png", _or_dash(summary["mean_measured_iou"]), "- (--measure)"),
        ("photos answered by footmesh measure", _or_dash(summary["answered"], "d"), "- (--measure)"),
        ("side right, per foot", "no left/right head" if side is None else f"{100 * side:.1f} %", ">= 95 %"),
        ("side right, per measured foot", _side_share(summary), "- (--measure: the side in result.json)"),
        ("measured feet mostly off every drawn foot", _or_dash(summary["measured_off_feet"], "d"), "0 (--measure)"),
        ("  of them the result's own foot", _or_dash(summary["primary_off_feet"], "d"), "0 (--measure)"),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f"real photos: {name} ({summary['photos']} photos, {summary['feet']} feet), RGB network, whole photo"]
    lines += [f"  {what:<{width}}  {ours:<34}  target {target}" for what, ours, target in rows]
    return "\n".join(lines)


def _side_share(summary: dict[str, float]) -> str:
    """The share of measured feet given their right side, and how many were measured, or a dash."""
    share = summary["measured_side_right_share"]
    return "-" if share is None else f"{100 * share:.1f} % of {summary['measured_feet']}"


def _or_dash(value: float | None, spec: str = ".3f") -> str:
    return "-" if value is None else format(value, spec)


def run_eval(
    folder: str | os.PathLike,
    sheet: str | os.PathLike | None,
    json_out: str | None,
    progress: bool,
    weights: str | os.PathLike | None = None,
    measure: bool = False,
) -> str:
    """Evaluate a real set (``evaluate_set``); optionally write per-photo scores to ``json_out``; return the
    printed table."""
    scores = evaluate_set(folder, sheet, progress, weights, measure)
    summary = summarise(scores)
    if json_out:
        write_json(json_out, {"summary": summary, "photos": [asdict(s) for s in scores]})
    return format_table(Path(folder).name, summary)
