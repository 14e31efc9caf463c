"""Step 9: a sheet with one side beyond the photo's edge, placed from the three sides in view and its known size.

A photo framed tightly on the foot often cuts the sheet: the end behind the heel (under the shin, in a photo taken
from in front of the toes) or the end beyond the toes leaves the picture. Three sides still show: the one in view
whole, and the two that run from its corners out of the photo. Those two are parallel on the floor, so their
vanishing point gives their direction in 3D, and the side in view whole, of known length, gives the scale
(``quads._completions``): the sheet's far corners are placed beyond the edge, and the pose is solved from the
whole rectangle as for any sheet.

Two things the three sides cannot tell:

- Which of the sheet's sides is the one in view whole. Only the proportions of what shows decide it: where the
  sides leaving the photo show longer than the short side would be, the side in view is the short one; otherwise
  either could be, and the sheet is not taken (``CUT_LENGTH_MARGIN``).
- The focal length: the right angle at a corner that fixes it for a whole sheet (``focal``) gives nothing here,
  and the scale along the cut sides depends on it where the sheet is seen at an angle (at 60 deg elevation, 10 %
  on the focal length is about 3 % along them). That dependence, at the caller's focal length's SD, is added to the
  scale's SD; where it is too large the sheet is not taken (straight down it vanishes).

And one thing it cannot check: that the object is the sheet. A whole sheet proves its kind by its proportions; here
any white rectangle whose sides leaving the photo show 0.79-1.41 of the side in view passes for one (a letter
sheet gives millimetres 2.8 % off; the pipeline's message says so, and gross cases make no adult's foot).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from footmesh.cues.reference import focal
from footmesh.cues.reference.objects import ReferenceObject
from footmesh.cues.reference.params import (
    BORDER_MARGIN_PX,
    COMPLETION_MIN_COVERAGE,
    CORNER_RADIUS_PX,
    CUT_ANGLE_TRUST_DEG,
    CUT_LENGTH_MARGIN,
    FIRST_RADIUS_PX,
    MAX_SCALE_REL_SD,
    MIN_COVERAGE,
    MIN_MEAN_SUPPORT,
    MIN_SIDE_PX,
    MIN_SIDE_SUPPORT,
    SIZE_REL_SD,
    SIZES_MM,
)
from footmesh.cues.reference.pose import placed, rectangle_pose
from footmesh.cues.reference.quads import _canonical, _classify, _completions, _intersect
from footmesh.cues.reference.sides import (
    _blank_inside,
    _continues,
    _curved,
    _is_paper,
    _Line,
    _moved,
    _paper_floor_lines,
    _side_line,
    _strange_borders,
)


def finish_cut(
    quad: np.ndarray,
    kind: str,
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    focal_prior_log_sd: float = 0.0,
    rejected: list[str] | None = None,
    masked: np.ndarray | None = None,
) -> tuple[float, ReferenceObject] | None:
    """A ``quads._cut_many`` quad refined and tested as a ``kind`` sheet cut by the photo's edge: (score, object)
    or None (then why, in words, appended to ``rejected``). Two of the object's corners lie beyond the photo; K is
    held (``focal_prior_log_sd``: its focal length's SD, whose effect joins the scale's SD). ``masked`` (H, W)
    bool: where ``valid`` is None, the feet the caller's mask covers, which must not pass for the sheet's inside."""

    def reject(why: str) -> None:
        if rejected is not None:
            rejected.append(f"it runs off the photo's edge and {why}")

    h, w = blurred.shape[:2]
    refined = _refine_cut(quad, blurred, valid, h, w)
    if refined is None:
        return reject("a side's edge could not be traced along it")
    visible, lines = refined
    shown = lines[1:]
    lengths = np.linalg.norm(np.roll(visible, -1, axis=0) - visible, axis=1)[1:]
    if lengths.min() < MIN_SIDE_PX:
        return reject("too little of it is in view")
    supports = np.array([ln.support for ln in shown])
    coverage = np.array([ln.coverage for ln in shown])
    if supports.min() < MIN_SIDE_SUPPORT or supports.mean() < MIN_MEAN_SUPPORT:
        return reject(f"a side's edge is missing along {100 * (1 - supports.min()):.0f} % of the side where it is seen")
    least, mean = MIN_COVERAGE[kind]
    if coverage.min() < least or coverage.mean() < mean:
        return reject(f"its sides show along only {100 * coverage.mean():.0f} % of their length (covered)")
    if _curved([ln.residual_sd for ln in shown], lengths):
        return reject("a side is not straight (curled, or a curved outline over it)")
    if not _is_paper(visible, lines):
        return reject("it is not white paper brighter than the floor")
    shown_paper = valid if valid is not None else (None if masked is None else ~masked)
    if shown_paper is not None and not _blank_inside(visible, lines, shown_paper, blurred):
        return reject("it is not blank inside (a pattern or an object on it: tiles, not a sheet)")
    strange, _ = _strange_borders(visible, lines)
    if strange:
        return reject(f"its side {strange[-1] + 1} of 4 does not part the paper from the floor (clothing over it?)")
    if _continues(blurred, visible, lines, valid):
        return reject("its sides run on past its corners (tiles, planks or a printed grid)")
    # the far corners rest on the directions of the sides leaving the photo: fitted again through the edge between
    # paper and floor alone (the foot's outline along a side, where the mask misses it, would turn it), and each
    # must show that edge along at least half of what is in view of it (a hidden corner's completion's bar)
    clean, paper_floor = _paper_floor_lines(visible, lines, blurred)
    cleaned = _visible_from([(ln.point, ln.direction) for ln in clean[1:]], visible, h, w)
    if cleaned is not None and np.max(np.linalg.norm(cleaned[2:] - visible[2:], axis=1)) <= 3.0 * CORNER_RADIUS_PX[0]:
        visible, lines = cleaned, clean
    least_shown = min(paper_floor[1], paper_floor[3])
    if least_shown < COMPLETION_MIN_COVERAGE:
        return reject(
            f"a side leaving the photo shows the paper's edge along only {100 * least_shown:.0f} % of what is in "
            "view of it (its direction, on which the far corners rest, is uncertain)"
        )
    reaches = _reaches(visible, K, kind)
    # a completion that is no rectangle in front of the camera is not ruled out by it: where the sides in view are
    # short, their vanishing point is too uncertain to say
    possible = [t for t, r in enumerate(reaches) if not r < 1.0 - CUT_LENGTH_MARGIN]
    if len(possible) > 1:
        return reject("which of its sides is cut cannot be told from what is in view")
    if not possible or not reaches[possible[0]] > 1.0:
        return reject("what is in view is longer than the sheet")
    target = possible[0]
    local = _local(_far_corners(visible, K, kind, target), K, kind)
    if local is None:
        return reject("its corners are no rectangle's image")
    solved = placed(local, kind, K)
    if isinstance(solved, str):
        return reject(solved)
    pose, reproj, _ = solved
    length, width = SIZES_MM[kind]
    seen_mm = _floor_lengths(visible, K, pose)  # the sides in view on the sheet's floor: what the SDs compare to
    fit_sd = _fit_rel_sd(lines, visible, K, kind, target, seen_mm, h, w)
    focal_rel = _focal_rel_effect(visible, K, kind, target, focal_prior_log_sd, seen_mm)
    if not fit_sd <= MAX_SCALE_REL_SD:
        return reject(f"its sides in view fix the scale only to {100 * fit_sd:.1f} %")
    if not math.hypot(fit_sd, focal_rel) <= MAX_SCALE_REL_SD:
        return reject(
            f"seen at an angle, its scale along the cut sides depends on the focal length ({100 * focal_rel:.1f} % "
            "at its uncertainty): keep the photo's EXIF, pass --intrinsics, or photograph the whole sheet"
        )
    corner_var = [
        ln.offset_sd**2 + (ln.angle_sd * float(np.linalg.norm(c - ln.point))) ** 2
        for c, ln in ((visible[2], lines[1]), (visible[2], lines[2]), (visible[3], lines[2]), (visible[3], lines[3]))
    ]
    obj = ReferenceObject(
        kind=kind,
        corners_px=local,
        size_mm=(length, width),
        cam_from_floor=pose,
        reprojection_px=reproj,
        corner_sd_px=float(np.sqrt(2.0 * np.mean(corner_var))),
        fit_rel_sd=fit_sd,
        scale_rel_sd=math.sqrt(fit_sd**2 + focal_rel**2 + SIZE_REL_SD[kind] ** 2),
        K=np.array(K, dtype=np.float64),
        focal_log_sd=focal_prior_log_sd,
        beyond_edge=True,
        kind_assumed=True,
    )
    return float(supports.mean() + coverage.mean()) - 10.0 * fit_sd, obj


def _refine_cut(
    quad: np.ndarray, blurred: np.ndarray, valid: np.ndarray | None, h: int, w: int
) -> tuple[np.ndarray, list[_Line | None]] | None:
    """The quad's corners 2 and 3 to sub-pixel from the edges along sides 1-3 (as ``sides._refine_sides``), its
    corners 0 and 1 where sides 3 and 1 leave the photo; and the lines [None, side 1, side 2, side 3]."""
    lines: list[_Line | None] = []
    for radius in (FIRST_RADIUS_PX, 1.5):
        fitted = [_side_line(blurred, quad[i], quad[(i + 1) % 4], radius, valid) for i in (1, 2, 3)]
        if any(ln is None for ln in fitted):
            return None
        one, two, three = fitted
        c2 = _intersect(one.point, one.direction, two.point, two.direction)
        c3 = _intersect(two.point, two.direction, three.point, three.direction)
        if c2 is None or c3 is None:
            return None
        e1, e0 = (
            _leaving(c2, _towards(one.direction, quad[1] - c2), h, w),
            _leaving(c3, _towards(three.direction, quad[0] - c3), h, w),
        )
        if e1 is None or e0 is None:
            return None
        new = np.array([e0, e1, c2, c3])
        if np.max(np.linalg.norm(new[2:] - quad[2:], axis=1)) > 3.0 * radius + 2.0:
            return None
        quad, lines = new, [None, *fitted]
    return quad, lines


def _towards(direction: np.ndarray, rough: np.ndarray) -> np.ndarray:
    """``direction`` (2,), or its opposite, whichever points the way of ``rough`` (2,)."""
    return direction if direction @ rough >= 0 else -direction


def _leaving(start: np.ndarray, toward: np.ndarray, h: int, w: int) -> np.ndarray | None:
    """Where the ray from ``start`` (inside the photo) along ``toward`` leaves it, ``BORDER_MARGIN_PX`` inside."""
    norm = float(np.linalg.norm(toward))
    if norm == 0:
        return None
    direction = toward / norm
    lo, hi = BORDER_MARGIN_PX, np.array([w - 1.0, h - 1.0]) - BORDER_MARGIN_PX
    steps = [
        ((hi[k] if direction[k] > 0 else lo) - start[k]) / direction[k] for k in (0, 1) if abs(direction[k]) > 1e-12
    ]
    reach = min(steps) if steps else -1.0
    return None if reach <= 0 else start + reach * direction


def _far_corners(visible: np.ndarray, K: np.ndarray, kind: str, target: int) -> np.ndarray:
    """(4, 2) px: the sheet whose sides 1-3 are those of ``visible`` (4, 2), completed across side 0 with side 2 the
    long side (``target`` 0) or the short one (1); NaN where it is no rectangle in front of the camera."""
    corners, ok = _completions(visible[None], K, 0, SIZES_MM[kind])[target]
    return corners[0] if ok[0] else np.full((4, 2), np.nan)


def _reaches(visible: np.ndarray, K: np.ndarray, kind: str) -> list[float]:
    """For each completion (``_far_corners`` targets 0, 1): how far its far corners lie along sides 1 and 3, as a
    fraction of what shows of them (the lesser of the two; > 1: beyond the photo's edge; NaN: no rectangle in front
    of the camera)."""
    shown = [visible[1] - visible[2], visible[0] - visible[3]]
    out = []
    for target in (0, 1):
        corners = _far_corners(visible, K, kind, target)
        if not np.isfinite(corners).all():
            out.append(float("nan"))
            continue
        along = [(corners[1] - visible[2]) @ shown[0], (corners[0] - visible[3]) @ shown[1]]
        out.append(min(a / float(s @ s) for a, s in zip(along, shown, strict=True)))
    return out


def _fit_rel_sd(
    lines: list[_Line | None],
    visible: np.ndarray,
    K: np.ndarray,
    kind: str,
    target: int,
    base: np.ndarray,
    h: int,
    w: int,
) -> float:
    """Relative SD of the floor lengths of the sides in view (``_floor_lengths``) from the three lines' noise: each
    line's offset, then angle, moved by its SD and the sheet completed again (linearised propagation); the largest
    of the three sides' (``base`` (3,): their lengths, mm, through the sheet found). The sides leaving the photo
    are trusted in direction to ``CUT_ANGLE_TRUST_DEG`` beyond their fits' own noise."""
    var = np.zeros(3)
    trust = math.radians(CUT_ANGLE_TRUST_DEG)
    for i in (1, 2, 3):
        ln = lines[i] if i == 2 else dataclasses.replace(lines[i], angle_sd=math.hypot(lines[i].angle_sd, trust))
        for moved in _moved(ln):
            trial = [(x.point, x.direction) for x in lines[1:]]
            trial[i - 1] = moved
            quad = _visible_from(trial, visible, h, w)
            pose = None if quad is None else _completed_pose(quad, K, kind, target)
            var += (_floor_lengths(visible, K, pose) / base - 1.0) ** 2
    worst = float(np.sqrt(var.max()))
    return worst if math.isfinite(worst) else math.inf


def _visible_from(lines: list[tuple[np.ndarray, np.ndarray]], visible: np.ndarray, h: int, w: int) -> np.ndarray | None:
    """(4, 2) the visible quad of sides 1-3 given as (point, direction), leaving the photo as ``visible`` does."""
    (p1, d1), (p2, d2), (p3, d3) = lines
    c2, c3 = _intersect(p1, d1, p2, d2), _intersect(p2, d2, p3, d3)
    if c2 is None or c3 is None:
        return None
    e1, e0 = _leaving(c2, _towards(d1, visible[1] - c2), h, w), _leaving(c3, _towards(d3, visible[0] - c3), h, w)
    return None if e1 is None or e0 is None else np.array([e0, e1, c2, c3])


def _local(corners: np.ndarray, K: np.ndarray, kind: str) -> np.ndarray | None:
    """(4, 2) the completed corners (``_far_corners``) in the object's local order (``quads._canonical``, then
    ``_classify``'s start); None where they are no ``kind`` rectangle's image."""
    canonical = _canonical(corners) if np.isfinite(corners).all() else None
    named = None if canonical is None else _classify(canonical, K, [kind])
    return None if named is None else np.roll(canonical, -named[1], axis=0)


def _completed_pose(visible: np.ndarray, K: np.ndarray, kind: str, target: int) -> np.ndarray | None:
    """``cam_from_floor`` (4, 4) of the sheet completed from ``visible`` (``_far_corners``); None if none fits."""
    local = _local(_far_corners(visible, K, kind, target), K, kind)
    solved = None if local is None else rectangle_pose(local, kind, K)
    return None if solved is None else solved[0]


def _floor_lengths(visible: np.ndarray, K: np.ndarray, pose: np.ndarray | None) -> np.ndarray:
    """(3,) floor lengths (mm) of sides 1, 2, 3 of the quad ``visible`` (4, 2) px seen through K on the floor of
    ``pose`` (NaN where None): what the sheet's plane says of lengths across and along it where it is in view."""
    if pose is None:
        return np.full(3, np.nan)
    rot, trans = pose[:3, :3], pose[:3, 3]
    normal = rot[:, 2]
    rays = np.concatenate([visible, np.ones((4, 1))], axis=1) @ np.linalg.inv(K).T
    with np.errstate(divide="ignore", invalid="ignore"):
        points = rays * ((normal @ trans) / (rays @ normal))[:, None]
    return np.linalg.norm(points[[1, 2, 3]] - points[[2, 3, 0]], axis=1)


def _focal_rel_effect(
    visible: np.ndarray, K: np.ndarray, kind: str, target: int, log_sd: float, base: np.ndarray
) -> float:
    """How much (relative) the floor lengths of the sides in view change when the sheet is completed, and they are
    seen, with the focal length one SD (``log_sd``) longer or shorter: the scale's error that the focal length's
    uncertainty brings (the largest of the sides', against their lengths ``base`` (3,) mm; 0 when it is known)."""
    if log_sd <= 0:
        return 0.0
    worst = 0.0
    for sign in (1.0, -1.0):
        other_K = focal.with_focal_scale(K, math.exp(sign * log_sd))
        other = _floor_lengths(visible, other_K, _completed_pose(visible, other_K, kind, target))
        worst = max(worst, float(np.max(np.abs(other / base - 1.0))))
    return worst if math.isfinite(worst) else math.inf
