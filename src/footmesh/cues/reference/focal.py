"""The focal length a rectangle's image gives: its corner must be a right angle (self-calibration, issue 19).

A photo without intrinsics gets an assumed focal length (a phone's 26 mm-equivalent main camera), but real photos
of a foot are often taken with the 2x or 3x lens, zoomed or cropped: 2-3x that focal length. A sheet seen
obliquely then recovers as no rectangle (at 45 deg elevation and 2x the assumed focal length: side ratio 1.18,
corner 99 deg, refused), and a top-down photo, where the sheet passes, puts the camera 2-3x too near, so the
foot's height above the floor looks magnified and the fitted foot comes out small.

The parallelogram's depths (``quads._corner_points_many``) do not depend on the focal length f (square pixels, the
principal point known): scaling f by ``s`` divides the corner points' x, y by ``s`` and keeps their z. So the
corner angle is a function of ``s`` alone, and ``s`` where it is a right angle is closed-form. Where the sheet is
seen nearly straight on, the angle hardly depends on ``s``: the caller's focal length is kept there (its prior,
``prior_log_sd``, weighs more than the measurement).

There a second prior helps (``distance_prior_scale``): how far from the floor a phone is held. For one image, the
object's distance grows with the focal length, so a prior on the distance is a prior on the focal length: a sheet
that fills a photo taken with the assumed main camera lies about 0.3 m away, nearer than most people hold a phone
over their foot; the 2x lens puts it at 0.6 m.
"""

from __future__ import annotations

import math

import numpy as np

FOCAL_RANGE = (0.7, 5.0)
"""The focal lengths considered, in multiples of the caller's: a main camera a little wider than the one assumed
to a 5x telephoto (or a crop of the 2x / 3x). Not the 0.5x ultra-wide: rarely used for a foot, and with the
range down to 0.4x two patterned rectangles of ``../shared/real/rafiansyah`` passed as A4 sheets at 0.45-0.57x."""
ANGLE_TRUST_DEG = 1.0
"""A real sheet's corner angle, as the photo shows it, is trusted to this much beyond its corners' own noise
(paper bows and curls, lenses keep some distortion): it bounds how well the angle fixes the focal length."""
_STEP = 0.05
"""Half the step in log focal length of the angle's numerical derivative."""


def right_angle_scale(points: np.ndarray) -> np.ndarray:
    """(M,) factor ``s`` on the focal length that makes the corner at point 0 a right angle, from the (M, 4, 3)
    corner points of ``quads._corner_points_many`` at the caller's focal length; NaN where no focal length does
    (then the quad is no rectangle's image at any)."""
    a, b = points[:, 1] - points[:, 0], points[:, 3] - points[:, 0]
    in_image = np.sum(a[:, :2] * b[:, :2], axis=1)
    along_sight = a[:, 2] * b[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        squared = -in_image / along_sight
    return np.where(squared > 0, np.sqrt(np.abs(squared)), np.nan)


def clamped_scale(points: np.ndarray) -> np.ndarray:
    """(M,) ``right_angle_scale`` within ``FOCAL_RANGE`` (1 where none exists): the focal factor the quick
    metric tests use when the focal length is not known."""
    scale = right_angle_scale(points)
    return np.where(np.isfinite(scale), np.clip(scale, *FOCAL_RANGE), 1.0)


def corner_angle_deg(points: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(M,) corner angle at point 0 (degrees) of the (M, 4, 3) corner points seen with the focal length times
    ``scale`` (M,)."""
    seen = points.copy()
    seen[..., :2] /= scale[:, None, None]
    a, b = seen[:, 1] - seen[:, 0], seen[:, 3] - seen[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def focal_estimate(points: np.ndarray, perturbed: np.ndarray, prior_log_sd: float) -> tuple[float, float]:
    """The focal factor ``s`` (x the caller's focal length) and the SD of ``log s``: the right angle's focal
    length (corner points (4, 3), and (P, 4, 3) at the corners perturbed by one SD of each side's line) combined
    with the caller's (``s = 1``, SD ``prior_log_sd`` in log units), within ``FOCAL_RANGE``.

    The measurement's SD sums the corners' noise and ``ANGLE_TRUST_DEG`` over the angle's sensitivity to the
    focal length; where no focal length gives a right angle, the caller's is kept.
    """
    if prior_log_sd <= 0:
        return 1.0, 0.0
    scale = right_angle_scale(points[None])[0]
    if not (math.isfinite(scale) and FOCAL_RANGE[0] <= scale <= FOCAL_RANGE[1]):
        return 1.0, prior_log_sd
    trials = right_angle_scale(perturbed)
    if not np.all(np.isfinite(trials)):
        return 1.0, prior_log_sd
    noise_var = float(np.sum(np.log(trials / scale) ** 2))
    steps = scale * np.exp([_STEP, -_STEP])
    slope = abs(float(np.diff(corner_angle_deg(np.repeat(points[None], 2, axis=0), steps))[0])) / (2 * _STEP)
    measured_var = noise_var + (ANGLE_TRUST_DEG / max(slope, 1e-9)) ** 2
    weight_measured, weight_prior = 1.0 / measured_var, 1.0 / prior_log_sd**2
    log_scale = weight_measured * math.log(scale) / (weight_measured + weight_prior)
    log_scale = min(max(log_scale, math.log(FOCAL_RANGE[0])), math.log(FOCAL_RANGE[1]))
    return math.exp(log_scale), 1.0 / math.sqrt(weight_measured + weight_prior)


def distance_prior_scale(
    log_sd: float, distance_mm: float, prior_median_mm: float, prior_log_sd: float
) -> tuple[float, float]:
    """The factor on an estimated focal length (known to ``log_sd`` in log units; the object then lies
    ``distance_mm`` from the camera) and the SD of the product's log, once a log-normal prior on the camera's
    distance (median ``prior_median_mm``, SD of its log ``prior_log_sd``) is weighed in: the object's distance is
    proportional to the focal length for one image, so the prior is a Gaussian in log focal length too."""
    if log_sd <= 0 or prior_log_sd <= 0:
        return 1.0, log_sd
    weight_estimate, weight_distance = 1.0 / log_sd**2, 1.0 / prior_log_sd**2
    log_factor = weight_distance * math.log(prior_median_mm / distance_mm) / (weight_estimate + weight_distance)
    return math.exp(log_factor), 1.0 / math.sqrt(weight_estimate + weight_distance)


def with_focal_scale(K: np.ndarray, scale: float) -> np.ndarray:
    """K (3, 3) with its focal lengths (and skew) times ``scale``; the principal point kept."""
    scaled = np.array(K, dtype=np.float64)
    scaled[:2, :2] *= scale
    return scaled
