"""Steps 2-3: candidate quadrilaterals from region outlines, the metric test that names them, the input checks."""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np

from footmesh.cues.reference import focal
from footmesh.cues.reference.params import (
    _COMBINATIONS,
    _KERNEL3,
    _KERNEL5,
    _MIN_REGION_AREA_PX,
    _THRESHOLD_LEVELS,
    ANGLE_TOLERANCE_DEG,
    ASPECT_TOLERANCE,
    BORDER_MARGIN_PX,
    CUT_EDGE_PX,
    END_SKIP,
    FOCAL_KINDS,
    LOOSE_FACTOR,
    MAX_HIDDEN_AREA_RATIO,
    MAX_HULL_SIDES,
    MAX_WHITE_GAIN,
    MIN_CONTRAST,
    MIN_PIECES_FILL,
    MIN_REGION_FILL,
    MIN_SIDE_PX,
    RECTANGLES,
    SEARCH_SIDE_PX,
    SHEET_MIN_AREA,
    SHEETS,
    SIZES_MM,
    WHITE_MIN_GAIN,
    WHITE_SHARE,
    assumed_sheet,
)
from footmesh.geometry.camera import pixel_rays, rescale_pixels


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


def white_balanced(image: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) float32 0..1 image with each channel scaled so that the mean colour of its brightest pixels
    (``WHITE_SHARE``, within ``valid`` (H, W) bool where given) is grey: the light's colour taken out (white
    patch); a channel gains at most ``MAX_WHITE_GAIN``, and none loses brightness. A channel clipped on the paper
    understates the light's colour there: the balance then falls short, never beyond. ``image`` itself where no
    channel would gain ``WHITE_MIN_GAIN``."""
    # every 4th pixel each way: the brightest 1 % of a 640 px photo is still ~200 of them, and 16x less work
    sample, kept = image[::4, ::4], None if valid is None else valid[::4, ::4]
    pixels = sample[kept] if kept is not None and kept.any() else sample.reshape(-1, 3)
    brightness = pixels.sum(axis=1)
    white = pixels[brightness >= np.quantile(brightness, 1.0 - WHITE_SHARE)].mean(axis=0)
    if white.min() <= 0:
        return image
    gain = np.minimum(white.max() / white, MAX_WHITE_GAIN).astype(np.float32)
    if gain.max() < WHITE_MIN_GAIN:
        return image
    return np.minimum(image * gain, 1.0)


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


def _candidate_groups(
    blurred: np.ndarray,
    K: np.ndarray,
    kinds: list[str],
    regions: str,
    seen: set[tuple[int, ...]],
    free_focal: bool = False,
) -> list[list[np.ndarray]]:
    """Rough (4, 2) px quadrilaterals (canonical order) that might be one of ``kinds``, from the outlines of
    ``regions``: "sheet" (bright in every channel) or "card" (thresholds of the grey level and of each channel,
    either way, of the chroma, and edges); in groups to try in turn: the quads the outlines make, then (sheets)
    those made by completing a hidden corner, then those of a sheet cut by the photo's edge (``_cut_many``), then
    those with one corner beyond it (``_beyond_many``). Near duplicates of each other and of the keys in ``seen``
    (updated) are left out. ``free_focal``: K's focal length is a guess; each quad is also tested, for the kinds
    whose perspective may correct it (``FOCAL_KINDS``), at the focal length that suits it best (``focal``)."""
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
    # the channels' mean and minimum as sums of the three planes: numpy's reductions over a 3-long last axis take
    # 10-25 ms on a 640 x 480 image, these 1-2 ms (the same float32 values, bit for bit)
    channels = small[..., 0], small[..., 1], small[..., 2]
    # a sheet's region is opened wide as well (white grout and other thin lines joined to it fall away), a card's
    # closed (over its stripe)
    wide = np.ones((2 * (min(h, w) // 200) + 5,) * 2, np.uint8)  # (sheets only: outlined at full resolution)
    features: list[tuple[np.ndarray, str]] = []
    if regions == "sheet":
        paper = np.minimum(np.minimum(*channels[:2]), channels[2])  # every channel high; skin, wood, most floors: not
        features.append((paper, "sheet"))
    else:
        grey = (channels[0] + channels[1] + channels[2]) / 3
        for f in (grey, *channels):
            features.extend([(f, "card"), (-f, "card")])
        # a coloured card's chroma parts it from white grout or a white line touching it, which every channel's
        # threshold joins to it
        chroma = np.maximum(np.maximum(*channels[:2]), channels[2]) - np.minimum(np.minimum(*channels[:2]), channels[2])
        features.append((chroma, "card"))
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
        groups = [(c, cv2.contourArea(c), MIN_REGION_FILL) for c in big]
        if sheet and len(big) > 1:
            # a leg across a sheet under the foot cuts its white region in two or three: try them together
            big.sort(key=cv2.contourArea, reverse=True)
            for m in (2, 3)[: len(big) - 1]:
                for combo in itertools.combinations(big[:3], m):
                    area = sum(cv2.contourArea(c) for c in combo)
                    groups.append((np.concatenate(combo), area, MIN_PIECES_FILL))
        for points, area, least_fill in groups:
            hull = cv2.convexHull(points)
            hull_area = cv2.contourArea(hull)
            if hull_area < _MIN_REGION_AREA_PX or area < least_fill * hull_area:
                continue
            for poly in _simplify(hull):
                polygons.append((poly, cv2.contourArea(poly.astype(np.float32)), points, sheet))
    if not polygons:
        return []

    rough, source = _polygon_quads(polygons)
    big = np.array([polygons[i][3] and polygons[i][1] >= SHEET_MIN_AREA * h * w for i in source])
    # a sheet's region cut by the photo's edge: its quads have a side along that edge (tried last of all)
    assumed = assumed_sheet(kinds)  # completed and cut sheets do not show their proportions
    sizes = [SIZES_MM[assumed]] if regions == "sheet" and assumed is not None else []
    cut = [quad for size in sizes for quad in _cut_many(rough[big], K, h, w, size)]
    beyond = _canonical_many(_beyond_many(rough[big], h, w)) if regions == "sheet" else np.zeros((0, 4, 2))
    keep = _inside_many(rough, h, w)
    rough, source, big = _canonical_many(rough[keep]), source[keep], big[keep]
    keep = np.isfinite(rough).all(axis=(1, 2))
    rough, source, big = rough[keep], source[keep], big[keep]
    # rough quads are let in by the shape of the one sheet a sheet is taken to be, not of every sheet (the final
    # test names the sheet: A4's loose window holds letter's ratio): letter's window let in tile cells taken for
    # cards (3 of the 80 photos of ../shared/real/rafiansyah that gave none before), and the hulls of A4 sheets
    # with a corner hidden, which were then tried whole rather than completed (2 of 30 random renders: one lost,
    # one 3 % off)
    shapes = [k for k in RECTANGLES if k not in SHEETS or k == assumed]
    focal_kinds = [k for k in shapes if k in FOCAL_KINDS]

    def shaped(candidates: np.ndarray) -> np.ndarray:
        """(M,) bool: which of (M, 4, 2) quads have one of ``shapes``, loosely (at a focal length of their own too)."""
        ok = _classify_many(candidates, K, shapes, 2 * LOOSE_FACTOR)
        if free_focal:
            ok |= _classify_many(candidates, K, focal_kinds, 2 * LOOSE_FACTOR, free_focal=True)
        return ok

    passed = shaped(rough)
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
            held = _classify(quad, K, [k for k in kinds if k in shapes], loose=LOOSE_FACTOR) is None
            if held and (not free_focal or _classify(quad, _free_focal_K(quad, K), focal_kinds, LOOSE_FACTOR) is None):
                continue
            quads.extend(_unseen([quad], seen))
    groups = [quads]
    if regions == "sheet":
        # a sheet's region with a corner hidden (the foot, the leg) is no rectangle's image: complete it from three
        # of its sides, and try it after the others
        quads = []
        groups.append(quads)
        todo = ~passed & big
        if todo.any():
            area = np.array([polygons[i][1] for i in source[todo]])
            completed = np.concatenate([_complete_many(rough[todo], area, K, h, w, size) for size in sizes])
            if len(completed):
                _, first = np.unique(
                    np.round(completed / 4.0).astype(np.int64).reshape(len(completed), -1), axis=0, return_index=True
                )
                quads.extend(_unseen(completed[np.sort(first)], seen))
        groups.append(cut)
        # a sheet with one corner beyond the photo's edge, its four sides' lines still showing its shape (tried
        # before the cut ones: ``search._try_groups``)
        beyond = beyond[np.isfinite(beyond).all(axis=(1, 2))]
        groups.append(_unseen(beyond[shaped(beyond)], seen))
    return groups


def _unseen(quads, seen: set[tuple[int, ...]]) -> list[np.ndarray]:
    """The (4, 2) px quads not yet in ``seen`` (keys to 2 px, updated), in order: one refinement per object."""
    out = []
    for quad in quads:
        key = tuple(np.round(quad / 2.0).astype(int).ravel().tolist())
        if key not in seen:
            seen.add(key)
            out.append(quad)
    return out


def _beyond_many(quads: np.ndarray, h: int, w: int) -> np.ndarray:
    """The (N, 4, 2) px of (M, 4, 2) rough quads with exactly one corner beyond the photo's edge (not
    ``BORDER_MARGIN_PX`` inside it), no farther out than the photo is large: a sheet's region that the edge cuts
    across a corner has a fifth side along the edge, which its quads skip."""
    inside = _inside_many(quads.reshape(-1, 1, 2), h, w).reshape(-1, 4)  # (M, 4) each corner
    return quads[(inside.sum(axis=1) == 3) & _inside_many(quads, h, w, margin=-max(h, w))]


def _complete_many(
    quads: np.ndarray, region_area: np.ndarray, K: np.ndarray, h: int, w: int, size_mm: tuple[float, float]
) -> np.ndarray:
    """Sheets (N, 4, 2) px that (M, 4, 2) quads could be with one side wrong (cut across a hidden corner): for
    each side m, the other three kept and the rectangle of the sheet's proportions (``size_mm``) they bound, for
    either side being the long one (``_completions``). Only those inside the image, holding the quad and at most
    MAX_HIDDEN_AREA_RATIO times the region."""
    qx, qy = quads[..., 0], quads[..., 1]
    quad_area = 0.5 * np.abs(np.sum(qx * np.roll(qy, -1, axis=1) - np.roll(qx, -1, axis=1) * qy, axis=1))
    out = []
    for m in range(4):
        for corners, ok in _completions(quads, K, m, size_mm):
            with np.errstate(invalid="ignore", over="ignore"):
                x, y = corners[..., 0], corners[..., 1]
                area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
                ok &= (area >= 0.98 * quad_area) & (area <= MAX_HIDDEN_AREA_RATIO * region_area)
            ok &= _inside_many(corners, h, w)
            out.append(corners[ok])
    completed = _canonical_many(np.concatenate(out))
    return completed[np.isfinite(completed).all(axis=(1, 2))]


def _completions(
    quads: np.ndarray, K: np.ndarray, m: int, size_mm: tuple[float, float]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """For (M, 4, 2) quads whose side m (corner m to m + 1) is wrong or unseen, the rectangles of the sheet's
    proportions ``size_mm`` that their other three sides bound: [(corners (M, 4, 2) px in the quads' own
    numbering, whether each is a rectangle in front of the camera (M,) bool)], side m + 2 first the long side, then
    the short one.

    Sides m + 1 and m + 3 are parallel on the floor: their images meet at the vanishing point v, and their 3D
    direction is D1 = K^-1 v. Side m + 2 lies in the plane through the camera with normal K^T l (l its image line)
    and is perpendicular to D1: D2 = K^T l x D1. The floor's normal is D1 x D2; corners m + 2 and m + 3 are cut
    from their rays by that plane, and corners m + 1, m = those plus the other side's length along D1 (towards the
    quad's own corners m + 1 and m).
    """
    k_inv = np.linalg.inv(K)
    hom = np.concatenate([quads, np.ones(quads.shape[:2] + (1,))], axis=2)  # (M, 4, 3)
    lines = np.cross(hom, np.roll(hom, -1, axis=1))  # side i: corner i -> i + 1
    length, width = size_mm
    out = []
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
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
            out.append((np.roll(px[..., :2] / px[..., 2:], m, axis=1), ok))
    return out


def _cut_many(quads: np.ndarray, K: np.ndarray, h: int, w: int, size_mm: tuple[float, float]) -> list[np.ndarray]:
    """Rough quads (4, 2) px of sheets cut by the photo's edge, numbered so that side 0 (corner 0 -> 1) runs along
    the edge (``cut``), from (M, 4, 2) rough quads of bright regions: those with one side along an edge of the
    photo (both its corners within ``CUT_EDGE_PX`` of it), the other two corners inside, and a sheet of proportions
    ``size_mm`` that the other three sides bound (``_completions``, either side the long one) with its far corners
    beyond that edge."""
    out: list[np.ndarray] = []
    with np.errstate(invalid="ignore"):
        x, y = quads[..., 0], quads[..., 1]
        inside = (x >= BORDER_MARGIN_PX) & (y >= BORDER_MARGIN_PX)
        inside &= (x <= w - 1 - BORDER_MARGIN_PX) & (y <= h - 1 - BORDER_MARGIN_PX)  # (M, 4)
    # the photo's edges as lines (a, b, c), a x + b y + c >= 0 inside
    for edge in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (-1.0, 0.0, w - 1.0), (0.0, -1.0, h - 1.0)):
        inward = np.array(edge[:2])
        with np.errstate(invalid="ignore"):
            on_edge = np.abs(quads @ inward + edge[2]) <= CUT_EDGE_PX  # (M, 4)
        for m in range(4):
            along = on_edge[:, m] & on_edge[:, (m + 1) % 4] & inside[:, (m + 2) % 4] & inside[:, (m + 3) % 4]
            if not along.any():
                continue
            rolled = np.roll(quads[along], -m, axis=1)
            beyond = np.zeros(len(rolled), dtype=bool)
            for corners, ok in _completions(rolled, K, 0, size_mm):
                with np.errstate(invalid="ignore"):
                    beyond |= ok & (corners[:, :2] @ inward + edge[2] < -CUT_EDGE_PX).all(axis=1)
            for quad in rolled[beyond]:
                if not any(np.max(np.linalg.norm(quad - kept, axis=1)) < 2.0 for kept in out):
                    out.append(quad)
    return out


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


def _corner_points_many(quads: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The plane parallelograms whose images are the (M, 4, 2) quads: corner points (M, 4, 3) up to a common scale
    per quad (the first at depth 1), and whether the solution exists with every corner in front of the camera (M,).

    With rays r_i = K^-1 (u_i, v_i, 1), depths l_i with l0 r0 + l2 r2 = l1 r1 + l3 r3 (the diagonals bisect each
    other) are unique up to scale, and do not depend on the focal length (``focal``).
    """
    rays = pixel_rays(quads, K)  # (M, 4, 3), z = 1
    a = np.stack([rays[:, 1], -rays[:, 2], rays[:, 3]], axis=2)  # (M, 3, 3): columns r1, -r2, r3
    good = np.abs(np.linalg.det(a)) > 1e-12
    a[~good] = np.eye(3)
    lam = np.linalg.solve(a, rays[:, 0][..., None])[..., 0]  # (M, 3)
    depths = np.concatenate([np.ones((len(quads), 1)), lam], axis=1)
    good &= (lam > 0).all(axis=1)
    return rays * depths[..., None], good


def _parallelogram_many(
    quads: np.ndarray, K: np.ndarray, free_focal: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Metric shape of the plane parallelograms whose images are the (M, 4, 2) quads: side ratio
    |P1 - P0| / |P3 - P0| (M,), angle at P0 in degrees (M,), depths (M, 4) up to a common scale, and whether the
    solution exists with every corner in front of the camera (M,): a rectangle's image gives a right angle and its
    true side ratio. ``free_focal``: each quad seen with the focal length (within ``focal.FOCAL_RANGE`` of K's)
    that makes its corner most nearly a right angle (K's focal length is a guess).
    """
    pts, good = _corner_points_many(quads, K)
    depths = pts[..., 2].copy()
    if free_focal:
        pts[..., :2] /= focal.clamped_scale(pts)[:, None, None]
    side_a, side_b = pts[:, 1] - pts[:, 0], pts[:, 3] - pts[:, 0]
    na, nb = np.linalg.norm(side_a, axis=1), np.linalg.norm(side_b, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.clip(np.sum(side_a * side_b, axis=1) / (na * nb), -1.0, 1.0)
        return na / nb, np.degrees(np.arccos(cos)), depths, good & np.isfinite(cos)


def _free_focal_K(quad: np.ndarray, K: np.ndarray) -> np.ndarray:
    """K with the focal length (within ``focal.FOCAL_RANGE`` of its own) that makes the (4, 2) quad's corner most
    nearly a right angle."""
    pts, _ = _corner_points_many(quad[None], K)
    return focal.with_focal_scale(K, float(focal.clamped_scale(pts)[0]))


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


def _classify_many(
    quads: np.ndarray, K: np.ndarray, kinds: list[str], loose: float, free_focal: bool = False
) -> np.ndarray:
    """(M,) bool: the metric test (with tolerances ``loose`` times wider) names each (M, 4, 2) quad one of
    ``kinds`` (``free_focal``: see ``_parallelogram_many``)."""
    if len(quads) == 0:
        return np.zeros(0, dtype=bool)
    ratio, angle, _, good = _parallelogram_many(quads, K, free_focal)
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
