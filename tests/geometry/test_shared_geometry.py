"""The shared geometry (footmesh.geometry): cameras, normals, rotations and alignment against known answers."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from footmesh.geometry.alignment import umeyama, weighted_procrustes
from footmesh.geometry.camera import (
    Camera,
    pixel_rays,
    rescale_pixels,
    resize_intrinsics,
    turned_frame,
    unproject,
)
from footmesh.geometry.mesh import batch_vertex_normals, face_normals, vertex_normals
from footmesh.geometry.plane import cam_from_plane, robust_plane
from footmesh.geometry.rotations import rotation_between, skew

K = np.array([[520.0, 0.8, 319.5], [0.0, 515.0, 241.0], [0.0, 0.0, 1.0]])
POINTS = np.array([[30.0, -12.0, 480.0], [-60.0, 40.0, 700.0], [0.0, 0.0, 350.0]])


def test_a_crop_and_a_resize_move_the_projections_as_the_pixels_move():
    camera = Camera(K, 640, 480)
    uv, z = camera.project(POINTS)
    crop = camera.cropped(100, -20, 300, 300)  # reaching past the top edge: a padded crop
    np.testing.assert_allclose(crop.project(POINTS)[0], uv - [100, -20], atol=1e-9)
    small = crop.resized(128, 128)
    np.testing.assert_allclose(small.project(POINTS)[0], rescale_pixels(uv - [100, -20], 128 / 300), atol=1e-9)
    assert (small.width, small.height) == (128, 128)
    np.testing.assert_allclose(z, POINTS[:, 2])
    halves = camera.resized(320, 240)  # each axis on its own
    np.testing.assert_allclose(halves.project(POINTS)[0], rescale_pixels(uv, [0.5, 0.5]), atol=1e-9)
    torch.testing.assert_close(resize_intrinsics(torch.from_numpy(K), 0.5), torch.from_numpy(halves.K))


def test_unproject_inverts_project_and_rays_have_unit_depth():
    camera = Camera(K, 640, 480)
    uv, z = camera.project(POINTS)
    np.testing.assert_allclose(camera.unproject(uv, z), POINTS, atol=1e-9)
    np.testing.assert_allclose(pixel_rays(uv, K)[:, 2], 1.0)
    np.testing.assert_allclose(unproject(uv[None], z[None], K)[0], POINTS, atol=1e-9)  # any leading shape


def test_normals_point_out_of_a_sphere_in_numpy_and_torch():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    radial = v / np.linalg.norm(v, axis=1, keepdims=True)
    normals = vertex_normals(v, f)
    assert np.min(np.sum(normals * radial, axis=1)) > 0.999
    batched = batch_vertex_normals(torch.from_numpy(v)[None], torch.from_numpy(f))[0].numpy()
    np.testing.assert_allclose(batched, normals, atol=1e-9)
    areas = np.linalg.norm(face_normals(v, f, unit=False), axis=1) / 2
    assert areas.sum() == pytest.approx(sphere.area, rel=1e-9)


def test_skew_is_the_cross_product_and_a_rotation_turns_one_direction_onto_another():
    rng = np.random.default_rng(3)
    w, u = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(w), u), np.cross(w, u), atol=1e-12)
    torch.testing.assert_close(skew(torch.from_numpy(w)), torch.from_numpy(skew(w)))
    for a, b in [(u[0], u[1]), (u[2], -u[2])]:  # any two, and opposite ones
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        r = rotation_between(a, b)
        np.testing.assert_allclose(r @ a, b, atol=1e-12)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)


def test_umeyama_recovers_a_similarity_with_weights_ignoring_outliers_they_zero():
    rng = np.random.default_rng(4)
    source = rng.normal(size=(40, 3)) * 30
    rot = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    target = 1.7 * source @ rot.T + [5.0, -8.0, 300.0]
    target[:5] += 200.0  # outliers
    weights = np.r_[np.zeros(5), np.ones(35)]
    sim = umeyama(source, target, weights)
    assert sim.scale == pytest.approx(1.7) and np.allclose(sim.rotation, rot)
    np.testing.assert_allclose(sim.inverse_apply(sim.apply(source)), source, atol=1e-9)
    r, s, t = weighted_procrustes(torch.from_numpy(source), torch.from_numpy(target)[None], torch.from_numpy(weights))
    np.testing.assert_allclose(r[0].numpy(), rot, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_robust_plane_ignores_what_stands_off_it_and_its_frame_faces_the_camera(seed):
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    centre = np.array([0.0, 0.0, 800.0]) + rng.normal(0, 50, 3)
    basis = np.linalg.svd(normal[None], full_matrices=True)[2][1:]  # two directions in the plane
    floor = centre + rng.uniform(-400, 400, (3000, 2)) @ basis + rng.normal(0, 1.0, (3000, 1)) * normal
    leg = centre + rng.uniform(-60, 60, (800, 2)) @ basis + rng.uniform(20, 400, (800, 1)) * normal
    plane = robust_plane(np.concatenate([floor, leg]))
    assert plane is not None and abs(abs(plane.normal @ normal) - 1) < 1e-4
    assert (
        abs(plane.height(centre[None])[0]) < 0.5
        and plane.inliers[:3000].mean() > 0.97
        and not plane.inliers[3000:].mean() > 0.1
    )
    pose = cam_from_plane(plane)
    np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(pose[:3, :3]) > 0 and np.linalg.inv(pose)[2, 3] > 0  # the camera is above it
    assert robust_plane(floor[:50]) is None


@pytest.mark.parametrize("quarter_turns", [0, 1, 2, 3, 5])
def test_a_turned_camera_projects_where_the_turn_takes_the_pixels(quarter_turns):
    camera = Camera(K, 640, 480)
    image = np.zeros((480, 640), np.uint8)
    uv = np.round(camera.project(POINTS)[0]).astype(int)
    image[uv[:, 1], uv[:, 0]] = [1, 2, 3]
    after = np.rot90(image, quarter_turns)
    turned = camera.turned(quarter_turns)
    assert (turned.width, turned.height) == (after.shape[1], after.shape[0])
    points = POINTS @ turned_frame(quarter_turns).T  # the camera frame turns with the image
    np.testing.assert_allclose(points @ turned_frame(quarter_turns), POINTS, atol=1e-12)  # and back
    if quarter_turns % 4 == 1:
        np.testing.assert_allclose(points, np.stack([POINTS[:, 1], -POINTS[:, 0], POINTS[:, 2]], axis=1))
    projected = turned.project(points)[0]
    for label, (x, y) in zip((1, 2, 3), projected, strict=True):
        ty, tx = np.argwhere(after == label)[0]
        assert abs(x - tx) <= 0.5 + 1e-9 and abs(y - ty) <= 0.5 + 1e-9
