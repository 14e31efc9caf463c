"""Seeded mutations of real input files: the loader and the web's upload checks answer each one with their own
one-line error or a result, never another exception (issue 23: 20,000 mutations found tracebacks in TIFF pages).

Bounded: ``MUTATIONS`` per file kind, a few seconds in all."""

from __future__ import annotations

import io
import json
import os
import zlib

import numpy as np
import pytest
from PIL import Image

from footmesh.load import LoadError, load_image, load_intrinsics, load_photo

MUTATIONS = int(os.environ.get("FOOTMESH_FUZZ_MUTATIONS", "150"))
"""Per file kind; set the variable for a longer run (e.g. 5000)."""
W, H = 96, 72


def _image(fmt: str, **kw) -> bytes:
    rng = np.random.default_rng(0)
    pixels = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    if fmt == "TIFF-pages":
        first, second = Image.fromarray(pixels), Image.fromarray(pixels[::-1].copy())
        first.save(buffer, "TIFF", save_all=True, append_images=[second])
    else:
        Image.fromarray(pixels).save(buffer, fmt, **kw)
    return buffer.getvalue()


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One random change: bytes flipped, a cut, a run duplicated or bytes inserted (what fuzzers do first)."""
    data = bytearray(data)
    kind = rng.integers(4)
    if kind == 0:
        for at in rng.integers(0, len(data), size=int(rng.integers(1, 9))):
            data[at] ^= 1 << int(rng.integers(8))
    elif kind == 1:
        data = data[: int(rng.integers(1, len(data)))]
    elif kind == 2:
        start = int(rng.integers(0, len(data)))
        data[start:start] = data[start : start + int(rng.integers(1, 64))]
    else:
        at = int(rng.integers(0, len(data)))
        data[at:at] = rng.integers(0, 256, int(rng.integers(1, 16)), dtype=np.uint8).tobytes()
    return bytes(data)


@pytest.mark.parametrize("fmt", ["JPEG", "PNG", "TIFF-pages", "WEBP", "BMP"])
def test_mutated_images_load_or_fail_with_a_load_error(tmp_path, fmt):
    original = _image(fmt)
    rng = np.random.default_rng(zlib.crc32(fmt.encode()))  # str hash() changes between runs
    path = tmp_path / "photo.bin"
    refused = 0
    for _ in range(MUTATIONS):
        path.write_bytes(mutate(original, rng))
        try:
            rgb, _ = load_image(path)
        except LoadError as exc:
            refused += 1
            assert "\n" not in str(exc) and str(path) in str(exc)
        else:
            assert rgb.dtype == np.uint8 and rgb.ndim == 3
    assert refused  # the mutations do reach the error paths


def test_mutated_intrinsics_and_depth_fail_with_a_load_error(tmp_path):
    photo = tmp_path / "p.png"
    photo.write_bytes(_image("PNG"))
    k = json.dumps({"fx": 80.0, "fy": 80.0, "cx": 47.5, "cy": 35.5, "width": W, "height": H}).encode()
    depth = io.BytesIO()
    np.save(depth, np.full((H, W), 600.0, np.float32))
    rng = np.random.default_rng(7)
    for _ in range(MUTATIONS):
        (tmp_path / "K.json").write_bytes(mutate(k, rng))
        (tmp_path / "d.npy").write_bytes(mutate(depth.getvalue(), rng))
        for load in (
            lambda: load_intrinsics(tmp_path / "K.json", (W, H)),
            lambda: load_photo(photo, depth=tmp_path / "d.npy"),
        ):
            try:
                load()
            except LoadError as exc:
                assert "\n" not in str(exc)


def test_mutated_uploads_are_accepted_or_refused_with_a_status(tmp_path):
    from footmesh.web import uploads

    rng = np.random.default_rng(11)
    originals = [_image("JPEG"), _image("PNG"), _image("TIFF-pages")]
    path = tmp_path / "photo.upload"
    for i in range(MUTATIONS):
        path.write_bytes(mutate(originals[i % len(originals)], rng))
        try:
            checked = uploads.check_photo(path, 10_000_000)
        except uploads.UploadError as exc:
            assert exc.status in (400, 413, 415) and str(tmp_path) not in str(exc)
        else:
            checked.path.rename(path)  # back under the upload's name for the next mutation
