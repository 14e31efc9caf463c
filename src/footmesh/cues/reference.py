"""Reference objects on the floor (A4 sheet, ID-1 card, printed ArUco marker) and the metric floor plane.

A plain photo has no scale; a known rectangle lying on the floor gives it. ``detect_reference`` finds the object,
its four corners to a fraction of a pixel, tells which object it is from its metric aspect ratio (recovered with
the intrinsics K), and solves the plane's pose in millimetres (planar PnP, IPPE). Method and measured accuracy:
docs/reference.md.

Steps:

1. Marker: ``cv2.aruco.ArucoDetector`` (DICT_4X4_50, id 0) on the image, else on its mirror image (a mirrored
   photo, or a mirrored print, still gives a metric plane).
2. Sheet and card: candidate quadrilaterals from the outlines of regions at several levels of whiteness (sheet),
   grey and each colour channel (card), and of Canny edges: each outline's convex hull is simplified
   (``approxPolyDP``) and every four of its sides that enclose it make a candidate (the foot on a sheet cuts
   corners off its region), screened at once by a loose metric test (3), its sides then re-fitted to the outline
   points near them.
3. Metric test: the rays through the four corners, cut by a plane, give a parallelogram (unique up to scale); a
   rectangle's image gives a right angle, and its side ratio names the object (A4 1.414, card 1.586).
4. Sub-pixel sides: along each side (its ends skipped: rounded card corners) the blurred image is sampled across
   the side and the strongest colour gradient that is a step (not a thin line) is located to sub-pixel
   precision; a robust line fit through these points and the intersections of neighbouring lines give the
   corners. The same for the marker's black square.
5. Strict tests: right angle and side ratio (tolerances widened by the corners' own noise), every side's edge
   present where it is not covered (the foot over a sheet may hide part of a side or a corner), straight (as
   straight as a real, slightly bowed sheet), and not running on past the corners (planks, tiles), a white sheet
   whose every side parts the paper from the floor, inside the image.
6. A sheet's sides fitted again through paper-to-floor edges only (the leg's outline left out) and, where they
   bow, its corners placed from the stretches of the sides next to them; then the pose:
   ``cv2.solvePnP(..., SOLVEPNP_IPPE)`` on the known rectangle, floor z pointing to the camera.
7. Uncertainty: each line's offset and angle SD from its fit residuals (counting their correlation along the
   side), pushed through intersection and PnP by finite differences to the camera-to-object distance; plus the
   object's size tolerance.
8. Nothing found with the caller's mask: the same candidates again without it (``search_reference`` says why the
   largest was rejected when nothing is found at all).

Frames: image pixels with the centre of the top-left pixel at (0, 0); camera OpenCV (x right, y down, z forward),
mm. The floor frame has its origin at corner 0, x along the first side (the length L), y along the width W,
z = x cross y up out of the floor (towards the camera).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from footmesh import references
from footmesh.geometry.camera import rescale_pixels

KINDS = references.BY_PREFERENCE
"""Object kinds in order of preference (``footmesh.references``): a marker is unambiguous, a sheet is large, a
card is small."""

SIZES_MM: dict[str, tuple[float, float]] = {k.name: k.size_mm for k in references.KINDS}
"""Length x width (mm) of the rectangle whose corners are returned."""

SIZE_REL_SD: dict[str, float] = {k.name: k.size_rel_sd for k in references.KINDS}
"""Relative SD of the object's true size, uniform within its tolerance (``ReferenceKind.size_tolerance_mm``)."""
SHEETS = references.with_detector("sheet")
"""The kinds found as sheets of paper (bright, may bow, may lie under the foot and be completed)."""
RECTANGLES = references.with_detector("sheet") + references.with_detector("card")
MARKERS = references.with_detector("marker")
"""The kinds named by their side ratio (markers are named by their pattern)."""

ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_50
ARUCO_ID = 0
MARKER_SHEET_SCALE = 1.5
"""The printed sheet around a marker's black square (140 mm around 100 mm), with room for perspective."""
MARKER_CELLS = 6
"""Cells across a DICT_4X4 marker's black square (4 pattern cells and a one-cell black border)."""
MARKER_RETRY_RADII_CELLS = (0.4, 0.6)
"""Where OpenCV's corners of a large marker sit up to half a cell inside its outline (its sub-pixel window is too
small to move them there), the sides are searched again this many cells either way, in turn. The white sheet's own
edge lies 1.2 cells outside the outline, out of reach; a side caught on the pattern's edges a cell inside would
make the square a rectangle of ratio 5:6, which the metric test refuses."""

ASPECT_TOLERANCE = 0.045
"""Largest |log(measured side ratio / the object's)| accepted; A4 and card differ by 0.115 in log ratio."""
ANGLE_TOLERANCE_DEG = 3.5
"""Largest departure from a right angle of the recovered corner angle (metric, with K)."""
MAX_ASPECT_TOLERANCE = 0.05
MAX_ANGLE_TOLERANCE_DEG = 6.0
"""Where the corners are noisy the tolerances grow to 3 SD of the measured ratio and angle, up to these (never
so far that a sheet could pass for a card)."""
LOOSE_FACTOR = 3.0
"""Candidates are refined when they pass the metric test with tolerances this many times wider."""
MIN_BLANK_SHARE = 0.5
"""Of a sheet's inside that the foot's mask leaves, at least this share must be of the paper's colour (a shadow
over part of the sheet is allowed for)."""
MIN_PAPER_SHOWN = 0.1
"""Searched again without the caller's mask, a sheet must show paper over at least this fraction of its area
outside the mask: the foot's lit skin (with the floor around the toes) passed as a white sheet once, while the
real sheets' masks, however spread, left 29-72 % of them in view."""
SHAPE_WEIGHT = 0.25
"""Of the candidates for one object, the score loses this much per tolerance that its shape departs from the
object's (side ratio and right angle): quads of one sheet that differ by a side caught on the leg's outline
differ by that most."""
MIN_SIDE_PX = 14.0
"""Shortest side (px) of an object worth measuring."""
FIRST_RADIUS_PX = 3.0
"""Search radius across a rough side of the first refinement pass (and of a sheet's completion), px."""
BORDER_MARGIN_PX = 2.0
"""Corners must lie this far inside the image: an object cut by the border gives a false quadrilateral."""
MIN_SIDE_SUPPORT = 0.35
MIN_MEAN_SUPPORT = 0.6
"""Each side must show its edge at this fraction (the four sides together: the second) of the positions along it
that show either the edge or plainly no edge; where the foot or its shadow covers the side nothing is known and
nothing counts (``_side_edge_points``)."""
MIN_COVERAGE: dict[str, tuple[float, float]] = {k.name: k.min_coverage for k in references.KINDS}
_LOOSEST_COVERAGE = tuple(min(c[i] for c in MIN_COVERAGE.values()) for i in (0, 1))
"""Each side must show its edge along the first fraction of its sampled length at least, and the four sides
together along the second: a sheet may lie under the foot, a card lies beside it; a marker is proven by its
decoded pattern, so the foot's shadow may cover more of its sides (the lines' fit still bounds the scale's SD).
A sheet stood on can show only 13-17 % of its far side: at 0.2, 7 of 60 sheets in guided photos (seeds 4242 /
777 / 999) were not found, at 0.1 five; the same on random views (``bench_reference --n 90``) and no new object
on 180 plain guided photos."""
OCCLUSION_MATCH = 0.35
"""Colours closer than this fraction of the change across a side count as the same colour."""
FLOOR_MATCH = 0.5
"""The floor beyond two sides of a sheet counts as the same floor when the colours differ by less than this
fraction of the typical change across the sides (light falls off across a sheet; a shadow lies over a side)."""
MAX_RESIDUAL_RATIO = 2.0
STRAIGHT_EDGE_PX = 0.5
STRAIGHT_EDGE_FRACTION = 0.003
"""A side's edge points may scatter about its line up to this many times the median side's residual SD, or up
to this many px (an edge this straight is straight), or up to this fraction of the side's length: a sheet on a
real floor bows (curl, waves, the lens' residual distortion), and a bow of 1 % of the side (3 mm on A4's length)
scatters 0.3 % of it about the line. A side fitted to a curved outline (the foot's, where it hides the sheet's
side) scatters more."""
CORNER_SPAN = 0.3
CORNER_RADIUS_PX = (4.0, 1.5)
MIN_CORNER_COVERAGE = 0.3
"""A sheet's corners are placed where the stretches of its two sides nearest to each (up to this fraction of
the side from it) meet, each side searched again there this far (px) either way of its line, then closer: paper
on a real floor bows and waves (curl, a step on it, the lens' residual distortion), and the line through a
whole bowed side misses its corners by several px where its middle sags. A stretch whose edge shows along less
than this fraction of it keeps the whole side's line."""
CORNER_MOVE_PX = 1.0
"""A corner is placed from the stretches next to it only when that moves it this far from where the whole sides
meet: along straight sides the whole sides fix it better (their lines' SD at a corner is a few hundredths of a
px)."""
CONTINUATION_SPAN = (0.05, 0.3)
"""Stretch beyond each corner, in side lengths, where the side's edge must not go on."""
MAX_CONTINUATION = 0.5
CONTINUATION_RADIUS_PX = 1.0
"""Largest fraction of that stretch that may show an edge within this distance of the side's line."""
MIN_CONTINUATIONS = 2
"""A quad is cut out of longer lines when its edges run on past this many corner ends (of the eight). At 1, a card
whose short side lay in line with a plank's seam (guided 999, photo 4) and sheets in line with a tile's grout
(4242, 45: a grout line was then taken for a side, the scale 13.5 % off) were refused: 50 -> 53 of 60 guided cards
found (seeds 4242 / 777 / 999), random views (``bench_reference --n 90``) unchanged, no new object on 180 plain
guided photos."""
PAPER_MAX_SATURATION = 0.3
"""An A4 sheet is white: (max - min) / max of its colour just inside its sides stays below this (and it is
brighter than the floor around it)."""
MIN_CONTRAST = 0.04
"""Smallest colour change across a side (image values 0..1, Euclidean over RGB) that counts as an edge."""
DISTANCE_RANGE_MM = (80.0, 5000.0)
"""Plausible camera-to-object distances of a foot photo."""
MAX_SCALE_REL_SD = 0.03
"""An object whose corners fix the scale worse than this (relative SD) is not reported."""
MIN_CORNER_SD_PX = 0.05
"""Floor of an edge's residual SD (px): residuals of a few points underestimate it."""
BLUR_SIGMA_PX = 0.75
"""Gaussian blur before locating edges; symmetric, so it does not move a straight edge."""
END_SKIP = 0.06
"""Fraction of each side skipped at both ends when fitting its line (a card's rounded corners: 3.7 % of its
length, 5.9 % of its width)."""
PLATEAU_PX = 2.5
"""The colours on both sides of an edge are read this far (px) beyond the search window."""
SHEET_MIN_AREA = 0.004
"""A white region smaller than this fraction of the image is not completed into a sheet with a hidden corner."""
COMPLETION_MIN_COVERAGE = 0.5
COMPLETION_MIN_SUPPORT = 0.8
"""A sheet is completed from three sides only when each shows its edge along this much of it (coverage,
support as in ``_Line``)."""
COMPLETED_MIN_SIDE_SUPPORT = 0.7
"""Each side of a completed sheet must show its edge at this fraction of the positions where it is seen: the
hidden corner is hidden by the foot (where nothing counts), not missing from a bright blob (the top of a leg
once passed as a sheet with a corner completed, sides supported at 0.48 and 0.49)."""
MAX_HULL_SIDES = 8
"""A region's hull simplified to more sides than this is no quadrilateral with a few corners cut off."""
MAX_HIDDEN_AREA_RATIO = 2.0
"""A quadrilateral guessed from a region with corners cut off may be at most this many times the region."""

_MIN_REGION_AREA_PX = 120.0
_THRESHOLD_LEVELS = 9
SEARCH_SIDE_PX = 640
"""Images larger than this (shorter side, px) are searched for a card's candidate regions at this size."""
_KERNEL3 = np.ones((3, 3), np.uint8)
_KERNEL5 = np.ones((5, 5), np.uint8)
_COMBINATIONS = {n: np.array(list(itertools.combinations(range(n), 4))) for n in range(4, MAX_HULL_SIDES + 1)}


@dataclass(frozen=True)
class ReferenceObject:
    """A reference object found on the floor, and the floor plane it gives.

    ``kind``: a ``references.NAMES`` entry; ``corners_px``: (4, 2) float64 px of the rectangle's corners in
    the order local (0, 0), (L, 0), (L, W), (0, W) (marker: its black square, the first corner at the bottom left
    of the pattern read upright; sheet and card: of the two possible starts, the one nearer the camera);
    ``size_mm``: (L, W); ``cam_from_floor``: (4, 4) floor frame (mm, origin at corner 0, x along L, z up out of
    the floor) -> camera frame (mm); ``reprojection_px``: RMS distance between ``corners_px`` and the rectangle
    projected with the pose; ``corner_sd_px``: estimated SD of a corner's position (from the line fits);
    ``fit_rel_sd``: relative SD of the camera-to-object distance from the corners' noise alone;
    ``scale_rel_sd``: the same with the object's size tolerance (``SIZE_REL_SD``) added, the relative SD of every
    length measured through this plane; ``mirrored``: the marker was read in the mirror image.
    """

    kind: str
    corners_px: np.ndarray
    size_mm: tuple[float, float]
    cam_from_floor: np.ndarray
    reprojection_px: float
    corner_sd_px: float
    fit_rel_sd: float
    scale_rel_sd: float
    mirrored: bool = False

    @property
    def floor_normal(self) -> np.ndarray:
        """(3,) unit normal of the floor in the camera frame, pointing up out of the floor (towards the camera)."""
        return self.cam_from_floor[:3, 2].copy()

    @property
    def floor_distance_mm(self) -> float:
        """Distance (mm) from the camera centre to the floor plane."""
        return float(-self.floor_normal @ self.cam_from_floor[:3, 3])

    @property
    def object_distance_mm(self) -> float:
        """Distance (mm) from the camera centre to the object's centre."""
        length, width = self.size_mm
        centre = self.cam_from_floor[:3, :3] @ [length / 2, width / 2, 0.0] + self.cam_from_floor[:3, 3]
        return float(np.linalg.norm(centre))

    def floor_points(self, points_px: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(N, 2) px -> (N, 3) mm: where the pixels' rays meet the floor, in the floor frame (z = 0); NaN if never."""
        pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
        rays = np.concatenate([pts, np.ones((len(pts), 1))], axis=1) @ np.linalg.inv(K).T  # camera frame, z = 1
        rot, trans = self.cam_from_floor[:3, :3], self.cam_from_floor[:3, 3]
        normal = rot[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (normal @ trans) / (rays @ normal)
        floor = (rays * depth[:, None] - trans) @ rot  # R^T (p - t)
        floor[~(depth > 0)] = np.nan
        floor[:, 2] = np.where(np.isfinite(floor[:, 0]), 0.0, np.nan)
        return floor


@dataclass(frozen=True)
class ReferenceSearch:
    """What the search for a reference object saw: the object found (None when none is convincing) and, when none
    was, why the most sheet-like candidate was not taken (``rejected``, in words; None when nothing looked like
    a reference object) and how much of the photo it covered (``rejected_area``, a fraction)."""

    found: ReferenceObject | None
    rejected: str | None = None
    rejected_area: float = 0.0


def detect_reference(
    rgb: np.ndarray,
    K: np.ndarray,
    kinds: tuple[str, ...] | list[str] = KINDS,
    exclude_mask: np.ndarray | None = None,
) -> ReferenceObject | None:
    """Find a reference object lying on the floor and the floor plane it gives; None when none is convincing
    (``search_reference``'s ``found``)."""
    return search_reference(rgb, K, kinds, exclude_mask).found


def search_reference(
    rgb: np.ndarray,
    K: np.ndarray,
    kinds: tuple[str, ...] | list[str] = KINDS,
    exclude_mask: np.ndarray | None = None,
) -> ReferenceSearch:
    """Find a reference object lying on the floor and the floor plane it gives, or say why none was taken.

    Args:
        rgb: (H, W, 3) uint8, or float in 0..1, RGB image.
        K: (3, 3) intrinsics in pixels of this image.
        kinds: which objects to look for (any of ``KINDS``); when several are found the marker wins, then the
            A4 sheet, then the card, whatever the order given.
        exclude_mask: optional (H, W) bool, pixels not to take edges from (e.g. the foot and leg): an edge there
            neither supports nor contradicts a side.

    Returns:
        ``ReferenceSearch``: the ``ReferenceObject`` (None: the caller reports the result as unscaled) and, when
        none was found, the reason the largest candidate was rejected.
    """
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
    blurred = cv2.GaussianBlur(image, (0, 0), BLUR_SIGMA_PX)
    found, markers = _detect_marker(image, blurred, K, valid, report=bool(references.with_detector("marker", kinds)))
    if found is not None:
        return ReferenceSearch(found)
    wanted = [k for k in RECTANGLES if k in kinds]
    if not wanted:
        return ReferenceSearch(None)
    # a marker's cells are rectangles too: nothing is taken from the printed sheet of any marker seen
    sheets = [(q - q.mean(axis=0)) * MARKER_SHEET_SCALE + q.mean(axis=0) for q in markers]
    seen: set[tuple[int, ...]] = set()  # rough quads already listed (both searches)
    sheet_groups = _candidate_groups(blurred, K, wanted, "sheet", seen) if set(wanted) & set(SHEETS) else []
    card_groups = _candidate_groups(blurred, K, wanted, "card", seen) if set(wanted) - set(SHEETS) else []
    searched = _try_groups(sheet_groups, card_groups, sheets, wanted, blurred, K, valid)
    if searched.found is not None:
        return searched
    if valid is not None:
        # the mask is the silhouette network's, and on real photos it sometimes spreads over the floor and hides
        # the sheet's sides; the sides' own tests (straight, supported, not running on) still hold without it
        # the sides' own tests (straight, supported, not running on) still hold without it; but the foot's own
        # lit skin is no sheet: what the mask leaves of a sheet must be paper
        masked = exclude_mask.astype(bool)
        again = _try_groups(sheet_groups, card_groups, sheets, wanted, blurred, K, None, masked)
        if again.found is not None:
            return again
    return ReferenceSearch(None, searched.rejected, searched.rejected_area / (h * w))


def _try_groups(
    sheet_groups: list[list[np.ndarray]],
    card_groups: list[list[np.ndarray]],
    sheets: list[np.ndarray],
    wanted: list[str],
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    masked: np.ndarray | None = None,
) -> ReferenceSearch:
    """Refine and test the rough quads of ``_candidate_groups`` in turn: the A4 sheet found, else the card, else
    (``rejected_area`` in px here) why the largest rough quad was rejected. Quads over a marker's printed sheet
    (``sheets``) are skipped, and objects found more than ``MAX_MASKED_SHARE`` inside ``masked`` (H, W) bool."""
    best: dict[str, tuple[float, ReferenceObject]] = {}
    accepted: list[np.ndarray] = []  # corners already found, in canonical order
    largest_rejected: list[tuple[float, str]] = []  # (area px, why) of the largest rough quad rejected

    def try_candidates(quads: list[np.ndarray], completed: bool = False) -> None:
        """Refine and test rough quads in turn, keeping the best-scoring object of each kind."""
        for quad in quads:
            # many thresholds give the same object: refine it once
            if any(np.max(np.linalg.norm(quad - corners, axis=1)) < 3.0 for corners in accepted):
                continue
            if any(_overlaps(quad, sheet) for sheet in sheets):
                continue
            why: list[str] = []
            result = _finish(quad, wanted, blurred, K, valid, completed=completed, rejected=why)
            if result is None:
                area = abs(_signed_area(quad))
                if why and (not largest_rejected or area > largest_rejected[0][0]):
                    largest_rejected[:] = [(area, why[0])]
                continue
            if masked is not None and not _paper_beside(result[1].corners_px, masked, blurred):
                continue
            if masked is not None and result[1].kind in SHEETS:
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
    for group in sheet_groups[:1] + card_groups:
        try_candidates(group)
        if (sheet := best_of(SHEETS)) is not None:
            return ReferenceSearch(sheet)
    if (card := best_of(cards)) is not None:
        return ReferenceSearch(card)
    for group in sheet_groups[1:]:
        try_candidates(group, completed=True)
        if (sheet := best_of(SHEETS)) is not None:
            return ReferenceSearch(sheet)
    if not largest_rejected:
        return ReferenceSearch(None)
    area, why = largest_rejected[0]
    return ReferenceSearch(None, why, area)


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
    ``MIN_BLANK_SHARE`` of those pixels within half the sides' typical change of the paper's colour. A square of a
    tiled floor's pattern passes every test of its sides, but has the pattern inside."""
    inside = np.zeros(valid.shape, np.uint8)
    cv2.fillPoly(inside, [np.round(quad).astype(np.int32)], 1)
    shown = (cv2.erode(inside, _KERNEL5) > 0) & valid
    if not shown.any():
        return True  # all of it under the foot: nothing to tell
    inner, outer = _inner_outer(quad, lines)
    paper = np.median(inner, axis=0)
    change = float(np.median(np.linalg.norm(inner - outer, axis=1)))
    near = np.linalg.norm(blurred[shown] - paper, axis=1) < 0.5 * change
    return float(near.mean()) >= MIN_BLANK_SHARE


# --- input checks -------------------------------------------------------------------------------------------


def _check_image(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 or float 0..1 -> (H, W, 3) float32 0..1 (contiguous)."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(
            f"rgb must be an (H, W, 3) colour image, got shape {rgb.shape}; convert grey or RGBA images to RGB first"
        )
    if rgb.shape[0] < 16 or rgb.shape[1] < 16:
        raise ValueError(f"rgb is too small to find a reference object in: {rgb.shape[1]} x {rgb.shape[0]} px")
    if rgb.dtype == np.uint8:
        return np.ascontiguousarray(rgb, dtype=np.float32) / 255.0
    if np.issubdtype(rgb.dtype, np.floating):
        if not np.all(np.isfinite(rgb)) or rgb.min() < 0.0 or rgb.max() > 1.0:
            raise ValueError("a float rgb image must hold finite values in 0..1 (uint8 images are taken as 0..255)")
        return np.ascontiguousarray(rgb, dtype=np.float32)
    raise ValueError(f"rgb must be uint8 (0..255) or float (0..1), got dtype {rgb.dtype}")


def _check_intrinsics(K: np.ndarray) -> np.ndarray:
    """Validated (3, 3) float64 intrinsics."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K must be the (3, 3) intrinsics matrix in pixels, got shape {K.shape}")
    if not np.all(np.isfinite(K)):
        raise ValueError("K holds NaN or infinite values")
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0.0:
        raise ValueError(f"K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K's focal lengths must be positive pixels, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K


# --- marker -------------------------------------------------------------------------------------------------


def _detect_marker(
    image: np.ndarray, blurred: np.ndarray, K: np.ndarray, valid: np.ndarray | None, report: bool = True
) -> tuple[ReferenceObject | None, list[np.ndarray]]:
    """The ArUco marker (DICT_4X4_50, id 0), read upright or in the mirror image (None unless ``report``), and
    the (4, 2) px quads of every marker seen (any id)."""
    grey = cv2.cvtColor((image * 255.0 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    # the printed sheet's outline lies 20 mm outside the black square: with OpenCV's default rate the two count as
    # "too close" and the outer one (no marker) is kept, then dropped when the sheet runs off the image
    params.minMarkerDistanceRate = 0.02
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY), params)
    w = grey.shape[1]
    seen: list[np.ndarray] = []
    for mirrored in (False, True):
        corners, ids, _ = detector.detectMarkers(cv2.flip(grey, 1) if mirrored else grey)
        if ids is None:
            continue
        for quad, marker_id in zip(corners, ids.ravel(), strict=True):
            quad = quad.reshape(4, 2).astype(np.float64)  # pattern's top-left, top-right, bottom-right, bottom-left
            if mirrored:
                quad[:, 0] = (w - 1) - quad[:, 0]
            seen.append(quad)
            if marker_id != ARUCO_ID or not report:
                continue
            # upright print seen from above: x along the pattern's bottom edge, y up it, z out of the paper; the
            # mirror image's reading order runs the other way round: top-left first keeps z up
            ordered = quad if mirrored else quad[[3, 2, 1, 0]]
            cell = float(np.mean(np.linalg.norm(np.roll(ordered, -1, axis=0) - ordered, axis=1))) / MARKER_CELLS
            wider = [r * cell for r in MARKER_RETRY_RADII_CELLS if r * cell > FIRST_RADIUS_PX]
            for radius in (FIRST_RADIUS_PX, *wider):
                found = _finish(ordered, MARKERS, blurred, K, valid, mirrored=mirrored, first_radius=radius)
                if found is not None:
                    return found[1], seen
    return None, seen


def _overlaps(quad: np.ndarray, region: np.ndarray) -> bool:
    """Whether a (4, 2) quad has its centre or a corner inside the convex (4, 2) region."""
    contour = region.astype(np.float32).reshape(-1, 1, 2)
    points = np.concatenate([quad, quad.mean(axis=0, keepdims=True)])
    return any(cv2.pointPolygonTest(contour, (float(x), float(y)), False) >= 0 for x, y in points)


# --- candidate quadrilaterals -------------------------------------------------------------------------------


def _candidate_groups(
    blurred: np.ndarray, K: np.ndarray, kinds: list[str], regions: str, seen: set[tuple[int, ...]]
) -> list[list[np.ndarray]]:
    """Rough (4, 2) px quadrilaterals (canonical order) that might be one of ``kinds``, from the outlines of
    ``regions``: "sheet" (bright in every channel) or "card" (thresholds of the grey level and of each channel,
    either way, and edges); in groups to try in turn: the quads the outlines make, then (sheets) those made by
    completing a hidden corner. Near duplicates of each other and of the keys in ``seen`` (updated) are left out."""
    if regions not in ("sheet", "card"):
        raise ValueError(f"regions must be 'sheet' or 'card', got {regions!r}")
    h, w = blurred.shape[:2]
    # a card's regions are outlined at a coarser scale (the refinement works at full resolution): most of the
    # time of its search goes into thresholds and outlines, and a rough quad within a pixel or two is all it
    # needs. A sheet's are not: its sides' refinement from a rough quad that far off sometimes settles on
    # another edge (its shadow), up to 1.8 px off on the eval photos.
    scale = max(1.0, min(h, w) / SEARCH_SIDE_PX) if regions == "card" else 1.0
    small = blurred
    if scale > 1.0:
        small = cv2.resize(blurred, (round(w / scale), round(h / scale)), interpolation=cv2.INTER_AREA)
    to_full = np.array([w / small.shape[1], h / small.shape[0]], np.float32)  # small px -> px, per axis
    grey = small.mean(axis=2)
    # a sheet's region is opened wide as well (white grout and other thin lines joined to it fall away), a card's
    # closed (over its stripe)
    wide = np.ones((2 * (min(h, w) // 200) + 5,) * 2, np.uint8)  # (sheets only: outlined at full resolution)
    features: list[tuple[np.ndarray, str]] = []
    if regions == "sheet":
        features.append((small.min(axis=2), "sheet"))  # paper: every channel high; skin, wood, most floors: not
    else:
        for f in (grey, small[..., 0], small[..., 1], small[..., 2]):
            features.extend([(f, "card"), (-f, "card")])
    outlines: list[tuple[tuple, bool]] = []  # (contours, whether a sheet's: the largest pieces also together)
    stride = max(1, int(round(4 / scale)))
    for feature, use in features:
        lo, hi = np.percentile(feature[::stride, ::stride], [1.0, 99.5])
        if hi - lo < MIN_CONTRAST:
            continue
        for level in np.linspace(lo, hi, _THRESHOLD_LEVELS + 2)[1:-1]:
            binary = cv2.morphologyEx((feature > level).astype(np.uint8), cv2.MORPH_OPEN, _KERNEL3)
            outlines.append((cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)[0], use == "sheet"))
            if use == "sheet":
                binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, wide)
                outlines.append((cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)[0], True))
            else:
                binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, _KERNEL5)
                outlines.append((cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)[0], False))
    if regions == "card":
        u8 = (grey * 255.0 + 0.5).astype(np.uint8)
        for low, high in ((10, 30), (25, 75)):
            edges = cv2.dilate(cv2.Canny(u8, low, high, L2gradient=True), _KERNEL3)
            outlines.append((cv2.findContours(edges, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)[0], False))

    # (simplified hull, its area, outline points, whether a sheet's)
    polygons: list[tuple[np.ndarray, float, np.ndarray, bool]] = []
    min_length, min_area = 20 / scale, _MIN_REGION_AREA_PX / scale**2
    for contours, sheet in outlines:
        big = [c for c in contours if len(c) >= min_length and cv2.contourArea(c) >= min_area]
        big = [rescale_pixels(c.astype(np.float32), to_full) for c in big]  # in px of the image
        groups = [(c, cv2.contourArea(c)) for c in big]
        if sheet and len(big) > 1:
            # a leg across a sheet under the foot cuts its white region in two or three: try them together
            big.sort(key=cv2.contourArea, reverse=True)
            for m in (2, 3)[: len(big) - 1]:
                for combo in itertools.combinations(big[:3], m):
                    groups.append((np.concatenate(combo), sum(cv2.contourArea(c) for c in combo)))
        for points, area in groups:
            hull = cv2.convexHull(points)
            hull_area = cv2.contourArea(hull)
            # the foot on a sheet eats into its region but leaves most of it: a ring or an L is no rectangle
            if hull_area < _MIN_REGION_AREA_PX or area < 0.45 * hull_area:
                continue
            for poly in _simplify(hull):
                polygons.append((poly, cv2.contourArea(poly.astype(np.float32)), points, sheet))
    if not polygons:
        return []

    rough, source = _polygon_quads(polygons)
    keep = _inside_many(rough, h, w)
    rough, source = _canonical_many(rough[keep]), source[keep]
    keep = np.isfinite(rough).all(axis=(1, 2))
    rough, source = rough[keep], source[keep]
    passed = _classify_many(rough, K, RECTANGLES, 2 * LOOSE_FACTOR)
    quads: list[np.ndarray] = []
    if passed.any():
        shape_ok, src = rough[passed], source[passed]
        _, first = np.unique(
            np.round(shape_ok / 2.0).astype(np.int64).reshape(len(shape_ok), -1), axis=0, return_index=True
        )
        for i in np.sort(first):
            quad = _fit_sides_to_points(shape_ok[i], polygons[src[i]][2].reshape(-1, 2).astype(np.float64))
            if quad is None or not _inside(quad, h, w) or (quad := _canonical(quad)) is None:
                continue
            if _classify(quad, K, kinds, loose=LOOSE_FACTOR) is None:
                continue
            key = tuple(np.round(quad / 2.0).astype(int).ravel().tolist())
            if key not in seen:
                seen.add(key)
                quads.append(quad)
    groups = [quads]
    if regions == "sheet":
        # a sheet's region with a corner hidden (the foot, the leg) is no rectangle's image: complete it from three
        # of its sides, and try it after the others
        quads = []
        groups.append(quads)
        big = np.array([polygons[i][3] and polygons[i][1] >= SHEET_MIN_AREA * h * w for i in source])
        todo = ~passed & big
        if todo.any():
            area = np.array([polygons[i][1] for i in source[todo]])
            sizes = [SIZES_MM[k] for k in SHEETS if k in kinds]
            completed = np.concatenate([_complete_many(rough[todo], area, K, h, w, size) for size in sizes])
            if len(completed):
                _, first = np.unique(
                    np.round(completed / 4.0).astype(np.int64).reshape(len(completed), -1), axis=0, return_index=True
                )
                for quad in completed[np.sort(first)]:
                    key = tuple(np.round(quad / 2.0).astype(int).ravel().tolist())
                    if key not in seen:
                        seen.add(key)
                        quads.append(quad)
    return groups


def _complete_many(
    quads: np.ndarray, region_area: np.ndarray, K: np.ndarray, h: int, w: int, size_mm: tuple[float, float]
) -> np.ndarray:
    """Sheets (N, 4, 2) px that (M, 4, 2) quads could be with one side wrong (cut across a hidden corner): for
    each side m, the other three kept and the rectangle of the sheet's proportions (``size_mm``) they bound, for
    either side being the
    long one. Only those inside the image, holding the quad and at most MAX_HIDDEN_AREA_RATIO times the region.

    Sides m + 1 and m + 3 are parallel on the floor: their images meet at the vanishing point v, and their 3D
    direction is D1 = K^-1 v. Side m + 2 lies in the plane through the camera with normal K^T l (l its image line)
    and is perpendicular to D1: D2 = K^T l x D1. The floor's normal is D1 x D2; corners m + 2 and m + 3 are cut
    from their rays by that plane, and corners m + 1, m = those plus the other side's length along D1.
    """
    k_inv = np.linalg.inv(K)
    hom = np.concatenate([quads, np.ones(quads.shape[:2] + (1,))], axis=2)  # (M, 4, 3)
    lines = np.cross(hom, np.roll(hom, -1, axis=1))  # side i: corner i -> i + 1
    length, width = size_mm
    out = []
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for m in range(4):
            i1, i2, i3 = (m + 1) % 4, (m + 2) % 4, (m + 3) % 4
            d1 = np.cross(lines[:, i1], lines[:, i3]) @ k_inv.T  # (M, 3)
            d2 = np.cross(lines[:, i2] @ K, d1)
            normal = np.cross(d1, d2)
            r2, r3 = hom[:, i2] @ k_inv.T, hom[:, i3] @ k_inv.T  # rays of corners m + 2, m + 3
            s2, s3 = np.sum(normal * r2, axis=1), np.sum(normal * r3, axis=1)
            p2, p3 = r2 / s2[:, None], r3 / s3[:, None]  # on the plane normal . X = 1 (up to scale and sign)
            p2 = p2 * np.sign(p2[:, 2:])
            p3 = p3 * np.sign(p3[:, 2:])
            u1 = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
            # towards the quad's own corner m + 1 (the sign of the step along D1 as seen in the image)
            ahead = p2 + 1e-3 * np.linalg.norm(p2, axis=1, keepdims=True) * u1
            step = ahead[:, :2] / ahead[:, 2:] - p2[:, :2] / p2[:, 2:]  # normalised image coordinates
            toward = (hom[:, i1, :2] - hom[:, i2, :2]) @ k_inv[:2, :2].T
            u1 = u1 * np.sign(np.sum(step * toward, axis=1))[:, None]
            side2 = np.linalg.norm(p2 - p3, axis=1)
            for target in (length / width, width / length):  # |side m + 2| / |side m + 1|
                side1 = side2 / target
                p1 = p2 + side1[:, None] * u1
                p0 = p3 + side1[:, None] * u1
                pts = np.stack([p0, p1, p2, p3], axis=1)  # corners m, m + 1, m + 2, m + 3
                ok = (pts[..., 2] > 0).all(axis=1) & np.isfinite(pts).all(axis=(1, 2))
                px = pts @ K.T
                corners = np.roll(px[..., :2] / px[..., 2:], m, axis=1)
                x, y = corners[..., 0], corners[..., 1]
                area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
                qx, qy = quads[..., 0], quads[..., 1]
                quad_area = 0.5 * np.abs(np.sum(qx * np.roll(qy, -1, axis=1) - np.roll(qx, -1, axis=1) * qy, axis=1))
                ok &= (area >= 0.98 * quad_area) & (area <= MAX_HIDDEN_AREA_RATIO * region_area)
                ok &= _inside_many(corners, h, w)
                out.append(corners[ok])
    completed = _canonical_many(np.concatenate(out))
    return completed[np.isfinite(completed).all(axis=(1, 2))]


def _simplify(hull: np.ndarray) -> list[np.ndarray]:
    """A convex hull simplified to 4..MAX_HULL_SIDES vertices (n, 2), finely and coarsely: a coarse outline may
    cut across the corner the foot hides, a fine one keeps it as a short side that the four long ones skip."""
    closed = hull.astype(np.float32)
    perimeter = cv2.arcLength(closed, True)
    out: list[np.ndarray] = []
    for eps in (0.01, 0.025, 0.05):
        poly = cv2.approxPolyDP(closed, eps * perimeter, True).reshape(-1, 2).astype(np.float64)
        if 4 <= len(poly) <= MAX_HULL_SIDES and not any(len(p) == len(poly) for p in out):
            out.append(poly)
    return out


def _polygon_quads(polygons: list[tuple]) -> tuple[np.ndarray, np.ndarray]:
    """Quadrilaterals (M, 4, 2) a convex polygon may be with some corners cut off (by the foot, a shadow), and
    the index (M,) of the polygon of each: every four of its sides, extended, that enclose it without adding more
    than MAX_HIDDEN_AREA_RATIO. Corner k = side k - 1 x side k, in homogeneous coordinates."""
    quads, sources = [], []
    by_sides: dict[int, list[int]] = {}
    for i, (poly, *_) in enumerate(polygons):
        by_sides.setdefault(len(poly), []).append(i)
    for n, members in by_sides.items():
        verts = np.stack([polygons[i][0] for i in members])  # (P, n, 2)
        hom = np.concatenate([verts, np.ones(verts.shape[:2] + (1,))], axis=2)
        lines = np.cross(hom, np.roll(hom, -1, axis=1))  # (P, n, 3): side i from vertex i to i + 1
        chosen = lines[:, _COMBINATIONS[n]]  # (P, C, 4, 3)
        corners = np.cross(np.roll(chosen, 1, axis=2), chosen)  # (P, C, 4, 3)
        weight = corners[..., 2:]
        ok = (np.abs(weight) > 1e-9 * np.linalg.norm(corners[..., :2], axis=-1, keepdims=True)).all(axis=(2, 3))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            xy = corners[..., :2] / weight
            x, y = xy[..., 0], xy[..., 1]
            area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=2) - np.roll(x, -1, axis=2) * y, axis=2))  # (P, C)
            poly_area = np.array([polygons[i][1] for i in members])[:, None]
            # the quad holds the polygon (its corners only cut off), and the cut-off part is not most of it
            ok &= (poly_area <= area * 1.02) & (area <= MAX_HIDDEN_AREA_RATIO * poly_area)
        p_idx, c_idx = np.nonzero(ok)
        quads.append(xy[p_idx, c_idx])
        sources.append(np.asarray(members)[p_idx])
    return np.concatenate(quads), np.concatenate(sources)


def _inside(quad: np.ndarray, h: int, w: int, margin: float = BORDER_MARGIN_PX) -> bool:
    """All corners of a (4, 2) quad finite and at least ``margin`` px inside the image."""
    return bool(_inside_many(quad[None], h, w, margin)[0])


def _inside_many(quads: np.ndarray, h: int, w: int, margin: float = BORDER_MARGIN_PX) -> np.ndarray:
    """(M,) bool: all corners of each (M, 4, 2) quad at least ``margin`` px inside the image (NaN: not)."""
    m = margin
    with np.errstate(invalid="ignore"):
        x, y = quads[..., 0], quads[..., 1]
        return ((x >= m) & (y >= m) & (x <= w - 1 - m) & (y <= h - 1 - m)).all(axis=1)


def _fit_sides_to_points(quad: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    """Re-fit each side of ``quad`` to the outline ``points`` (N, 2) near it and intersect the lines."""
    lines = []
    for i in range(4):
        p, q = quad[i], quad[(i + 1) % 4]
        length = float(np.linalg.norm(q - p))
        if length < MIN_SIDE_PX:
            return None
        t = (q - p) / length
        n = np.array([-t[1], t[0]])
        rel = points - p
        along, across = rel @ t, rel @ n
        near = np.abs(across) <= max(2.0, 0.03 * length)
        near &= (along > END_SKIP * length) & (along < (1 - END_SKIP) * length)
        if near.sum() < 5:
            lines.append((p, t))
            continue
        vx, vy, x0, y0 = cv2.fitLine(points[near].astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
        lines.append((np.array([x0, y0], dtype=np.float64), np.array([vx, vy], dtype=np.float64)))
    return _corners_from_lines(lines)


def _intersect(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> np.ndarray | None:
    """Intersection (2,) of the lines p1 + s d1 and p2 + s d2; None when nearly parallel."""
    den = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(den) < 1e-6 * np.linalg.norm(d1) * np.linalg.norm(d2) + 1e-12:
        return None
    r = p2 - p1
    return p1 + (r[0] * d2[1] - r[1] * d2[0]) / den * d1


def _corners_from_lines(lines: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray | None:
    """(4, 2) corners: corner i = intersection of line i - 1 and line i (lines given as point, direction)."""
    corners = []
    for i in range(4):
        c = _intersect(*lines[i - 1], *lines[i])
        if c is None:
            return None
        corners.append(c)
    return np.array(corners)


def _signed_area(quad: np.ndarray) -> float:
    """Shoelace area in image coordinates (x right, y down): negative when the corners run counter-clockwise as
    seen on the screen, which is how a floor rectangle in local order appears seen from above."""
    x, y = quad[:, 0], quad[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _canonical(quad: np.ndarray) -> np.ndarray | None:
    """Convex quad with negative signed area, starting at its top-left-most corner; None if not convex."""
    # ``_canonical_many`` of one quad, in plain floats: the candidate search calls it thousands of times
    q = [(float(x), float(y)) for x, y in quad]
    area = sum(q[i][0] * q[(i + 1) % 4][1] - q[(i + 1) % 4][0] * q[i][1] for i in range(4))
    if area > 0:
        q = q[::-1]
    edges = [(q[(i + 1) % 4][0] - q[i][0], q[(i + 1) % 4][1] - q[i][1]) for i in range(4)]
    if not all(edges[i][0] * edges[(i + 1) % 4][1] - edges[i][1] * edges[(i + 1) % 4][0] < 0 for i in range(4)):
        return None
    start = min(range(4), key=lambda i: q[i][0] + q[i][1])
    return np.array(q[start:] + q[:start])


def _canonical_many(quads: np.ndarray) -> np.ndarray:
    """``_canonical`` of (M, 4, 2) quads; NaN rows where not convex."""
    x, y = quads[..., 0], quads[..., 1]
    area = np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    quads = np.where((area > 0)[:, None, None], quads[:, ::-1], quads)
    edges = np.roll(quads, -1, axis=1) - quads
    nxt = np.roll(edges, -1, axis=1)
    convex = (edges[..., 0] * nxt[..., 1] - edges[..., 1] * nxt[..., 0] < 0).all(axis=1)
    start = np.argmin(quads.sum(axis=2), axis=1)
    order = (start[:, None] + np.arange(4)[None]) % 4
    quads = np.take_along_axis(quads, order[..., None], axis=1)
    quads[~convex] = np.nan
    return quads


# --- metric tests -------------------------------------------------------------------------------------------


def _parallelogram_many(quads: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Metric shape of the plane parallelograms whose images are the (M, 4, 2) quads: side ratio
    |P1 - P0| / |P3 - P0| (M,), angle at P0 in degrees (M,), depths (M, 4) up to a common scale, and whether the
    solution exists with every corner in front of the camera (M,).

    With rays r_i = K^-1 (u_i, v_i, 1), depths l_i with l0 r0 + l2 r2 = l1 r1 + l3 r3 (the diagonals bisect each
    other) are unique up to scale: a rectangle's image gives a right angle and its true side ratio.
    """
    rays = np.concatenate([quads, np.ones(quads.shape[:2] + (1,))], axis=2) @ np.linalg.inv(K).T  # (M, 4, 3)
    a = np.stack([rays[:, 1], -rays[:, 2], rays[:, 3]], axis=2)  # (M, 3, 3): columns r1, -r2, r3
    good = np.abs(np.linalg.det(a)) > 1e-12
    a[~good] = np.eye(3)
    lam = np.linalg.solve(a, rays[:, 0][..., None])[..., 0]  # (M, 3)
    depths = np.concatenate([np.ones((len(quads), 1)), lam], axis=1)
    good &= (lam > 0).all(axis=1)
    pts = rays * depths[..., None]
    side_a, side_b = pts[:, 1] - pts[:, 0], pts[:, 3] - pts[:, 0]
    na, nb = np.linalg.norm(side_a, axis=1), np.linalg.norm(side_b, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.clip(np.sum(side_a * side_b, axis=1) / (na * nb), -1.0, 1.0)
        return na / nb, np.degrees(np.arccos(cos)), depths, good & np.isfinite(cos)


def _parallelogram(quad: np.ndarray, K: np.ndarray) -> tuple[float, float, np.ndarray] | None:
    """``_parallelogram_many`` of one (4, 2) quad: (side ratio, angle in degrees, (4,) depths) or None."""
    # in plain floats (Cramer's rule): the search and the sheet completion call it tens of thousands of times
    fx, skew, cx, fy, cy = float(K[0, 0]), float(K[0, 1]), float(K[0, 2]), float(K[1, 1]), float(K[1, 2])
    rays = []
    for u, v in quad:
        y = (float(v) - cy) / fy
        rays.append(((float(u) - cx - skew * y) / fx, y, 1.0))
    (r0, r1, r2, r3) = rays
    m2 = (-r2[0], -r2[1], -r2[2])

    def det(a: tuple, b: tuple, c: tuple) -> float:  # columns a, b, c
        return (
            a[0] * (b[1] * c[2] - b[2] * c[1]) - b[0] * (a[1] * c[2] - a[2] * c[1]) + c[0] * (a[1] * b[2] - a[2] * b[1])
        )

    d = det(r1, m2, r3)
    if not abs(d) > 1e-12:
        return None
    lam = (det(r0, m2, r3) / d, det(r1, r0, r3) / d, det(r1, m2, r0) / d)
    if not min(lam) > 0:
        return None
    p0, p1, p3 = r0, [lam[0] * c for c in r1], [lam[2] * c for c in r3]
    a = [p1[i] - p0[i] for i in range(3)]
    b = [p3[i] - p0[i] for i in range(3)]
    na, nb = math.sqrt(sum(x * x for x in a)), math.sqrt(sum(x * x for x in b))
    if not (na > 0 and nb > 0 and math.isfinite(na * nb)):
        return None
    cos = min(max(sum(a[i] * b[i] for i in range(3)) / (na * nb), -1.0), 1.0)
    return na / nb, math.degrees(math.acos(cos)), np.array([1.0, *lam])


def _classify_many(quads: np.ndarray, K: np.ndarray, kinds: list[str], loose: float) -> np.ndarray:
    """(M,) bool: the metric test (with tolerances ``loose`` times wider) names each (M, 4, 2) quad one of
    ``kinds``."""
    if len(quads) == 0:
        return np.zeros(0, dtype=bool)
    ratio, angle, _, good = _parallelogram_many(quads, K)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_ratio = np.abs(np.log(ratio))
    good &= np.abs(angle - 90.0) <= ANGLE_TOLERANCE_DEG * loose
    fits = np.zeros(len(quads), dtype=bool)
    for kind in kinds:
        length, width = SIZES_MM[kind]
        fits |= np.abs(log_ratio - math.log(length / width)) <= ASPECT_TOLERANCE * loose
    return good & fits


def _classify(
    quad: np.ndarray,
    K: np.ndarray,
    kinds: list[str],
    loose: float = 1.0,
    tol_ratio: float = ASPECT_TOLERANCE,
    tol_angle: float = ANGLE_TOLERANCE_DEG,
) -> tuple[str, int] | None:
    """Which of ``kinds`` the quad is (nearest metric side ratio, right angle), and the index of the corner that
    starts its local order (side 0 -> 1 along the length; of the two such starts, the one nearer the camera)."""
    shape = _parallelogram(quad, K)
    if shape is None:
        return None
    ratio, angle, depths = shape
    if abs(angle - 90.0) > tol_angle * loose:
        return None
    long_first = ratio >= 1.0
    ratio = ratio if long_first else 1.0 / ratio
    misfit = {kind: abs(math.log(ratio * SIZES_MM[kind][1] / SIZES_MM[kind][0])) for kind in kinds}
    kind = min(misfit, key=misfit.get)
    if misfit[kind] > tol_ratio * loose:
        return None
    start = 0 if long_first else 1
    if depths[(start + 2) % 4] < depths[start]:
        start = (start + 2) % 4
    return kind, start


# --- sub-pixel sides ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Profiles:
    """Edges across a line at positions along it: ``points`` (S, 2) px, ``found`` (S,) bool, ``min_step`` the
    smallest colour change across the line that counted, the colours ``ends`` (S, 2, 3) read at both ends of
    each profile (-n, +n), and ``usable`` (S,) bool: not excluded by the caller's mask."""

    points: np.ndarray
    found: np.ndarray
    min_step: float
    ends: np.ndarray
    usable: np.ndarray


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
    not of a thin line. None when nothing changes across the line.
    """
    d = q - p
    t = d / np.linalg.norm(d)
    n = np.array([-t[1], t[0]])
    step = 0.25
    # the profile reaches PLATEAU_PX beyond the search window, where the colours on both sides are read
    reach = radius + PLATEAU_PX
    across = np.arange(-reach, reach + 1e-9, step)
    pts = p + along[:, None, None] * t + across[None, :, None] * n  # (S, O, 2)
    map_x = np.ascontiguousarray(pts[..., 0], dtype=np.float32)
    map_y = np.ascontiguousarray(pts[..., 1], dtype=np.float32)
    # bicubic: a bilinear profile's derivative is constant between pixel centres and pulls the peak onto them
    values = cv2.remap(blurred, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)  # (S, O, 3)
    size = np.linalg.norm(values[:, -1] - values[:, 0], axis=1)  # (S,) colour change across the line
    if min_step is None:
        # where the foot covers the side the change is another one: half the median of the larger half
        min_step = max(MIN_CONTRAST, 0.5 * float(np.median(size[size >= np.median(size)])))
    if size.max() < min_step:
        return None
    # central differences (np.gradient's, without its one-sided ends, which lie beyond the window)
    diff = values[:, 2:] - values[:, :-2]
    grad = np.zeros(values.shape[:2], values.dtype)  # (S, O)
    grad[:, 1:-1] = np.sqrt(np.sum(diff * diff, axis=2)) / (2.0 * step)
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
    usable = np.ones(len(along), dtype=bool)
    if valid is not None:
        h, w = valid.shape
        ix = np.clip(np.rint(points[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.rint(points[:, 1]).astype(int), 0, h - 1)
        usable = valid[iy, ix]
        found &= usable
    return _Profiles(points, found, min_step, values[:, [0, -1]], usable)


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
) -> _SideEdges | None:
    """Edges along the side p -> q, 1 px apart, END_SKIP of it skipped at both ends.

    A position without the edge either shows something else across the side (the foot, its shadow: occluded)
    or shows the colour of one side of the edge on both sides of the line: the edge is plainly not there. Only
    the latter counts against the side (``_Line.support``).
    """
    length = float(np.linalg.norm(q - p))
    skip = END_SKIP * length + 1.0
    along = np.arange(skip, length - skip + 1e-9, 1.0)
    if len(along) < 6:
        return None
    prof = _profiles(blurred, p, q, along, radius, valid)
    if prof is None or prof.found.sum() < 5:
        return None
    near, far = np.median(prof.ends[prof.found], axis=0)  # (3,) each: typical colours at -n and +n
    tol = OCCLUSION_MATCH * float(np.linalg.norm(far - near))
    a, b = prof.ends[:, 0], prof.ends[:, 1]

    def like(x: np.ndarray, c: np.ndarray) -> np.ndarray:
        return np.linalg.norm(x - c, axis=1) < tol

    missing = ~prof.found & prof.usable & ((like(a, near) & like(b, near)) | (like(a, far) & like(b, far)))
    return _SideEdges(prof.points[prof.found], len(along), int(missing.sum()), prof.min_step, near, far)


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


def _fit_line(edges: _SideEdges) -> _Line | None:
    """Robust total-least-squares line through edge points: Huber fit, outliers beyond 3 robust SD dropped, refit."""
    points = edges.points
    if len(points) < 5:
        return None
    vx, vy, x0, y0 = cv2.fitLine(points.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
    direction = np.array([vx, vy], dtype=np.float64)
    normal = np.array([-direction[1], direction[0]])
    resid = (points - np.array([x0, y0])) @ normal
    mad = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    pts = points[np.abs(resid - np.median(resid)) <= max(3.0 * mad, 0.3)]
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
    quad: np.ndarray, blurred: np.ndarray, valid: np.ndarray | None, radius: float
) -> list[_Line | None] | None:
    """The line fitted to the image's edges along each side of a quad (None where none), or None if a side is
    too short (line i runs from corner i to corner i + 1).

    Once one side has no line and two could not carry a sheet's completion, the quad can neither be refined
    (every side needed) nor completed (three good sides needed): the remaining sides are left None unfitted.
    """
    sides = [float(np.linalg.norm(quad[(i + 1) % 4] - quad[i])) for i in range(4)]
    if min(sides) < MIN_SIDE_PX:
        return None
    lines: list[_Line | None] = []
    for i in range(4):
        edges = _side_edge_points(blurred, quad[i], quad[(i + 1) % 4], min(radius, 0.15 * sides[i]), valid)
        lines.append(None if edges is None else _fit_line(edges))
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
) -> tuple[np.ndarray, list[_Line]] | None:
    """Sub-pixel corners of a quad (4, 2) px from the image's edges along its sides, and the four fitted lines
    (line i runs from corner i to corner i + 1). ``first``: ``_fit_sides(quad, ..., radii[0])`` when the caller
    already has it."""
    lines: list[_Line] = []
    for step, radius in enumerate(radii):
        fitted = first if step == 0 and first is not None else _fit_sides(quad, blurred, valid, radius)
        if fitted is None or any(ln is None for ln in fitted):
            return None
        lines = fitted
        new = _corners_from_lines([(ln.point, ln.direction) for ln in lines])
        if new is None or np.max(np.linalg.norm(new - quad, axis=1)) > 3.0 * radius + 2.0:
            return None
        quad = new
    return quad, lines


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
    """A sheet's sides fitted again through the edges between the paper and the floor only (``_stretch_line`` along
    the whole side): where the leg or the foot lies over a side and the mask misses it, their outline no longer
    pulls the line. A side that shows too little of its own edge keeps its line. Also returns (4,) the fraction
    of each side that shows that edge (0 where too little)."""
    # the paper's colour from all four sides (a side the leg covers has the skin's as its own)
    inner, _ = _inner_outer(corners, lines)
    paper = np.median(inner, axis=0)
    centre = corners.mean(axis=0)
    clean, shown = [], []
    for i, ln in enumerate(lines):
        p, q = corners[i], corners[(i + 1) % 4]
        t = q - p
        if (centre - p) @ np.array([-t[1], t[0]]) > 0:  # the paper lies on the +n (far) side
            ln = dataclasses.replace(ln, far=paper)
        else:
            ln = dataclasses.replace(ln, near=paper)
        length = float(np.linalg.norm(q - p))
        along = np.arange(END_SKIP * length + 1.0, (1.0 - END_SKIP) * length - 1.0 + 1e-9, 1.0)
        line = _stretch_line(blurred, p, q, along, ln) if len(along) >= 6 else None
        clean.append(ln if line is None else line)
        shown.append(0.0 if line is None else line.coverage)
    new = _corners_from_lines([(ln.point, ln.direction) for ln in clean])
    if new is None or np.max(np.linalg.norm(new - corners, axis=1)) > 3.0 * CORNER_RADIUS_PX[0]:
        return corners, lines, perturbed, np.array(shown)
    return new, clean, _perturbed_corners(clean), np.array(shown)


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
            normal = np.array([-ln.direction[1], ln.direction[0]])
            c, s = math.cos(ln.angle_sd), math.sin(ln.angle_sd)
            turned = np.array([c * ln.direction[0] - s * ln.direction[1], s * ln.direction[0] + c * ln.direction[1]])
            for point, direction in ((ln.point + ln.offset_sd * normal, ln.direction), (ln.point, turned)):
                lines = [(a.point, a.direction) for a in pair]
                lines[k] = (point, direction)
                corner = _intersect(*lines[0], *lines[1])
                if corner is not None:
                    trial = base.copy()
                    trial[j] = corner
                    out.append(trial)
    return out


def _continues(blurred: np.ndarray, quad: np.ndarray, lines: list[_Line], valid: np.ndarray | None) -> bool:
    """Whether the sides' edges run on past the corners, in line with them, at ``MIN_CONTINUATIONS`` places or more:
    the quad is then cut out of longer lines (planks, tiles, a marker's grid) and is not an object lying on the
    floor. At one place only, it is a seam or grout line that happens to meet a corner in line with a side."""
    h, w = blurred.shape[:2]
    found = 0
    for i in range(4):
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


def _inner_outer(quad: np.ndarray, lines: list[_Line]) -> tuple[np.ndarray, np.ndarray]:
    """(4, 3) each: the typical colours just inside and just outside each side, read beyond its edges where they
    were found (so that the foot over the sheet does not count)."""
    centre = quad.mean(axis=0)
    inner, outer = [], []
    for i, ln in enumerate(lines):
        t = quad[(i + 1) % 4] - quad[i]  # the side was sampled from corner i to corner i + 1
        n = np.array([-t[1], t[0]])
        far_inside = (centre - quad[i]) @ n > 0
        inner.append(ln.far if far_inside else ln.near)
        outer.append(ln.near if far_inside else ln.far)
    return np.array(inner), np.array(outer)


def _is_paper(quad: np.ndarray, lines: list[_Line]) -> bool:
    """A white sheet: little colour inside, and brighter inside than outside along at least three sides."""
    inner, outer = _inner_outer(quad, lines)
    paper = np.median(inner, axis=0)
    if (paper.max() - paper.min()) / max(float(paper.max()), 1e-6) > PAPER_MAX_SATURATION:
        return False
    return int(np.sum(inner.mean(axis=1) > outer.mean(axis=1) + MIN_CONTRAST / 2)) >= 3


def _strange_borders(quad: np.ndarray, lines: list[_Line]) -> tuple[list[int], list[int]]:
    """The sides (0..3) of a sheet that do not part the paper from the floor, and of those the ones with the
    floor inside (placed beside the sheet, not over it).

    Inside each side the paper must be brighter than what lies outside (not a line in the floor beside the
    sheet), and what lies outside must look like the floor beyond another side (not the hem of dark trousers
    across the sheet; where the sheet lies across two floors, a rug's edge, the sides still pair up; a shadow
    darkens the floor less than the change across the sides)."""
    inner, outer = _inner_outer(quad, lines)
    change = float(np.median(np.linalg.norm(inner - outer, axis=1)))
    floor = np.median(outer, axis=0)
    strange, outside = [], []
    for i in range(4):
        darker = inner[i].mean() < outer[i].mean() + MIN_CONTRAST
        if darker or min(np.linalg.norm(outer[i] - outer[j]) for j in range(4) if j != i) >= FLOOR_MATCH * change:
            strange.append(i)
            if np.linalg.norm(inner[i] - floor) < FLOOR_MATCH * change:
                outside.append(i)
    return strange, outside


# --- pose and uncertainty -----------------------------------------------------------------------------------


def _object_points(kind: str) -> np.ndarray:
    """(4, 3) corners of the object's rectangle in the floor frame (mm), in local order."""
    length, width = SIZES_MM[kind]
    return np.array([[0, 0, 0], [length, 0, 0], [length, width, 0], [0, width, 0]], dtype=np.float64)


def rectangle_pose(corners: np.ndarray, kind: str, K: np.ndarray) -> tuple[np.ndarray, float] | None:
    """``cam_from_floor`` (4, 4) mm and RMS reprojection (px) of the ``kind`` object's rectangle from its (4, 2) px
    corners in local order (IPPE, K (3, 3)); None when no pose puts it in front of the camera, facing it."""
    obj = _object_points(kind)
    ok, rvec, tvec = cv2.solvePnP(obj, corners.reshape(4, 1, 2), K, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return None
    rot, _ = cv2.Rodrigues(rvec)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, tvec.ravel()
    # the floor's z must face the camera (the corners' order sees to it) and every corner lie in front of it
    if -(rot[:, 2] @ pose[:3, 3]) <= 0 or np.any((obj @ rot.T + pose[:3, 3])[:, 2] <= 0):
        return None
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    reproj = float(np.sqrt(np.mean(np.sum((proj.reshape(4, 2) - corners) ** 2, axis=1))))
    return pose, reproj


def _distance(corners: np.ndarray, kind: str, K: np.ndarray) -> float:
    """Camera-to-object-centre distance (mm) implied by the corners (NaN when there is no pose)."""
    found = rectangle_pose(corners, kind, K)
    if found is None:
        return float("nan")
    pose = found[0]
    length, width = SIZES_MM[kind]
    return float(np.linalg.norm(pose[:3, :3] @ [length / 2, width / 2, 0.0] + pose[:3, 3]))


def _perturbed_corners(lines: list[_Line]) -> list[np.ndarray]:
    """Corners (4, 2) with one line's offset, or angle, moved by its SD: 8 quads for linearised propagation."""
    base = [(ln.point, ln.direction) for ln in lines]
    out = []
    for i, ln in enumerate(lines):
        normal = np.array([-ln.direction[1], ln.direction[0]])
        c, s = math.cos(ln.angle_sd), math.sin(ln.angle_sd)
        turned = np.array([c * ln.direction[0] - s * ln.direction[1], s * ln.direction[0] + c * ln.direction[1]])
        for moved in ((ln.point + ln.offset_sd * normal, ln.direction), (ln.point, turned)):
            trial = list(base)
            trial[i] = moved
            corners = _corners_from_lines(trial)
            if corners is not None:
                out.append(corners)
    return out


def _shape_sd(corners: np.ndarray, perturbed: list[np.ndarray], K: np.ndarray) -> tuple[float, float]:
    """SD of the log side ratio and of the corner angle (deg) of ``_parallelogram``, from the perturbed corners."""
    ratio, angle, _ = _parallelogram(corners, K)
    var_r = var_a = 0.0
    for trial in perturbed:
        shape = _parallelogram(trial, K)
        if shape is None:
            return float("inf"), float("inf")
        var_r += math.log(shape[0] / ratio) ** 2
        var_a += (shape[1] - angle) ** 2
    return math.sqrt(var_r), math.sqrt(var_a)


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
) -> tuple[float, ReferenceObject] | None:
    """Refine a rough quad, name it, test it strictly and solve the plane: (score, object) or None (then why,
    in words, appended to ``rejected``).

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
    )
    for sheet_kind in [k for k in SHEETS if k in kinds] if result is None else []:
        for sheet in _complete_sheet(quad, blurred, K, valid, lines=first, size_mm=SIZES_MM[sheet_kind]):
            # the quad's own reason stands: a completion is a guess
            result = _finish_quad(sheet, [sheet_kind], blurred, K, valid, completed=True)
            if result is not None:
                return result
    return result


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
) -> tuple[float, ReferenceObject] | None:
    """``_finish`` without the completion of a sheet (``first``: the sides fitted at ``first_radius``;
    ``completed``: the quad is a sheet completed across a hidden corner; ``rejected``: why the quad is not the
    object, appended in words when it is not)."""

    def reject(why: str) -> None:
        if rejected is not None:
            rejected.append(why)

    h, w = blurred.shape[:2]
    refined = _refine_sides(quad, blurred, valid, radii=(first_radius, 1.5), first=first)
    if refined is None:
        return reject("a side's edge could not be traced along it")
    corners, lines = refined
    # a marker is read by its pattern, not cut out by the border: it only has to lie in the image
    marker = all(references.kind(k).detector == "marker" for k in kinds)
    if not _inside(corners, h, w, margin=0.0 if marker else BORDER_MARGIN_PX):
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
    shape = _parallelogram(corners, K)
    if shape is None:
        return reject("its corners are no rectangle's image")
    perturbed = _perturbed_corners(lines)
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
        if found is None or found[0] not in kinds:
            ratio, angle = max(shape[0], 1.0 / shape[0]), shape[1]
            aspects = ", ".join(f"{references.kind(k).described} {references.kind(k).aspect:.3f}" for k in RECTANGLES)
            return reject(
                f"its shape is no reference object's (side ratio {ratio:.3f}; {aspects}; corner angle "
                f"{angle:.1f} deg; the photo's focal length may be wrong)"
            )
        kind, start = found
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
    if sheet:
        strange, outside = _strange_borders(corners, lines)
        # a completed sheet's fourth side runs where the foot hides it (its colours are the foot's), not beside it
        if outside or len(strange) > (1 if completed else 0):
            side = (outside or strange)[-1] + 1
            return reject(f"its side {side} of 4 does not part the paper from the floor (clothing over it?)")
    if _continues(blurred, corners, lines, valid):
        return reject("its sides run on past its corners (tiles, planks or a printed grid)")
    at_corner = [(j, ln) for i, ln in enumerate(lines) for j in (i, (i + 1) % 4)]  # each corner's two lines
    if sheet:
        corners, lines, perturbed, coverage = _clean_sides(corners, lines, blurred, perturbed)
    if sheet and (bowed := _bowed_corners(corners, lines, blurred)) is not None:
        local_perturbed = _perturbed_corner_pairs(bowed)
        local = _corners_of(bowed)
        local_sd = _shape_sd(local, local_perturbed, K)
        tol_ratio = min(max(ASPECT_TOLERANCE, 3.0 * local_sd[0]), MAX_ASPECT_TOLERANCE)
        tol_angle = min(max(ANGLE_TOLERANCE_DEG, 3.0 * local_sd[1]), MAX_ANGLE_TOLERANCE_DEG)
        if _classify(local, K, RECTANGLES, tol_ratio=tol_ratio, tol_angle=tol_angle) == (kind, 0):
            corners, perturbed = local, local_perturbed
            at_corner = [(j, ln) for j, pair in enumerate(bowed) for ln in pair]
    solved = rectangle_pose(corners, kind, K)
    if solved is None:
        return reject("no pose of the object fits its corners")
    pose, reproj = solved
    length, width = SIZES_MM[kind]
    distance = float(np.linalg.norm(pose[:3, :3] @ [length / 2, width / 2, 0.0] + pose[:3, 3]))
    if not DISTANCE_RANGE_MM[0] <= distance <= DISTANCE_RANGE_MM[1]:
        return reject(f"it would lie {distance / 1000:.2f} m from the camera")
    fit_sd = math.sqrt(sum((_distance(c, kind, K) - distance) ** 2 for c in perturbed)) / distance
    if not fit_sd <= MAX_SCALE_REL_SD:
        return reject(f"its corners fix the scale only to {100 * fit_sd:.1f} %")
    # a corner's SD: the two lines' offsets there (the line's offset SD at its centroid plus the angle's lever)
    corner_var = [
        ln.offset_sd**2 + (ln.angle_sd * float(np.linalg.norm(corners[j] - ln.point))) ** 2 for j, ln in at_corner
    ]
    obj = ReferenceObject(
        kind=kind,
        corners_px=corners,
        size_mm=(length, width),
        cam_from_floor=pose,
        reprojection_px=reproj,
        corner_sd_px=float(np.sqrt(2.0 * np.mean(corner_var))),
        fit_rel_sd=fit_sd,
        scale_rel_sd=math.sqrt(fit_sd**2 + SIZE_REL_SD[kind] ** 2),
        mirrored=mirrored,
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
