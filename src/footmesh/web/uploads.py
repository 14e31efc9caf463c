"""Checking uploaded files by their content (never their name): photos, depth maps and intrinsics.

Every upload is copied into the request's own temporary folder under a name chosen here (``photo.jpg``,
``depth.npy``, ``intrinsics.json``); the client's file name is never used on disk. A file is accepted only when
its bytes are one of the accepted formats, its pixel count (read from the header, before decoding) is within
the limit, and it decodes completely.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from PIL import Image, UnidentifiedImageError

from footmesh.formats import accepted, heif
from footmesh.formats.accepted import FileFormat

PHOTO_FORMATS: dict[str, str] = {name: f.suffix for f in accepted.PHOTO_FORMATS for name in f.image_formats}
"""Accepted photo formats (Pillow's names, ``formats.accepted``) -> the suffix the saved file gets."""
DEPTH_IMAGE_FORMATS: dict[str, str] = {name: f.suffix for f in accepted.DEPTH_IMAGE_FORMATS for name in f.image_formats}
"""Depth maps as images (16-bit PNG in mm, or TIFF); ``.npy`` is recognised separately."""
NPY_MAGIC = accepted.NPY.signatures[0][1]
EXR_MAGIC = b"\x76\x2f\x31\x01"
COPY_CHUNK = 1 << 20
PHOTO_KINDS = accepted.listed(accepted.PHOTO_FORMATS, "image")
DEPTH_KINDS = accepted.DEPTH_HELP

# What a rejected file looks like, to say so in the message (first bytes -> description).
_SIGNATURES: tuple[tuple[int, bytes, str], ...] = (
    (0, b"%PDF", "a PDF document"),
    (0, b"PK\x03\x04", "a ZIP archive or an office document"),
    (0, b"GIF8", "a GIF image"),
    (0, EXR_MAGIC, "an OpenEXR image (not read: save the depth with numpy.save, as .npy)"),
    (4, b"ftypheic", "a HEIC photo"),
    (4, b"ftypheix", "a HEIC photo"),
    (4, b"ftypmif1", "a HEIF photo"),
    (4, b"ftypavif", "an AVIF image (export it as JPEG or HEIC)"),
    (4, b"ftyp", "a video or MP4/MOV file"),
    (0, b"\x1f\x8b", "a gzip archive"),
)


class UploadError(Exception):
    """A bad upload: ``status`` is the HTTP status to answer, ``str(exc)`` a one-line message for the user."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class CheckedFile:
    """An accepted upload: where it lies (in the request's temporary folder), its format and size in pixels."""

    path: Path
    kind: str
    width: int | None = None
    height: int | None = None


def describe(head: bytes) -> str:
    """A short description of what the first bytes of a file look like, for error messages."""
    for offset, magic, what in _SIGNATURES:
        if head[offset : offset + len(magic)] == magic:
            return what
    stripped = head.lstrip()
    if stripped[:1] in (b"<", b"{", b"["):
        return "a text file (HTML, XML, SVG or JSON)"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return "an unknown binary format"
    return "a text file" if text and text.isprintable() or "\n" in text else "an unknown binary format"


def save_upload(source: BinaryIO, dest: Path, max_bytes: int, what: str) -> Path:
    """Copy an uploaded stream to ``dest`` (a path of our choosing), refusing more than ``max_bytes``.

    Raises:
        UploadError: 400 for an empty file, 413 for one over the limit.
    """
    copied = 0
    with open(dest, "wb") as out:
        while chunk := source.read(COPY_CHUNK):
            copied += len(chunk)
            if copied > max_bytes:
                raise UploadError(413, f"the {what} is larger than {format_bytes(max_bytes)}")
            out.write(chunk)
    if copied == 0:
        raise UploadError(400, f"the {what} is an empty file")
    return dest


def check_photo(path: Path, max_pixels: int) -> CheckedFile:
    """Accept a JPEG, PNG, WebP, TIFF or HEIC/HEIF photo of at most ``max_pixels`` that decodes completely.

    Renames the file to the suffix of its real format. Raises ``UploadError`` 415 (not an accepted image),
    413 (too many pixels) or 400 (corrupt or truncated).
    """
    # always: PIL tries every format named, HEIF too when a corrupt JPEG fails, and an unregistered one raises
    # KeyError (a corrupt JPEG got 500 from a server that had not read a HEIC yet)
    heif.register()
    kind, width, height = _check_image(path, accepted.PHOTO_FORMATS, max_pixels, "photo", PHOTO_KINDS)
    return CheckedFile(_rename(path, PHOTO_FORMATS[kind]), kind, width, height)


def check_depth(path: Path, max_pixels: int) -> CheckedFile:
    """Accept a depth map: 16-bit PNG or TIFF, or ``.npy`` (2D numbers), of at most ``max_pixels``
    (``formats.accepted.DEPTH_FORMATS``, what the loader reads).

    Units are not checked here (the pipeline does, with the declared unit). Raises ``UploadError``.
    """
    head = _head(path)
    if head.startswith(NPY_MAGIC):
        height, width = _npy_size(path)
        _check_pixels(width, height, max_pixels, "depth map")
        return CheckedFile(_rename(path, ".npy"), "NPY", width, height)
    kind, width, height = _check_image(path, accepted.DEPTH_IMAGE_FORMATS, max_pixels, "depth map", DEPTH_KINDS)
    return CheckedFile(_rename(path, DEPTH_IMAGE_FORMATS[kind]), kind, width, height)


def check_intrinsics(path: Path) -> CheckedFile:
    """Accept camera intrinsics: a JSON object (rewritten as plain JSON), or an OpenCV YAML / XML calibration
    file (kept as it is); the pipeline checks what they hold (``footmesh.formats.camera``)."""
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise UploadError(400, f"the intrinsics file is not text; it looks like {describe(_head(path))}") from None
    if "\x00" in text:
        raise UploadError(400, "the intrinsics file is not text (it holds NUL characters)")
    stripped = text.lstrip()
    if stripped and stripped[0] not in "{[":  # not JSON: YAML (OpenCV, ROS) or OpenCV XML
        return CheckedFile(
            _rename(path, ".xml" if stripped[0] == "<" else ".yml"), "XML" if stripped[0] == "<" else "YAML"
        )
    try:
        data = json.loads(text, parse_constant=_no_constant)
    except ValueError as exc:  # JSONDecodeError, NaN / Infinity, an integer of more than 4,300 digits
        raise UploadError(400, f"the intrinsics file is not valid JSON: {exc}"[:300]) from None
    except RecursionError:
        raise UploadError(400, "the intrinsics file is not valid JSON: nested too deeply") from None
    if not isinstance(data, dict):
        raise UploadError(400, f"the intrinsics file must hold a JSON object, got {type(data).__name__}")
    out = _rename(path, ".json")
    out.write_text(json.dumps(data))
    return CheckedFile(out, "JSON")


# ----------------------------------------------------------------------------------------------------------


def _check_image(
    path: Path, formats: tuple[FileFormat, ...], max_pixels: int, what: str, kinds: str
) -> tuple[str, int, int]:
    names = accepted.pillow_names(formats)
    try:
        img = Image.open(path, formats=list(names))
    except UnidentifiedImageError:
        # a file that starts like an accepted format but does not open is corrupt (400), not foreign (415)
        head = _head(path)
        started = accepted.started_like(head, formats)
        if started is not None:
            message = f"the {what} starts like a {started.name} file but could not be read (corrupt?)"
            raise UploadError(400, message) from None
        raise UploadError(415, f"the {what} must be {kinds}; this file looks like {describe(head)}") from None
    except Image.DecompressionBombError:
        limit = 2 * Image.MAX_IMAGE_PIXELS / 1e6
        raise UploadError(413, f"the {what} has more than {limit:.4g} MP; downscale it") from None
    except (OSError, SyntaxError, ValueError) as exc:
        reason = str(exc).replace(str(path), f"the {what}")  # never a server path
        raise UploadError(400, f"the {what} could not be read (corrupt file?): {reason}") from None
    with img:
        kind = img.format
        width, height = img.size
        _check_pixels(width, height, max_pixels, what)
        try:
            img.load()  # decode everything now: a truncated file fails here, not in the pipeline
        except (OSError, SyntaxError, ValueError, EOFError) as exc:
            raise UploadError(400, f"the {what} could not be decoded (corrupt or truncated file?): {exc}") from None
    if accepted.format_of(kind, formats) is None:  # Pillow's formats= filter makes this impossible; kept as a guard
        raise UploadError(415, f"the {what} must be {kinds}, got {kind}")
    return kind, width, height


def _check_pixels(width: int, height: int, max_pixels: int, what: str) -> None:
    if width < 1 or height < 1:
        raise UploadError(400, f"the {what} has no pixels ({width} x {height})")
    if width * height > max_pixels:
        raise UploadError(
            413,
            f"the {what} is {width} x {height} = {width * height / 1e6:.1f} megapixels; "
            f"the limit is {max_pixels / 1e6:.1f} megapixels",
        )


def _npy_size(path: Path) -> tuple[int, int]:
    """(height, width) of a 2D ``.npy`` array of numbers, from its header; checks the data is all there."""
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            fmt = np.lib.format
            read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, _, dtype = read_header(fh)
            data_start = fh.tell()
    except (ValueError, OSError, SyntaxError) as exc:
        raise UploadError(400, f"the depth map is not a readable .npy file: {exc}") from None
    if dtype.hasobject or dtype.kind not in "uif":
        raise UploadError(400, f"the depth map must hold numbers, got dtype {dtype}")
    if len(shape) == 3 and shape[2] == 1:
        shape = shape[:2]
    if len(shape) != 2:
        raise UploadError(400, f"the depth map must be a 2D array (H, W), got shape {shape}")
    height, width = (int(s) for s in shape)
    if height * width > 0 and path.stat().st_size < data_start + height * width * dtype.itemsize:
        raise UploadError(400, f"the depth map .npy file is truncated (header says {shape} {dtype})")
    return height, width


def _head(path: Path, n: int = 64) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)


def _rename(path: Path, suffix: str) -> Path:
    target = path.with_suffix(suffix)
    if target != path:
        shutil.move(path, target)
    return target


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number a camera can have")


def format_bytes(n: int) -> str:
    """``n`` bytes as "30 MB" or "200 KB"."""
    return f"{n / (1024 * 1024):.0f} MB" if n >= 1024 * 1024 else f"{n / 1024:.0f} KB"
