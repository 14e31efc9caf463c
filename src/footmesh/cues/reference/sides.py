"""Steps 4-7: sub-pixel sides, their support and straightness, sheet completion, paper tests, bowed corners, noise."""

from __future__ import annotations

import contextlib
import dataclasses
import math
from contextvars import ContextVar
from dataclasses import dataclass

import cv2
import numpy as np

from footmesh.cues.reference.params import (
    _KERNEL5,
    BLUR_SIGMA_PX,
    BORDER_MARGIN_PX,
    COMPLETION_MIN_COVERAGE,
    COMPLETION_MIN_SUPPORT,
    CONTINUATION_RADIUS_PX,
    CONTINUATION_SPAN,
    CORNER_MOVE_PX,
    CORNER_RADIUS_PX,
    CORNER_SPAN,
    END_SKIP,
    FIRST_RADIUS_PX,
    FLOOR_MATCH,
    MAX_CONTINUATION,
    MAX_INSIDE_BLOBS,
    MAX_RESIDUAL_RATIO,
    MIN_BLANK_SHARE,
    MIN_BLOB_SHARE,
    MIN_CONTINUATIONS,
    MIN_CONTRAST,
    MIN_CORNER_COVERAGE,
    MIN_CORNER_SD_PX,
    MIN_PAPER_SHOWN,
    MIN_SIDE_PX,
    OCCLUSION_MATCH,
    PAPER_MAX_SATURATION,
    PLATEAU_PX,
    SHADOW_MAX_BRIGHTNESS,
    SHEETS,
    SIZES_MM,
    STRAIGHT_EDGE_FRACTION,
    STRAIGHT_EDGE_PX,
    WEAK_SIDE_SHARE,
)
from footmesh.cues.reference.quads import _corners_from_lines, _inside_many, _intersect, _parallelogram


def _paper_beside(quad: np.ndarray, masked: np.ndarray, blurred: np.ndarray) -> bool:
    """Whether the part of a sheet's (4, 2) px quad outside ``masked`` (H, W) bool is paper: at least
    ``MIN_PAPER_SHOWN`` of its area, of a colour with little saturation (``PAPER_MAX_SATURATION``)."""
    inside = np.zeros(masked.shape, np.uint8)
    cv2.fillPoly(inside, [np.round(quad).astype(np.int32)], 1)
    inside = cv2.erode(inside, _KERNEL5)  # not the sides' own blur
    area = int(inside.sum())
    shown = (inside > 0) & ~masked
    if area == 0 or shown.sum() < MIN_PAPER_SHOWN * area:
        return False
    colour = np.median(blurred[shown], axis=0)
    return float((colour.max() - colour.min()) / max(float(colour.max()), 1e-6)) <= PAPER_MAX_SATURATION


def _blank_inside(quad: np.ndarray, lines: list[_Line], valid: np.ndarray, blurred: np.ndarray) -> bool:
    """Whether a sheet's inside, where the caller's mask leaves it (``valid`` (H, W) bool), is blank paper: at least
    ``MIN_BLANK_SHARE`` of those pixels within half the sides' typical change of the paper's colour, and the rest
    in at most ``MAX_INSIDE_BLOBS`` blobs (a shadow, not a pattern). A square of a tiled floor's pattern passes every
    test of its sides, but has the pattern inside."""
    h, w = valid.shape
    x0, y0 = np.maximum(np.floor(quad.min(axis=0)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(quad.max(axis=0)).astype(int) + 1, [w, h])
    if x1 <= x0 or y1 <= y0:
        return True
    inside = np.zeros((y1 - y0, x1 - x0), np.uint8)  # the quad's bounding box: the test is per candidate
    cv2.fillPoly(inside, [np.round(quad - [x0, y0]).astype(np.int32)], 1)
    shown = (cv2.erode(inside, _KERNEL5) > 0) & valid[y0:y1, x0:x1]
    if not shown.any():
        return True  # all of it under the foot: nothing to tell
    inner, outer = _inner_outer(quad, lines)
    paper = np.median(inner, axis=0)
    change = float(np.median(np.linalg.norm(inner - outer, axis=1)))
    near = np.linalg.norm(blurred[y0:y1, x0:x1] - paper, axis=2) < 0.5 * change
    if float(near[shown].mean()) < MIN_BLANK_SHARE:
        return False
    stained = shown & ~near
    # the pieces of a foot that the mask covers only in part (toes, the instep beside it) are one object: the
    # blobs are counted with the masked part joining those that touch it (within the blur's reach of it)
    masked = cv2.dilate(((inside > 0) & ~valid[y0:y1, x0:x1]).astype(np.uint8), _KERNEL5) > 0
    joined = stained | masked
    count, labels = cv2.connectedComponents(joined.astype(np.uint8), connectivity=8)
    blob_areas = np.bincount(labels[stained], minlength=count)[1:]
    blobs = int(np.sum(blob_areas >= MIN_BLOB_SHARE * shown.sum()))
    return blobs <= MAX_INSIDE_BLOBS


@dataclass(frozen=True)
class _Profiles:
    """Edges across a line at positions along it: ``points`` (S, 2) px, ``found`` (S,) bool, ``min_step`` the
    smallest colour change across the line that counted, the colours ``ends`` (S, 2, 3) read at both ends of
    each profile (-n, +n), ``usable`` (S,) bool: not excluded by the caller's mask, and ``edge`` (S,) bool: an
    edge whether the mask excludes it or not (``found`` is ``edge & usable``)."""

    points: np.ndarray
    found: np.ndarray
    min_step: float
    ends: np.ndarray
    usable: np.ndarray
    edge: np.ndarray


_READ_PROFILES: ContextVar[dict | None] = ContextVar("footmesh_reference_profiles", default=None)
"""What ``_profiles`` read and the sides' lines fitted (``_side_line``) inside the running ``remembered_profiles``
block (None outside one)."""


@contextlib.contextmanager
def remembered_profiles():
    """Inside it (a ``with`` block or a decorated function, e.g. ``search_reference``), the image is read across
    a line once: a search that finds nothing with the caller's mask refines the same candidates again without it,
    and two thirds of their sides' profiles are the same lines (on eval photos where no reference was found). What
    is kept is what does not depend on the mask (a side's line: where the mask left out none of its edges); the
    image must not change inside the block."""
    token = _READ_PROFILES.set({})
    try:
        yield
    finally:
        _READ_PROFILES.reset(token)


def _profiles(
    blurred: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    along: np.ndarray,
    radius: float,
    valid: np.ndarray | None,
    min_step: float | None = None,
) -> _Profiles | None:
    """Sub-pixel edges across the line p -> q at positions ``along`` (S,) px from p (any, also beyond q).

    At each position the blurred image is sampled across the line every 0.25 px; the strongest colour gradient
    (Euclidean norm over the channels, so any colours and either polarity) within ``radius`` is located by a
    parabola through its peak. It counts as an edge where the colours beyond both ends of the profile differ by
    ``min_step`` at least (given, or half the typical change across the line) and the peak is that of a step,
    not of a thin line, and where ``valid`` (H, W) bool, if given, holds at the edge. None when nothing changes
    across the line.
    """
    read = _READ_PROFILES.get()
    if read is None:
        edges = _edges_across(blurred, p, q, along, radius, min_step)
    else:
        key = (id(blurred), np.asarray(p, np.float64).tobytes(), np.asarray(q, np.float64).tobytes())
        key += (np.asarray(along, np.float64).tobytes(), float(radius), min_step)
        if key not in read:
            read[key] = _edges_across(blurred, p, q, along, radius, min_step)
        edges = read[key]
    if edges is None:
        return None
    points, edge, min_step, ends = edges
    usable = np.ones(len(along), dtype=bool)
    if valid is not None:
        h, w = valid.shape
        ix = np.clip(np.rint(points[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.rint(points[:, 1]).astype(int), 0, h - 1)
        usable = valid[iy, ix]
    return _Profiles(points, edge & usable, min_step, ends, usable, edge)


def _edges_across(
    blurred: np.ndarray, p: np.ndarray, q: np.ndarray, along: np.ndarray, radius: float, min_step: float | None
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray] | None:
    """``_profiles`` without the mask: the edge points (S, 2) px, which of them are edges (S,) bool, the smallest
    change that counted and the colours (S, 2, 3) at both ends; None when nothing changes across the line."""
    d = q - p
    t = d / np.linalg.norm(d)
    n = np.array([-t[1], t[0]])
    step = 0.25
    # the profile reaches PLATEAU_PX beyond the search window, where the colours on both sides are read
    reach = radius + PLATEAU_PX
    across = np.arange(-reach, reach + 1e-9, step)
    # the sample points p + along t + across n (S, O), each coordinate on its own: no (S, O, 2) array to split
    map_x, map_y = ((p[c] + along[:, None] * t[c] + across[None, :] * n[c]).astype(np.float32) for c in (0, 1))
    # bicubic: a bilinear profile's derivative is constant between pixel centres and pulls the peak onto them
    values = cv2.remap(blurred, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)  # (S, O, 3)
    size = np.linalg.norm(values[:, -1] - values[:, 0], axis=1)  # (S,) colour change across the line
    if min_step is None:
        # where the foot covers the side the change is another one: half the median of the larger half
        min_step = max(MIN_CONTRAST, 0.5 * float(_median(size[size >= _median(size)])))
    if size.max() < min_step:
        return None
    # central differences (np.gradient's, without its one-sided ends, which lie beyond the window)
    diff = values[:, 2:] - values[:, :-2]
    grad = np.zeros(values.shape[:2], values.dtype)  # (S, O)
    squared = diff * diff  # summed plane by plane: numpy's sum over a 3-long last axis is 7x slower, the same values
    grad[:, 1:-1] = np.sqrt(squared[..., 0] + squared[..., 1] + squared[..., 2]) / (2.0 * step)
    window = np.flatnonzero(np.abs(across) <= radius + 1e-9)
    k = window[0] + np.argmax(grad[:, window], axis=1)
    rows = np.arange(len(along))
    y0, y1, y2 = grad[rows, k - 1], grad[rows, k], grad[rows, k + 1]
    den = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(den < 0, 0.5 * (y0 - y2) / den, 0.0)
    offset = across[k] + np.clip(frac, -0.5, 0.5) * step
    # an edge: a peak inside the window (not at its end), a change across, and a peak no lower than a quarter of
    # a sharp step's (blurred by BLUR_SIGMA_PX; lenses blur more)
    found = (k > window[0]) & (k < window[-1]) & (size >= min_step)
    found &= grad[rows, k] > 0.25 * size / (BLUR_SIGMA_PX * math.sqrt(2 * math.pi))
    points = p + along[:, None] * t + offset[:, None] * n
    return points, found, min_step, values[:, [0, -1]]


@dataclass(frozen=True)
class _SideEdges:
    """Edge points (M, 2) px found along a side, the number of positions sampled, how many of them contradict
    the side, the smallest colour change across it that counted, and the typical colours (3,) each beyond the
    found edges on the -n (``near``) and the +n (``far``) side (n: the side's direction turned +90 deg)."""

    points: np.ndarray
    sampled: int
    contradicted: int
    min_step: float
    near: np.ndarray
    far: np.ndarray


def _side_edge_points(
    blurred: np.ndarray, p: np.ndarray, q: np.ndarray, radius: float, valid: np.ndarray | None
) -> tuple[_SideEdges | None, bool]:
    """Edges along the side p -> q, 1 px apart, END_SKIP of it skipped at both ends (None when too few), and
    whether ``valid`` left out any of them (if not, they are the same without it).

    A position without the edge either shows something else across the side (the foot, its shadow: occluded)
    or shows the colour of one side of the edge on both sides of the line: the edge is plainly not there. Only
    the latter counts against the side (``_Line.support``).
    """
    length = float(np.linalg.norm(q - p))
    skip = END_SKIP * length + 1.0
    along = np.arange(skip, length - skip + 1e-9, 1.0)
    if len(along) < 6:
        return None, False
    prof = _profiles(blurred, p, q, along, radius, valid)
    if prof is None:
        return None, False
    masked = not prof.usable.all()
    if prof.found.sum() < 5:
        return None, masked
    near, far = np.median(prof.ends[prof.found], axis=0)  # (3,) each: typical colours at -n and +n
    tol = OCCLUSION_MATCH * float(np.linalg.norm(far - near))
    a, b = prof.ends[:, 0], prof.ends[:, 1]

    def like(x: np.ndarray, c: np.ndarray) -> np.ndarray:
        return np.linalg.norm(x - c, axis=1) < tol

    missing = ~prof.found & prof.usable & ((like(a, near) & like(b, near)) | (like(a, far) & like(b, far)))
    # the mask is the feet's, grown: where it lies over the side but the side's own two colours meet there (the
    # paper's and the floor's), the edge is the side's (real photos: the foot's mask leaks onto shaded paper)
    found = prof.found | (prof.edge & ~prof.usable & like(a, near) & like(b, far))
    return _SideEdges(prof.points[found], len(along), int(missing.sum()), prof.min_step, near, far), masked


def _side_line(
    blurred: np.ndarray, p: np.ndarray, q: np.ndarray, radius: float, valid: np.ndarray | None
) -> _Line | None:
    """The line fitted to the edges along the side p -> q (``_side_edge_points``, ``_fit_line``), or None. Inside
    ``remembered_profiles`` a line that the mask did not touch is kept for the search without it."""
    read = _READ_PROFILES.get()
    key = ("line", id(blurred), np.asarray(p, np.float64).tobytes(), np.asarray(q, np.float64).tobytes(), radius)
    if read is not None and valid is None and key in read:
        return read[key]
    edges, masked = _side_edge_points(blurred, p, q, radius, valid)
    line = None if edges is None else _fit_line(edges)
    if read is not None and not masked:
        read[key] = line
    return line


@dataclass(frozen=True)
class _Line:
    """A fitted side: centroid (2,), unit direction (2,), SD of the offset at the centroid (px) and of the angle
    (rad); ``support``: the fraction of the positions along it that show the edge among those that show the
    edge or plainly its absence (positions where something covers the side do not count), ``coverage``: among
    all; the residual SD (px), the smallest colour change across it that counted, and the typical colours (3,)
    beyond its edge on either side (``_SideEdges``)."""

    point: np.ndarray
    direction: np.ndarray
    offset_sd: float
    angle_sd: float
    support: float
    coverage: float
    residual_sd: float
    min_step: float
    near: np.ndarray
    far: np.ndarray


def _median(values: np.ndarray) -> np.floating:
    """``np.median`` of a non-empty 1-D array without NaNs, the same value: the sides' fits take tens of thousands
    of medians of a few hundred values in a search, and ``np.median``'s own checks cost 8x the partition."""
    half = len(values) // 2
    if len(values) % 2:
        return np.partition(values, half)[half]
    part = np.partition(values, (half - 1, half))
    return (part[half - 1] + part[half]) / 2


def _fit_line(edges: _SideEdges) -> _Line | None:
    """Robust total-least-squares line through edge points: Huber fit, outliers beyond 3 robust SD dropped, refit."""
    points = edges.points
    if len(points) < 5:
        return None
    vx, vy, x0, y0 = cv2.fitLine(points.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
    direction = np.array([vx, vy], dtype=np.float64)
    normal = np.array([-direction[1], direction[0]])
    resid = (points - np.array([x0, y0])) @ normal
    off = np.abs(resid - _median(resid))
    mad = 1.4826 * float(_median(off))
    pts = points[off <= max(3.0 * mad, 0.3)]
    if len(pts) < 5:
        return None
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    direction = vt[0] if vt[0] @ direction >= 0 else -vt[0]
    normal = np.array([-direction[1], direction[0]])
    resid = (pts - centroid) @ normal
    along = (pts - centroid) @ direction
    sd = max(float(np.sqrt(np.sum(resid**2) / max(len(pts) - 2, 1))), MIN_CORNER_SD_PX)
    # neighbouring residuals are alike where the edge bows or a shadow bends it: fewer independent points
    ordered = resid[np.argsort(along)] - resid.mean()
    spread = float(ordered @ ordered)
    rho = float(np.clip(ordered[:-1] @ ordered[1:] / spread, 0.0, 0.99)) if spread > 1e-12 else 0.0
    independent = max(2.0, len(pts) * (1.0 - rho) / (1.0 + rho))
    return _Line(
        point=centroid,
        direction=direction,
        offset_sd=sd / math.sqrt(independent),
        angle_sd=sd / math.sqrt(float(np.sum(along**2)) * independent / len(pts)),
        support=len(pts) / (len(pts) + edges.contradicted),
        coverage=len(pts) / edges.sampled,
        residual_sd=sd,
        min_step=edges.min_step,
        near=edges.near,
        far=edges.far,
    )


def _fit_sides(
    quad: np.ndarray, blurred: np.ndarray, valid: np.ndarray | None, radius: float, in_view: bool = False
) -> list[_Line | None] | None:
    """The line fitted to the image's edges along each side of a quad (None where none), or None if a side is
    too short (line i runs from corner i to corner i + 1). ``in_view``: a corner may lie beyond the photo's edge,
    and each side is read along its part in the photo only (``side_in_view``).

    Once one side has no line and two could not carry a sheet's completion, the quad can neither be refined
    (every side needed) nor completed (three good sides needed): the remaining sides are left None unfitted.
    """
    h, w = blurred.shape[:2]
    ends = [(quad[i], quad[(i + 1) % 4]) for i in range(4)]
    if in_view:
        ends = [side_in_view(p, q, h, w) for p, q in ends]
        if any(end is None for end in ends):
            return None
    sides = [float(np.linalg.norm(q - p)) for p, q in ends]
    if min(sides) < MIN_SIDE_PX:
        return None
    lines: list[_Line | None] = []
    for i, (p, q) in enumerate(ends):
        lines.append(_side_line(blurred, p, q, min(radius, 0.15 * sides[i]), valid))
        if any(ln is None for ln in lines) and sum(not _completable(ln) for ln in lines) >= 2:
            return lines + [None] * (3 - i)
    return lines


def _curved(residual_sd: list[float] | np.ndarray, length_px: list[float] | np.ndarray) -> bool:
    """Whether a side's edge points scatter about its line more than a straight edge's (``STRAIGHT_EDGE_PX``)."""
    residual_sd, length_px = np.asarray(residual_sd), np.asarray(length_px)
    limit = max(MAX_RESIDUAL_RATIO * float(np.median(residual_sd)), STRAIGHT_EDGE_PX)
    return bool(np.any(residual_sd > np.maximum(limit, STRAIGHT_EDGE_FRACTION * length_px)))


def _completable(line: _Line | None) -> bool:
    """Whether a fitted side is good enough to complete a sheet from (``_complete_sheet``)."""
    return line is not None and line.coverage >= COMPLETION_MIN_COVERAGE and line.support >= COMPLETION_MIN_SUPPORT


def _refine_sides(
    quad: np.ndarray,
    blurred: np.ndarray,
    valid: np.ndarray | None,
    radii: tuple[float, ...] = (FIRST_RADIUS_PX, 1.5),
    first: list[_Line | None] | None = None,
    in_view: bool = False,
) -> tuple[np.ndarray, list[_Line]] | None:
    """Sub-pixel corners of a quad (4, 2) px from the image's edges along its sides, and the four fitted lines
    (line i runs from corner i to corner i + 1). ``first``: ``_fit_sides(quad, ..., radii[0])`` when the caller
    already has it. ``in_view``: a corner may lie beyond the photo's edge (``_fit_sides``); it is placed where its
    two sides' lines meet, however far that moves it."""
    h, w = blurred.shape[:2]
    lines: list[_Line] = []
    for step, radius in enumerate(radii):
        fitted = first if step == 0 and first is not None else _fit_sides(quad, blurred, valid, radius, in_view)
        if fitted is None or any(ln is None for ln in fitted):
            return None
        lines = fitted
        new = _corners_from_lines([(ln.point, ln.direction) for ln in lines])
        seen = _inside_many(quad[:, None], h, w) if in_view else np.ones(4, dtype=bool)
        if new is None or np.max(np.linalg.norm(new - quad, axis=1)[seen]) > 3.0 * radius + 2.0:
            return None
        quad = new
    return quad, lines


def side_in_view(p: np.ndarray, q: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The part of the segment p -> q (2,) px each inside the photo (``BORDER_MARGIN_PX`` in from its edges), in the
    same direction; None when none of it is. (Liang-Barsky clipping: ``cv2.clipLine`` takes whole pixels only.)"""
    lo, hi = BORDER_MARGIN_PX, np.array([w - 1.0, h - 1.0]) - BORDER_MARGIN_PX
    d = q - p
    t0, t1 = 0.0, 1.0
    for k in (0, 1):
        if abs(d[k]) < 1e-12:
            if not lo <= p[k] <= hi[k]:
                return None
            continue
        a, b = (lo - p[k]) / d[k], (hi[k] - p[k]) / d[k]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    if t1 <= t0:
        return None
    return p + t0 * d, p + t1 * d


def _complete_sheet(
    quad: np.ndarray,
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    lines: list[_Line | None] | None = None,
    size_mm: tuple[float, float] = SIZES_MM[SHEETS[0]],
) -> list:
    """Quads (4, 2) px for a sheet of which three sides show and the fourth is hidden or cut short (the foot over
    a corner): the two corners on the three sides' lines that are not their intersections are placed so that
    the four make a rectangle of the sheet's proportions ``size_mm`` (metric, with K), for either side being the
    long one.
    ``lines``: ``_fit_sides(quad, ..., FIRST_RADIUS_PX)`` when the caller already has it."""
    from scipy.optimize import least_squares

    if lines is None:
        lines = _fit_sides(quad, blurred, valid, FIRST_RADIUS_PX)
    if lines is None:
        return []
    good = [_completable(ln) for ln in lines]
    if sum(good) != 3:
        return []
    m = good.index(False)  # the missing side, from corner m to corner m + 1
    side = {k: lines[(m + k) % 4] for k in (1, 2, 3)}
    lengths = [float(np.linalg.norm(quad[(m + k + 1) % 4] - quad[(m + k) % 4])) for k in (1, 2, 3)]
    if _curved([ln.residual_sd for ln in side.values()], lengths):
        return []
    c2 = _intersect(side[1].point, side[1].direction, side[2].point, side[2].direction)  # corner m + 2
    c3 = _intersect(side[2].point, side[2].direction, side[3].point, side[3].direction)  # corner m + 3
    if c2 is None or c3 is None:
        return []
    # corner m + 1 = c2 + a d1 on side m + 1, corner m = c3 + b d3 on side m + 3, towards the rough quad's corners
    d1 = side[1].direction * np.sign(side[1].direction @ (quad[(m + 1) % 4] - c2) or 1.0)
    d3 = side[3].direction * np.sign(side[3].direction @ (quad[m] - c3) or 1.0)
    start = np.array([max(float(d1 @ (quad[(m + 1) % 4] - c2)), 1.0), max(float(d3 @ (quad[m] - c3)), 1.0)])
    length, width = size_mm
    out = []
    for target in (length / width, width / length):  # metric |side m + 2| / |side m + 1|

        def misfit(ab: np.ndarray, target: float = target) -> np.ndarray:
            corners = np.array([c3 + ab[1] * d3, c2 + ab[0] * d1, c2, c3])  # corners m, m + 1, m + 2, m + 3
            shape = _parallelogram(corners, K)
            if shape is None:
                return np.array([1.0, 1.0])
            ratio, angle, _ = shape  # |m -> m + 1| / |m -> m + 3| = |side m + 2| / |side m + 1|
            return np.array([math.log(ratio / target), math.radians(angle - 90.0)])

        fit = least_squares(misfit, start, x_scale=np.maximum(start, 10.0), max_nfev=60)
        a, b = fit.x
        if min(a, b) < MIN_SIDE_PX or np.abs(fit.fun).max() > 1e-3:
            continue
        corners = np.array([c3 + b * d3, c2 + a * d1, c2, c3])
        out.append(np.roll(corners, m, axis=0))  # back to the rough quad's corner numbering
    return out


def _stretch_line(blurred: np.ndarray, p: np.ndarray, q: np.ndarray, along: np.ndarray, side: _Line) -> _Line | None:
    """The line through the edge of ``side`` (running p -> q) at positions ``along`` (S,) px from p, searched
    ``CORNER_RADIUS_PX`` about p -> q and then about the line found; only edges between the side's own colours
    count. None where the edge shows along less than ``MIN_CORNER_COVERAGE`` of the stretch."""
    line = None
    tol = OCCLUSION_MATCH * float(np.linalg.norm(side.far - side.near))
    for radius in CORNER_RADIUS_PX:
        if line is not None:  # search again about the stretch's own line, through the same positions
            start = line.point + ((p - line.point) @ line.direction) * line.direction
            p, q = start, start + line.direction * float(np.linalg.norm(q - p))
        # no mask: where the silhouette network spreads over the floor it would hide the corner, and the edge's
        # colours (the side's own, paper and floor) already leave out the foot's outline
        prof = _profiles(blurred, p, q, along, radius, None, side.min_step)
        if prof is None:
            return None
        a, b = prof.ends[:, 0], prof.ends[:, 1]
        own = prof.found & (np.linalg.norm(a - side.near, axis=1) < tol) & (np.linalg.norm(b - side.far, axis=1) < tol)
        if own.sum() < max(5, MIN_CORNER_COVERAGE * len(along)):
            return None
        line = _fit_line(_SideEdges(prof.points[own], len(along), 0, side.min_step, side.near, side.far))
        if line is None:
            return None
        if line.direction @ (q - p) < 0:
            line = dataclasses.replace(line, direction=-line.direction)
    return line


def _corner_lines(corners: np.ndarray, lines: list[_Line], blurred: np.ndarray) -> list[tuple[_Line, _Line]]:
    """For each corner j (4, 2) px, the lines of the stretches of side j - 1 (ending at it) and side j (starting
    at it) nearest to it (``CORNER_SPAN``); the whole side's line where a stretch shows too little edge."""
    out = []
    for j in range(4):
        pair = []
        for i, ending in (((j - 1) % 4, True), (j, False)):
            p, q = corners[i], corners[(i + 1) % 4]
            length = float(np.linalg.norm(q - p))
            near_end = np.arange(END_SKIP * length + 1.0, CORNER_SPAN * length, 1.0)
            along = length - near_end[::-1] if ending else near_end
            stretch = _stretch_line(blurred, p, q, along, lines[i]) if len(along) >= 6 else None
            pair.append(stretch if stretch is not None else lines[i])
        out.append((pair[0], pair[1]))
    return out


def _clean_sides(
    corners: np.ndarray, lines: list[_Line], blurred: np.ndarray, perturbed: list[np.ndarray]
) -> tuple[np.ndarray, list[_Line], list[np.ndarray], np.ndarray]:
    """A sheet's sides fitted again through the edges between the paper and the floor only (``_paper_floor_lines``):
    where the leg or the foot lies over a side and the mask misses it, their outline no longer pulls the line. Also
    returns (4,) the fraction of each side that shows that edge (0 where too little)."""
    clean, shown = _paper_floor_lines(corners, lines, blurred)
    new = _corners_from_lines([(ln.point, ln.direction) for ln in clean])
    if new is None or np.max(np.linalg.norm(new - corners, axis=1)) > 3.0 * CORNER_RADIUS_PX[0]:
        return corners, lines, perturbed, shown
    return new, clean, _perturbed_corners(clean), shown


def _paper_floor_lines(
    corners: np.ndarray, lines: list[_Line | None], blurred: np.ndarray
) -> tuple[list[_Line | None], np.ndarray]:
    """Each side's line (None kept None) fitted again along the whole side through the edges between the paper and
    the floor only (``_stretch_line``; the paper's colour from all the sides, as the leg covering one side gives it
    the skin's as its own, and where that shows too little, the side's own, where it is paper's); a side that shows
    too little of that edge keeps its line. And (4,) the fraction of each side that shows that edge (0 where too
    little, or no line)."""
    inner, _ = _inner_outer(corners, lines)
    paper = np.median(inner, axis=0)
    centre = corners.mean(axis=0)
    clean: list[_Line | None] = []
    shown = np.zeros(len(lines))
    for i, ln in enumerate(lines):
        if ln is None:
            clean.append(None)
            continue
        p, q = corners[i], corners[(i + 1) % 4]
        t = q - p
        paper_far = (centre - p) @ np.array([-t[1], t[0]]) > 0  # the paper lies on the +n (far) side
        own, beyond = (ln.far, ln.near) if paper_far else (ln.near, ln.far)
        length = float(np.linalg.norm(q - p))
        along = np.arange(END_SKIP * length + 1.0, (1.0 - END_SKIP) * length - 1.0 + 1e-9, 1.0)
        # the light falls off across a sheet: the paper inside the sides of one real sheet, cropped close, read
        # 0.67, 0.80 and 0.93, and the side beside the brightest showed none of its edge with the median
        models = [dataclasses.replace(ln, **{"far" if paper_far else "near": c}) for c in (paper, own)]
        line = _stretch_line(blurred, p, q, along, models[0]) if len(along) >= 6 else None
        if line is None and len(along) >= 6 and _paper_colour(own, beyond):
            line = _stretch_line(blurred, p, q, along, models[1])
        clean.append(models[0] if line is None else line)
        shown[i] = 0.0 if line is None else line.coverage
    return clean, shown


def _bowed_corners(corners: np.ndarray, lines: list[_Line], blurred: np.ndarray) -> list[tuple[_Line, _Line]] | None:
    """Each corner's pair of lines (``_corner_lines``) where a sheet's sides bow: where the stretches next to some
    corner meet ``CORNER_MOVE_PX`` away from where the whole sides do; else None (straight sides fix the corners
    best). A corner that did not move keeps the whole sides' lines."""
    pairs = _corner_lines(corners, lines, blurred)
    local = _corners_of(pairs)
    if local is None:
        return None
    moved = np.linalg.norm(local - corners, axis=1)
    if np.any(moved > 3.0 * CORNER_RADIUS_PX[0]):  # the stretches caught another edge
        return None
    bowed = moved > CORNER_MOVE_PX
    if not bowed.any():
        return None
    return [pair if bowed[j] else (lines[(j - 1) % 4], lines[j]) for j, pair in enumerate(pairs)]


def _corners_of(pairs: list[tuple[_Line, _Line]]) -> np.ndarray | None:
    """(4, 2) corners where each pair of lines (``_corner_lines``) meets; None where a pair is parallel."""
    corners = [_intersect(a.point, a.direction, b.point, b.direction) for a, b in pairs]
    return None if any(c is None for c in corners) else np.array(corners)


def _perturbed_corner_pairs(pairs: list[tuple[_Line, _Line]]) -> list[np.ndarray]:
    """Corners (4, 2) with one corner's line moved by its offset SD, or turned by its angle SD: 16 quads for
    linearised propagation (``_perturbed_corners`` for corners of their own lines)."""
    base = _corners_of(pairs)
    out = []
    for j, pair in enumerate(pairs):
        for k, ln in enumerate(pair):
            for point, direction in _moved(ln):
                lines = [(a.point, a.direction) for a in pair]
                lines[k] = (point, direction)
                corner = _intersect(*lines[0], *lines[1])
                if corner is not None:
                    trial = base.copy()
                    trial[j] = corner
                    out.append(trial)
    return out


def _continues(blurred: np.ndarray, quad: np.ndarray, lines: list[_Line | None], valid: np.ndarray | None) -> bool:
    """Whether the sides' edges run on past the corners, in line with them, at ``MIN_CONTINUATIONS`` places or more:
    the quad is then cut out of longer lines (planks, tiles, a marker's grid) and is not an object lying on the
    floor. At one place only, it is a seam or grout line that happens to meet a corner in line with a side. (A side
    without a line, beyond the photo's edge, is skipped.)"""
    h, w = blurred.shape[:2]
    found = 0
    for i in range(4):
        if lines[i] is None:
            continue
        p, q = quad[i], quad[(i + 1) % 4]
        length = float(np.linalg.norm(q - p))
        beyond = np.arange(CONTINUATION_SPAN[0] * length + 2.0, CONTINUATION_SPAN[1] * length + 2.0, 1.0)
        if len(beyond) < 4:
            continue
        for along in (length + beyond, -beyond):
            # any edge (of any colours: a marker's cells change polarity along a grid line), but only in line with
            # the side: a line that merely crosses near the corner leaves the narrow window at once
            prof = _profiles(blurred, p, q, along, CONTINUATION_RADIUS_PX, valid, lines[i].min_step)
            if prof is None:
                continue
            x, y = prof.points[:, 0], prof.points[:, 1]
            inside = (x > 1) & (x < w - 2) & (y > 1) & (y < h - 2)
            if inside.sum() >= 4 and prof.found[inside].mean() > MAX_CONTINUATION:
                found += 1
                if found >= MIN_CONTINUATIONS:
                    return True
    return False


def _inner_outer(quad: np.ndarray, lines: list[_Line | None]) -> tuple[np.ndarray, np.ndarray]:
    """(S, 3) each: the typical colours just inside and just outside each side with a line (S of them: a sheet cut
    by the photo's edge has no line along it), read beyond its edges where they were found (so that the foot over
    the sheet does not count)."""
    centre = quad.mean(axis=0)
    inner, outer = [], []
    for i, ln in enumerate(lines):
        if ln is None:
            continue
        t = quad[(i + 1) % 4] - quad[i]  # the side was sampled from corner i to corner i + 1
        n = np.array([-t[1], t[0]])
        far_inside = (centre - quad[i]) @ n > 0
        inner.append(ln.far if far_inside else ln.near)
        outer.append(ln.near if far_inside else ln.far)
    return np.array(inner), np.array(outer)


def _paper_colour(colour: np.ndarray, beyond: np.ndarray) -> bool:
    """Whether a side's (3,) inside colour is white paper's: little colour, brighter than ``beyond`` it."""
    saturation = (colour.max() - colour.min()) / max(float(colour.max()), 1e-6)
    return saturation <= PAPER_MAX_SATURATION and float(colour.mean()) > float(beyond.mean()) + MIN_CONTRAST / 2


def _is_paper(quad: np.ndarray, lines: list[_Line | None]) -> bool:
    """A white sheet: little colour inside, and brighter inside than outside along at least three sides (of those
    with a line)."""
    inner, outer = _inner_outer(quad, lines)
    paper = np.median(inner, axis=0)
    if (paper.max() - paper.min()) / max(float(paper.max()), 1e-6) > PAPER_MAX_SATURATION:
        return False
    return int(np.sum(inner.mean(axis=1) > outer.mean(axis=1) + MIN_CONTRAST / 2)) >= min(3, len(inner))


def _strange_borders(
    quad: np.ndarray, lines: list[_Line | None], floor_match: float = FLOOR_MATCH
) -> tuple[list[int], list[int]]:
    """The sides (0..3, of those with a line) of a sheet that do not part the paper from the floor, and of those
    the ones with the floor inside (placed beside the sheet, not over it).

    Inside each side the paper must be brighter than what lies outside (not a line in the floor beside the
    sheet), and what lies outside must look like the floor beyond another side (not the hem of dark trousers
    across the sheet; where the sheet lies across two floors, a rug's edge, the sides still pair up; a shadow
    darkens the floor less than the change across the sides). A shadow over a whole side (the leg's, in a photo
    taken from in front of the toes) darkens the paper inside it and the floor beyond it alike: that side's floor
    is compared with the others' darkened as much as its paper is (where its paper is darker than
    ``SHADOW_MAX_BRIGHTNESS`` of the rest); a trouser's hem over the sheet leaves the paper inside it as bright as
    elsewhere. And the step across each side must be a sheet's side's (``WEAK_SIDE_SHARE`` of the strongest), not
    the shading of the paper or the skin's folds that a quad the search completed itself may run along.
    ``floor_match``: how near (a share of the sides' typical step) the outsides must match."""
    inner, outer = _inner_outer(quad, lines)
    steps = np.linalg.norm(inner - outer, axis=1)
    change = float(np.median(steps))
    floor = np.median(outer, axis=0)
    paper = float(np.median(inner, axis=0).mean())
    strange, outside = [], []
    sides = [i for i, ln in enumerate(lines) if ln is not None]
    for i, side in enumerate(sides):
        darker = inner[i].mean() < outer[i].mean() + MIN_CONTRAST
        shade = float(inner[i].mean()) / max(paper, 1e-6)
        shade = shade if shade < SHADOW_MAX_BRIGHTNESS else 1.0
        unlike = min(np.linalg.norm(outer[i] - shade * outer[j]) for j in range(len(sides)) if j != i)
        weak = steps[i] < WEAK_SIDE_SHARE * steps.max()
        if darker or weak or unlike >= floor_match * shade * change:
            strange.append(side)
            if np.linalg.norm(inner[i] - floor) < floor_match * change:
                outside.append(side)
    return strange, outside


def _moved(ln: _Line) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The line as (point, direction) with its offset moved by its SD, and with its angle turned by its SD."""
    normal = np.array([-ln.direction[1], ln.direction[0]])
    c, s = math.cos(ln.angle_sd), math.sin(ln.angle_sd)
    turned = np.array([c * ln.direction[0] - s * ln.direction[1], s * ln.direction[0] + c * ln.direction[1]])
    return (ln.point + ln.offset_sd * normal, ln.direction), (ln.point, turned)


def _perturbed_corners(lines: list[_Line]) -> list[np.ndarray]:
    """Corners (4, 2) with one line's offset, or angle, moved by its SD: 8 quads for linearised propagation."""
    base = [(ln.point, ln.direction) for ln in lines]
    out = []
    for i, ln in enumerate(lines):
        for moved in _moved(ln):
            trial = list(base)
            trial[i] = moved
            corners = _corners_from_lines(trial)
            if corners is not None:
                out.append(corners)
    return out
