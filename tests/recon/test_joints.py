"""Joints from vertex groups: the model's own joints at rest, close to them when posed, and the aligned error."""

from __future__ import annotations

import pytest
import torch

from footmesh.model.ik import sample_poses
from footmesh.model.layer import default_model
from footmesh.model.lbs import rot_y, rot_z
from footmesh.recon.joints import joints_from_vertices, midfoot_aligned_error


@pytest.fixture(scope="module")
def shapes() -> torch.Tensor:
    return torch.randn(6, default_model().num_components, generator=torch.Generator().manual_seed(0))


def test_rest_pose_gives_the_models_joints_exactly(shapes):
    out = default_model()(shapes)
    assert torch.equal(joints_from_vertices(out.vertices), out.joints)


def test_placed_scaled_and_mirrored_feet(shapes):
    """Rows sum to 1, so scale, mirror, rotation and translation carry over (to float rounding)."""
    rotation = (rot_z(torch.tensor(0.4)) @ rot_y(torch.tensor(-2.2))).expand(6, 3, 3)
    translation = torch.tensor([[30.0, -80.0, 520.0]]).expand(6, 3)
    sides = ["left", "right"] * 3
    out = default_model()(shapes, scale=torch.linspace(0.85, 1.15, 6), side=sides, rotation=rotation,
                          translation=translation)  # fmt: skip
    assert torch.allclose(joints_from_vertices(out.vertices), out.joints, atol=1e-3)


def test_posed_feet_are_close(shapes):
    """Skinning does not carry the inner joints rigidly: vertex groups approximate the kinematic joints."""
    model = default_model()
    angles = sample_poses(model(shapes).rest_joints[0], 1, len(shapes), method="natural")
    out = model(shapes, angles)
    error = (joints_from_vertices(out.vertices) - out.joints).norm(dim=-1)
    assert float(error.mean()) < 3.0 and float(error.max()) < 15.0


def test_rendered_sample():
    """A synthetic sample's camera-frame mesh gives joints near its stored camera-frame joints."""
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    sample = Renderer(SynthConfig(size=48)).render(5, 1)
    joints = joints_from_vertices(torch.from_numpy(sample["vertices"])[None])[0]
    error = (joints - torch.from_numpy(sample["joints3d"])).norm(dim=-1)
    assert float(error.mean()) < 5.0
    aligned = midfoot_aligned_error(joints[None], torch.from_numpy(sample["joints3d"])[None])
    assert aligned.shape == (1, 18) and float(aligned[0, 0]) == 0.0


def test_midfoot_aligned_error():
    gen = torch.Generator().manual_seed(1)
    truth = torch.randn(4, 18, 3, generator=gen) * 50
    shifted = midfoot_aligned_error(truth + torch.tensor([5.0, -7.0, 100.0]), truth)
    assert torch.allclose(shifted, torch.zeros(4, 18), atol=1e-4)
    pred = truth + torch.randn(4, 18, 3, generator=gen)
    error = midfoot_aligned_error(pred, truth)
    for b in range(4):
        for j in range(18):
            moved = pred[b, j] - pred[b, 0] + truth[b, 0]
            assert float(error[b, j]) == pytest.approx(float((moved - truth[b, j]).norm()), abs=1e-5)
    assert (error[:, 0] == 0).all() and (error[:, 1:] > 0).all()


def test_bad_input():
    with pytest.raises(ValueError, match="topology"):
        joints_from_vertices(torch.zeros(1, 100, 3))
    with pytest.raises(ValueError, match=r"\(B, V, 3\)"):
        joints_from_vertices(torch.zeros(4002, 3))
    with pytest.raises(ValueError, match="joints must both be"):
        midfoot_aligned_error(torch.zeros(2, 17, 3), torch.zeros(2, 17, 3))
