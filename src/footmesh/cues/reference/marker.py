"""Step 1: the printed ArUco marker (and its mirror image)."""

from __future__ import annotations

import cv2
import numpy as np

from footmesh.cues.reference.finish import _finish
from footmesh.cues.reference.objects import ReferenceObject
from footmesh.cues.reference.params import (
    ARUCO_DICTIONARY,
    ARUCO_ID,
    FIRST_RADIUS_PX,
    MARKER_CELLS,
    MARKER_RETRY_RADII_CELLS,
    MARKERS,
)


def _detect_marker(
    image: np.ndarray,
    blurred: np.ndarray,
    K: np.ndarray,
    valid: np.ndarray | None,
    report: bool = True,
    focal_prior_log_sd: float = 0.0,
) -> tuple[ReferenceObject | None, list[np.ndarray]]:
    """The ArUco marker (DICT_4X4_50, id 0), read upright or in the mirror image (None unless ``report``), and
    the (4, 2) px quads of every marker seen (any id). ``focal_prior_log_sd``: see ``search_reference``."""
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
                found = _finish(
                    ordered,
                    MARKERS,
                    blurred,
                    K,
                    valid,
                    mirrored=mirrored,
                    first_radius=radius,
                    focal_prior_log_sd=focal_prior_log_sd,
                )
                if found is not None:
                    return found[1], seen
    return None, seen


def _overlaps(quad: np.ndarray, region: np.ndarray) -> bool:
    """Whether a (4, 2) quad has its centre or a corner inside the convex (4, 2) region."""
    contour = region.astype(np.float32).reshape(-1, 1, 2)
    points = np.concatenate([quad, quad.mean(axis=0, keepdims=True)])
    return any(cv2.pointPolygonTest(contour, (float(x), float(y)), False) >= 0 for x, y in points)
