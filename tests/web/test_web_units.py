"""Pieces of the web app on their own: content checks of uploads, the result store, settings, the serve command."""

from __future__ import annotations

import argparse
import io
import json
import struct
import time

import numpy as np
import pillow_heif
import pytest
from PIL import Image

from footmesh.web import uploads
from footmesh.web.settings import WebSettings
from footmesh.web.store import ResultStore


def write(path, data: bytes):
    path.write_bytes(data)
    return path


def image_bytes(fmt: str, size=(40, 30), mode="RGB") -> bytes:
    if fmt == "HEIF":  # Pillow writes no HEIF itself
        buffer = io.BytesIO()
        pillow_heif.from_pillow(Image.new(mode, size, 90)).save(buffer, quality=90)
        return buffer.getvalue()
    buffer = io.BytesIO()
    if fmt == "MPO":  # a phone's JPEG with a multi-picture index (a second, smaller picture)
        Image.new(mode, size, 90).save(buffer, format="MPO", save_all=True, append_images=[Image.new(mode, (8, 6))])
        return buffer.getvalue()
    Image.new(mode, size, 90).save(buffer, format=fmt)
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("fmt", "suffix"),
    [
        ("JPEG", ".jpg"),
        ("MPO", ".jpg"),
        ("PNG", ".png"),
        ("WEBP", ".webp"),
        ("TIFF", ".tiff"),
        ("HEIF", ".heic"),
        ("BMP", ".bmp"),
    ],
)
def test_photo_formats_get_their_own_suffix(tmp_path, fmt, suffix):
    checked = uploads.check_photo(write(tmp_path / "photo.upload", image_bytes(fmt)), max_pixels=10_000)
    assert (checked.kind, checked.path.suffix, checked.width, checked.height) == (fmt, suffix, 40, 30)
    assert checked.path.parent == tmp_path and checked.path.exists()


def test_photo_refusals(tmp_path):
    with pytest.raises(uploads.UploadError, match="GIF") as gif:
        uploads.check_photo(write(tmp_path / "a.upload", image_bytes("GIF")), 10_000)
    assert gif.value.status == 415
    with pytest.raises(uploads.UploadError, match="megapixels") as big:
        uploads.check_photo(write(tmp_path / "b.upload", image_bytes("PNG", (200, 100))), 10_000)
    assert big.value.status == 413
    png = image_bytes("PNG", (200, 100))
    with pytest.raises(uploads.UploadError, match="corrupt") as cut:
        uploads.check_photo(write(tmp_path / "c.upload", png[: len(png) - 30]), 100_000)
    assert cut.value.status == 400
    heic = image_bytes("HEIF", (200, 100))
    with pytest.raises(uploads.UploadError, match="corrupt") as cut:
        uploads.check_photo(write(tmp_path / "d.upload", heic[: len(heic) // 2]), 100_000)
    assert cut.value.status == 400


def test_save_upload_limits(tmp_path):
    assert uploads.save_upload(io.BytesIO(b"x" * 100), tmp_path / "ok", 100, "photo").read_bytes() == b"x" * 100
    with pytest.raises(uploads.UploadError, match="larger than 1 KB") as big:
        uploads.save_upload(io.BytesIO(b"x" * 2000), tmp_path / "big", 1024, "photo")
    assert big.value.status == 413
    with pytest.raises(uploads.UploadError, match="empty") as empty:
        uploads.save_upload(io.BytesIO(b""), tmp_path / "empty", 1024, "photo")
    assert empty.value.status == 400


def test_depth_npy(tmp_path):
    def npy(array) -> bytes:
        buffer = io.BytesIO()
        np.save(buffer, array)
        return buffer.getvalue()

    ok = uploads.check_depth(write(tmp_path / "d1.upload", npy(np.ones((30, 40), np.float32))), 10_000)
    assert (ok.kind, ok.path.suffix, ok.width, ok.height) == ("NPY", ".npy", 40, 30)
    assert uploads.check_depth(write(tmp_path / "d2.upload", npy(np.ones((30, 40, 1), np.uint16))), 10_000).width == 40
    for array, message in [
        (np.array([{"a": 1}], dtype=object), "numbers"),
        (np.ones((2, 30, 40)), "2D"),
        (np.ones((300, 400)), "megapixels"),
    ]:
        with pytest.raises(uploads.UploadError, match=message):
            uploads.check_depth(write(tmp_path / "bad.upload", npy(array)), 10_000)
    truncated = npy(np.ones((30, 40), np.float32))[:-100]
    with pytest.raises(uploads.UploadError, match="truncated"):
        uploads.check_depth(write(tmp_path / "cut.upload", truncated), 10_000)


def test_depth_png_accepted_and_exr_refused_as_the_loader_refuses_it(tmp_path):
    png = io.BytesIO()
    Image.fromarray(np.full((30, 40), 700, np.uint16)).save(png, format="PNG")
    checked = uploads.check_depth(write(tmp_path / "d.upload", png.getvalue()), 10_000)
    assert (checked.kind, checked.width, checked.height) == ("PNG", 40, 30)
    exr = uploads.EXR_MAGIC + struct.pack("<i", 2) + b"compression\0compression\0" + struct.pack("<i", 1) + bytes(65)
    with pytest.raises(uploads.UploadError, match="OpenEXR .* numpy.save") as refused:
        uploads.check_depth(write(tmp_path / "e.upload", exr), 10_000)
    assert refused.value.status == 415 and "16-bit PNG or TIFF" in str(refused.value)


def test_the_web_and_the_loader_accept_the_same_formats(tmp_path):
    """One table (formats.accepted): every photo the upload check takes, the loader reads, and the reverse."""
    from footmesh.load import LoadError, load_image

    for fmt in ("JPEG", "MPO", "PNG", "WEBP", "TIFF", "HEIF", "BMP", "GIF", "ICO", "TGA"):
        path = write(tmp_path / f"{fmt}.upload", image_bytes(fmt, (96, 72)))
        try:
            load_image(path)
            loads = True
        except LoadError as exc:
            loads = False
            assert "footmesh reads a JPEG, PNG" in str(exc)
        try:
            uploads.check_photo(path, 100_000)
            uploaded = True
        except uploads.UploadError:
            uploaded = False
        assert loads == uploaded == (fmt not in ("GIF", "ICO", "TGA")), fmt


def test_intrinsics(tmp_path):
    k = {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0}
    checked = uploads.check_intrinsics(write(tmp_path / "k.upload", json.dumps(k).encode()))
    assert checked.path.name == "k.json" and json.loads(checked.path.read_text()) == k
    yaml = b"%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
    yaml += b"  data: [80, 0, 47, 0, 80, 36, 0, 0, 1]\n"
    checked = uploads.check_intrinsics(write(tmp_path / "cal.upload", yaml))
    assert (checked.kind, checked.path.name, checked.path.read_bytes()) == ("YAML", "cal.yml", yaml)
    for data, message in [(b"[1, 2]", "object"), (b'{"fx": Infinity}', "Infinity"), (b"\xff\xfe", "not text")]:
        with pytest.raises(uploads.UploadError, match=message):
            uploads.check_intrinsics(write(tmp_path / "bad.upload", data))


def test_describe():
    assert uploads.describe(b"%PDF-1.4") == "a PDF document"
    assert "HEIC" in uploads.describe(b"\0\0\0\x18ftypheic")
    assert uploads.describe(b"<html><body>") == "a text file (HTML, XML, SVG or JSON)"
    assert uploads.describe(bytes(range(128, 160))) == "an unknown binary format"


# ----------------------------------------------------------------------------------------------------------


def make_output(folder, names=("mesh.obj", "result.json")):
    folder.mkdir(exist_ok=True)
    for name in names:
        (folder / name).write_text(name)
    return folder


def test_store_add_get_and_refuse_unsafe_names(tmp_path):
    store = ResultStore(tmp_path)
    out = make_output(tmp_path / "out")
    (tmp_path / "secret.txt").write_text("secret")
    (out / "link.obj").symlink_to(tmp_path / "secret.txt")
    result = {"files": {"mesh_obj": "mesh.obj", "result_json": "result.json", "up": "../secret.txt", "l": "link.obj"}}
    rid = store.add(result, out)
    assert store.get(rid).result == result
    assert store.file(rid, "mesh.obj").read_text() == "mesh.obj"
    assert store.file(rid, "mesh.obj").parent.parent == store.root
    for name in ("../secret.txt", "link.obj", "missing.glb"):
        assert store.file(rid, name) is None
    assert store.get("../../etc") is None and store.get(rid[:-1]) is None
    store.close()
    assert not store.root.exists()


def test_store_writes_result_json_when_not_listed(tmp_path):
    store = ResultStore(tmp_path)
    rid = store.add({"files": {}, "side": "left"}, make_output(tmp_path / "out", ()))
    assert json.loads(store.file(rid, "result.json").read_text()) == {"files": {}, "side": "left"}


def test_store_expiry_and_capacity(tmp_path):
    store = ResultStore(tmp_path, ttl_s=0.2, max_entries=2)
    rids = [store.add({"files": {}}, make_output(tmp_path / f"out{i}", ())) for i in range(3)]
    assert store.get(rids[0]) is None and len(store) == 2  # the oldest went first
    assert not (store.root / rids[0]).exists()
    time.sleep(0.25)
    assert store.get(rids[2]) is None and store.sweep() >= 0 and len(store) == 0
    assert list(store.root.iterdir()) == []


# ----------------------------------------------------------------------------------------------------------


def test_settings_are_checked():
    with pytest.raises(ValueError, match="workers"):
        WebSettings(workers=0)
    with pytest.raises(ValueError, match="isolation"):
        WebSettings(isolation="none")
    with pytest.raises(ValueError, match="queue"):
        WebSettings(queue=-1)


def test_serve_command_arguments():
    from footmesh.errors import InputError
    from footmesh.web.cli import add_serve_command, run_serve, settings_from_args

    parser = argparse.ArgumentParser()
    add_serve_command(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["serve", "--port", "8123", "--workers", "2", "--max-upload-mb", "5", "--time-limit", "9"])
    settings = settings_from_args(args)
    assert (args.host, args.port) == ("127.0.0.1", 8123)
    assert (settings.workers, settings.max_upload_bytes, settings.time_limit_s) == (2, 5 * 2**20, 9.0)
    assert settings.allowed_hosts == ("127.0.0.1", "localhost", "::1")  # this machine only, by default
    named = settings_from_args(parser.parse_args(["serve", "--host", "192.168.1.5", "--allowed-host", "feet.example"]))
    assert named.allowed_hosts[-2:] == ("192.168.1.5", "feet.example")
    with pytest.raises(InputError, match="port"):
        run_serve(parser.parse_args(["serve", "--port", "0"]))
    with pytest.raises(ValueError, match="workers"):
        run_serve(parser.parse_args(["serve", "--workers", "0"]))


def test_only_input_errors_and_refusals_are_the_users_fault():
    from footmesh.errors import InputError, Refusal
    from footmesh.web.jobs import _classify

    assert _classify(Refusal("no foot found in the photo", "take it from above")) == (
        "input",
        "no foot found in the photo; take it from above",
    )
    assert _classify(InputError("depth map d.png is 8-bit"))[0] == "input"
    # a bare ValueError from inside a stage is a broken contract of footmesh, not a fault of the photo
    kind, message = _classify(ValueError("operands could not be broadcast together"))
    assert kind == "crash" and "broadcast" in message
    kind, message = _classify(np.linalg.LinAlgError("SVD did not converge"))
    assert kind == "crash" and "LinAlgError" in message  # 500 and the server log, never a 422 blaming the photo
