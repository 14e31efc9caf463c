"""Training data (``footmesh.train.data``): resizing, the cache beside a dataset, batches and augmentation."""

from __future__ import annotations

import os
import shutil

import cv2
import numpy as np
import pytest
import torch
from _tiny_cues import SIZE
from hypothesis import given, settings
from hypothesis import strategies as st

from footmesh.train.data import (
    Augment,
    Batch,
    augment_batch,
    inside_image,
    jpeg_roundtrip,
    load_arrays,
    make_batch,
    resize_joints,
    resize_sample,
)

NO_PHOTOMETRIC = {
    "brightness": (1.0, 1.0),
    "contrast": (1.0, 1.0),
    "saturation": (1.0, 1.0),
    "white_balance": 0.0,
    "noise_sd": (0.0, 0.0),
    "blur_p": 0.0,
    "jpeg_p": 0.0,
    "depth_noise_mm": (0.0, 0.0),
    "depth_dropout_p": 0.0,
}
IDENTITY_GEOMETRY = {"scale": (1.0, 1.0), "rotate_deg": 0.0, "shift": 0.0, "flip": 0.0}


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


# --- resizing ---------------------------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-20, 300), st.floats(-20, 300)), min_size=1, max_size=18),
    st.integers(16, 512),
    st.integers(16, 512),
)
def test_resize_joints_there_and_back_is_the_identity(values, src, dst):
    joints = np.asarray(values, np.float64).reshape(-1, 2)
    back = resize_joints(resize_joints(joints, src, dst), dst, src)
    np.testing.assert_allclose(back, joints, atol=1e-9)


def test_resize_joints_maps_pixel_centres():
    # the centre of a 4-pixel image (1.5) stays the centre of an 8-pixel one (3.5); its outer edges (-0.5, 3.5)
    # stay the outer edges (-0.5, 7.5)
    np.testing.assert_allclose(resize_joints(np.array([[1.5, -0.5], [3.5, 0.0]]), 4, 8), [[3.5, -0.5], [7.5, 0.5]])
    # a bright pixel keeps its place under cv2's area resize (what resize_sample does to the image)
    image = np.zeros((96, 96), np.float32)
    image[30:33, 60:63] = 1.0  # a 3x3 block centred on (x, y) = (61, 31)
    small = cv2.resize(image, (32, 32), interpolation=cv2.INTER_AREA)
    ys, xs = np.mgrid[:32, :32]
    centroid = np.array([(xs * small).sum(), (ys * small).sum()]) / small.sum()
    np.testing.assert_allclose(resize_joints(np.array([61.0, 31.0]), 96, 32), centroid, atol=1e-4)


def test_resize_sample_keeps_joints_on_their_dots():
    size, dst = 96, 40
    rng = np.random.default_rng(0)
    joints = rng.uniform(10, 85, (18, 2)).astype(np.float32)
    rgb = np.zeros((size, size, 3), np.uint8)
    for x, y in joints[:3]:
        cv2.circle(rgb, (int(round(x)), int(round(y))), 3, (255, 255, 255), -1)
    joints[:3] = np.round(joints[:3])
    sil = np.zeros((size, size), bool)
    sil[20:60, 30:50] = True
    sample = {"rgb": rgb, "depth": np.full((size, size), 500, np.uint16), "silhouette": sil, "joints2d": joints}
    out = resize_sample(sample, dst)
    assert out["rgb"].shape == (dst, dst, 3) and out["depth"].shape == (dst, dst)
    assert out["silhouette"].dtype == np.uint8 and out["silhouette"].max() == 255
    # the silhouette's area coverage is kept (x 255)
    assert out["silhouette"].sum() / 255 == pytest.approx(sil.sum() * (dst / size) ** 2, rel=0.02)
    grey = out["rgb"].astype(np.float64).mean(-1)
    ys, xs = np.mgrid[:dst, :dst]
    for x, y in out["joints2d"][:3]:
        window = (np.abs(xs - x) < 3) & (np.abs(ys - y) < 3)
        w = grey * window
        np.testing.assert_allclose([(xs * w).sum() / w.sum(), (ys * w).sum() / w.sum()], [x, y], atol=0.3)


# --- the cache of a dataset folder -------------------------------------------------------------------------------


def _mtimes(folder) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in sorted(folder.iterdir())}


@pytest.fixture
def small_data(tmp_path):
    """A fresh 12-sample, 32 px dataset in 3 chunks (its own: these tests change it)."""
    from footmesh.synth.dataset import generate
    from footmesh.synth.scene import SynthConfig

    folder = tmp_path / "data"
    generate(folder, 12, seed=5, config=SynthConfig(size=32), progress=False, chunk=4)
    return folder


def test_load_arrays_builds_the_cache_once_and_reuses_it(small_data):
    from footmesh.synth.dataset import SynthDataset

    arrays = load_arrays(small_data, 24, progress=False)
    cache = small_data / "cues-cache-24"
    assert len(arrays) == 12 and arrays.size == 24
    assert arrays.rgb.shape == (12, 24, 24, 3) and arrays.depth.dtype == np.uint16
    assert arrays.joints2d.shape == (12, 18, 2) and arrays.joints_visible.dtype == bool
    # the cache holds what resize_sample makes of each sample
    sample = SynthDataset(small_data)[5]
    want = resize_sample(sample, 24)
    for key in ("rgb", "depth", "silhouette", "joints2d", "joints_visible", "view_id"):
        np.testing.assert_array_equal(getattr(arrays, key)[5], want[key], err_msg=key)
    assert arrays.index.tolist() == list(range(12))

    before = _mtimes(cache)
    again = load_arrays(small_data, 24, progress=False)
    assert _mtimes(cache) == before  # not rebuilt
    assert isinstance(again.rgb, np.memmap)  # read lazily, not into memory
    np.testing.assert_array_equal(again.rgb, arrays.rgb)
    # another side is another cache
    assert load_arrays(small_data, 32, progress=False).rgb.shape == (12, 32, 32, 3)
    assert _mtimes(cache) == before


def test_load_arrays_rebuilds_when_chunks_are_added_or_removed(small_data):
    from footmesh.synth.dataset import generate
    from footmesh.synth.scene import SynthConfig

    assert len(load_arrays(small_data, 24, progress=False)) == 12
    chunk = small_data / "chunk-000001.npz"
    kept = chunk.read_bytes()
    chunk.unlink()
    arrays = load_arrays(small_data, 24, progress=False)
    assert len(arrays) == 8 and arrays.index.tolist() == [0, 1, 2, 3, 8, 9, 10, 11]
    # the resumable generator writes the missing chunk again: the cache follows
    generate(small_data, 12, seed=5, config=SynthConfig(size=32), progress=False, chunk=4)
    assert chunk.read_bytes() == kept
    arrays = load_arrays(small_data, 24, progress=False)
    assert len(arrays) == 12 and arrays.index.tolist() == list(range(12))


def test_load_arrays_rebuilds_when_a_chunk_is_replaced(small_data, tmp_path):
    from footmesh.synth.dataset import generate
    from footmesh.synth.scene import SynthConfig

    old = load_arrays(small_data, 24, progress=False)
    old_rgb = np.array(old.rgb[4:8])
    other = tmp_path / "other"
    generate(other, 12, seed=6, config=SynthConfig(size=32), progress=False, chunk=4)
    shutil.copyfile(other / "chunk-000001.npz", small_data / "chunk-000001.npz")
    os.utime(small_data / "chunk-000001.npz")
    new = load_arrays(small_data, 24, progress=False)
    assert not np.array_equal(np.asarray(new.rgb[4:8]), old_rgb)


def test_make_batch_converts_units_and_flags_joints_inside(tiny_data):
    arrays = load_arrays(tiny_data, SIZE, progress=False)
    rows = np.array([5, 2, 9])
    batch = make_batch(arrays, rows)
    order = np.sort(rows)  # rows are read in sorted order
    assert batch.rgb.shape == (3, 3, SIZE, SIZE) and 0 <= batch.rgb.min() and batch.rgb.max() <= 1
    np.testing.assert_array_equal(batch.depth[:, 0].numpy(), arrays.depth[order].astype(np.float32))
    np.testing.assert_allclose(batch.silhouette[:, 0].numpy(), arrays.silhouette[order] / 255, atol=1e-6)
    np.testing.assert_array_equal(batch.joints.numpy(), arrays.joints2d[order])
    inside = ((arrays.joints2d[order] >= -0.5) & (arrays.joints2d[order] <= SIZE - 0.5)).all(-1)
    np.testing.assert_array_equal(batch.inside.numpy(), inside.astype(np.float32))
    # the renderer only calls joints visible that are in the image
    assert (batch.visible <= batch.inside).all()


# --- augmentation ------------------------------------------------------------------------------------------------


def _dot_batch(b: int, seed: int) -> tuple[Batch, np.ndarray]:
    """Black images with a bright Gaussian dot (SD 1 px) at each of 4 well-separated joints (the rest outside),
    a disc silhouette and a disc of nearer depth; returns the batch and the disc centres (B, 2)."""
    rng = np.random.default_rng(seed)
    s = SIZE
    ys, xs = np.mgrid[:s, :s].astype(np.float64)
    joints = np.full((b, 18, 2), -100.0)
    corners = np.array([[20.0, 20.0], [43.0, 20.0], [20.0, 43.0], [43.0, 43.0]])
    joints[:, :4] = corners + rng.uniform(-2.5, 2.5, (b, 4, 2))
    images = np.zeros((b, 3, s, s))
    for i in range(b):
        for x, y in joints[i, :4]:
            images[i] += np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / 2.0)
    centres = rng.uniform(28, 36, (b, 2))
    disc = ((xs - centres[:, 0, None, None]) ** 2 + (ys - centres[:, 1, None, None]) ** 2) < 8.0**2
    t_joints = torch.from_numpy(joints).float()
    batch = Batch(
        rgb=torch.from_numpy(images).float().clamp(0, 1),
        depth=torch.from_numpy(np.where(disc, 400.0, 600.0)).float()[:, None],
        silhouette=torch.from_numpy(disc).float()[:, None],
        joints=t_joints,
        visible=torch.ones(b, 18),
        inside=inside_image(t_joints, s),
    )
    return batch, centres


def _centroid(image: np.ndarray, x: float, y: float, radius: float) -> np.ndarray:
    ys, xs = np.mgrid[: image.shape[0], : image.shape[1]]
    w = image * ((xs - x) ** 2 + (ys - y) ** 2 <= radius**2)
    return np.array([(xs * w).sum(), (ys * w).sum()]) / w.sum()


@pytest.mark.parametrize("flip", [0.0, 1.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_augment_keeps_joints_on_the_image_content(seed, flip):
    batch, centres = _dot_batch(4, seed)
    # zoom kept moderate so the dots (10+ px from the border) stay inside after shift and rotation
    aug = Augment(scale=(0.85, 1.15), rotate_deg=25.0, shift=0.05, flip=flip, **NO_PHOTOMETRIC)
    out = augment_batch(batch, aug, torch.Generator().manual_seed(seed))
    assert out.joints.shape == batch.joints.shape
    moved = 0.0
    for i in range(4):
        grey = out.rgb[i].mean(0).numpy()
        for j in range(4):
            x, y = out.joints[i, j].tolist()
            assert out.inside[i, j] == 1.0
            # 0.25 px (measured: < 0.1): a half-pixel convention slip between image and joints would show
            np.testing.assert_allclose(_centroid(grey, x, y, 4.0), [x, y], atol=0.25)
            moved += float((out.joints[i, j] - batch.joints[i, j]).norm())
        assert out.inside[i, 4:].sum() == 0  # joints outside stay outside
        # silhouette and depth move with the image: their discs have the same centre, the image's dots
        # around it keep their arrangement (a flip mirrors it)
        sil = out.silhouette[i, 0].numpy()
        near = (out.depth[i, 0].numpy() < 500).astype(np.float64)
        ys, xs = np.mgrid[:SIZE, :SIZE]
        sil_c = np.array([(xs * sil).sum(), (ys * sil).sum()]) / sil.sum()
        depth_c = np.array([(xs * near).sum(), (ys * near).sum()]) / near.sum()
        np.testing.assert_allclose(depth_c, sil_c, atol=1.0)
        # the disc centre goes where the joints' affine map sends it: estimate that map from the 4 joints
        src = np.c_[batch.joints[i, :4].numpy(), np.ones(4)]
        m, *_ = np.linalg.lstsq(src, out.joints[i, :4].numpy(), rcond=None)
        np.testing.assert_allclose(np.r_[centres[i], 1.0] @ m, sil_c, atol=1.0)
        orientation = np.sign(np.linalg.det(m[:2]))
        assert orientation == (-1.0 if flip == 1.0 else 1.0)
    assert moved > 4 * 4 * 0.5  # the augmentation did something


def test_augment_flags_joints_pushed_out_of_the_image():
    s = SIZE
    joints = torch.tensor([[[1.0, 32.0], [32.0, 32.0], [62.5, 5.0], [-3.0, 10.0]] + [[32.0, 32.0]] * 14])
    batch = Batch(
        rgb=torch.zeros(1, 3, s, s),
        depth=torch.full((1, 1, s, s), 500.0),
        silhouette=torch.zeros(1, 1, s, s),
        joints=joints,
        visible=torch.ones(1, 18),
        inside=inside_image(joints, s),
    )
    assert batch.inside[0, :4].tolist() == [1.0, 1.0, 1.0, 0.0]
    # a 25 % zoom about the centre pushes joints near the border out
    aug = Augment(scale=(1.25, 1.25), rotate_deg=0.0, shift=0.0, flip=0.0, **NO_PHOTOMETRIC)
    out = augment_batch(batch, aug, torch.Generator().manual_seed(0))
    np.testing.assert_allclose(out.joints[0, :3].numpy(), ((joints[0, :3] - 31.5) * 1.25 + 31.5).numpy(), atol=1e-4)
    assert out.inside[0, :4].tolist() == [0.0, 1.0, 0.0, 0.0]
    assert out.visible.equal(batch.visible)  # visibility is a label of the scene, kept as it is


def test_photometric_changes_keep_images_in_range():
    g = torch.Generator().manual_seed(0)
    s = SIZE
    rgb = torch.rand(6, 3, s, s, generator=g)
    rgb[:2] = (rgb[:2] > 0.5).float()  # saturated black and white
    batch = Batch(rgb, torch.full((6, 1, s, s), 500.0), torch.zeros(6, 1, s, s), torch.zeros(6, 18, 2),
                  torch.ones(6, 18), torch.ones(6, 18))  # fmt: skip
    strong = Augment(
        brightness=(1.4, 1.4), contrast=(1.3, 1.3), saturation=(1.4, 1.4), noise_sd=(0.2, 0.2), blur_p=1.0,
        jpeg_p=1.0, jpeg_quality=(30, 30), **IDENTITY_GEOMETRY,
    )  # fmt: skip
    out = augment_batch(batch, strong, g)
    assert out.rgb.min() >= 0.0 and out.rgb.max() <= 1.0
    assert out.rgb.dtype == torch.float32 and out.rgb.shape == rgb.shape
    assert (out.rgb - rgb).abs().mean() > 0.01  # it did change the images
    dark = Augment(brightness=(0.6, 0.6), contrast=(0.7, 0.7), **IDENTITY_GEOMETRY)
    out = augment_batch(batch, dark, g)
    assert out.rgb.min() >= 0.0 and out.rgb.max() <= 1.0
    assert 0.0 <= out.silhouette.min() and out.silhouette.max() <= 1.0


def test_jpeg_roundtrip_is_in_range_and_close():
    g = torch.Generator().manual_seed(1)
    image = torch.nn.functional.avg_pool2d(torch.rand(1, 3, SIZE, SIZE, generator=g), 5, 1, 2)[0]
    for quality in (30, 95):
        out = jpeg_roundtrip(image, quality)
        assert out.shape == image.shape and out.min() >= 0 and out.max() <= 1
        assert (out - image).abs().mean() < 0.05
    # RGB order is kept (OpenCV's BGR is undone): a red image stays red
    red = torch.zeros(3, 16, 16)
    red[0] = 1.0
    out = jpeg_roundtrip(red, 90)
    assert out[0].mean() > 0.9 and out[1:].mean() < 0.1


def test_depth_dropout_only_zeroes_pixels():
    g = torch.Generator().manual_seed(2)
    s, b = SIZE, 8
    depth = 300 + 400 * torch.rand(b, 1, s, s, generator=g)
    depth[:, :, :5] = 0.0  # missing already
    batch = Batch(torch.rand(b, 3, s, s, generator=g), depth, torch.zeros(b, 1, s, s), torch.zeros(b, 18, 2),
                  torch.ones(b, 18), torch.ones(b, 18))  # fmt: skip
    kept = Augment(**{**NO_PHOTOMETRIC, **IDENTITY_GEOMETRY})
    dropped = Augment(**{**NO_PHOTOMETRIC, **IDENTITY_GEOMETRY, "depth_dropout_p": 1.0})
    base = augment_batch(batch, kept, torch.Generator().manual_seed(3)).depth
    torch.testing.assert_close(base, depth)  # the identity transform leaves depth as it is
    out = augment_batch(batch, dropped, torch.Generator().manual_seed(3)).depth
    zeroed = out == 0
    assert torch.equal(out[~zeroed], depth[~zeroed])  # every pixel is either kept exactly or zeroed
    assert (zeroed & (depth > 0)).any()  # some holes were made
    assert zeroed[:, :, :5].all()  # missing stays missing
    assert zeroed.float().mean() < 0.5  # holes, not the whole map
    # with noise, valid pixels stay valid (> 0) and near their value; missing ones stay 0
    noisy = Augment(**{**NO_PHOTOMETRIC, **IDENTITY_GEOMETRY, "depth_noise_mm": (2.0, 2.0)})
    out = augment_batch(batch, noisy, torch.Generator().manual_seed(3)).depth
    assert (out[depth > 0] > 0).all() and (out[depth == 0] == 0).all()
    assert (out - depth)[depth > 0].abs().max() < 15.0
