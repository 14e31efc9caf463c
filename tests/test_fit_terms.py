"""The fit's cost-term registry (footmesh.fit.terms): a term added by one class and one entry is fitted with the
others; a name no term has is an error, never a silent least squares."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh.eval.fit_check import synthetic_cues
from footmesh.fit import FitConfig, fit_foot, terms
from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig


class MidfootDepth(terms.Term):
    """A test term: the midfoot joint's camera depth pulled towards a given value (mm, sigma 1 mm)."""

    name = "midfoot_depth"

    def __init__(self, depth_mm: float) -> None:
        self.depth_mm = depth_mm

    def associate(self, problem, frame):
        return {"scale": 1.0}

    def residual(self, problem, out, blocks):
        return (out["joints"][:, 0, 2] - self.depth_mm)[:, None]


def test_every_term_has_a_kernel_and_unknown_names_are_refused():
    assert [t.name for t in terms.TERMS][:3] == ["joints", "inside", "contour"]
    for term in terms.TERMS:
        kind, scale = term.kernel(FitConfig())
        assert kind in ("l2", "huber", "gm", "gm_above") and scale >= 0
    with pytest.raises(KeyError):
        terms.kernel("contuor", FitConfig())


def test_a_term_added_in_one_place_is_fitted(monkeypatch):
    sample = Renderer(SynthConfig(size=240, reference="none")).render(3, 0)
    cues = synthetic_cues(sample, joint_noise_px=2.0, rng=0)
    side = "right" if int(sample["side"]) else "left"
    plain = fit_foot(cues, sample["K"], side=side)  # no scale evidence: the midfoot's depth is a guess
    target = float(plain.joints_cam[0, 2]) * 1.2
    extra = MidfootDepth(target)
    monkeypatch.setattr(terms, "TERMS", (*terms.TERMS, extra))
    monkeypatch.setitem(terms.BY_NAME, extra.name, extra)
    pulled = fit_foot(cues, sample["K"], side=side)
    assert "midfoot_depth" in pulled.loss_terms and "midfoot_depth" not in plain.loss_terms
    assert abs(pulled.joints_cam[0, 2] - target) < abs(plain.joints_cam[0, 2] - target) - 1.0  # moved towards it
    assert np.isfinite(pulled.loss)
