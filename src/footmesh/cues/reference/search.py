"""Steps 1-8 in order: ``search_reference`` and ``detect_reference``."""

from __future__ import annotations

import functools
from collections.abc import Callable

import cv2
import numpy as np

from footmesh import references
from footmesh.cues.reference import focal
from footmesh.cues.reference.cut import finish_cut
from footmesh.cues.reference.finish import _finish, finish_beyond
from footmesh.cues.reference.marker import _detect_marker, _overlaps
from footmesh.cues.reference.objects import ReferenceObject, ReferenceSearch
from footmesh.cues.reference.params import (
    _KERNEL5,
    BLUR_SIGMA_PX,
    KINDS,
    MARKER_SHEET_SCALE,
    RECTANGLES,
    SHEETS,
    assumed_sheet,
)
from footmesh.cues.reference.pose import seen_with
from footmesh.cues.reference.quads import (
    _candidate_groups,
    _canonical,
    _check_image,
    _check_intrinsics,
    white_balanced,
)
from footmesh.cues.reference.sides import _blank_inside, _fit_sides, _paper_beside, remembered_profiles


def detect_reference(
    rgb: np.ndarray,
    K: np.ndarray,
    kinds: tuple[str, ...] | list[str] = KINDS,
    exclude_mask: np.ndarray | None = None,
    focal_prior_log_sd: float = 0.0,
    distance_prior: tuple[float, float] | None = None,
) -> ReferenceObject | None:
    """Find a reference object lying on the floor and the floor plane it gives; None when none is convincing
    (``search_reference``'s ``found``)."""
    return search_reference(rgb, K, kinds, exclude_mask, focal_prior_log_sd, distance_prior).found


def search_reference(
    rgb: np.ndarray,
    K: np.ndarray,
    kinds: tuple[str, ...] | list[str] = KINDS,
    exclude_mask: np.ndarray | None = None,
    focal_prior_log_sd: float = 0.0,
    distance_prior: tuple[float, float] | None = None,
) -> ReferenceSearch:
    """Find a reference object lying on the floor and the floor plane it gives, or say why none was taken.

    Args:
        rgb: (H, W, 3) uint8, or float in 0..1, RGB image.
        K: (3, 3) intrinsics in pixels of this image.
        kinds: which objects to look for (any of ``KINDS``); when several are found the marker wins, then the
            A4 sheet, then the card, whatever the order given.
        exclude_mask: optional (H, W) bool, pixels not to take edges from (e.g. the foot and leg): an edge there
            neither supports nor contradicts a side.
        focal_prior_log_sd: 0 when K's focal length is known; else the SD of its log (a guess, or a photo's EXIF):
            a sheet or card is then tested at the focal length that suits it, and found with the focal length its
            perspective gives (``ReferenceObject.K``; ``focal``).
        distance_prior: (median mm, SD of the log) of the camera's distance from the object: where the focal
            length is estimated, weighed in too (``focal.distance_prior_scale``); None: not used.

    Returns:
        ``ReferenceSearch``: the ``ReferenceObject`` (None: the caller reports the result as unscaled) and, when
        none was found, the reason the largest candidate was rejected.
    """
    searched = _search(rgb, K, kinds, exclude_mask, focal_prior_log_sd)
    if searched.found is None or distance_prior is None:
        return searched
    return ReferenceSearch(_with_distance_prior(searched.found, K, *distance_prior))


def _with_distance_prior(found: ReferenceObject, K: np.ndarray, median_mm: float, log_sd: float) -> ReferenceObject:
    """``found`` with its estimated focal length (``focal_log_sd`` > 0) weighed against a prior on the camera's
    distance and its pose solved again; as it is when its focal length is held or no pose fits the new one.

    Its shape was tested at the focal length of its perspective alone: the prior moves it far only where the
    perspective barely tells it, which is where the shape barely depends on it. It only ever lengthens the focal
    length: an object farther than the median is what a standing person's main camera (the guess) sees, and
    shortened, a false "sheet" far off on a real photo came near enough to the foot to be taken."""
    if found.focal_log_sd <= 0 or found.beyond_edge:  # a cut sheet's far corners were placed at K's focal length
        return found
    factor, new_log_sd = focal.distance_prior_scale(found.focal_log_sd, found.object_distance_mm, median_mm, log_sd)
    if factor <= 1.0:
        return found
    total = found.K[0, 0] * factor / K[0, 0]
    total = min(max(total, focal.FOCAL_RANGE[0]), focal.FOCAL_RANGE[1])
    new_K = focal.with_focal_scale(K, total)
    seen = seen_with(found, new_K, new_log_sd)
    return found if seen is None else seen


def _search(
    rgb: np.ndarray,
    K: np.ndarray,
    kinds: tuple[str, ...] | list[str],
    exclude_mask: np.ndarray | None,
    focal_prior_log_sd: float,
) -> ReferenceSearch:
    """``search_reference`` before the distance prior."""
    image = _check_image(rgb)
    K = _check_intrinsics(K)
    kinds = tuple(kinds)
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise ValueError(f"kinds must be a non-empty selection of {KINDS}, got {kinds!r}")
    h, w = image.shape[:2]
    valid = None
    if exclude_mask is not None:
        exclude_mask = np.asarray(exclude_mask)
        if exclude_mask.shape != (h, w):
            raise ValueError(f"exclude_mask must be (H, W) = {(h, w)} like the image, got {exclude_mask.shape}")
        # edges right next to the masked object are its own outline, not the reference's
        valid = cv2.dilate(exclude_mask.astype(np.uint8), _KERNEL5) == 0
    # the colour tests (white paper, a card's chroma) read the surfaces, not the light; where the brightest
    # surface is no white but a coloured wall, the photo as it is is searched too
    balanced = white_balanced(image, valid)
    searched = _search_image(balanced, K, kinds, exclude_mask, valid, focal_prior_log_sd)
    if searched.found is None and balanced is not image:
        again = _search_image(image, K, kinds, exclude_mask, valid, focal_prior_log_sd)
        if again.found is not None:
            return again
    return searched


@remembered_profiles()  # the fallback without the mask reads most of the same sides again
def _search_image(
    image: np.ndarray,
    K: np.ndarray,
    kinds: tuple[str, ...],
    exclude_mask: np.ndarray | None,
    valid: np.ndarray | None,
    focal_prior_log_sd: float,
) -> ReferenceSearch:
    """``_search`` in one (H, W, 3) float32 image (``valid``: where its edges count, from ``exclude_mask``)."""
    h, w = image.shape[:2]
    blurred = cv2.GaussianBlur(image, (0, 0), BLUR_SIGMA_PX)
    found, markers = _detect_marker(
        image, blurred, K, valid, bool(references.with_detector("marker", kinds)), focal_prior_log_sd
    )
    if found is not None:
        return ReferenceSearch(found)
    wanted = [k for k in RECTANGLES if k in kinds]
    if not wanted:
        return ReferenceSearch(None)
    # a marker's cells are rectangles too: nothing is taken from the printed sheet of any marker seen
    sheets = [(q - q.mean(axis=0)) * MARKER_SHEET_SCALE + q.mean(axis=0) for q in markers]
    seen: set[tuple[int, ...]] = set()  # rough quads already listed (both searches)
    free_focal = focal_prior_log_sd > 0
    sheet_groups = _candidate_groups(blurred, K, wanted, "sheet", seen, free_focal) if set(wanted) & set(SHEETS) else []

    @functools.cache
    def card_groups() -> list[list[np.ndarray]]:
        # listed only when a sheet's own quads gave none (most of a card search's time, wasted beside a sheet)
        return _candidate_groups(blurred, K, wanted, "card", seen, free_focal) if set(wanted) - set(SHEETS) else []

    searched = _try_groups(sheet_groups, card_groups, sheets, wanted, blurred, K, valid, None, focal_prior_log_sd)
    if searched.found is not None:
        return searched
    if valid is not None:
        # the mask is the silhouette network's, and on real photos it sometimes spreads over the floor and hides
        # the sheet's sides; the sides' own tests (straight, supported, not running on) still hold without it,
        # but the foot's own lit skin is no sheet: what the mask leaves of a sheet must be paper
        masked = exclude_mask.astype(bool)
        again = _try_groups(sheet_groups, card_groups, sheets, wanted, blurred, K, None, masked, focal_prior_log_sd)
        if again.found is not None:
            return again
    return ReferenceSearch(None, searched.rejected, searched.rejected_area / (h * w))


def _try_groups(
    sheet_groups: list[list[np.ndarray]],
    card_groups: Callable[[], list[list[np.ndarray]]],
    sheets: list[np.ndarray],
    wanted: list[str],
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    masked: np.ndarray | None = None,
    focal_prior_log_sd: float = 0.0,
) -> ReferenceSearch:
    """Refine and test the rough quads of ``_candidate_groups`` in turn (the cards' listed by ``card_groups()``
    once no sheet was found among the sheets' own): the A4 sheet found, else the card, else
    (``rejected_area`` in px here) why the largest rough quad was rejected. Quads over a marker's printed sheet
    (``sheets``) are skipped, and objects found more than ``MAX_MASKED_SHARE`` inside ``masked`` (H, W) bool.
    ``focal_prior_log_sd``: see ``search_reference``."""
    best: dict[str, tuple[float, ReferenceObject]] = {}
    accepted: list[np.ndarray] = []  # corners already found, in canonical order
    largest_rejected: list[tuple[float, str]] = []  # (area px, why) of the largest rough quad rejected

    def try_candidates(
        quads: list[np.ndarray], completed: bool = False, cut: bool = False, beyond: bool = False
    ) -> None:
        """Refine and test rough quads in turn, keeping the best-scoring object of each kind (``cut``: quads of
        sheets cut by the photo's edge, ``cut.finish_cut``; ``beyond``: with a corner beyond it,
        ``finish.finish_beyond``)."""
        for quad in quads:
            # many thresholds give the same object: refine it once
            if any(np.max(np.linalg.norm(quad - corners, axis=1)) < 3.0 for corners in accepted):
                continue
            if any(_overlaps(quad, sheet) for sheet in sheets):
                continue
            why: list[str] = []
            if cut:  # three sides do not show the sheet's proportions
                result = finish_cut(quad, assumed_sheet(wanted), blurred, K, valid, focal_prior_log_sd, why, masked)
            elif beyond:
                result = finish_beyond(quad, wanted, blurred, K, valid, why, focal_prior_log_sd)
            else:
                result = _finish(
                    quad,
                    wanted,
                    blurred,
                    K,
                    valid,
                    completed=completed,
                    rejected=why,
                    focal_prior_log_sd=focal_prior_log_sd,
                )
            if result is None:
                area = _area_in_photo(quad, *blurred.shape[:2])  # a cut sheet's rough quad reaches past the photo
                if why and (not largest_rejected or area > largest_rejected[0][0]):
                    largest_rejected[:] = [(area, why[0])]
                continue
            if masked is not None and not _paper_beside(result[1].corners_px, masked, blurred):
                continue
            if masked is not None and result[1].kind in SHEETS and not result[1].beyond_edge:
                lines = _fit_sides(result[1].corners_px, blurred, None, 1.5)
                if lines is not None and all(ln is not None for ln in lines):
                    if not _blank_inside(result[1].corners_px, lines, ~masked, blurred):
                        continue
            accepted.append(_canonical(result[1].corners_px))
            score, obj = result
            if obj.kind not in best or score > best[obj.kind][0]:
                best[obj.kind] = (score, obj)

    # a sheet wins over any card: once one is found, the candidates left (most of the time spent on those that
    # are none) are not tried. Sheets with a hidden corner completed come last, only when no card was found.
    def best_of(names: list[str]) -> ReferenceObject | None:
        found = [best[k] for k in names if k in best]
        return max(found, key=lambda scored: scored[0])[1] if found else None

    cards = [k for k in RECTANGLES if k not in SHEETS]
    for group in sheet_groups[:1]:
        try_candidates(group)
        if (sheet := best_of(SHEETS)) is not None:
            return ReferenceSearch(sheet)
    for group in card_groups():
        try_candidates(group)
        if (sheet := best_of(SHEETS)) is not None:
            return ReferenceSearch(sheet)
    if (card := best_of(cards)) is not None:
        return ReferenceSearch(card)
    for group in sheet_groups[1:2]:
        try_candidates(group, completed=True)
        if (sheet := best_of(SHEETS)) is not None:
            return ReferenceSearch(sheet)
    # then a sheet with one corner beyond the photo's edge: its four sides' lines show its shape and perspective
    for group in sheet_groups[3:4]:
        try_candidates(group, beyond=True)
        if (sheet := best_of(SHEETS)) is not None:
            return ReferenceSearch(sheet)
    # last, a sheet with a side beyond the photo's edge: its scale along the cut sides rests on the focal length,
    # and its proportions are assumed (tried before the one above, it took sheets with one corner beyond the edge
    # for sheets cut across two: their corners 120-620 px off on front and guided renders)
    for group in sheet_groups[2:3]:
        try_candidates(group, cut=True)
        if (sheet := best_of(SHEETS)) is not None:
            return ReferenceSearch(sheet)
    if not largest_rejected:
        return ReferenceSearch(None)
    area, why = largest_rejected[0]
    return ReferenceSearch(None, why, area)


def _area_in_photo(quad: np.ndarray, h: int, w: int) -> float:
    """Area (px) of the part of a convex (4, 2) px quad inside the (h, w) photo."""
    photo = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    return float(cv2.intersectConvexConvex(np.asarray(quad, np.float32), photo)[0])
