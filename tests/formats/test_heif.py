"""HEIC / HEIF photos and the depth image inside them, on files the tests write (``formats.heif_writer``)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from PIL import Image

from footmesh.formats.embedded import EmbeddedDepth, align_depth, orient
from footmesh.formats.heif import read_heif_depth
from footmesh.formats.heif_writer import write_heic
from footmesh.load import LoadError, load_photo

W, H = 160, 120  # photo as stored, px
DW, DH = 64, 48  # depth as stored: a quarter of the photo's resolution per side... 2.5x, like an iPhone's
NEAR_M, FAR_M = 0.26, 1.36  # the range of a real iPhone LiDAR HEIC
MUTATIONS = int(os.environ.get("FOOTMESH_FUZZ_MUTATIONS", "150"))


def quadrants(w: int = W, h: int = H) -> np.ndarray:
    """(h, w, 3) uint8: red, green / blue, white quadrants, so any turn or flip shows."""
    img = np.zeros((h, w, 3), np.uint8)
    img[: h // 2, : w // 2] = (220, 30, 30)
    img[: h // 2, w // 2 :] = (30, 220, 30)
    img[h // 2 :, : w // 2] = (30, 30, 220)
    img[h // 2 :, w // 2 :] = (240, 240, 240)
    return img


def exif(orientation: int = 1, f35: int | None = 26) -> bytes:
    tags = Image.Exif()
    tags[0x0112] = orientation
    if f35 is not None:
        tags.get_ifd(0x8769)[0xA405] = f35
    return tags.tobytes()


def depth_quadrants() -> np.ndarray:
    """(DH, DW) metres as stored: 0.4 m top-left, 0.6 top-right, 0.8 bottom-left, 1.0 bottom-right."""
    z = np.empty((DH, DW))
    z[: DH // 2, : DW // 2], z[: DH // 2, DW // 2 :] = 0.4, 0.6
    z[DH // 2 :, : DW // 2], z[DH // 2 :, DW // 2 :] = 0.8, 1.0
    return z


def encode(z_m: np.ndarray, representation: str, bits: int = 8) -> np.ndarray:
    """Samples of depth ``z_m`` in a representation, as a file stores them (uint8 or 10-bit in uint16)."""
    full = (1 << bits) - 1
    if representation == "uniform_z":
        v = (z_m - NEAR_M) / (FAR_M - NEAR_M)
    elif representation == "uniform_inverse_z":
        v = (1 / z_m - 1 / FAR_M) / (1 / NEAR_M - 1 / FAR_M)
    else:
        v = z_m / z_m.max()
    return np.round(v * full).astype(np.uint8 if bits == 8 else np.uint16)


def heic_with_depth(tmp_path, name="photo.heic", orientation=1, representation="uniform_z", bits=8, **kwargs):
    z = depth_quadrants()
    options = {"z_near": NEAR_M, "z_far": FAR_M} | kwargs
    data = write_heic(
        quadrants(),
        exif=exif(orientation),
        depth_samples=encode(z, representation, bits),
        representation=representation,
        **options,
    )
    path = tmp_path / name
    path.write_bytes(data)
    return path


def quadrant_means(a: np.ndarray) -> np.ndarray:
    h, w = a.shape[:2]
    return np.array(
        [
            a[: h // 2, : w // 2].mean(),
            a[: h // 2, w // 2 :].mean(),
            a[h // 2 :, : w // 2].mean(),
            a[h // 2 :, w // 2 :].mean(),
        ]
    )


# --- the photo ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("orientation", [1, 3, 6, 8])
def test_a_heic_photo_loads_upright_by_its_orientation(tmp_path, orientation):
    path = tmp_path / "IMG_0001.HEIC"
    path.write_bytes(write_heic(quadrants(), exif=exif(orientation)))
    photo = load_photo(path)
    assert photo.info.format == "HEIF" and photo.info.orientation == orientation
    expected = orient(quadrants(), orientation)
    assert photo.rgb.shape == expected.shape
    assert np.abs(photo.rgb.astype(int) - expected).mean() < 6  # lossy HEVC
    assert photo.info.focal_length_35mm == 26 and photo.intrinsics.source == "exif"
    assert photo.depth_mm is None and photo.depth_source is None


def test_a_10_bit_heic_photo_loads_as_8_bit_rgb(tmp_path):
    path = tmp_path / "hdr.heic"
    path.write_bytes(write_heic(quadrants(), bit_depth=10))
    photo = load_photo(path)
    assert photo.rgb.dtype == np.uint8
    assert np.abs(photo.rgb.astype(int) - quadrants()).mean() < 6


def test_a_truncated_heic_is_refused_as_corrupt(tmp_path):
    data = write_heic(quadrants())
    path = tmp_path / "cut.heic"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(LoadError, match=r"^image .*cut\.heic is truncated or corrupt"):
        load_photo(path)


def test_a_file_named_heic_that_is_not_heif_is_refused_by_its_content(tmp_path):
    path = tmp_path / "fake.heic"
    path.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(64))
    with pytest.raises(LoadError, match=r"fake\.heic is an ISO media file of brand b'mp42'"):
        load_photo(path)
    path.write_bytes(b"hello, this is text and not a photo" * 4)
    with pytest.raises(LoadError, match=r"fake\.heic is not an image that can be read"):
        load_photo(path)


# --- its depth image ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("representation", ["uniform_z", "uniform_inverse_z"])
@pytest.mark.parametrize("bits", [8, 10])
def test_the_embedded_depth_becomes_millimetres_by_its_representation(tmp_path, representation, bits):
    photo = load_photo(heic_with_depth(tmp_path, representation=representation, bits=bits))
    assert photo.depth_mm is not None and photo.depth_mm.shape == (H, W)
    source = photo.depth_source
    assert (source.source, source.container, source.representation) == ("embedded", "HEIF depth image", representation)
    assert (source.near_mm, source.far_mm, source.bits, source.stored_size) == (260.0, 1360.0, bits, (DW, DH))
    step_mm = 1000 * (FAR_M - NEAR_M) / ((1 << bits) - 1) * (1 if representation == "uniform_z" else 4)
    np.testing.assert_allclose(quadrant_means(photo.depth_mm), [400, 600, 800, 1000], atol=step_mm)
    assert any("depth from the photo's HEIF depth image" in note for note in photo.info.notes)


@pytest.mark.parametrize("orientation", [1, 2, 3, 4, 5, 6, 7, 8])
def test_the_embedded_depth_is_turned_with_the_photo(tmp_path, orientation):
    photo = load_photo(heic_with_depth(tmp_path, orientation=orientation))
    # the photo's red quadrant and the depth's 0.4 m quadrant were stored in the same corner
    red = (photo.rgb[:, :, 0] > 150) & (photo.rgb[:, :, 1] < 100)
    near = (photo.depth_mm > 0) & (photo.depth_mm < 500)
    assert photo.depth_mm.shape == photo.rgb.shape[:2]
    assert (red & near).sum() / red.sum() > 0.9


def test_relative_disparity_is_not_used_for_millimetres(tmp_path):
    path = heic_with_depth(tmp_path, representation="uniform_disparity", z_near=None, z_far=None, d_min=0.15, d_max=3.2)
    photo = load_photo(path)
    assert photo.depth_mm is None and photo.depth_source is None
    assert any("not used" in n and "uniform disparity, which is relative" in n for n in photo.info.notes)


def test_a_depth_without_its_range_is_not_used(tmp_path):
    photo = load_photo(heic_with_depth(tmp_path, z_near=None, z_far=None))
    assert photo.depth_mm is None
    assert any("does not state its near and far range" in n for n in photo.info.notes)


def test_low_confidence_depth_is_dropped(tmp_path):
    confidence = np.full((DH, DW), 255, np.uint8)
    confidence[:, : DW // 4] = 0  # ARKit's "low" on the left quarter
    confidence[:, DW // 4 : DW // 2] = 128  # "medium": kept
    z = depth_quadrants()
    path = tmp_path / "c.heic"
    path.write_bytes(
        write_heic(quadrants(), depth_samples=encode(z, "uniform_z"), z_near=NEAR_M, z_far=FAR_M, confidence=confidence)
    )
    photo = load_photo(path)
    assert (photo.depth_mm[:, : W // 4 - 2] == 0).all()
    assert (photo.depth_mm[:, W // 4 + 2 :] > 0).all()
    assert photo.depth_source.dropped_low_confidence == pytest.approx(0.25)


def test_no_embedded_depth_and_a_depth_file_both_leave_it_unused(tmp_path):
    path = heic_with_depth(tmp_path)
    assert load_photo(path, embedded_depth=False).depth_mm is None
    depth_file = tmp_path / "d.npy"
    np.save(depth_file, np.full((H, W), 555.0, np.float32))
    photo = load_photo(path, depth=depth_file)
    assert photo.depth_source.source == "file" and float(photo.depth_mm.max()) == 555.0


def test_a_depth_of_another_aspect_ratio_is_not_used(tmp_path):
    z = np.full((40, 64), 0.5)
    path = tmp_path / "crop.heic"
    path.write_bytes(write_heic(quadrants(), depth_samples=encode(z, "uniform_z"), z_near=NEAR_M, z_far=FAR_M))
    photo = load_photo(path)
    assert photo.depth_mm is None and any("another aspect ratio" in n for n in photo.info.notes)


def test_read_heif_depth_reports_what_the_file_states(tmp_path):
    data = heic_with_depth(tmp_path, representation="uniform_inverse_z", bits=10).read_bytes()
    depth, notes = read_heif_depth(data)
    assert notes == [] and isinstance(depth, EmbeddedDepth)
    assert depth.representation == "uniform_inverse_z" and depth.bits == 10 and depth.size == (DW, DH)
    assert depth.near_m == pytest.approx(NEAR_M, rel=1e-6) and depth.far_m == pytest.approx(FAR_M, rel=1e-6)
    assert read_heif_depth(write_heic(quadrants())) == (None, [])


def test_ray_distances_become_z():
    samples = np.full((48, 64), 0.5, np.float32)
    depth = EmbeddedDepth(samples, "range_linear", 0.0 + 0.2, 1.8, "GDepth XMP", 8, measure="optic_ray")
    mm, _source, why = align_depth(depth, 1, (64, 48), 50.0, 50.0, 31.5, 23.5)
    assert why is None
    corner_ray = np.sqrt(1 + (31.5 / 50) ** 2 + (23.5 / 50) ** 2)
    assert mm[0, 0] == pytest.approx(1000.0 / corner_ray, rel=1e-5) and mm[23, 31] == pytest.approx(1000.0, rel=1e-3)


# --- measured end to end -------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_an_iphone_like_heic_is_measured_from_its_own_depth(tmp_path):
    from footmesh.cli import main
    from footmesh.examples import examples

    ex = next(e for e in examples() if e.depth is not None)
    rgb = np.asarray(Image.open(ex.image).convert("RGB"))
    depth_mm = np.asarray(Image.open(ex.depth)).astype(np.float64)
    # stored as the sensor saw it: turned back by EXIF 6 (the viewer turns it upright), depth at 1/4 resolution
    raw_rgb, raw_depth = np.rot90(rgb, 1), np.rot90(depth_mm, 1)
    small = raw_depth[::4, ::4]
    z = np.where(small > 0, small / 1000.0, FAR_M)
    samples = np.round(np.clip((z - NEAR_M) / (FAR_M - NEAR_M), 0, 1) * 1023).astype(np.uint16)
    path = tmp_path / "IMG_0002.HEIC"
    path.write_bytes(
        write_heic(
            np.ascontiguousarray(raw_rgb), exif=exif(6, f35=None), depth_samples=samples, z_near=NEAR_M, z_far=FAR_M
        )
    )
    out = tmp_path / "out"
    assert main(["measure", str(path), "--intrinsics", str(ex.intrinsics), "--out", str(out)]) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["input"] == "rgbd" and result["scale_source"] == "depth"
    assert result["depth"]["container"] == "HEIF depth image" and result["depth"]["representation"] == "uniform_z"
    length = result["measurements"]["stick_length"]["value_mm"]
    assert abs(length - ex.truth_mm["stick_length"]) < 4.23  # half a shoe size
    assert (
        main(["measure", str(path), "--intrinsics", str(ex.intrinsics), "--out", str(out), "--no-embedded-depth"]) == 0
    )
    plain = json.loads((out / "result.json").read_text())
    assert plain["input"] == "rgb" and plain["request"]["embedded_depth"] is False


def test_a_depth_the_container_turned_already_is_not_turned_twice():
    z = np.full((64, 48), 0.5)  # portrait, like the upright photo, although the photo was stored turned (EXIF 6)
    z[:8] = 0.3  # the top of the upright view is near
    depth = EmbeddedDepth(((z - NEAR_M) / (FAR_M - NEAR_M)).astype(np.float32), "uniform_z", NEAR_M, FAR_M, "x", 8)
    mm, _source, why = align_depth(depth, 6, (120, 160), 100.0, 100.0, 59.5, 79.5)
    assert why is None and mm.shape == (160, 120)
    assert mm[:16].mean() == pytest.approx(300, abs=1) and mm[40:].mean() == pytest.approx(500, abs=1)


def test_mutated_heic_files_load_or_fail_with_one_line(tmp_path):
    """Bytes flipped, cut or inserted anywhere (the container, the HEVC streams, the SEI): a photo, with or without
    its depth, or a one-line LoadError; never another exception."""
    original = heic_with_depth(tmp_path, bits=10).read_bytes()
    rng = np.random.default_rng(20)
    path = tmp_path / "m.heic"
    outcomes = {"depth": 0, "rgb": 0, "refused": 0}
    for _ in range(MUTATIONS):
        data = bytearray(original)
        at = int(rng.integers(0, len(data)))
        if rng.random() < 0.3:
            data = data[:at]
        else:
            for offset in rng.integers(0, len(data), size=int(rng.integers(1, 6))):
                data[offset] ^= 1 << int(rng.integers(8))
        path.write_bytes(bytes(data))
        try:
            photo = load_photo(path)
        except LoadError as exc:
            assert "\n" not in str(exc) and str(path) in str(exc)
            outcomes["refused"] += 1
        else:
            outcomes["depth" if photo.depth_mm is not None else "rgb"] += 1
    assert outcomes["refused"] and outcomes["depth"]
