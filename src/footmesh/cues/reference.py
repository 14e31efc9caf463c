"""Reference objects on the floor (A4 sheet, ID-1 card, printed ArUco marker) and the metric floor plane.

A plain photo has no scale; a known rectangle lying on the floor gives it. ``detect_reference`` finds the object,
its four corners to a fraction of a pixel, tells which object it is from its metric aspect ratio (recovered with
the intrinsics K), and solves the plane's pose in millimetres (planar PnP, IPPE). Method and numbers:
docs/reference.md.

Pipeline:

1. Marker: ``cv2.aruco.ArucoDetector`` (DICT_4X4_50, id 0) on the image, else on its mirror image (a mirrored
   photo, or a mirrored print, still gives a metric plane).
2. Sheet and card: candidate quadrilaterals from the outlines of regions at several brightness / whiteness /
   channel thresholds and from Canny edges (convex hull, ``approxPolyDP``; a hull with a corner cut off by the
   foot keeps its four longest sides), each side re-fitted to the outline points near it.
3. A cheap test first: the quad's rays, cut by a plane, give a parallelogram (unique up to scale); a rectangle's
   image must give a right angle, and its side ratio names the object (A4 1.414, card 1.586).
4. Sub-pixel sides: along each side (its ends skipped: rounded card corners, the foot over a sheet's corner)
   the blurred image is sampled across the side, projected on the side's own colour contrast, and the strongest
   edge of that polarity is located to sub-pixel precision; a robust line fit through these points and the
   intersections of neighbouring lines give the corners. The same for the marker's black square.
5. Strict tests (right angle, side ratio, edge support on every side, size, inside the image), then the pose:
   ``cv2.solvePnP(..., SOLVEPNP_IPPE)`` on the known rectangle, floor z pointing to the camera.
6. Uncertainty: each line's offset and angle SD from its fit residuals, pushed through intersection and PnP by
   finite differences to the camera-to-object distance; plus the object's size tolerance.

Frames: image pixels with the centre of the top-left pixel at (0, 0); camera OpenCV (x right, y down, z forward),
mm. The floor frame has its origin at corner 0, x along the first side (the length L), y along the width W,
z = x cross y up out of the floor (towards the camera).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np

KINDS = ("marker", "a4", "card")
"""Object kinds in order of preference: a marker is unambiguous, a sheet is large, a card is small."""

SIZES_MM: dict[str, tuple[float, float]] = {
    "a4": (297.0, 210.0),  # ISO 216
    "card": (85.60, 53.98),  # ISO/IEC 7810 ID-1
    "marker": (100.0, 100.0),  # the printed black square of the marker
}
"""Length x width (mm) of the rectangle whose corners are returned."""

SIZE_REL_SD: dict[str, float] = {
    "a4": 2.0 / 297.0 / math.sqrt(3.0),
    "card": 0.125 / 85.60 / math.sqrt(3.0),
    "marker": 0.005 / math.sqrt(3.0),
}
"""Relative SD of the object's true size, uniform within its tolerance: A4 +-2 mm (ISO 216), card +-0.125 mm
(ISO/IEC 7810: 85.47-85.72 mm), marker print scale +-0.5 % (a printer at "100 %", checked with a ruler)."""

ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_50
ARUCO_ID = 0

ASPECT_TOLERANCE = 0.045
"""Largest |log(measured side ratio / the object's)| accepted; A4 and card differ by 0.115 in log ratio."""
ANGLE_TOLERANCE_DEG = 3.5
"""Largest departure from a right angle of the recovered corner angle (metric, with K)."""
MAX_ASPECT_TOLERANCE = 0.05
MAX_ANGLE_TOLERANCE_DEG = 6.0
"""Where the corners are noisy the tolerances grow to 3 SD of the measured ratio and angle, up to these."""
LOOSE_FACTOR = 3.0
"""Candidates are refined when they pass the tests with tolerances this many times wider."""
MIN_SIDE_PX = 14.0
"""Shortest side (px) of an object worth measuring: below it the corners cannot give the scale to 1 %."""
BORDER_MARGIN_PX = 2.0
"""Corners must lie this far inside the image: an object cut by the border gives a false quadrilateral."""
MIN_SIDE_SUPPORT = 0.4
"""Each side must show its edge along at least this fraction of its sampled length (the foot may hide some)."""
MIN_MEAN_SUPPORT = 0.7
"""... and the four sides together along this fraction."""
MIN_CONTRAST = 0.04
"""Smallest colour step across a side (image values 0..1) that counts as an edge."""
DISTANCE_RANGE_MM = (80.0, 5000.0)
"""Plausible camera-to-object distances of a foot photo."""
MAX_SCALE_REL_SD = 0.03
"""An object whose corners fix the scale worse than this (relative SD) is not reported."""
MIN_CORNER_SD_PX = 0.05
"""Floor of the corners' noise estimate (px): residuals of a few points underestimate it."""
BLUR_SIGMA_PX = 1.0
"""Gaussian blur before locating edges; symmetric, so it does not move a straight edge."""
END_SKIP = 0.1
PLATEAU_PX = 2.5
"""The colours on both sides of an edge are read this far (px) beyond the search window."""
"""Fraction of each side skipped at both ends when fitting its line (rounded corners, occluded corners)."""

CONTINUATION_SPAN = (0.05, 0.3)
"""Stretch beyond each corner, in side lengths, where the side's edge must not go on."""
MAX_CONTINUATION = 0.5
"""Largest fraction of that stretch that may show the side's edge (in line with it, same colours)."""
PAPER_MAX_SATURATION = 0.3
"""An A4 sheet is white: (max - min) / max of its colour just inside its sides stays below this."""

_MIN_REGION_AREA_PX = 120.0
_THRESHOLD_LEVELS = 9
_KERNEL3 = np.ones((3, 3), np.uint8)
_KERNEL5 = np.ones((5, 5), np.uint8)


@dataclass(frozen=True)
class ReferenceObject:
    """A reference object found on the floor, and the floor plane it gives.

    ``kind``: ``"a4"``, ``"card"`` or ``"marker"``; ``corners_px``: (4, 2) float64 px of the rectangle's corners in
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
        return float(
            np.linalg.norm(self.cam_from_floor[:3, :3] @ [length / 2, width / 2, 0] + self.cam_from_floor[:3, 3])
        )

    def floor_points(self, points_px: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(N, 2) px -> (N, 3) mm: where the pixels' rays meet the floor, in the floor frame (z = 0); NaN if never."""
        pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
        rays = np.concatenate([pts, np.ones((len(pts), 1))], axis=1) @ np.linalg.inv(K).T  # camera frame, z = 1
        rot, trans = self.cam_from_floor[:3, :3], self.cam_from_floor[:3, 3]
        normal = rot[:, 2]
        denom = rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (normal @ trans) / denom
        hits = rays * depth[:, None]
        floor = (hits - trans) @ rot  # R^T (p - t)
        floor[~(depth > 0)] = np.nan
        floor[:, 2] = np.where(np.isfinite(floor[:, 0]), 0.0, np.nan)
        return floor


def detect_reference(
    rgb: np.ndarray,
    K: np.ndarray,
    kinds: tuple[str, ...] | list[str] = KINDS,
    exclude_mask: np.ndarray | None = None,
) -> ReferenceObject | None:
    """Find a reference object lying on the floor and the floor plane it gives; None when none is convincing.

    Args:
        rgb: (H, W, 3) uint8, or float in 0..1, RGB image.
        K: (3, 3) intrinsics in pixels of this image.
        kinds: which objects to look for (any of ``KINDS``); when several are found the marker wins, then the
            A4 sheet, then the card, whatever the order given.
        exclude_mask: optional (H, W) bool, pixels not to take edges from (e.g. the foot and leg).

    Returns:
        The ``ReferenceObject``, or None: then the caller reports the result as unscaled.
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
        grown = cv2.dilate(exclude_mask.astype(np.uint8), np.ones((5, 5), np.uint8))
        valid = grown == 0
    blurred = cv2.GaussianBlur(image, (0, 0), BLUR_SIGMA_PX)
    if "marker" in kinds:
        found = _detect_marker(image, blurred, K, valid)
        if found is not None:
            return found
    wanted = [k for k in ("a4", "card") if k in kinds]
    if not wanted:
        return None
    best: dict[str, tuple[float, ReferenceObject]] = {}
    for quad in _candidate_quads(blurred, K, wanted):
        result = _finish(quad, wanted, blurred, K, valid)
        if result is None:
            continue
        score, obj = result
        if obj.kind not in best or score > best[obj.kind][0]:
            best[obj.kind] = (score, obj)
    for kind in ("a4", "card"):
        if kind in best:
            return best[kind][1]
    return None


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
    image: np.ndarray, blurred: np.ndarray, K: np.ndarray, valid: np.ndarray | None
) -> ReferenceObject | None:
    """The ArUco marker (DICT_4X4_50, id 0), read upright or in the mirror image."""
    grey = cv2.cvtColor((image * 255.0 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY), params)
    w = grey.shape[1]
    for mirrored in (False, True):
        corners, ids, _ = detector.detectMarkers(cv2.flip(grey, 1) if mirrored else grey)
        if ids is None:
            continue
        for quad, marker_id in zip(corners, ids.ravel(), strict=True):
            if marker_id != ARUCO_ID:
                continue
            quad = quad.reshape(4, 2).astype(np.float64)  # pattern's top-left, top-right, bottom-right, bottom-left
            if mirrored:
                quad[:, 0] = (w - 1) - quad[:, 0]
                # the mirror image's reading order runs the other way round: top-left first keeps z up
                ordered = quad
            else:
                # upright print seen from above: x along the pattern's bottom edge, y up it, z out of the paper
                ordered = quad[[3, 2, 1, 0]]
            obj = _finish(ordered, ["marker"], blurred, K, valid, mirrored=mirrored)
            if obj is not None:
                return obj[1]
    return None


# --- candidate quadrilaterals -------------------------------------------------------------------------------


def _candidate_quads(blurred: np.ndarray, K: np.ndarray, kinds: list[str]) -> list[np.ndarray]:
    """Rough (4, 2) px quadrilaterals (canonical order) that might be a sheet or a card, near duplicates removed.

    Outlines of regions above and below several levels of whiteness (sheet), grey and each colour channel (card,
    also closed over a card's stripe), and of Canny edges; each outline's hull reduced to four sides, screened by
    the loose metric test, its sides re-fitted to the outline points near them and screened again.
    """
    h, w = blurred.shape[:2]
    grey = blurred.mean(axis=2)
    # a sheet's region is opened wide as well (white grout and other thin lines joined to it fall away), a card's
    # closed (over its stripe)
    wide = np.ones((2 * (min(h, w) // 200) + 5,) * 2, np.uint8)
    features: list[tuple[np.ndarray, str]] = []
    if "a4" in kinds:
        features.append((blurred.min(axis=2), "sheet"))  # paper: every channel high; skin, wood, most floors: not
    if "card" in kinds:
        for f in (grey, blurred[..., 0], blurred[..., 1], blurred[..., 2]):
            features.extend([(f, "card"), (-f, "card")])
    outlines: list[tuple[np.ndarray, bool]] = []  # (contours, whether to add hulls of the largest pieces)
    for feature, use in features:
        lo, hi = np.percentile(feature[::4, ::4], [1.0, 99.5])
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
    if "card" in kinds:
        u8 = (grey * 255.0 + 0.5).astype(np.uint8)
        for low, high in ((10, 30), (25, 75)):
            edges = cv2.dilate(cv2.Canny(u8, low, high, L2gradient=True), _KERNEL3)
            outlines.append((cv2.findContours(edges, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)[0], False))
    seen: set[tuple[int, ...]] = set()
    quads: list[np.ndarray] = []
    for contours, pieces in outlines:
        big = [c for c in contours if len(c) >= 20 and cv2.contourArea(c) >= _MIN_REGION_AREA_PX]
        groups = [(c, cv2.contourArea(c)) for c in big]
        if pieces and len(big) > 1:
            # a leg across a sheet under the foot cuts its white region in two or three: try them together
            big.sort(key=cv2.contourArea, reverse=True)
            for m in (2, 3)[: len(big) - 1]:
                for combo in itertools.combinations(big[:3], m):
                    groups.append((np.concatenate(combo), sum(cv2.contourArea(c) for c in combo)))
        for points, area in groups:
            hull = cv2.convexHull(points)
            hull_area = cv2.contourArea(hull)
            if hull_area < _MIN_REGION_AREA_PX:
                continue
            # the foot on a sheet eats into its region but leaves most of it: a ring or an L is no rectangle
            if area < 0.45 * hull_area:
                continue
            quad = _hull_quad(hull.reshape(-1, 2).astype(np.float64))
            if quad is None or not _inside(quad, h, w) or (quad := _canonical(quad)) is None:
                continue
            if _classify(quad, K, ["a4", "card"], loose=2 * LOOSE_FACTOR) is None:
                continue
            quad = _fit_sides_to_points(quad, points.reshape(-1, 2).astype(np.float64))
            if quad is None or not _inside(quad, h, w) or (quad := _canonical(quad)) is None:
                continue
            if _classify(quad, K, kinds, loose=LOOSE_FACTOR) is None:
                continue
            key = tuple(np.round(quad / 2.0).astype(int).ravel().tolist())
            if key in seen:
                continue
            seen.add(key)
            quads.append(quad)
    return quads


def _inside(quad: np.ndarray, h: int, w: int) -> bool:
    """All corners at least BORDER_MARGIN_PX inside the image."""
    m = BORDER_MARGIN_PX
    return bool(
        np.all(np.isfinite(quad))
        and np.all(quad >= m)
        and np.all(quad[:, 0] <= w - 1 - m)
        and np.all(quad[:, 1] <= h - 1 - m)
    )


def _hull_quad(hull: np.ndarray) -> np.ndarray | None:
    """(4, 2) corners of a convex polygon that is a quadrilateral with at most a few corners cut off."""
    perimeter = cv2.arcLength(hull.astype(np.float32), True)
    poly = cv2.approxPolyDP(hull.astype(np.float32), 0.02 * perimeter, True).reshape(-1, 2).astype(np.float64)
    if len(poly) < 4 or len(poly) > 8:
        return None
    if len(poly) > 4:  # corners cut off (by the foot, by a shadow): keep the four longest sides and extend them
        lengths = np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1)
        keep = np.sort(np.argsort(lengths)[-4:])
        lines = [(poly[i], poly[(i + 1) % len(poly)]) for i in keep]
        corners = []
        for k in range(4):
            c = _intersect_segments(lines[k - 1], lines[k])
            if c is None:
                return None
            corners.append(c)
        quad = np.array(corners)
        area = abs(_signed_area(quad))
        hull_area = cv2.contourArea(hull.astype(np.float32))
        if not hull_area <= area * 1.02 or area > 1.5 * hull_area:
            return None
        return quad
    return poly


def _intersect_segments(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> np.ndarray | None:
    """Intersection (2,) of the infinite lines through two segments; None when nearly parallel."""
    d1, d2 = a[1] - a[0], b[1] - b[0]
    den = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(den) < 1e-6 * np.linalg.norm(d1) * np.linalg.norm(d2) + 1e-12:
        return None
    r = b[0] - a[0]
    s = (r[0] * d2[1] - r[1] * d2[0]) / den
    return a[0] + s * d1


def _fit_sides_to_points(quad: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    """Re-fit each side of ``quad`` to the outline ``points`` (N, 2) near it and intersect the lines."""
    lines = []
    for i in range(4):
        p, q = quad[i], quad[(i + 1) % 4]
        d = q - p
        length = float(np.linalg.norm(d))
        if length < MIN_SIDE_PX:
            return None
        t = d / length
        n = np.array([-t[1], t[0]])
        rel = points - p
        along, across = rel @ t, rel @ n
        near = (
            (np.abs(across) <= max(2.0, 0.03 * length))
            & (along > END_SKIP * length)
            & (along < (1 - END_SKIP) * length)
        )
        if near.sum() < 5:
            lines.append((p, t))
            continue
        vx, vy, x0, y0 = cv2.fitLine(points[near].astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
        lines.append((np.array([x0, y0], dtype=np.float64), np.array([vx, vy], dtype=np.float64)))
    return _corners_from_lines(lines)


def _corners_from_lines(lines: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray | None:
    """Corner i = intersection of line i - 1 and line i (lines given as point, unit direction)."""
    corners = []
    for i in range(4):
        (p1, d1), (p2, d2) = lines[i - 1], lines[i]
        c = _intersect_segments((p1, p1 + d1), (p2, p2 + d2))
        if c is None:
            return None
        corners.append(c)
    return np.array(corners)


def _signed_area(quad: np.ndarray) -> float:
    """Shoelace area in image coordinates (x right, y down): negative when the corners run counter-clockwise as
    seen on the screen, which is how a floor rectangle in local order appears when seen from above."""
    x, y = quad[:, 0], quad[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _canonical(quad: np.ndarray) -> np.ndarray | None:
    """Convex quad with negative signed area, starting at its top-left-most corner; None if not convex."""
    if _signed_area(quad) > 0:
        quad = quad[::-1]
    edges = np.roll(quad, -1, axis=0) - quad
    cross = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    if not np.all(cross < 0):
        return None
    start = int(np.argmin(quad.sum(axis=1)))
    return np.roll(quad, -start, axis=0)


# --- metric tests -------------------------------------------------------------------------------------------


def _parallelogram(quad: np.ndarray, K: np.ndarray) -> tuple[float, float, np.ndarray] | None:
    """Metric shape of the plane parallelogram whose image is ``quad``: (side ratio |P1-P0| / |P3-P0|, angle at
    P0 in degrees, (4,) depths up to a common scale); None if a corner would lie behind the camera.

    With rays r_i = K^-1 (u_i, v_i, 1), depths l_i with l0 r0 + l2 r2 = l1 r1 + l3 r3 (the diagonals bisect each
    other) are unique up to scale: a rectangle's image gives a right angle and its true side ratio.
    """
    rays = np.concatenate([quad, np.ones((4, 1))], axis=1) @ np.linalg.inv(K).T
    a = np.stack([rays[1], -rays[2], rays[3]], axis=1)
    try:
        lam = np.linalg.solve(a, rays[0])
    except np.linalg.LinAlgError:
        return None
    depths = np.concatenate([[1.0], lam])
    if not np.all(depths > 0):
        return None
    pts = rays * depths[:, None]
    side_a, side_b = pts[1] - pts[0], pts[3] - pts[0]
    na, nb = np.linalg.norm(side_a), np.linalg.norm(side_b)
    cos = float(side_a @ side_b / (na * nb))
    return float(na / nb), math.degrees(math.acos(max(-1.0, min(1.0, cos)))), depths


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
class _Line:
    """A fitted side: centroid (2,), unit direction (2,), SD of the offset at the centroid (px) and of the angle
    (rad), the fraction of the side's samples that support it, the residual SD (px), the colour contrast (3,)."""

    point: np.ndarray
    direction: np.ndarray
    offset_sd: float
    angle_sd: float
    support: float
    residual_sd: float
    contrast: np.ndarray


@dataclass(frozen=True)
class _Profiles:
    """Edges found across a line at positions along it: ``points`` (S, 2) px, ``found`` (S,) bool, the colour
    ``contrast`` (3,) across the line (+n side minus -n side), and ``inner``/``outer`` (3,) median colours read
    on the side where the quad's centre lies and on the other."""

    points: np.ndarray
    found: np.ndarray
    contrast: np.ndarray


def _profiles(
    blurred: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    along: np.ndarray,
    radius: float,
    valid: np.ndarray | None,
    contrast: np.ndarray | None = None,
) -> _Profiles | None:
    """Sub-pixel edges across the line p -> q at positions ``along`` (S,) px from p (any, also beyond q).

    At each position the blurred image is sampled across the line every 0.25 px, projected on the colour
    contrast (given, or the median difference across the line), differentiated, and the strongest edge of that
    polarity within ``radius`` located by a parabola through the peak. None when there is no contrast.
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
    steps = values[:, -1] - values[:, 0]  # (S, 3)
    if contrast is None:
        size = np.linalg.norm(steps, axis=1)
        # where the foot covers the side the colour change is another one: take the median of the larger half
        contrast = np.median(steps[size >= np.median(size)], axis=0)
    norm = float(np.linalg.norm(contrast))
    if norm < MIN_CONTRAST:
        return None
    profile = values @ (contrast / norm)  # (S, O): rises across the line along +n
    deriv = np.gradient(profile, step, axis=1)
    window = np.flatnonzero(np.abs(across) <= radius + 1e-9)
    k = window[0] + np.argmax(deriv[:, window], axis=1)
    rows = np.arange(len(along))
    y0, y1, y2 = deriv[rows, k - 1], deriv[rows, k], deriv[rows, k + 1]
    den = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(den < 0, 0.5 * (y0 - y2) / den, 0.0)
    offset = across[k] + np.clip(frac, -0.5, 0.5) * step
    # an edge: a peak inside the window (not at its end), a step of at least half the contrast, a sharp peak
    found = (k > window[0]) & (k < window[-1]) & (profile[:, -1] - profile[:, 0] > 0.5 * norm)
    found &= deriv[rows, k] > 0.5 * norm / (BLUR_SIGMA_PX * math.sqrt(2 * math.pi)) / 2
    points = p + along[:, None] * t + offset[:, None] * n
    if valid is not None:
        h, w = valid.shape
        ix = np.clip(np.rint(points[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.rint(points[:, 1]).astype(int), 0, h - 1)
        found &= valid[iy, ix]
    return _Profiles(points, found, contrast)


def _side_edge_points(
    blurred: np.ndarray, p: np.ndarray, q: np.ndarray, radius: float, valid: np.ndarray | None
) -> tuple[np.ndarray, int, np.ndarray] | None:
    """Edge points (M, 2) px along the side p -> q (1 px apart, END_SKIP of it skipped at both ends), the number
    of positions sampled, and the side's colour contrast (3,)."""
    length = float(np.linalg.norm(q - p))
    skip = END_SKIP * length + 1.0
    along = np.arange(skip, length - skip + 1e-9, 1.0)
    if len(along) < 6:
        return None
    prof = _profiles(blurred, p, q, along, radius, valid)
    if prof is None:
        return None
    return prof.points[prof.found], len(along), prof.contrast


def _continues(blurred: np.ndarray, quad: np.ndarray, contrasts: list[np.ndarray], valid: np.ndarray | None) -> bool:
    """Whether any side's edge runs on past a corner, in line with it: the quad is then cut out of longer lines
    (planks, tiles, grout) and is not an object lying on the floor."""
    for i in range(4):
        p, q = quad[i], quad[(i + 1) % 4]
        length = float(np.linalg.norm(q - p))
        beyond = np.arange(CONTINUATION_SPAN[0] * length + 2.0, CONTINUATION_SPAN[1] * length + 2.0, 1.0)
        if len(beyond) < 4:
            continue
        for along in (length + beyond, -beyond):
            prof = _profiles(blurred, p, q, along, 1.5, valid, contrasts[i])
            h, w = blurred.shape[:2]
            inside = (prof.points[:, 0] > 1) & (prof.points[:, 0] < w - 2) & (prof.points[:, 1] > 1)
            inside &= prof.points[:, 1] < h - 2
            if inside.sum() >= 4 and prof.found[inside].mean() > MAX_CONTINUATION:
                return True
    return False


def _inner_colour(blurred: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """(3,) median colour along a band just inside the quad's sides (a few px in, away from the edge blur)."""
    centre = quad.mean(axis=0)
    inset = (
        quad + (centre - quad) * np.minimum(1.0, (PLATEAU_PX + 2.0) / np.linalg.norm(centre - quad, axis=1))[:, None]
    )
    samples = []
    for i in range(4):
        p, q = inset[i], inset[(i + 1) % 4]
        u = np.linspace(END_SKIP, 1 - END_SKIP, 32)[:, None]
        samples.append(p + u * (q - p))
    pts = np.concatenate(samples).astype(np.float32)
    values = cv2.remap(blurred, pts[:, :1], pts[:, 1:], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.median(values.reshape(-1, 3), axis=0)


def _fit_line(points: np.ndarray, total: int, contrast: np.ndarray) -> _Line | None:
    """Robust total-least-squares line through edge points: Huber fit, outliers beyond 3 robust SD dropped, refit."""
    if len(points) < 5:
        return None
    vx, vy, x0, y0 = cv2.fitLine(points.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
    direction = np.array([vx, vy], dtype=np.float64)
    normal = np.array([-direction[1], direction[0]])
    resid = (points - np.array([x0, y0])) @ normal
    mad = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    keep = np.abs(resid - np.median(resid)) <= max(3.0 * mad, 0.3)
    pts = points[keep]
    if len(pts) < 5:
        return None
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    direction = vt[0] if vt[0] @ direction >= 0 else -vt[0]
    normal = np.array([-direction[1], direction[0]])
    resid = (pts - centroid) @ normal
    along = (pts - centroid) @ direction
    sd = max(float(np.sqrt(np.sum(resid**2) / max(len(pts) - 2, 1))), MIN_CORNER_SD_PX)
    return _Line(
        point=centroid,
        direction=direction,
        offset_sd=sd / math.sqrt(len(pts)),
        angle_sd=sd / math.sqrt(float(np.sum(along**2))),
        support=len(pts) / total,
        residual_sd=sd,
        contrast=contrast,
    )


def _refine_sides(
    quad: np.ndarray, blurred: np.ndarray, valid: np.ndarray | None, radii: tuple[float, ...] = (3.0, 1.5)
) -> tuple[np.ndarray, list[_Line]] | None:
    """Sub-pixel corners of a quad (4, 2) px from the image's edges along its sides, and the four fitted lines."""
    lines: list[_Line] = []
    for radius in radii:
        lines = []
        for i in range(4):
            p, q = quad[i], quad[(i + 1) % 4]
            side = float(np.linalg.norm(q - p))
            if side < MIN_SIDE_PX:
                return None
            found = _side_edge_points(blurred, p, q, min(radius, 0.15 * side), valid)
            if found is None:
                return None
            line = _fit_line(found[0], found[1], found[2])
            if line is None:
                return None
            lines.append(line)
        new = _corners_from_lines([(ln.point, ln.direction) for ln in lines])
        if new is None or np.max(np.linalg.norm(new - quad, axis=1)) > 3.0 * radius + 2.0:
            return None
        quad = new
    return quad, lines


# --- pose and uncertainty -----------------------------------------------------------------------------------


def _object_points(kind: str) -> np.ndarray:
    length, width = SIZES_MM[kind]
    return np.array([[0, 0, 0], [length, 0, 0], [length, width, 0], [0, width, 0]], dtype=np.float64)


def _pose(corners: np.ndarray, kind: str, K: np.ndarray) -> tuple[np.ndarray, float] | None:
    """``cam_from_floor`` (4, 4) mm and RMS reprojection (px) of the rectangle from its corners (IPPE)."""
    obj = _object_points(kind)
    ok, rvec, tvec = cv2.solvePnP(obj, corners.reshape(4, 1, 2), K, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return None
    rot, _ = cv2.Rodrigues(rvec)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, tvec.ravel()
    # the floor's z must face the camera: -n . t > 0 (the corners' order guarantees it unless the fit is wrong)
    if -(rot[:, 2] @ pose[:3, 3]) <= 0 or np.any((obj @ rot.T + pose[:3, 3])[:, 2] <= 0):
        return None
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    reproj = float(np.sqrt(np.mean(np.sum((proj.reshape(4, 2) - corners) ** 2, axis=1))))
    return pose, reproj


def _distance(corners: np.ndarray, kind: str, K: np.ndarray) -> float:
    """Camera-to-object-centre distance (mm) implied by the corners."""
    found = _pose(corners, kind, K)
    if found is None:
        return float("nan")
    pose = found[0]
    length, width = SIZES_MM[kind]
    return float(np.linalg.norm(pose[:3, :3] @ [length / 2, width / 2, 0] + pose[:3, 3]))


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
) -> tuple[float, ReferenceObject] | None:
    """Refine a rough quad, name it, test it strictly and solve the plane: (score, object) or None.

    A marker's quad comes in its local order (``kinds == ["marker"]``); a sheet's or card's is put in local
    order once its sides are known.
    """
    h, w = blurred.shape[:2]
    refined = _refine_sides(quad, blurred, valid)
    if refined is None:
        return None
    corners, lines = refined
    if not _inside(corners, h, w):
        return None
    if min(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)) < MIN_SIDE_PX:
        return None
    supports = np.array([ln.support for ln in lines])
    if supports.min() < MIN_SIDE_SUPPORT or supports.mean() < MIN_MEAN_SUPPORT:
        return None
    shape = _parallelogram(corners, K)
    if shape is None:
        return None
    perturbed = _perturbed_corners(lines)
    ratio_sd, angle_sd = _shape_sd(corners, perturbed, K)
    # the tolerances widen with the corners' noise (small or oblique objects), never so far that a sheet could
    # pass for a card: they differ by 0.115 in log ratio
    tol_ratio = min(max(ASPECT_TOLERANCE, 3.0 * ratio_sd), MAX_ASPECT_TOLERANCE)
    tol_angle = min(max(ANGLE_TOLERANCE_DEG, 3.0 * angle_sd), MAX_ANGLE_TOLERANCE_DEG)
    if kinds == ["marker"]:
        kind, start = "marker", 0
        if abs(math.log(shape[0])) > tol_ratio or abs(shape[1] - 90.0) > tol_angle:
            return None
    else:
        found = _classify(corners, K, ["a4", "card"], tol_ratio=tol_ratio, tol_angle=tol_angle)
        if found is None or found[0] not in kinds:
            return None
        kind, start = found
    if start:
        corners = np.roll(corners, -start, axis=0)
        lines = lines[start:] + lines[:start]
        perturbed = [np.roll(c, -start, axis=0) for c in perturbed]
    if kind == "a4":
        paper = _inner_colour(blurred, corners)
        if (paper.max() - paper.min()) / max(float(paper.max()), 1e-6) > PAPER_MAX_SATURATION:
            return None
    if _continues(blurred, corners, [ln.contrast for ln in lines], valid):
        return None
    solved = _pose(corners, kind, K)
    if solved is None:
        return None
    pose, reproj = solved
    length, width = SIZES_MM[kind]
    distance = float(np.linalg.norm(pose[:3, :3] @ [length / 2, width / 2, 0] + pose[:3, 3]))
    if not DISTANCE_RANGE_MM[0] <= distance <= DISTANCE_RANGE_MM[1]:
        return None
    fit_sd = math.sqrt(sum((_distance(c, kind, K) - distance) ** 2 for c in perturbed)) / distance
    if not fit_sd <= MAX_SCALE_REL_SD:
        return None
    # a corner's SD: the two lines' offsets there (line offset SD at the centroid plus the angle's lever)
    corner_var = [
        ln.offset_sd**2 + (ln.angle_sd * float(np.linalg.norm(corners[j] - ln.point))) ** 2
        for i, ln in enumerate(lines)
        for j in (i, (i + 3) % 4)
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
    # among candidates of one kind: the best-supported, most precise, then the larger (a sheet, not part of it)
    score = float(supports.mean()) - 10.0 * fit_sd + 1e-6 * abs(_signed_area(corners))
    return score, obj
