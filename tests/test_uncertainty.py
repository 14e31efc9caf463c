"""The measurements' uncertainty (``footmesh.uncertainty``) on a real fit of a rendered foot."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from footmesh.config import MeasureConfig
from footmesh.eval.fit_check import synthetic_cues
from footmesh.fit import fit_foot
from footmesh.measure import FootLandmarks, measure_foot
from footmesh.model.layer import default_model
from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig
from footmesh.uncertainty import measurement_uncertainty


@pytest.fixture(scope="module")
def fitted():
    """A depth fit of one rendered standing foot and its measurements."""
    sample = Renderer(SynthConfig(size=320, reference="none", lifted_fraction=0.0)).render(5, 0)
    fit = fit_foot(
        synthetic_cues(sample, joint_noise_px=2.0, rng=0),
        sample["K"],
        depth_mm=sample["depth"].astype(np.float32),
        side="right" if int(sample["side"]) else "left",
    )
    model = default_model()
    with torch.no_grad():
        rest = model(torch.as_tensor(fit.shape, dtype=torch.float32)[None], side=fit.side)
    faces = model.faces(fit.side).numpy()
    joints = FootLandmarks.from_joints(rest.joints[0].double().numpy())
    return fit, measure_foot(fit.canonical_vertices(model), faces, joints, side=fit.side), model


def test_a_fit_that_explains_its_photo_worse_owns_a_wider_uncertainty(fitted):
    """The covariance part grows as the square root of the fit's cost, as a least-squares fit's does with its
    residuals' variance factor: four times the cost, twice the SD (the floor added in quadrature aside)."""
    fit, measured, model = fitted
    config = MeasureConfig()
    once = measurement_uncertainty(fit, measured, "depth", None, model, config)
    worse = measurement_uncertainty(
        dataclasses.replace(fit, loss=4.0 * fit.loss), measured, "depth", None, model, config
    )
    floor = config.uncertainty_floor_mm
    for name in ("stick_length", "ball_width"):
        assert once[name] > floor
        # the reported figures are rounded to 0.01 mm
        assert np.sqrt(worse[name] ** 2 - floor**2) == pytest.approx(
            2.0 * np.sqrt(once[name] ** 2 - floor**2), abs=0.03
        )
