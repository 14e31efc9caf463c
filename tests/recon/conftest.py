"""Shared fixtures: the template's mesh hierarchy (built once per session) and a small closed mesh."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from footmesh.model.layer import default_model
from footmesh.recon.hierarchy import MeshHierarchy, template_hierarchy


@pytest.fixture(scope="session")
def hierarchy() -> MeshHierarchy:
    return template_hierarchy()


@pytest.fixture(scope="session")
def sphere() -> tuple[np.ndarray, np.ndarray]:
    """A 162-vertex icosphere of radius 50 mm: (V, 3) float64 vertices and (F, 3) int64 outward faces."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=50.0)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)


@pytest.fixture(scope="session")
def foot_target() -> torch.Tensor:
    """(1, V, 3) mm: a random foot shape in a random pose, turned and placed ~470 mm in front of a camera."""
    from footmesh.model.ik import sample_poses
    from footmesh.model.lbs import rot_y, rot_z

    model = default_model()
    gen = torch.Generator().manual_seed(3)
    shape = torch.randn(1, model.num_components, generator=gen)
    rest = model(shape).rest_joints[0]
    angles = sample_poses(rest, 3, 1, method="natural")
    rotation = (rot_z(torch.tensor(0.7)) @ rot_y(torch.tensor(2.0))).unsqueeze(0)
    vertices = model(shape, angles, rotation=rotation).vertices.detach()
    # centroid 40 mm off the decoder's prior (0, 0, 500): the camera looks at a point near the foot's centre
    return vertices - vertices.mean(dim=1, keepdim=True) + torch.tensor([20.0, -30.0, 470.0])
