"""Load stage: a photo, an optional depth map and optional intrinsics -> arrays in the project's conventions.

Accepted inputs, limits and error messages: docs/load.md. In short:

- the image is identified by its content (never its name), decoded in full (a truncated file is an error, not a
  grey band), turned upright by its EXIF orientation and converted to ``(H, W, 3) uint8`` RGB; HEIC/HEIF is read
  through pillow-heif (``footmesh.formats.heif``);
- the depth map (16-bit PNG/TIFF in mm, or ``.npy``) must be aligned pixel for pixel with the *upright* image and
  becomes ``(H, W) float32`` mm with 0 = missing; its unit is declared and checked, never guessed. Without one, a
  metric depth map embedded in the photo (an iPhone HEIC's depth image, an Android depth JPEG) is used instead
  (``footmesh.formats``); a relative one is not, and ``ImageInfo.notes`` says why;
- the intrinsics come from a calibration file (K.json, OpenCV YAML / JSON / XML, ARKit, Record3D:
  ``footmesh.formats.camera``; its lens distortion is removed from the photo), else from EXIF
  ``FocalLengthIn35mmFilm``, else from a documented default
  (a 26 mm-equivalent phone main camera); ``Intrinsics.source`` says which.

Every problem with an input raises :class:`LoadError` (a ``ValueError``) with one sentence naming the file, so the
command line prints one line and exits 2 (``footmesh.cli.main``). Pixel coordinates follow docs/conventions.md:
the centre of the top-left pixel is ``(0, 0)`` and an image of width ``W`` spans ``-0.5 .. W - 0.5``.
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import logging
import math
import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from footmesh.errors import InputError
from footmesh.formats import accepted, heif
from footmesh.formats.embedded import DepthSource, align_depth
from footmesh.geometry.camera import Camera, rescale_pixels

log = logging.getLogger(__name__)

DepthUnit = Literal["mm", "m"]
IntrinsicsSource = Literal["file", "exif", "default"]

MAX_PIXELS = 50_000_000
"""Default largest image accepted, in pixels (width x height): a phone's 48-50 MP mode still fits."""
MIN_SIDE_PX = 64
"""Shortest image side accepted, px: below this there is no foot to find."""
MAX_FILE_BYTES = 1 << 30
"""Largest input file read into memory (1 GiB); anything bigger is not a photo or depth map of a foot."""
DEPTH_RANGE_MM = (100.0, 3000.0)
"""The median valid depth of a foot photo lies in this range (mm): 10 cm to 3 m from the camera."""
MIN_VALID_DEPTH_FRACTION = 0.01
"""A depth map with fewer valid pixels than this fraction of the image is refused (sensor failure or all zeros)."""
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
"""Diagonal of the 36 x 24 mm frame that 35 mm-equivalent focal lengths refer to (43.27 mm, CIPA DC-008)."""
DEFAULT_FOCAL_35MM = 26.0
"""35 mm-equivalent focal length assumed without K.json or EXIF: the main camera of most phones (24-28 mm)."""
FOCAL_35MM_RANGE = (10.0, 400.0)
"""EXIF 35 mm-equivalent focal lengths outside this range (mm) are taken for broken tags and ignored."""
MAX_FOV_DEG = 170.0
"""Intrinsics giving a wider field of view than this (degrees) are refused: fx or fy is not in pixels."""
INTRINSICS_KEYS = ("fx", "fy", "cx", "cy", "width", "height")
"""The keys of a K.json, all required (others are ignored with a note)."""

# EXIF tags (CIPA DC-008): orientation and camera in IFD0, focal lengths in the Exif sub-IFD
_EXIF_IFD = 0x8769
_TAG_ORIENTATION = 0x0112
_TAG_MAKE = 0x010F
_TAG_MODEL = 0x0110
_TAG_FOCAL_LENGTH = 0x920A
_TAG_FOCAL_35MM = 0xA405

_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = b"PK\x03\x04"
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_SIXTEEN_BIT_MODES = ("I;16", "I;16L", "I;16B", "I;16N")
_ALPHA_MODES = ("RGBA", "RGBa", "LA", "La", "PA")


class LoadError(InputError):
    """An input file that cannot be used; the message is one sentence naming the file."""


# --- results --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels of one image: ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.

    ``source`` is ``"file"`` (a K.json), ``"exif"`` (EXIF 35 mm-equivalent focal length) or ``"default"`` (assumed
    phone camera); ``note`` says the same for people.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    source: IntrinsicsSource = "file"
    note: str = ""

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"Intrinsics.{name} must be a positive finite number of pixels, got {value}")
        for name in ("cx", "cy"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"Intrinsics.{name} must be finite, got {getattr(self, name)}")
        if int(self.width) != self.width or int(self.height) != self.height or self.width < 1 or self.height < 1:
            raise ValueError(f"Intrinsics width and height must be positive integers, got {self.width} x {self.height}")
        if self.source not in ("file", "exif", "default"):
            raise ValueError(f"Intrinsics.source must be 'file', 'exif' or 'default', got {self.source!r}")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) px of the image these intrinsics belong to."""
        return self.width, self.height

    def matrix(self) -> np.ndarray:
        """(3, 3) float64 camera matrix K, px."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def camera(self) -> Camera:
        """The camera of the image (``geometry.camera.Camera``)."""
        return Camera(self.matrix(), int(self.width), int(self.height))

    def resized(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of this image resized to ``width x height`` px (the whole image, each axis scaled on its own)."""
        sx, sy = width / self.width, height / self.height
        return replace(
            self,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=rescale_pixels(self.cx, sx),
            cy=rescale_pixels(self.cy, sy),
            width=int(width),
            height=int(height),
        )

    def cropped(self, x0: int, y0: int, width: int, height: int) -> Intrinsics:
        """Intrinsics of the crop whose top-left pixel is ``(x0, y0)`` of this image, ``width x height`` px."""
        return replace(self, cx=self.cx - x0, cy=self.cy - y0, width=int(width), height=int(height))

    def fov_deg(self) -> tuple[float, float]:
        """(horizontal, vertical) field of view, degrees."""
        return (
            math.degrees(2 * math.atan(self.width / (2 * self.fx))),
            math.degrees(2 * math.atan(self.height / (2 * self.fy))),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: the six numbers of a K.json plus ``source`` and ``note``."""
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
            "source": self.source,
            "note": self.note,
        }


@dataclass(frozen=True)
class ImageInfo:
    """What the image file held besides its pixels, and what loading did to it."""

    path: Path
    format: str  # Pillow's name of the format found in the bytes: "JPEG", "PNG", "WEBP", "TIFF", ...
    mode: str  # Pillow mode as stored: "RGB", "I;16", "P", "RGBA", ...
    raw_size: tuple[int, int]  # (width, height) px as stored, before EXIF rotation
    size: tuple[int, int]  # (width, height) px after EXIF rotation: the size of ``rgb``
    orientation: int  # EXIF orientation 1..8 that was applied (1: none or absent)
    focal_length_35mm: float | None  # EXIF FocalLengthIn35mmFilm, mm (None: absent or unusable)
    focal_length_mm: float | None  # EXIF FocalLength, mm of the real lens (informative only)
    camera: str | None  # EXIF Make and Model
    sha256: str  # of the file's bytes
    notes: tuple[str, ...] = ()  # conversions made: bit depth reduced, alpha flattened, first frame of many, ...


@dataclass(frozen=True, eq=False)
class Photo:
    """One loaded photo: upright RGB, optional aligned depth (mm), intrinsics, and the inputs' hashes."""

    rgb: np.ndarray  # (H, W, 3) uint8
    depth_mm: np.ndarray | None  # (H, W) float32, camera z in mm, 0 = missing
    intrinsics: Intrinsics  # in pixels of ``rgb``
    info: ImageInfo
    input_sha256: dict[str, str]  # {"image": ..., "depth": ..., "intrinsics": ...}, only the inputs given
    depth_source: DepthSource | None = None  # where ``depth_mm`` came from (a file, or the photo's own depth map)

    @property
    def path(self) -> Path:
        """The image file."""
        return self.info.path

    @property
    def sha256(self) -> str:
        """SHA-256 (hex) of the image file's bytes."""
        return self.input_sha256["image"]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) px."""
        return self.rgb.shape[1], self.rgb.shape[0]

    def __repr__(self) -> str:
        depth = "none" if self.depth_mm is None else f"{self.depth_mm.shape[1]}x{self.depth_mm.shape[0]} mm"
        w, h = self.size
        return f"Photo({self.path.name}, {w}x{h} rgb, depth {depth}, intrinsics from {self.intrinsics.source})"


# --- files ----------------------------------------------------------------------------------------------------


def _read_bytes(path: str | os.PathLike, role: str) -> tuple[Path, bytes]:
    """The bytes of ``path``, or a LoadError saying in one sentence why there are none."""
    p = Path(path)
    try:
        if not p.exists():
            raise LoadError(_missing(role, p))
        if p.is_dir():
            raise LoadError(f"{role} {p} is a directory, not a file")
        size = p.stat().st_size
        if size == 0:
            raise LoadError(f"{role} {p} is empty (0 bytes)")
        if size > MAX_FILE_BYTES:
            raise LoadError(f"{role} {p} is {size / 2**20:.0f} MiB, more than the {MAX_FILE_BYTES >> 20} MiB accepted")
        data = p.read_bytes()
    except OSError as exc:
        raise LoadError(f"{role} {p} cannot be read: {exc.strerror or exc}") from exc
    if not data:  # a pipe or a file emptied meanwhile
        raise LoadError(f"{role} {p} is empty (0 bytes)")
    return p, data


def _missing(role: str, path: Path) -> str:
    """Why ``path`` (which does not exist as a file) cannot be read: a symbolic-link loop, a dangling link, or
    nothing there."""
    if path.is_symlink():
        try:
            path.resolve(strict=True)
        except RuntimeError:  # Python < 3.13 reports a loop so
            return f"{role} {path} is a symbolic-link loop"
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                return f"{role} {path} is a symbolic-link loop"
        return f"{role} {path} is a symbolic link to {os.readlink(path)}, which does not exist"
    return f"{role} {path} does not exist"


def sha256_hex(data: bytes) -> str:
    """SHA-256 of ``data`` as 64 hex digits."""
    return hashlib.sha256(data).hexdigest()


def _not_readable(role: str, path: Path, data: bytes) -> LoadError:
    """The error for bytes Pillow does not recognise, saying what they look like when that is known."""
    if data[4:8] == b"ftyp":
        return LoadError(
            f"{role} {path} is an ISO media file of brand {data[8:12]!r} (a video or an unsupported image), "
            "not a photo that can be read; accepted: JPEG, PNG, WebP, TIFF, BMP, GIF, AVIF, HEIC/HEIF"
        )
    return LoadError(
        f"{role} {path} is not an image that can be read (its first bytes are {data[:12]!r}); "
        "accepted: JPEG, PNG, WebP, TIFF, BMP, GIF, AVIF, HEIC/HEIF"
    )


def _too_many_pixels(role: str, path: Path, max_pixels: int) -> LoadError:
    """The error for an image past Pillow's own hard limit (its size is not known then)."""
    return LoadError(
        f"{role} {path} has more than {2 * Image.MAX_IMAGE_PIXELS / 1e6:.4g} MP, far more than the limit of "
        f"{max_pixels / 1e6:.1f} MP; downscale it"
    )


def _one_line(exc: BaseException) -> str:
    """``Type: message`` of a decoder's exception on one line (libheif's messages span several)."""
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:300]


def _open_image(data: bytes, path: Path, role: str, max_pixels: int) -> Image.Image:
    """Open and fully decode ``data`` (a truncated file fails here, not later), refusing more than ``max_pixels``."""
    if heif.is_heif(data):
        heif.register()
    with warnings.catch_warnings():
        # we apply our own pixel limit; Pillow's hard limit (2 x Image.MAX_IMAGE_PIXELS) still raises
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            im = Image.open(io.BytesIO(data))
        except Image.DecompressionBombError as exc:
            raise _too_many_pixels(role, path, max_pixels) from exc
        except UnidentifiedImageError as exc:
            raise _not_readable(role, path, data) from exc
        except Exception as exc:  # Pillow's plugins raise many types for a broken header
            raise LoadError(
                f"{role} {path} is truncated or corrupt (its header cannot be read: {_one_line(exc)})"
            ) from exc
        w, h = im.size
        if w * h > max_pixels:
            raise LoadError(
                f"{role} {path} is {w} x {h} px ({w * h / 1e6:.1f} MP), more than the limit of "
                f"{max_pixels / 1e6:.1f} MP; downscale it"
            )
        try:
            im.load()
        except Image.DecompressionBombError as exc:
            raise _too_many_pixels(role, path, max_pixels) from exc
        except Exception as exc:
            raise LoadError(f"{role} {path} is truncated or corrupt ({_one_line(exc)})") from exc
    return im


# --- image ----------------------------------------------------------------------------------------------------


def _positive_float(value: Any) -> float | None:
    """EXIF number (int, IFDRational, tuple) as a positive finite float, else None."""
    try:
        if isinstance(value, tuple) and len(value) == 2:  # (numerator, denominator) from some writers
            value = value[0] / value[1]
        f = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return f if math.isfinite(f) and f > 0 else None


def _read_exif(im: Image.Image, path: Path) -> tuple[int, float | None, float | None, str | None, list[str]]:
    """(orientation 1..8, FocalLengthIn35mmFilm, FocalLength, camera, notes) from the image's EXIF."""
    notes: list[str] = []
    try:
        exif = im.getexif()
        sub = exif.get_ifd(_EXIF_IFD)
    except Exception as exc:  # broken maker notes and the like: the pixels are still good
        log.warning("%s: EXIF unreadable (%s); orientation and focal length ignored", path, exc)
        return 1, None, None, None, [f"EXIF unreadable ({exc}); orientation and focal length ignored"]
    orientation = exif.get(_TAG_ORIENTATION, 1)
    if orientation not in range(1, 9):
        notes.append(f"EXIF orientation {orientation!r} is not 1..8 and was ignored")
        orientation = 1
    f35 = _positive_float(sub.get(_TAG_FOCAL_35MM))
    if f35 is not None and not FOCAL_35MM_RANGE[0] <= f35 <= FOCAL_35MM_RANGE[1]:
        notes.append(f"EXIF FocalLengthIn35mmFilm {f35:g} mm is implausible and was ignored")
        f35 = None
    focal = _positive_float(sub.get(_TAG_FOCAL_LENGTH))
    make, model = (str(exif.get(t, "")).strip(" \x00") for t in (_TAG_MAKE, _TAG_MODEL))
    camera = model if make and model.startswith(make) else f"{make} {model}".strip()
    return int(orientation), f35, focal, camera or None, notes


def _to_rgb(im: Image.Image, role: str, path: Path) -> tuple[np.ndarray, list[str]]:
    """(H, W, 3) uint8 RGB of any Pillow mode, with notes on what the conversion did."""
    mode = im.mode
    if mode in _SIXTEEN_BIT_MODES or mode == "I":
        grey = np.asarray(im).astype(np.int64)
        if mode == "I" and (grey.min() < 0 or grey.max() > 65535):
            raise LoadError(f"{role} {path} is a 32-bit integer image, not a photo; save it as 8-bit or 16-bit")
        # 65535 / 257 = 255: full scale maps to full scale (Pillow's own convert("L") would clip instead)
        grey8 = ((grey * 255 + 32767) // 65535).astype(np.uint8)
        return np.repeat(grey8[:, :, None], 3, axis=2), ["16-bit grey reduced to 8-bit RGB"]
    if mode == "F":
        grey = np.asarray(im, dtype=np.float64)
        if not (np.isfinite(grey).all() and grey.min() >= 0 and grey.max() <= 1):
            raise LoadError(f"{role} {path} is a floating-point image outside 0..1, not a photo; save it as 8-bit")
        grey8 = np.round(grey * 255).astype(np.uint8)
        return np.repeat(grey8[:, :, None], 3, axis=2), ["floating-point grey (0..1) converted to 8-bit RGB"]
    notes = []
    if mode not in ("RGB", "L", "1", "P", *_ALPHA_MODES):
        notes.append(f"colour mode {mode} converted to RGB")
    if mode in _ALPHA_MODES or "transparency" in im.info:
        rgba = im.convert("RGBA")
        if rgba.getextrema()[3][0] < 255:
            # transparent pixels have no defined colour: flatten onto white, as a viewer would show them
            white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
            rgba = Image.alpha_composite(white, rgba)
            notes.append("transparent pixels composited onto white")
        im = rgba
    try:
        return np.array(im.convert("RGB"), dtype=np.uint8), notes
    except (ValueError, OSError) as exc:  # modes Pillow cannot turn into RGB (LAB, HSV in some builds)
        raise LoadError(f"{role} {path} has colour mode {mode}, which cannot be converted to RGB ({exc})") from exc


def load_image(path: str | os.PathLike, max_pixels: int = MAX_PIXELS) -> tuple[np.ndarray, ImageInfo]:
    """Decode an image file of any format Pillow reads: upright (EXIF orientation applied) (H, W, 3) uint8 RGB."""
    p, data = _read_bytes(path, "image")
    return _decode_photo(data, p, max_pixels)


def _decode_photo(data: bytes, path: Path, max_pixels: int) -> tuple[np.ndarray, ImageInfo]:
    role = "image"
    im = _open_image(data, path, role, max_pixels)
    fmt, mode, raw_size = im.format or "unknown", im.mode, im.size
    if accepted.format_of(im.format, accepted.PHOTO_FORMATS) is None:
        raise LoadError(f"{role} {path} is a {fmt} image; footmesh reads {accepted.PHOTO_HELP}")
    orientation, f35, focal, camera, notes = _read_exif(im, path)
    try:
        frames = getattr(im, "n_frames", 1)  # a TIFF counts its pages by walking them: a broken chain raises
    except Exception as exc:  # Pillow raises TypeError, KeyError, OSError... for a broken page chain
        raise LoadError(
            f"{role} {path} is truncated or corrupt (its pages cannot be counted: {type(exc).__name__})"
        ) from exc
    if frames > 1:
        notes.append(f"first of {frames} frames used")
    if fmt == "HEIF":
        # libheif turned the pixels already (irot / imir) and reset the EXIF tag; pillow-heif keeps the original
        orientation = im.info.get("original_orientation") or 1
        if orientation not in range(1, 9):
            notes.append(f"EXIF orientation {orientation!r} is not 1..8 and was ignored")
            orientation = 1
    elif orientation != 1:
        try:
            im = ImageOps.exif_transpose(im)
        except Exception as exc:
            raise LoadError(f"{role} {path} has EXIF orientation {orientation} that cannot be applied ({exc})") from exc
    rgb, convert_notes = _to_rgb(im, role, path)
    h, w = rgb.shape[:2]
    if min(w, h) < MIN_SIDE_PX:
        raise LoadError(f"{role} {path} is only {w} x {h} px; its shorter side must be at least {MIN_SIDE_PX} px")
    info = ImageInfo(
        path=path,
        format=fmt,
        mode=mode,
        raw_size=raw_size,
        size=(w, h),
        orientation=orientation,
        focal_length_35mm=f35,
        focal_length_mm=focal,
        camera=camera,
        sha256=sha256_hex(data),
        notes=tuple(notes + convert_notes),
    )
    return rgb, info


# --- depth ----------------------------------------------------------------------------------------------------


def load_depth(
    path: str | os.PathLike, unit: DepthUnit, image_size: tuple[int, int], rotated: bool = False
) -> np.ndarray:
    """Depth map aligned with an upright image of ``image_size`` = (width, height) px: (H, W) float32 mm, 0 = missing.

    A 16-bit single-channel PNG/TIFF or an integer ``.npy`` holds millimetres (0 = missing) whatever ``unit`` says,
    so ``unit="m"`` with integer depth is refused; a float ``.npy`` is in ``unit`` (NaN, inf, <= 0 = missing).
    The size must equal ``image_size``; the unit is checked against the depths a foot photo has
    (``DEPTH_RANGE_MM``), and fewer than ``MIN_VALID_DEPTH_FRACTION`` valid pixels is an error. ``rotated``: the
    image was turned by its EXIF orientation (a map of swapped size is then blamed on the rotation).
    """
    p, data = _read_bytes(path, "depth map")
    return _decode_depth(data, p, unit, image_size, rotated)


def _depth_array(data: bytes, path: Path) -> np.ndarray:
    """The raw depth values of ``data`` (.npy or a single-channel 16-bit/float image), as stored."""
    role = "depth map"
    if data.startswith(_NPY_MAGIC):
        try:
            return np.load(io.BytesIO(data), allow_pickle=False)
        except Exception as exc:  # object arrays (pickles), truncated data, bad header
            raise LoadError(f"{role} {path} is not a readable .npy array ({exc})") from exc
    if data.startswith(_ZIP_MAGIC):
        raise LoadError(f"{role} {path} is a zip/.npz archive; save the one depth array with numpy.save (.npy)")
    if data.startswith(_EXR_MAGIC):
        raise LoadError(f"{role} {path} is OpenEXR, which is not supported; save the depth with numpy.save (.npy)")
    im = _open_image(data, path, role, MAX_PIXELS)
    if accepted.format_of(im.format, accepted.DEPTH_IMAGE_FORMATS) is None:
        raise LoadError(f"{role} {path} is a {im.format or 'unknown'} image; footmesh reads {accepted.DEPTH_HELP}")
    if im.mode in _SIXTEEN_BIT_MODES or im.mode in ("I", "F"):
        return np.asarray(im)
    if im.mode in ("L", "P", "1"):
        raise LoadError(
            f"{role} {path} is an 8-bit image, which cannot hold millimetres; save it as a 16-bit PNG in mm"
        )
    raise LoadError(f"{role} {path} has {len(im.getbands())} channels ({im.mode}); depth must be a single channel")


def _decode_depth(data: bytes, path: Path, unit: str, image_size: tuple[int, int], rotated: bool = False) -> np.ndarray:
    role = "depth map"
    if unit not in ("mm", "m"):
        raise LoadError(f"depth unit must be 'mm' or 'm', got {unit!r} (for depth map {path})")
    raw = _depth_array(data, path)
    if raw.ndim == 3 and raw.shape[2] == 1:
        raw = raw[:, :, 0]
    if raw.ndim != 2:
        raise LoadError(f"{role} {path} has shape {raw.shape}; depth must be a 2-D (height, width) array")
    if raw.dtype.kind in "ui":
        if unit != "mm":
            raise LoadError(
                f"{role} {path} holds integers ({raw.dtype}), which are millimetres by definition; "
                "--depth-unit m applies only to a float .npy in metres (drop the flag, or save float metres)"
            )
        integer = True
    elif raw.dtype.kind == "f":
        integer = False
    else:
        raise LoadError(f"{role} {path} has dtype {raw.dtype}; depth must be unsigned 16-bit (mm) or float")

    h, w = raw.shape
    iw, ih = image_size
    if (w, h) != (iw, ih):
        if (w, h) == (ih, iw) and rotated:
            hint = "; it looks taken before the image's EXIF rotation (width and height swapped): rotate it to match"
        elif (w, h) == (ih, iw):
            hint = "; its width and height are swapped (turned by 90 degrees?): it must be aligned with the image"
        else:
            hint = "; it must be aligned pixel for pixel with the image"
        raise LoadError(f"{role} {path} is {w} x {h} px but the image is {iw} x {ih} px after EXIF rotation{hint}")

    with np.errstate(invalid="ignore", over="ignore"):  # NaN, inf and huge values are simply missing
        values = raw.astype(np.float32)  # float32 keeps 0.1 um at 1 m and halves the memory of a 50 MP map
        if unit == "m":
            values *= 1000.0
        valid = np.isfinite(values) & (values > 0)
    fraction = float(valid.mean())
    if fraction < MIN_VALID_DEPTH_FRACTION:
        raise LoadError(f"{role} {path} {_too_few_valid(fraction)}")
    median_mm = float(np.median(values[valid]))
    lo, hi = DEPTH_RANGE_MM
    if not lo <= median_mm <= hi:
        other = "m" if unit == "mm" else "mm"
        other_median_mm = median_mm * (1000.0 if other == "m" else 1e-3)
        if not integer and lo <= other_median_mm <= hi:
            hint = f"; the values look like {'metres' if other == 'm' else 'millimetres'}: use --depth-unit {other}"
        elif integer:
            hint = "; integer depth must be in millimetres"
        else:
            hint = "; neither mm nor m fits: check the depth's unit and scale"
        raise LoadError(
            f"{role} {path} has a median valid depth of {median_mm:.4g} mm (read as {unit}), outside the "
            f"{lo:g}-{hi:g} mm of a foot photo{hint}"
        )
    values[~valid] = 0.0
    return values


def _too_few_valid(fraction: float) -> str:
    return (
        f"has only {100 * fraction:.2f} % valid pixels (finite and > 0); "
        f"at least {100 * MIN_VALID_DEPTH_FRACTION:g} % are needed"
    )


# --- depth embedded in the photo --------------------------------------------------------------------------------


def _android_depth(data: bytes) -> tuple[Any, list[str]]:
    from footmesh.formats.android import read_android_depth

    return read_android_depth(data)


EMBEDDED_DEPTH_READERS = (
    (heif.is_heif, heif.read_heif_depth),
    (lambda data: data.startswith(b"\xff\xd8\xff"), _android_depth),
)
"""(recognises the file's bytes, reads its embedded depth -> (EmbeddedDepth | None, notes)) per container."""


def _embedded_depth(
    data: bytes, info: ImageInfo, k: Intrinsics
) -> tuple[np.ndarray | None, DepthSource | None, list[str]]:
    """(depth mm aligned with the upright photo, its source, notes) from a depth map inside the photo file."""
    for recognises, read in EMBEDDED_DEPTH_READERS:
        if recognises(data):
            embedded, notes = read(data)
            break
    else:
        return None, None, []
    if embedded is None:
        return None, None, notes
    depth_mm, source, why = align_depth(embedded, info.orientation, info.size, k.fx, k.fy, k.cx, k.cy)
    if depth_mm is not None:
        valid = depth_mm > 0
        fraction = float(valid.mean())
        median_mm = float(np.median(depth_mm[valid])) if fraction else 0.0
        lo, hi = DEPTH_RANGE_MM
        if fraction < MIN_VALID_DEPTH_FRACTION:
            why = f"it {_too_few_valid(fraction)}"
        elif not lo <= median_mm <= hi:
            why = f"its median depth of {median_mm:.4g} mm is outside the {lo:g}-{hi:g} mm of a foot photo"
    if why is not None:
        return None, None, [*notes, f"the depth map inside the photo was not used ({why}); measured as RGB"]
    stored_w, stored_h = embedded.size
    note = (
        f"depth from the photo's {embedded.container}: {embedded.representation.replace('_', ' ')}, "
        f"{1000 * embedded.near_m:g}-{1000 * embedded.far_m:g} mm, {embedded.bits}-bit, {stored_w} x {stored_h} px"
    )
    if source is not None and source.dropped_low_confidence:
        note += f", {100 * source.dropped_low_confidence:.1f} % of it dropped for low confidence"
    return depth_mm, source, [*notes, note]


# --- intrinsics -----------------------------------------------------------------------------------------------


def default_intrinsics(width: int, height: int, focal_length_35mm: float | None = None) -> Intrinsics:
    """Intrinsics from a 35 mm-equivalent focal length (EXIF), else the 26 mm-equivalent default; centred.

    f_px = f35 * image diagonal (px) / 43.27 mm, square pixels, principal point at the image centre
    ((W - 1) / 2, (H - 1) / 2). An approximation: no lens centre offset, no crop after capture.
    """
    usable = focal_length_35mm is not None and FOCAL_35MM_RANGE[0] <= focal_length_35mm <= FOCAL_35MM_RANGE[1]
    f35 = float(focal_length_35mm) if usable else DEFAULT_FOCAL_35MM
    f_px = f35 * math.hypot(width, height) / FULL_FRAME_DIAGONAL_MM
    if usable:
        source: IntrinsicsSource = "exif"
        note = (
            f"from EXIF FocalLengthIn35mmFilm = {f35:g} mm over the image diagonal (f = {f_px:.1f} px); "
            "principal point assumed at the image centre"
        )
    else:
        source = "default"
        note = (
            f"no intrinsics file and no EXIF 35 mm-equivalent focal length: assumed a {f35:g} mm-equivalent phone "
            f"main camera (f = {f_px:.1f} px), principal point at the centre; pass --intrinsics for exact figures"
        )
    return Intrinsics(f_px, f_px, (width - 1) / 2, (height - 1) / 2, int(width), int(height), source, note)


def load_intrinsics(path: str | os.PathLike, image_size: tuple[int, int], rotated: bool = False) -> Intrinsics:
    """Intrinsics from a calibration file (``footmesh.formats.camera``), in px of the upright image.

    ``image_size`` = (width, height) px of the upright image the file must fit (``rotated``: the image was turned
    by its EXIF orientation, as for ``load_depth``). The file's lens distortion is not applied here (``load_photo``
    removes it from the photo).
    """
    from footmesh.formats.camera import parse_camera_file

    p, data = _read_bytes(path, "intrinsics file")
    return parse_camera_file(data, p, image_size, rotated).intrinsics


_UNUSABLE_NUMBER = object()
"""What ``_json_int`` makes of an integer with more digits than any camera needs."""


def _json_int(text: str) -> int | object:
    """A JSON integer, or ``_UNUSABLE_NUMBER`` past 30 digits (Python refuses to convert beyond 4,300)."""
    return int(text) if len(text) <= 30 else _UNUSABLE_NUMBER


def _json_float(text: str) -> float | object:
    """A JSON decimal, or ``_UNUSABLE_NUMBER`` when it overflows a float."""
    value = float(text)
    return value if math.isfinite(value) else _UNUSABLE_NUMBER


def _json_number(role: str, path: Path, key: str, value: Any) -> float:
    if value is _UNUSABLE_NUMBER:
        raise LoadError(f"{role} {path}: {key!r} is not a usable number (too many digits, or too large for a float)")
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise LoadError(f"{role} {path}: {key!r} must be a number, got {json.dumps(value)}")
    if not math.isfinite(value):
        raise LoadError(f"{role} {path}: {key!r} must be finite, got {value}")
    return float(value)


# --- everything at once ---------------------------------------------------------------------------------------


def load_photo(
    image: str | os.PathLike,
    depth: str | os.PathLike | None = None,
    depth_unit: DepthUnit = "mm",
    intrinsics: str | os.PathLike | None = None,
    max_pixels: int = MAX_PIXELS,
    embedded_depth: bool = True,
) -> Photo:
    """Load one photo with its optional depth map (``depth_unit`` "mm" or "m") and intrinsics file (K.json).

    Without ``intrinsics`` the camera comes from EXIF or the documented default (``default_intrinsics``).
    Without ``depth``, a metric depth map stored inside the photo file is used unless ``embedded_depth`` is off.
    """
    image_path, image_bytes = _read_bytes(image, "image")
    rgb, info = _decode_photo(image_bytes, image_path, max_pixels)
    hashes = {"image": info.sha256}
    camera = None
    if intrinsics is not None:
        from footmesh.formats.camera import parse_camera_file

        k_path, k_bytes = _read_bytes(intrinsics, "intrinsics file")
        camera = parse_camera_file(k_bytes, k_path, info.size, info.orientation != 1)
        k = camera.intrinsics
        info = replace(info, notes=(*info.notes, *camera.notes))
        hashes["intrinsics"] = sha256_hex(k_bytes)
    else:
        k = default_intrinsics(*info.size, info.focal_length_35mm)
    depth_mm, depth_source = None, None
    if depth is not None:
        depth_path, depth_bytes = _read_bytes(depth, "depth map")
        depth_mm = _decode_depth(depth_bytes, depth_path, depth_unit, info.size, info.orientation != 1)
        depth_source = DepthSource("file", "depth map file", "millimetres")
        hashes["depth"] = sha256_hex(depth_bytes)
    elif embedded_depth:
        depth_mm, depth_source, notes = _embedded_depth(image_bytes, info, k)
        info = replace(info, notes=(*info.notes, *notes))
    if camera is not None and camera.distortion is not None:
        from footmesh.formats.camera import undistort

        rgb, depth_mm = undistort(rgb, depth_mm, camera)
        coefficients = ", ".join(f"{c:.4g}" for c in camera.distortion)
        info = replace(info, notes=(*info.notes, f"lens distortion ({coefficients}) removed; intrinsics {k.note}"))
    return Photo(rgb=rgb, depth_mm=depth_mm, intrinsics=k, info=info, input_sha256=hashes, depth_source=depth_source)
