"""When a photo cannot be measured: each refusal a pure function of the evidence, returning a ``Refusal`` or None.

The pipeline (``footmesh.pipeline``) gathers the evidence -- the silhouette, the 2D joints, the fitted foot's
quality and view, the floor a reference object shows -- and raises the first refusal that applies, in the order
of this file. Each refusal says what it saw and what to retake (``Refusal.why``, ``Refusal.retake``); each is
tested on its own (``tests/test_refusals.py``). A fit that went wrong is retried by the fit itself (several
starts, both sides) before any of these sees it; what reaches them is evidence about the photo.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

from footmesh import references
from footmesh.config import MeasureConfig
from footmesh.errors import Refusal
from footmesh.model.skeleton import TOE_TIPS

if TYPE_CHECKING:  # the fit (and torch) is not needed to judge its numbers
    from footmesh.fit import FitQuality

FLAT_AND_IN_VIEW = "retake it from above and to the side, the whole foot flat on the floor"
"""What to retake when the fitted foot does not match the photo."""
FROM_THE_SIDE = "photograph it from the side and above"
HEEL = 17
LENGTH_ENDS = (3, 6, 17)
"""Big toe tip, second toe tip, heel: the ends of the foot's length."""


def no_foot(largest_region_px: float, photo_px: float, config: MeasureConfig) -> Refusal | None:
    """No silhouette region of at least ``config.min_foot_fraction`` of the photo."""
    if largest_region_px >= config.min_foot_fraction * photo_px:
        return None
    return Refusal(
        "no foot found in the photo",
        "photograph one bare foot from above, standing on the floor, filling about a third of the picture",
    )


def foot_vanished() -> Refusal:
    """The regions of the first look at the photo held no foot on the closer look."""
    return Refusal("no foot found in the photo (the foot region vanished on a closer look)")


def cut_off(mask: np.ndarray, joints_px: np.ndarray, width: int, height: int, config: MeasureConfig) -> Refusal | None:
    """A foot cut off by the photo's edge: its length could not be measured. The leg leaving the frame is normal:
    only silhouette pixels (``mask`` (H, W) bool) on the edge near the foot's joints (``joints_px`` (18, 2),
    within ``config.foot_zone_margin`` of the foot's length around their hull) count, or a toe tip or the heel
    beyond the edge."""
    length_px = float(np.linalg.norm(joints_px[list(TOE_TIPS)] - joints_px[HEEL], axis=1).max())
    hull = cv2.convexHull(np.round(joints_px).astype(np.int32))
    reach = max(int(round(config.foot_zone_margin * length_px)), 0)
    # the zone grown by ``reach`` stays inside the hull's box grown by as much: drawn and dilated in that window
    # only (a large kernel over the whole photo took 40 ms), and not at all when the window misses the photo's edge
    rows, cols = mask.shape
    x, y, box_w, box_h = cv2.boundingRect(hull)
    x0, y0 = max(x - reach, 0), max(y - reach, 0)
    x1, y1 = min(x + box_w + reach, cols), min(y + box_h + reach, rows)
    zone = np.zeros(mask.shape, np.uint8)
    if x1 > x0 and y1 > y0 and (x0 == 0 or y0 == 0 or x1 == cols or y1 == rows):
        window = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillConvexPoly(window, hull - np.array([x0, y0], np.int32), 1)
        if reach > 0:
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
            window = cv2.dilate(window, kernel)
        zone[y0:y1, x0:x1] = window
    near = mask & (zone > 0)
    border = np.concatenate([near[0], near[-1], near[:, 0], near[:, -1]])
    ends = joints_px[list(LENGTH_ENDS)]
    margin = config.edge_margin_px
    outside = (ends[:, 0] < -margin) | (ends[:, 0] > width - 1 + margin)
    outside |= (ends[:, 1] < -margin) | (ends[:, 1] > height - 1 + margin)
    if border.sum() <= config.max_border_pixels and not outside.any():
        return None
    return Refusal(
        "the foot is cut off by the edge of the photo",
        "step back or zoom out so that the whole foot, heel to toes, is in the picture",
    )


def implausible_length(length_mm: float | None, config: MeasureConfig) -> Refusal | None:
    """A scaled fit whose foot no adult has: without a reference to blame, the fit went wrong on this photo."""
    low, high = config.plausible_length_mm
    if length_mm is None or low <= length_mm <= high:
        return None
    return Refusal(
        f"the foot fitted to this photo would be {length_mm:.0f} mm long, outside the {low:.0f}-{high:.0f} mm "
        "of adult feet, so the fit went wrong",
        "retake it from above and to the side, the whole foot flat on the floor and the leg out of the way",
    )


def contradicted_reference(
    kind: str,
    length_mm: float | None,
    quality: FitQuality,
    config: MeasureConfig,
    separation_mm: float | None = None,
) -> str | None:
    """Why the object taken for a reference of ``kind`` was something else, or None: the floor it implies makes
    no adult foot, none that stands on it and covers the foot in the photo (the cut top of a trouser leg once
    passed as a card), or puts the foot far from it (``separation_mm``: between their centres on that floor).
    Not a refusal: the pipeline says so and measures without it."""
    low, high = config.plausible_length_mm
    if length_mm is not None and not low <= length_mm <= high:
        why = f"would make the foot {length_mm:.0f} mm long, outside the {low:.0f}-{high:.0f} mm of adult feet"
    elif (
        length_mm is not None
        and separation_mm is not None
        and separation_mm > config.max_reference_separation * length_mm
    ):
        why = (
            f"lies {separation_mm / 1000:.1f} m from the foot (more than {config.max_reference_separation:g} foot "
            "lengths): not the object put beside it"
        )
    elif quality.vertices_outside_2px > config.max_model_outside:
        outside = 100 * quality.vertices_outside_2px
        why = f"implies a floor no fitted foot stands on ({outside:.0f} % of it fell outside the foot)"
    else:
        return None
    return f"the rectangle taken for {references.kind(kind).described} {why}, so it was ignored"


def heel_hidden(end_on: float, floor_end_on_bound: float, reference_kind: str, config: MeasureConfig) -> Refusal | None:
    """A plain photo whose fit points the foot more end-on (``end_on``: |cos| to the line of sight) than a foot
    lying on the floor a reference shows can be seen (``floor_end_on_bound``, ``pipeline.floor_end_on_bound``):
    the fit lifted the foot off that floor, as when the heel is hidden behind the leg. The pipeline refuses it only
    when a second fit held upright on that floor fails too (``MeasureConfig.flat_refit_upright_robust``)."""
    if end_on <= config.max_rgb_end_on or floor_end_on_bound > config.max_rgb_end_on:
        return None
    named = references.kind(reference_kind).described
    return Refusal(
        f"the foot could not be fitted lying on the floor that {named} in the photo "
        f"shows (the fit points it {_degrees(end_on):.0f} deg from the line of sight; on that floor it lies at "
        f"least {_degrees(floor_end_on_bound):.0f} deg from it): the heel is probably hidden behind the leg",
        "photograph the foot from the side and above, with the heel in view",
    )


def seen_end_on(end_on: float, kind: str, config: MeasureConfig) -> Refusal | None:
    """A foot whose length points too nearly along the line of sight for ``kind`` input (``MeasureConfig``)."""
    limit = {"rgb": config.max_rgb_end_on, "rgbd": config.max_rgbd_end_on, "depth": config.max_depth_end_on}[kind]
    if end_on <= limit:
        return None
    seen = f"the foot is seen end-on (its length points {_degrees(end_on):.0f} deg from the line of sight)"
    if kind == "rgb":
        return Refusal(f"{seen}, so its length cannot be measured from a plain photo", FROM_THE_SIDE)
    return Refusal(
        f"{seen}, so the far end of the foot is hidden behind the near one and its length cannot be measured",
        FROM_THE_SIDE,
    )


def end_on_note(end_on: float, kind: str, config: MeasureConfig) -> str | None:
    """What an unscaled result says instead of refusing a foot its fit points end-on (``fitted_foot``): its
    width/length ratio, which that foreshortening would spoil, is not given; None when it is not end-on."""
    if seen_end_on(end_on, kind, config) is None:
        return None
    return (
        f"the fitted foot points {_degrees(end_on):.0f} deg from the line of sight (nearly end-on), so its "
        f"width/length ratio is not given; {FROM_THE_SIDE} for it"
    )


def model_outside(quality: FitQuality, config: MeasureConfig) -> Refusal | None:
    """More than ``config.max_model_outside`` of the fitted foot falls outside the foot in the photo."""
    if quality.vertices_outside_2px <= config.max_model_outside:
        return None
    return Refusal(
        f"the foot model could not be fitted to this photo ({100 * quality.vertices_outside_2px:.0f} % of the "
        "fitted foot falls outside the foot in the photo)",
        FLAT_AND_IN_VIEW,
    )


def outline_not_followed(quality: FitQuality, kind: str, config: MeasureConfig) -> Refusal | None:
    """With depth: too little of the foot's outline lies near the fitted foot's (``min_depth_contour_followed``)."""
    if kind == "rgb" or quality.contour_within_2px >= config.min_depth_contour_followed:
        return None
    return Refusal(
        f"the foot model could not be fitted to this photo (only {100 * quality.contour_within_2px:.0f} % of the "
        "foot's outline lies within 2 px of the fitted foot's)",
        "retake it from above and to the side, the whole foot flat on the floor and the leg out of the way",
    )


def foot_hidden(quality: FitQuality, kind: str, config: MeasureConfig) -> Refusal | None:
    """Too little of the fitted foot below the ankle shows (``min_depth_foot_shown``, without depth
    ``min_rgb_foot_shown``); the fit makes the rest up."""
    least = config.min_rgb_foot_shown if kind == "rgb" else config.min_depth_foot_shown
    if quality.foot_shown >= least:
        return None
    return Refusal(
        f"only {100 * quality.foot_shown:.0f} % of the fitted foot below the ankle shows in the photo (the leg or a "
        "trouser hides the rest), so its length cannot be measured",
        "retake it from the side and above, the trouser rolled up and the heel in view",
    )


def fitted_foot(
    quality: FitQuality,
    end_on: float,
    kind: str,
    config: MeasureConfig,
    floor: tuple[str, float] | None = None,
    scaled: bool = True,
) -> Refusal | None:
    """The first refusal of a fitted foot, in order: heel hidden (a plain photo with a reference's ``floor`` =
    (its kind, ``floor_end_on_bound``)), end-on, model outside the silhouette, outline not followed, foot hidden.
    ``scaled`` False (a plain photo without a reference): no length is given to be foreshortened, and the end-on
    angle would come from the fit's pose alone, which nothing in such a photo checks: it is not refused but said
    (``end_on_note``)."""
    hidden = None
    if kind == "rgb" and floor is not None:
        hidden = heel_hidden(end_on, floor[1], floor[0], config)
    return (
        hidden
        or (seen_end_on(end_on, kind, config) if scaled else None)
        or model_outside(quality, config)
        or outline_not_followed(quality, kind, config)
        or foot_hidden(quality, kind, config)
    )


def unmeasurable(reason: str) -> Refusal:
    """A fitted shape so far outside the population (a failed fit) that its measurements are not defined."""
    return Refusal(
        f"the fitted foot could not be measured ({reason})",
        "retake the photo from the side and above, the whole foot flat on the floor and in view",
    )


def _degrees(cos_angle: float) -> float:
    return math.degrees(math.acos(min(cos_angle, 1.0)))
