"""The measurements' uncertainty: the fit's shape covariance pushed through the measurements, calibrated per
scale source, with the reference object's own size tolerance and, where the focal length was estimated, its
share (docs/measure.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import torch

from footmesh.config import MeasureConfig
from footmesh.measure import MEASUREMENT_NAMES, FootLandmarks, Measurements, measure_foot


def measurement_uncertainty(
    fit,
    measured: Measurements,
    scale_source: str,
    reference,
    model,
    config: MeasureConfig,
    focal_effect_mm: Mapping[str, float] | None = None,
) -> dict[str, float]:
    """One-SD uncertainty (mm) of each measurement: the fit's shape covariance propagated through the
    measurements (central differences along its principal axes, ``FootFit.shape_sigma_points``), times the
    calibration factor of the scale source and the square root of the fit's cost against a typical calibration
    fit's (``MeasureConfig``), the reference object's scale uncertainty and,
    where the focal length was estimated, how much each measurement moves with one SD of it (``focal_effect_mm``)."""
    points = fit.shape_sigma_points()  # (2, K, K)
    faces = model.faces(fit.side).numpy()
    with torch.no_grad():
        out = model(torch.as_tensor(points.reshape(-1, points.shape[-1]), dtype=torch.float32), side=fit.side)
    values = np.full((points.shape[0] * points.shape[1], len(MEASUREMENT_NAMES)), np.nan)
    for i, (v, j) in enumerate(zip(out.vertices.double().numpy(), out.joints.double().numpy(), strict=True)):
        try:
            m = measure_foot(v, faces, FootLandmarks.from_joints(j), side=fit.side)
        except ValueError:  # a shape too odd to measure: that side of the axis falls back on the other
            continue
        values[i] = [m.values_mm()[n] for n in MEASUREMENT_NAMES]
    plus, minus = values.reshape(2, points.shape[1], -1)  # (K, M) each
    centre = np.array([measured.values_mm()[n] for n in MEASUREMENT_NAMES], dtype=float)
    one_sided = np.fmax(np.abs(plus - centre), np.abs(minus - centre))
    half = np.where(np.isnan(plus) | np.isnan(minus), one_sided, 0.5 * np.abs(plus - minus))
    sd = np.sqrt(np.nansum(half**2, axis=0))
    factor = config.uncertainty_factor[scale_source]  # every scale source has its calibration
    # the residuals' variance factor against a typical calibration fit's (``MeasureConfig.uncertainty_loss_reference``)
    factor *= math.sqrt(max(fit.loss, 0.0) / config.uncertainty_loss_reference[scale_source])
    floor = config.uncertainty_floor_mm
    rel = float(reference.scale_rel_sd) if reference is not None else 0.0
    out_u = {}
    for name, s in zip(MEASUREMENT_NAMES, sd, strict=True):
        value = measured.values_mm()[name]
        focal = 0.0 if focal_effect_mm is None else float(focal_effect_mm[name])
        u = math.hypot(factor * float(s), rel * float(value), floor, focal)
        out_u[name] = round(u, 2)
    return out_u
