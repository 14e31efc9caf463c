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


def test_the_outline_where_the_leg_hides_the_foot_is_not_matched():
    """Contour samples whose pixel just outside the silhouette shows the model's leg are occlusion, not the foot's
    edge: the contour term leaves them out (``FitConfig.contour_leg_probe_px``)."""
    from types import SimpleNamespace

    import torch

    # a foot's outline along x = 10 (outward +x) and along x = 60 (outward +x); the leg covers x > 62
    contour = np.array([[10.0, y] for y in range(5)] + [[60.0, y] for y in range(5)])
    normal = np.tile([1.0, 0.0], (len(contour), 1))
    vertices = np.stack([np.r_[np.full(5, 9.0), np.full(5, 59.0)], np.tile(np.arange(5.0), 2)], axis=1)
    frame = terms.Frame(
        vertices=np.zeros((10, 3)),
        normals=np.zeros((10, 3)),
        projected=vertices,
        subset=np.arange(10),
        hidden=np.zeros(10, bool),
        facing=np.arange(10),
        rim=np.zeros(0, int),
        sample=lambda image, uv: np.zeros(len(uv)),
        shows_leg=lambda uv: uv[:, 0] > 62.0,
    )

    def matched(probe_px, max_fraction=0.5):
        problem = SimpleNamespace(
            ev=SimpleNamespace(contour=contour, contour_normal=normal),
            config=FitConfig(contour_leg_probe_px=probe_px, contour_leg_max_fraction=max_fraction),
            arrays=SimpleNamespace(mean=torch.zeros(10, 3)),
        )
        return terms.BY_NAME["contour"].associate(problem, frame)

    def points(probe_px, max_fraction=0.5):
        return matched(probe_px, max_fraction)["points"].numpy()

    np.testing.assert_array_equal(np.unique(points(3.0)[:, 0]), [10.0])  # the leg's side left out
    assert len(points(None)) == len(contour)  # off: every sample matched
    # the samples left out hand their weight to the rest: hiding more of the outline does not make a pose cheaper
    assert matched(3.0)["scale"] == pytest.approx(2.0 * matched(None)["scale"])
    # a leg that would hide more of the outline than the limit (here half of it) hides none: a pose cannot shed
    # the silhouette by pointing the leg at the camera
    assert len(points(3.0, max_fraction=0.4)) == len(contour)
