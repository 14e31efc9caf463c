"""The fit stage: the kinematic foot model fitted to one photo's cues, its depth map and its floor plane.

- ``core``: the evidence, the data association, Levenberg-Marquardt with the joint limits, the starts, and
  ``fit_foot`` (its docstring: the terms, the scale, the solver and the uncertainty);
- ``terms``: the cost terms, one class each (residual, robust kernel, quality figures), registered in ``TERMS``.

The fit's own check on synthetic scenes is ``footmesh.eval.fit_check``.
"""

from footmesh.fit.core import (
    MIN_SILHOUETTE_PX,
    SIDES,
    FitConfig,
    FitInit,
    FitQuality,
    FootFit,
    LegCylinder,
    canonical_measures,
    farthest_point_subset,
    fit_foot,
    foot_image,
    foot_shown,
    forward_kinematics_by_level,
    leg_occludes,
    mesh_side_residuals,
    parameter_names,
    projected_mask,
    shape_for_scale,
    silhouette_contour,
    skin_batched,
)

__all__ = [
    "MIN_SILHOUETTE_PX",
    "SIDES",
    "FitConfig",
    "FitInit",
    "FitQuality",
    "FootFit",
    "LegCylinder",
    "canonical_measures",
    "farthest_point_subset",
    "fit_foot",
    "foot_image",
    "foot_shown",
    "forward_kinematics_by_level",
    "leg_occludes",
    "mesh_side_residuals",
    "parameter_names",
    "projected_mask",
    "shape_for_scale",
    "silhouette_contour",
    "skin_batched",
]
