"""Step 5: a rough quad refined, named and tested strictly, its pose and scale uncertainty solved (``_finish``)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from footmesh import references
from footmesh.cues.reference import focal
from footmesh.cues.reference.objects import ReferenceObject
from footmesh.cues.reference.params import (
    _LOOSEST_COVERAGE,
    ANGLE_TOLERANCE_DEG,
    ASPECT_TOLERANCE,
    BEYOND_CLEAR_PX,
    BEYOND_EDGE_INSET_PX,
    BEYOND_FLOOR_MATCH,
    BEYOND_MIN_SHOWN,
    BORDER_MARGIN_PX,
    COMPLETED_MIN_SIDE_SUPPORT,
    FIRST_RADIUS_PX,
    FLOOR_MATCH,
    FOCAL_KINDS,
    MAX_ANGLE_TOLERANCE_DEG,
    MAX_ASPECT_TOLERANCE,
    MAX_SCALE_REL_SD,
    MIN_BLANK_SHARE,
    MIN_COVERAGE,
    MIN_MEAN_SUPPORT,
    MIN_SIDE_PX,
    MIN_SIDE_SUPPORT,
    RECTANGLES,
    SHAPE_WEIGHT,
    SHEET_KIND_SDS,
    SHEETS,
    SIZE_REL_SD,
    SIZES_MM,
    assumed_sheet,
)
from footmesh.cues.reference.pose import _distance, _shape_sd, placed
from footmesh.cues.reference.quads import (
    _classify,
    _corner_points_many,
    _inside,
    _inside_many,
    _parallelogram,
    _signed_area,
)
from footmesh.cues.reference.sides import (
    _blank_inside,
    _bowed_corners,
    _clean_sides,
    _complete_sheet,
    _continues,
    _corners_of,
    _curved,
    _fit_sides,
    _inner_outer,
    _is_paper,
    _Line,
    _perturbed_corner_pairs,
    _perturbed_corners,
    _refine_sides,
    _strange_borders,
    side_in_view,
)


def _finish(
    quad: np.ndarray,
    kinds: list[str],
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    mirrored: bool = False,
    completed: bool = False,
    first_radius: float = FIRST_RADIUS_PX,
    rejected: list[str] | None = None,
    focal_prior_log_sd: float = 0.0,
) -> tuple[float, ReferenceObject] | None:
    """Refine a rough quad, name it, test it strictly and solve the plane: (score, object) or None (then why,
    in words, appended to ``rejected``). ``focal_prior_log_sd`` > 0: K's focal length is known only to this SD
    (log units) and the rectangle's perspective may correct it (``focal.focal_estimate``).

    A marker's quad comes in its local order (``kinds == MARKERS``); a sheet's or card's is put in local
    order once its sides are known. A sheet whose fourth side the rough quad misses (the foot hides a corner,
    the region's outline cuts across it) is completed from its other three (``_complete_sheet``) and tried again;
    ``completed``: the rough quad is such a completion already. A completion's sides must all show their edge
    (``COMPLETED_MIN_SIDE_SUPPORT``). ``first_radius``: the search radius (px) across the rough sides.
    """
    # the first pass of the sides' refinement is also what the completion starts from: fitted once for both
    first = _fit_sides(quad, blurred, valid, first_radius)
    result = _finish_quad(
        quad,
        kinds,
        blurred,
        K,
        valid,
        mirrored,
        first=first,
        completed=completed,
        first_radius=first_radius,
        rejected=rejected,
        focal_prior_log_sd=focal_prior_log_sd,
    )
    sheet_kind = assumed_sheet(kinds)  # three sides do not show the sheet's proportions
    if result is not None or sheet_kind is None:
        return result
    for sheet in _complete_sheet(quad, blurred, K, valid, lines=first, size_mm=SIZES_MM[sheet_kind]):
        # the quad's own reason stands: a completion is a guess
        # completed with K's focal length: a completion's perspective says nothing of its own, so that focal
        # length stays as uncertain as the caller's
        result = _finish_quad(sheet, [sheet_kind], blurred, K, valid, completed=True)
        if result is not None:
            return result[0], replace(result[1], focal_log_sd=focal_prior_log_sd)
    return None


def _finish_quad(
    quad: np.ndarray,
    kinds: list[str],
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    mirrored: bool = False,
    first: list[_Line | None] | None = None,
    completed: bool = False,
    first_radius: float = FIRST_RADIUS_PX,
    rejected: list[str] | None = None,
    focal_prior_log_sd: float = 0.0,
    corner_beyond: bool = False,
) -> tuple[float, ReferenceObject] | None:
    """``_finish`` without the completion of a sheet (``first``: the sides fitted at ``first_radius``;
    ``completed``: the quad is a sheet completed across a hidden corner, whose kind is ``assumed_sheet``'s;
    ``rejected``: why the quad is not the object, appended in words when it is not; ``focal_prior_log_sd``: see
    ``_finish``; ``corner_beyond``: one corner of the quad lies beyond the photo's edge, ``finish_beyond``)."""

    def reject(why: str) -> None:
        if rejected is not None:
            rejected.append(why)

    h, w = blurred.shape[:2]
    if not _inside(quad, h, w, margin=-max(h, w)):  # a completion's guess far off: nothing there to read
        return reject("a corner lies far beyond the edge of the photo")
    refined = _refine_sides(quad, blurred, valid, radii=(first_radius, 1.5), first=first, in_view=corner_beyond)
    if refined is None:
        return reject("a side's edge could not be traced along it")
    corners, lines = refined
    # a marker is read by its pattern, not cut out by the border: it only has to lie in the image
    marker = all(references.kind(k).detector == "marker" for k in kinds)
    if corner_beyond:
        if (why := _beyond_too_far(corners, h, w)) is not None:
            return reject(why)
    elif not _inside(corners, h, w, margin=0.0 if marker else BORDER_MARGIN_PX):
        return reject("a corner lies on or beyond the edge of the photo")
    if min(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)) < MIN_SIDE_PX:
        return reject("it is too small in the photo")
    supports = np.array([ln.support for ln in lines])
    coverage = np.array([ln.coverage for ln in lines])
    residuals = np.array([ln.residual_sd for ln in lines])
    min_side_support = COMPLETED_MIN_SIDE_SUPPORT if completed else MIN_SIDE_SUPPORT
    if supports.min() < min_side_support or supports.mean() < MIN_MEAN_SUPPORT:
        return reject(f"a side's edge is missing along {100 * (1 - supports.min()):.0f} % of the side where it is seen")
    if coverage.min() < _LOOSEST_COVERAGE[0] or coverage.mean() < _LOOSEST_COVERAGE[1]:
        return reject(f"its sides show along only {100 * coverage.mean():.0f} % of their length (covered)")
    if _curved(residuals, np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)):
        return reject(f"a side is not straight (scatter {residuals.max():.1f} px: curled, or a curved outline over it)")
    perturbed = _perturbed_corners(lines)
    focal_scale, focal_log_sd, held_K = 1.0, 0.0, K
    if focal_prior_log_sd > 0:
        # the focal length is a guess: the rectangle's own perspective corrects it, and every test and the pose
        # below use the corrected one
        points, good = _corner_points_many(np.stack([corners, *perturbed]), K)
        if good.all():
            focal_scale, focal_log_sd = focal.focal_estimate(points[0], points[1:], focal_prior_log_sd)
            K = focal.with_focal_scale(K, focal_scale)
    shape = _parallelogram(corners, K)
    if shape is None:
        return reject("its corners are no rectangle's image")
    ratio_sd, angle_sd = _shape_sd(corners, perturbed, K)
    # small or oblique objects measure their shape less well: the tolerances widen with the corners' noise
    tol_ratio = min(max(ASPECT_TOLERANCE, 3.0 * ratio_sd), MAX_ASPECT_TOLERANCE)
    tol_angle = min(max(ANGLE_TOLERANCE_DEG, 3.0 * angle_sd), MAX_ANGLE_TOLERANCE_DEG)
    if marker:
        kind, start = kinds[0], 0
        if abs(math.log(shape[0] / references.kind(kind).aspect)) > tol_ratio or abs(shape[1] - 90.0) > tol_angle:
            return reject("its shape is not square")
    else:
        # named among every rectangle kind, so that a sheet asked for as a card is not one
        found = _classify(corners, K, RECTANGLES, tol_ratio=tol_ratio, tol_angle=tol_angle)
        if found is not None and found[0] in SHEETS:
            # a completion was drawn with its sheet's proportions: they tell nothing of its kind
            sheets = [assumed_sheet(kinds)] if completed else kinds
            focal_sd = _focal_ratio_sd(corners, K, focal_log_sd)
            named, undecided = _named_sheet(shape[0], math.hypot(ratio_sd, focal_sd), tol_ratio, sheets)
            if undecided is not None:
                return reject(undecided)
            found = None if named is None else (named, found[1])
        if found is None or found[0] not in kinds:
            ratio, angle = max(shape[0], 1.0 / shape[0]), shape[1]
            aspects = ", ".join(f"{references.kind(k).described} {references.kind(k).aspect:.3f}" for k in RECTANGLES)
            return reject(
                f"its shape is no reference object's (side ratio {ratio:.3f}; {aspects}; corner angle "
                f"{angle:.1f} deg; the photo's focal length may be wrong)"
            )
        kind, start = found
    if focal_scale != 1.0 and kind not in FOCAL_KINDS:
        # named at a corrected focal length, but of a kind that may not correct it: tested again at K's own
        return _finish_quad(
            quad,
            kinds,
            blurred,
            held_K,
            valid,
            mirrored,
            first,
            completed,
            first_radius,
            rejected,
            focal_prior_log_sd=0.0,
            corner_beyond=corner_beyond,
        )
    sheet = kind in SHEETS
    if coverage.min() < MIN_COVERAGE[kind][0] or coverage.mean() < MIN_COVERAGE[kind][1]:
        return reject(f"its sides show along only {100 * coverage.mean():.0f} % of their length (covered)")
    if start:
        corners = np.roll(corners, -start, axis=0)
        lines = lines[start:] + lines[:start]
        perturbed = [np.roll(c, -start, axis=0) for c in perturbed]
    if sheet and not _is_paper(corners, lines):
        return reject("it is not white paper brighter than the floor")
    if sheet and valid is not None and not _blank_inside(corners, lines, valid, blurred):
        return reject("it is not blank inside (a pattern or an object on it: tiles, not a sheet)")
    if corner_beyond and not _paper_to_the_edge(corners, lines, blurred, valid):
        return reject("its paper does not reach the photo's edge where its sides leave it (a shadow across it?)")
    if sheet:
        strange, outside = _strange_borders(corners, lines, BEYOND_FLOOR_MATCH if corner_beyond else FLOOR_MATCH)
        # a completed sheet's fourth side runs where the foot hides it (its colours are the foot's), not beside it
        if outside or len(strange) > (1 if completed else 0):
            side = (outside or strange)[-1] + 1
            return reject(f"its side {side} of 4 does not part the paper from the floor (clothing over it?)")
    if _continues(blurred, corners, lines, valid):
        return reject("its sides run on past its corners (tiles, planks or a printed grid)")
    at_corner = [(j, ln) for i, ln in enumerate(lines) for j in (i, (i + 1) % 4)]  # each corner's two lines
    # (the sides' second readings follow whole sides and every corner: a corner beyond the photo keeps the first)
    if sheet and not corner_beyond:
        corners, lines, perturbed, coverage = _clean_sides(corners, lines, blurred, perturbed)
    if sheet and not corner_beyond and (bowed := _bowed_corners(corners, lines, blurred)) is not None:
        local_perturbed = _perturbed_corner_pairs(bowed)
        local = _corners_of(bowed)
        local_sd = _shape_sd(local, local_perturbed, K)
        tol_ratio = min(max(ASPECT_TOLERANCE, 3.0 * local_sd[0]), MAX_ASPECT_TOLERANCE)
        tol_angle = min(max(ANGLE_TOLERANCE_DEG, 3.0 * local_sd[1]), MAX_ANGLE_TOLERANCE_DEG)
        if _classify(local, K, RECTANGLES, tol_ratio=tol_ratio, tol_angle=tol_angle) == (kind, 0):
            corners, perturbed = local, local_perturbed
            at_corner = [(j, ln) for j, pair in enumerate(bowed) for ln in pair]
    solved = placed(corners, kind, K)
    if isinstance(solved, str):
        return reject(solved)
    pose, reproj, distance = solved
    length, width = SIZES_MM[kind]
    fit_sd = math.sqrt(sum((_distance(c, kind, K) - distance) ** 2 for c in perturbed)) / distance
    if not fit_sd <= MAX_SCALE_REL_SD:
        return reject(f"its corners fix the scale only to {100 * fit_sd:.1f} %")
    # a corner's SD: the two lines' offsets there (the line's offset SD at its centroid plus the angle's lever)
    corner_var = [
        ln.offset_sd**2 + (ln.angle_sd * float(np.linalg.norm(corners[j] - ln.point))) ** 2 for j, ln in at_corner
    ]
    obj = ReferenceObject(
        kind=kind,
        kind_assumed=completed,
        corners_px=corners,
        size_mm=(length, width),
        cam_from_floor=pose,
        reprojection_px=reproj,
        corner_sd_px=float(np.sqrt(2.0 * np.mean(corner_var))),
        fit_rel_sd=fit_sd,
        scale_rel_sd=math.sqrt(fit_sd**2 + SIZE_REL_SD[kind] ** 2),
        K=K,
        focal_log_sd=focal_log_sd,
        mirrored=mirrored,
        corner_beyond_edge=corner_beyond,
    )
    # among candidates of one kind: the best-supported (a sheet: along its paper-to-floor edges), most precise,
    # then the larger (a sheet, not part of it)
    # and of the quads of one object, the one most like its shape
    final = _parallelogram(corners, K)
    ratio_misfit = abs(math.log(max(final[0], 1.0 / final[0]) * width / length)) / tol_ratio
    shape_misfit = ratio_misfit + abs(final[1] - 90.0) / tol_angle
    score = float(supports.mean() + coverage.mean()) - SHAPE_WEIGHT * shape_misfit - 10.0 * fit_sd
    score += 1e-6 * abs(_signed_area(corners))
    return score, obj


def finish_beyond(
    quad: np.ndarray,
    kinds: list[str],
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    rejected: list[str] | None = None,
    focal_prior_log_sd: float = 0.0,
) -> tuple[float, ReferenceObject] | None:
    """``_finish`` for a rough quad with one corner beyond the photo's edge (``quads._beyond_many``): its four
    sides read where they are in view, that corner placed where the two running to it meet, and every test of
    a whole rectangle made, its proportions naming it (a sheet's or a card's). (score, object) or None (then
    why, in words, appended to ``rejected``)."""
    why: list[str] = []
    result = _finish_quad(
        quad, kinds, blurred, K, valid, rejected=why, focal_prior_log_sd=focal_prior_log_sd, corner_beyond=True
    )
    if result is None and why and rejected is not None:
        rejected.append(f"a corner lies beyond the photo's edge and {why[0]}")
    return result


def _beyond_too_far(corners: np.ndarray, h: int, w: int) -> str | None:
    """Why a refined quad (4, 2) px with a corner beyond the photo's edge cannot be placed from its sides in view,
    or None when it can: three corners clear of the edge (``BEYOND_CLEAR_PX``: a side along the edge shows only a
    sliver, and the line read there is another edge's), the fourth beyond it (not on it), and both sides running
    to that one mostly in view (``BEYOND_MIN_SHOWN``)."""
    out = ~_inside_many(corners[:, None], h, w, margin=-BORDER_MARGIN_PX)
    clear = _inside_many(corners[:, None], h, w, margin=BEYOND_CLEAR_PX)
    if out.sum() != 1 or clear.sum() != 3:
        return "a corner lies on the edge of the photo"
    far = int(np.flatnonzero(out)[0])
    for near in (corners[(far - 1) % 4], corners[(far + 1) % 4]):
        seen = side_in_view(near, corners[far], h, w)
        length = float(np.linalg.norm(corners[far] - near))
        shown = 0.0 if seen is None else float(np.linalg.norm(seen[1] - seen[0])) / length
        if shown < BEYOND_MIN_SHOWN:
            return f"a side running to that corner shows only {100 * shown:.0f} % of its length"
    return None


def _paper_to_the_edge(corners: np.ndarray, lines: list[_Line], blurred: np.ndarray, valid: np.ndarray | None) -> bool:
    """Whether a sheet's paper (the colour inside its sides, ``_inner_outer``) reaches the photo's edge between the
    two points where the sides running to its corner beyond the edge leave the photo: along that stretch, just
    inside the edge, at least ``MIN_BLANK_SHARE`` of the pixels that ``valid`` (H, W) bool leaves (all when None)
    lie within half the sides' typical step of it. A shadow or a line across the paper can pass for the fourth
    side of a smaller sheet with a corner beyond the edge; the paper then runs on past it to the edge."""
    h, w = blurred.shape[:2]
    far = int(np.flatnonzero(~_inside_many(corners[:, None], h, w, margin=-BORDER_MARGIN_PX))[0])
    exits = [side_in_view(corners[k], corners[far], h, w) for k in ((far - 1) % 4, (far + 1) % 4)]
    if any(seen is None for seen in exits):
        return False
    a, b = exits[0][1], exits[1][1]
    inward = corners.mean(axis=0) - (a + b) / 2
    inward *= BEYOND_EDGE_INSET_PX / max(float(np.linalg.norm(inward)), 1e-9)
    steps = max(int(np.linalg.norm(b - a)), 2)
    points = a + np.linspace(0.1, 0.9, steps)[:, None] * (b - a) + inward
    ix = np.clip(np.rint(points[:, 0]).astype(int), 0, w - 1)
    iy = np.clip(np.rint(points[:, 1]).astype(int), 0, h - 1)
    shown = np.ones(len(ix), dtype=bool) if valid is None else valid[iy, ix]
    if not shown.any():
        return True  # all of it under the foot or the leg: nothing to tell
    inner, outer = _inner_outer(corners, lines)
    paper = np.median(inner, axis=0)
    change = float(np.median(np.linalg.norm(inner - outer, axis=1)))
    near = np.linalg.norm(blurred[iy, ix] - paper, axis=1) < 0.5 * change
    return float(near[shown].mean()) >= MIN_BLANK_SHARE


def _named_sheet(ratio: float, ratio_sd: float, tol_ratio: float, kinds: list[str]) -> tuple[str | None, str | None]:
    """Which sheet among ``kinds`` a rectangle of measured side ratio ``ratio`` (either way up; the SD of its log
    ``ratio_sd``) is: (the most preferred one within ``tol_ratio`` (log) of it, None), unless a more preferred one
    lies within ``SHEET_KIND_SDS`` SDs, which the photo cannot then rule out: (None, why it is neither, in words).
    (None, None) where no sheet among ``kinds`` is within ``tol_ratio``."""
    log_ratio = abs(math.log(ratio))
    misfit = {k: abs(log_ratio - math.log(references.kind(k).aspect)) for k in SHEETS if k in kinds}
    within = [k for k in misfit if misfit[k] <= tol_ratio]
    if not within:
        return None, None
    possible = [k for k in misfit if misfit[k] <= max(tol_ratio, SHEET_KIND_SDS * ratio_sd)]
    if possible[0] == within[0]:
        return within[0], None
    aspects = " and ".join(f"{references.kind(k).described}'s {references.kind(k).aspect:.3f}" for k in possible)
    return None, (
        f"its side ratio, {math.exp(log_ratio):.3f} (SD {100 * ratio_sd:.1f} %), lies between {aspects}; the photo's "
        "focal length may be wrong"
    )


def _focal_ratio_sd(corners: np.ndarray, K: np.ndarray, focal_log_sd: float) -> float:
    """The SD of the log side ratio of the rectangle with these (4, 2) px corners that K's focal length, known to
    ``focal_log_sd`` (log), gives it."""
    if focal_log_sd <= 0:
        return 0.0
    here, there = _parallelogram(corners, K), _parallelogram(corners, focal.with_focal_scale(K, math.exp(focal_log_sd)))
    if here is None or there is None:
        return float("inf")
    return abs(math.log(there[0] / here[0]))
