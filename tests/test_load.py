"""The load stage: every kind of image, depth map and intrinsics file, made on the fly, and every refusal."""

from __future__ import annotations

import hashlib
import json
import math

import cv2
import numpy as np
import pytest
from PIL import Image

from footmesh.load import (
    DEFAULT_FOCAL_35MM,
    MIN_SIDE_PX,
    Intrinsics,
    LoadError,
    default_intrinsics,
    load_depth,
    load_image,
    load_intrinsics,
    load_photo,
)

W, H = 96, 72  # stored (raw) size of most test images, px


def quadrants(w: int = W, h: int = H) -> np.ndarray:
    """(h, w, 3) uint8: red, green / blue, white quadrants plus a gradient, so any flip or turn shows."""
    img = np.zeros((h, w, 3), np.uint8)
    img[: h // 2, : w // 2] = (255, 0, 0)
    img[: h // 2, w // 2 :] = (0, 255, 0)
    img[h // 2 :, : w // 2] = (0, 0, 255)
    img[h // 2 :, w // 2 :] = (255, 255, 255)
    img[h // 4, :, 1] = np.linspace(0, 255, w).astype(np.uint8)  # breaks the symmetry of a transpose
    return img


def exif(orientation: int | None = None, f35: int | None = None) -> Image.Exif:
    tags = Image.Exif()
    if orientation is not None:
        tags[0x0112] = orientation
    if f35 is not None:
        tags.get_ifd(0x8769)[0xA405] = f35
        tags.get_ifd(0x8769)[0x920A] = 5.1  # the real lens' focal length, mm
    return tags


def save(path, array: np.ndarray, fmt: str | None = None, mode: str | None = None, **kw):
    Image.fromarray(array, mode).save(path, fmt, **kw)
    return path


def error(fn, *args, **kwargs) -> str:
    """The LoadError message of ``fn(*args)``; it must be one line."""
    with pytest.raises(LoadError) as exc:
        fn(*args, **kwargs)
    message = str(exc.value)
    assert "\n" not in message and isinstance(exc.value, ValueError)
    return message


# --- images ---------------------------------------------------------------------------------------------------

# what a viewer shows for each EXIF orientation of a stored array a (CIPA DC-008 / TIFF 6.0 tag 274)
UPRIGHT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],  # mirrored left-right
    3: lambda a: a[::-1, ::-1],  # turned 180 degrees
    4: lambda a: a[::-1],  # mirrored top-bottom
    5: lambda a: a.transpose(1, 0, 2),  # transposed
    6: lambda a: np.rot90(a, -1),  # turned 90 degrees clockwise (phone held upright)
    7: lambda a: a.transpose(1, 0, 2)[::-1, ::-1],  # transversed
    8: lambda a: np.rot90(a, 1),  # turned 90 degrees anticlockwise
}


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_gives_the_upright_image(tmp_path, orientation):
    raw = quadrants()
    path = save(tmp_path / "photo.png", raw, exif=exif(orientation))  # lossless, so compared exactly
    rgb, info = load_image(path)
    np.testing.assert_array_equal(rgb, UPRIGHT[orientation](raw))
    assert info.orientation == orientation and info.raw_size == (W, H)
    assert info.size == (rgb.shape[1], rgb.shape[0])
    assert rgb.dtype == np.uint8 and rgb.flags.c_contiguous


def test_rotated_phone_jpeg(tmp_path):
    raw = quadrants(160, 120)
    path = save(tmp_path / "IMG_0001.JPG", raw, "JPEG", quality=95, exif=exif(6, f35=26))
    rgb, info = load_image(path)
    assert rgb.shape == (160, 120, 3) and info.format == "JPEG" and info.size == (120, 160)
    assert np.abs(rgb.astype(int) - np.rot90(raw, -1)).mean() < 3  # JPEG loss only
    assert tuple(rgb[5, -5]) == pytest.approx((255, 0, 0), abs=8)  # the stored top-left is now top-right
    assert info.focal_length_35mm == 26 and info.focal_length_mm == pytest.approx(5.1)
    assert info.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize(("name", "fmt", "kw"), [("a.jpg", "PNG", {}), ("b.bin", "WEBP", {"lossless": True}),
                                                 ("c.png", "TIFF", {}), ("d", "BMP", {})])  # fmt: skip
def test_format_comes_from_the_content_not_the_name(tmp_path, name, fmt, kw):
    raw = quadrants()
    rgb, info = load_image(save(tmp_path / name, raw, fmt, **kw))
    np.testing.assert_array_equal(rgb, raw)
    assert info.format == fmt


def test_sixteen_bit_grey_png_is_scaled_not_clipped(tmp_path):
    grey = np.linspace(0, 65535, W * H).reshape(H, W).astype(np.uint16)
    rgb, info = load_image(save(tmp_path / "g16.png", grey))
    assert info.mode.startswith("I;16") and rgb.shape == (H, W, 3)
    np.testing.assert_array_equal(rgb[..., 0], np.round(grey / 257).astype(np.uint8))
    assert (rgb[..., 0] == rgb[..., 2]).all() and rgb.max() == 255
    assert any("16-bit" in n for n in info.notes)


def test_sixteen_bit_colour_png(tmp_path):
    rgb16 = (quadrants().astype(np.uint16) * 257)[..., ::-1]  # OpenCV writes BGR
    path = tmp_path / "rgb16.png"
    assert cv2.imwrite(str(path), rgb16)
    rgb, _ = load_image(path)
    np.testing.assert_array_equal(rgb, quadrants())


def test_alpha_is_composited_onto_white(tmp_path):
    rgba = np.zeros((H, W, 4), np.uint8)
    rgba[..., :3] = (200, 40, 0)
    rgba[:, : W // 3, 3] = 0  # transparent
    rgba[:, W // 3 : 2 * W // 3, 3] = 128  # half
    rgba[:, 2 * W // 3 :, 3] = 255  # opaque
    rgb, info = load_image(save(tmp_path / "a.png", rgba, mode="RGBA"))
    assert tuple(rgb[0, 0]) == (255, 255, 255)
    assert tuple(rgb[0, W // 2]) == pytest.approx((228, 147, 127), abs=1)  # 0.5 * colour + 0.5 * white
    assert tuple(rgb[0, -1]) == (200, 40, 0)
    assert any("white" in n for n in info.notes)
    rgba[..., 3] = 255  # fully opaque: the alpha channel is just dropped
    rgb, info = load_image(save(tmp_path / "opaque.webp", rgba, lossless=True, mode="RGBA"))
    assert (rgb == (200, 40, 0)).all() and not info.notes


def test_palette_grey_and_bilevel_images(tmp_path):
    raw = quadrants()
    palette = Image.fromarray(raw).quantize(8)
    palette.save(tmp_path / "p.png")
    rgb, info = load_image(tmp_path / "p.png")
    assert info.mode == "P"
    np.testing.assert_array_equal(rgb, np.asarray(palette.convert("RGB")))
    grey = raw[..., 1]
    rgb, info = load_image(save(tmp_path / "l.jpg", grey, "PNG"))
    assert info.mode == "L" and (rgb == grey[..., None]).all()
    Image.fromarray(grey > 127).save(tmp_path / "bw.tif")
    rgb, info = load_image(tmp_path / "bw.tif")
    assert info.mode == "1" and set(np.unique(rgb)) == {0, 255}
    la = np.stack([grey, np.full_like(grey, 255)], axis=-1)
    rgb, _ = load_image(save(tmp_path / "la.png", la, mode="LA"))
    assert (rgb == grey[..., None]).all()


def test_palette_with_a_transparent_entry(tmp_path):
    im = Image.fromarray(quadrants()).quantize(4)
    im.info["transparency"] = int(np.asarray(im)[0, 0])  # the red quadrant's index becomes transparent
    im.save(tmp_path / "t.png", transparency=im.info["transparency"])
    rgb, _ = load_image(tmp_path / "t.png")
    assert tuple(rgb[0, 0]) == (255, 255, 255) and tuple(rgb[-1, 0]) == (0, 0, 255)


@pytest.mark.parametrize("fmt", ["JPEG", "PNG", "TIFF", "WEBP"])
def test_truncated_image_is_refused(tmp_path, fmt):
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)  # incompressible, so half the file is half the image
    full = save(tmp_path / "full", noise, fmt).read_bytes()
    path = tmp_path / "cut.img"
    path.write_bytes(full[: len(full) // 2])
    message = error(load_image, path)
    assert message.startswith(f"image {path} is truncated or corrupt (")


def test_corrupt_png_data_is_refused(tmp_path):
    data = bytearray(save(tmp_path / "ok.png", quadrants()).read_bytes())
    idat = data.index(b"IDAT")
    data[idat + 8 : idat + 40] = bytes(32)  # zeros inside the compressed stream
    (tmp_path / "bad.png").write_bytes(bytes(data))
    assert "bad.png is truncated or corrupt" in error(load_image, tmp_path / "bad.png")


def test_symbolic_link_loops_and_dangling_links_are_named(tmp_path):
    (tmp_path / "a.jpg").symlink_to(tmp_path / "b.jpg")
    (tmp_path / "b.jpg").symlink_to(tmp_path / "a.jpg")
    assert "is a symbolic-link loop" in error(load_image, tmp_path / "a.jpg")
    (tmp_path / "c.jpg").symlink_to(tmp_path / "gone.jpg")
    assert "is a symbolic link to" in error(load_image, tmp_path / "c.jpg")
    assert "does not exist" in error(load_image, tmp_path / "none.jpg")


def test_a_multi_page_tiff_with_a_broken_page_chain_is_corrupt(tmp_path):
    pages = [Image.fromarray(quadrants()), Image.fromarray(quadrants()[::-1].copy())]
    path = tmp_path / "p.tif"
    pages[0].save(path, save_all=True, append_images=pages[1:])
    rgb, info = load_image(path)
    assert rgb.shape == (H, W, 3) and "first of 2 frames used" in info.notes
    data = bytearray(path.read_bytes())
    offset = int.from_bytes(data[4:8], "little")  # first IFD; its entries are followed by the next IFD's offset
    entries = int.from_bytes(data[offset : offset + 2], "little")
    next_at = offset + 2 + 12 * entries
    data[next_at : next_at + 4] = (len(data) + 10_000).to_bytes(4, "little")  # the second page points nowhere
    path.write_bytes(bytes(data))
    message = error(load_image, path)
    assert "truncated or corrupt" in message


def test_files_that_are_not_images(tmp_path):
    text = tmp_path / "foot.jpg"
    text.write_text("this is not a photo\n")
    message = error(load_image, text)
    assert message.startswith(f"image {text} is not an image") and "this is not" in message
    heic = tmp_path / "IMG_0002.HEIC"
    heic.write_bytes(b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic" + bytes(100))
    assert "HEIC/HEIF" in error(load_image, heic) and "JPEG" in error(load_image, heic)
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    assert error(load_image, empty) == f"image {empty} is empty (0 bytes)"
    assert error(load_image, tmp_path / "missing.jpg") == f"image {tmp_path / 'missing.jpg'} does not exist"
    assert error(load_image, tmp_path) == f"image {tmp_path} is a directory, not a file"


def test_size_limits(tmp_path, monkeypatch):
    tiny = save(tmp_path / "tiny.png", quadrants(200, MIN_SIDE_PX - 1))
    assert "200 x 63 px" in error(load_image, tiny) and f"at least {MIN_SIDE_PX} px" in error(load_image, tiny)
    load_image(save(tmp_path / "small.png", quadrants(MIN_SIDE_PX, MIN_SIDE_PX)))  # the limit itself is fine
    big = save(tmp_path / "big.png", quadrants())
    message = error(load_image, big, max_pixels=W * H - 1)
    assert f"{W} x {H} px" in message and "more than the limit" in message and "big.png" in message
    load_image(big, max_pixels=W * H)
    # Pillow's own decompression-bomb guard becomes the same kind of message
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)
    message = error(load_image, big)
    assert "big.png has more than 0.002 MP" in message and "downscale it" in message
    assert "bomb" not in message and "DOS" not in message  # the project's words, not Pillow's


# --- depth ----------------------------------------------------------------------------------------------------


def depth_scene(w: int = W, h: int = H) -> np.ndarray:
    """(h, w) float64 mm: a tilted floor 400-700 mm away with a hole of missing pixels."""
    y = np.arange(h)[:, None]
    d = 400.0 + 300.0 * y / (h - 1) + 0.0 * np.arange(w)[None]
    d[5:15, 10:30] = 0.0
    return d


def test_depth_png_and_integer_npy_are_millimetres(tmp_path):
    mm = np.round(depth_scene()).astype(np.uint16)
    from_png = load_depth(save(tmp_path / "d.png", mm), "mm", (W, H))
    np.save(tmp_path / "d.npy", mm)
    from_npy = load_depth(tmp_path / "d.npy", "mm", (W, H))
    for depth in (from_png, from_npy):
        assert depth.dtype == np.float32 and depth.shape == (H, W)
        np.testing.assert_array_equal(depth, mm.astype(np.float32))
    assert (from_png[5:15, 10:30] == 0).all()


@pytest.mark.parametrize(("unit", "factor"), [("m", 1e-3), ("mm", 1.0)])
def test_float_npy_in_the_declared_unit(tmp_path, unit, factor):
    mm = depth_scene()
    raw = (mm * factor).astype(np.float32)
    raw[0, 0], raw[0, 1], raw[0, 2], raw[0, 3] = np.nan, np.inf, -1.0, -np.inf  # all "missing"
    np.save(tmp_path / "d.npy", raw[..., None])  # (H, W, 1) is accepted too
    depth = load_depth(tmp_path / "d.npy", unit, (W, H))
    expected = mm.copy()
    expected[0, :4] = 0
    np.testing.assert_allclose(depth, expected, rtol=1e-6)
    assert np.isfinite(depth).all() and depth.dtype == np.float32


def test_depth_in_the_wrong_unit_names_the_flag(tmp_path):
    np.save(tmp_path / "metres.npy", depth_scene() / 1000)
    message = error(load_depth, tmp_path / "metres.npy", "mm", (W, H))
    assert "metres.npy" in message and "look like metres" in message and "--depth-unit m" in message
    np.save(tmp_path / "millimetres.npy", depth_scene())
    message = error(load_depth, tmp_path / "millimetres.npy", "m", (W, H))
    assert "look like millimetres" in message and "--depth-unit mm" in message
    np.save(tmp_path / "centimetres.npy", depth_scene() / 10)
    assert "neither mm nor m fits" in error(load_depth, tmp_path / "centimetres.npy", "mm", (W, H))
    png = save(tmp_path / "d.png", depth_scene().astype(np.uint16))
    assert "millimetres by definition" in error(load_depth, png, "m", (W, H))  # integers are never metres
    assert "unit must be 'mm' or 'm'" in error(load_depth, png, "cm", (W, H))


def test_depth_of_the_wrong_size(tmp_path):
    np.save(tmp_path / "d.npy", depth_scene(64, 48).astype(np.float32))
    message = error(load_depth, tmp_path / "d.npy", "mm", (W, H))
    assert f"is 64 x 48 px but the image is {W} x {H} px" in message and "pixel for pixel" in message
    np.save(tmp_path / "t.npy", depth_scene(H, W).astype(np.float32))
    assert "before the image's EXIF rotation" in error(load_depth, tmp_path / "t.npy", "mm", (W, H), rotated=True)
    assert "width and height are swapped" in error(load_depth, tmp_path / "t.npy", "mm", (W, H))  # no rotation


def test_intrinsics_with_width_and_height_swapped_are_not_blamed_on_a_rotation(tmp_path):
    photo = save(tmp_path / "p.png", quadrants())  # no EXIF orientation
    k = write_k(tmp_path, width=H, height=W, cx=35.5, cy=47.5)
    message = error(load_photo, photo, intrinsics=k)
    assert "width and height are swapped" in message and "EXIF" not in message


def test_intrinsics_json_that_is_deeply_nested_or_has_huge_numbers(tmp_path):
    (tmp_path / "deep.json").write_text("[" * 60000)
    assert "not valid JSON" in error(load_intrinsics, tmp_path / "deep.json", (W, H))
    path = write_k(tmp_path)
    for huge in ("9" * 5001, "9" * 5001 + ".0"):
        path.write_text(json.dumps({**GOOD_K, "fx": 1}).replace('"fx": 1', '"fx": ' + huge))
        message = error(load_intrinsics, path, (W, H))
        assert "'fx' is not a usable number" in message and str(path) in message and "4300" not in message


def test_depth_with_too_few_valid_pixels(tmp_path):
    sparse = np.zeros((H, W), np.uint16)
    sparse[0, :60] = 500  # 60 of 6912 pixels: 0.87 %
    message = error(load_depth, save(tmp_path / "sparse.png", sparse), "mm", (W, H))
    assert "sparse.png has only 0.87 % valid pixels" in message
    sparse[1, :20] = 500  # 80 pixels: 1.16 %, enough
    assert (load_depth(save(tmp_path / "ok.png", sparse), "mm", (W, H)) > 0).sum() == 80


def test_depth_files_that_cannot_be_depth(tmp_path):
    mm = depth_scene()
    assert "8-bit image" in error(load_depth, save(tmp_path / "d8.png", (mm / 4).astype(np.uint8)), "mm", (W, H))
    assert "3 channels" in error(load_depth, save(tmp_path / "rgb.png", quadrants()), "mm", (W, H))
    np.save(tmp_path / "obj.npy", np.array([{"depth": 1}], dtype=object), allow_pickle=True)
    assert "not a readable .npy" in error(load_depth, tmp_path / "obj.npy", "mm", (W, H))
    np.save(tmp_path / "rgbd.npy", np.zeros((H, W, 4), np.float32))
    assert "shape (72, 96, 4)" in error(load_depth, tmp_path / "rgbd.npy", "mm", (W, H))
    np.save(tmp_path / "b.npy", mm > 0)
    assert "dtype bool" in error(load_depth, tmp_path / "b.npy", "mm", (W, H))
    np.savez(tmp_path / "d.npz", depth=mm)
    assert "numpy.save" in error(load_depth, tmp_path / "d.npz", "mm", (W, H))
    (tmp_path / "notes.txt").write_text("depth")
    assert "notes.txt is not an image" in error(load_depth, tmp_path / "notes.txt", "mm", (W, H))


# --- intrinsics -----------------------------------------------------------------------------------------------

GOOD_K = {"fx": 80.0, "fy": 81.0, "cx": 47.0, "cy": 36.5, "width": W, "height": H}


def write_k(tmp_path, name="K.json", **changes):
    k = {**GOOD_K, **changes}
    path = tmp_path / name
    path.write_text(json.dumps({key: v for key, v in k.items() if v is not None}))
    return path


def test_intrinsics_file(tmp_path):
    k = load_intrinsics(write_k(tmp_path), (W, H))
    np.testing.assert_array_equal(k.matrix(), [[80, 0, 47], [0, 81, 36.5], [0, 0, 1]])
    assert (k.source, k.size) == ("file", (W, H)) and "K.json" in k.note
    assert json.loads(json.dumps(k.to_dict()))["source"] == "file"


def test_intrinsics_taken_before_the_exif_rotation(tmp_path):
    photo = save(tmp_path / "p.jpg", quadrants(), "JPEG", exif=exif(6))  # upright: H x W
    k = write_k(tmp_path)  # for the stored W x H frame
    message = error(load_photo, photo, intrinsics=k)
    assert f"is for a {W} x {H} px image but the image is {H} x {W} px" in message
    assert "before the image's EXIF rotation" in message
    upright = write_k(tmp_path, "Ku.json", width=H, height=W, cx=35.5, cy=47.5)
    assert load_photo(photo, intrinsics=upright).intrinsics.size == (H, W)


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        ({"fy": None}, "missing fy"),
        ({"fx": "80"}, "'fx' must be a number, got \"80\""),
        ({"width": True}, "'width' must be a number"),
        ({"fx": -80.0}, "'fx' must be positive"),
        ({"fy": float("nan")}, "'fy' must be finite"),
        ({"width": 96.5}, "whole number of pixels"),
        ({"cx": 96.0}, "cx = 96.0 px is outside the image"),
        ({"cy": -1}, "cy = -1 px is outside the image"),
        ({"fx": 2.0, "fy": 2.0}, "175.2 degree field of view; they must be in pixels, not millimetres"),
        ({"width": 192, "height": 144}, "same aspect ratio, so scale fx, fy, cx, cy by 0.5"),
        ({"width": 100}, "is for a 100 x 72 px image but the image is 96 x 72 px"),
    ],
)
def test_bad_intrinsics_files(tmp_path, changes, expected):
    path = write_k(tmp_path, **changes)
    message = error(load_intrinsics, path, (W, H))
    assert expected in message and message.startswith(f"intrinsics file {path}")


def test_a_calibration_file_with_extra_keys_and_lens_distortion_is_used(tmp_path):
    image = tmp_path / "p.png"
    Image.fromarray(quadrants()).save(image)
    plain = load_photo(image)
    photo = load_photo(image, intrinsics=write_k(tmp_path, depth_unit_mm=1.0, dist=[-0.2, 0.05, 0.0, 0.0, 0.0]))
    assert photo.intrinsics.fx == 80 and photo.rgb.shape == plain.rgb.shape
    assert "ignored key 'depth_unit_mm' in K.json" in photo.info.notes
    assert any(n.startswith("lens distortion (-0.2, 0.05, 0, 0, 0) removed") for n in photo.info.notes)
    centre = (slice(H // 2 - 4, H // 2 + 4), slice(W // 2 - 4, W // 2 + 4))
    assert (photo.rgb != plain.rgb).any(axis=2).sum() > 100  # the quadrants' edges moved
    assert (photo.rgb[centre] == plain.rgb[centre]).all()  # but not at the principal point


def test_intrinsics_files_that_are_not_json_objects(tmp_path):
    (tmp_path / "a.json").write_text('{"fx": 80,')
    assert "not valid JSON" in error(load_intrinsics, tmp_path / "a.json", (W, H))
    (tmp_path / "b.json").write_text("[[80, 0, 47], [0, 80, 36], [0, 0, 1]]")
    assert "must hold a JSON object" in error(load_intrinsics, tmp_path / "b.json", (W, H))


def test_intrinsics_from_exif_35mm_focal_length(tmp_path):
    # 120 x 90 px: diagonal 150 px, so f = 28 * 150 / 43.27 px
    photo = load_photo(save(tmp_path / "p.jpg", quadrants(120, 90), "JPEG", exif=exif(f35=28)))
    k = photo.intrinsics
    assert k.source == "exif" and "FocalLengthIn35mmFilm = 28 mm" in k.note
    assert k.fx == pytest.approx(28 * 150 / 43.27, rel=1e-4) and k.fy == k.fx
    assert (k.cx, k.cy) == (59.5, 44.5)  # the centre of a 120 x 90 image, pixel centres at integers


def test_default_intrinsics_without_file_or_exif(tmp_path):
    photo = load_photo(save(tmp_path / "p.png", quadrants(120, 90)))
    k = photo.intrinsics
    assert k.source == "default" and f"{DEFAULT_FOCAL_35MM:g} mm-equivalent" in k.note
    assert k.fx == pytest.approx(26 * 150 / 43.27, rel=1e-4)
    horizontal, _ = k.fov_deg()
    assert 60 < horizontal < 75  # what a phone's main camera sees across its long side
    # an implausible EXIF value is ignored, and said so
    photo = load_photo(save(tmp_path / "q.jpg", quadrants(120, 90), "JPEG", exif=exif(f35=2)))
    assert photo.intrinsics.source == "default" and any("implausible" in n for n in photo.info.notes)
    assert default_intrinsics(120, 90, 28.0).source == "exif"


def test_resized_and_cropped_intrinsics_project_like_the_resized_and_cropped_image():
    k = Intrinsics(1000.0, 1010.0, 2015.3, 1508.7, 4032, 3024)
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(-200, 200, (50, 2)), rng.uniform(300, 900, 50)])  # camera frame, mm

    def project(kk: Intrinsics) -> np.ndarray:
        uvw = points @ kk.matrix().T
        return uvw[:, :2] / uvw[:, 2:]

    uv = project(k)
    small = k.resized(1008, 756)
    # the pixel grid scales about the image's outer corner (-0.5, -0.5), not the first pixel centre
    np.testing.assert_allclose(project(small), (uv + 0.5) * 0.25 - 0.5, atol=1e-9)
    assert small.size == (1008, 756)
    crop = k.cropped(100, 200, 640, 480)
    np.testing.assert_allclose(project(crop), uv - (100, 200), atol=1e-9)
    back = small.resized(4032, 3024)
    np.testing.assert_allclose(back.matrix(), k.matrix(), atol=1e-9)
    with pytest.raises(ValueError, match="fx"):
        Intrinsics(0.0, 1.0, 1.0, 1.0, 10, 10)


# --- everything at once ---------------------------------------------------------------------------------------


def test_load_photo_with_depth_and_intrinsics(tmp_path):
    image = save(tmp_path / "rgbd.jpg", quadrants(), "JPEG", exif=exif(8, f35=24))  # upright: H x W
    upright_depth = depth_scene(H, W)  # aligned with the upright image
    np.save(tmp_path / "depth.npy", (upright_depth / 1000).astype(np.float32))
    k = write_k(tmp_path, width=H, height=W, cx=35.5, cy=47.5)
    photo = load_photo(image, tmp_path / "depth.npy", "m", k)
    assert photo.rgb.shape == (W, H, 3) and photo.depth_mm.shape == (W, H) and photo.size == (H, W)
    np.testing.assert_allclose(photo.depth_mm, upright_depth, rtol=1e-6)
    assert photo.intrinsics.source == "file"  # the file wins over EXIF
    sha = {name: hashlib.sha256(p.read_bytes()).hexdigest() for name, p in
           [("image", image), ("depth", tmp_path / "depth.npy"), ("intrinsics", k)]}  # fmt: skip
    assert photo.input_sha256 == sha and photo.sha256 == sha["image"] and photo.path == image
    assert "rgbd.jpg" in repr(photo) and "depth 72x96 mm" in repr(photo)
    # the depth in the stored (not upright) frame is refused, with the reason
    np.save(tmp_path / "raw.npy", depth_scene().astype(np.float32))
    assert "before the image's EXIF rotation" in error(load_photo, image, tmp_path / "raw.npy")


def test_load_photo_without_depth_hashes_only_the_image(tmp_path):
    image = save(tmp_path / "p.png", quadrants())
    photo = load_photo(image)
    assert photo.depth_mm is None and set(photo.input_sha256) == {"image"}
    assert math.isclose(photo.intrinsics.cx, (W - 1) / 2)
