"""Camera intrinsics files as real tools write them, and the lens distortion they carry.

Every file is recognised by its content, never by its name; all numbers are pixels of the upright photo.

- **K.json** (this project's own): a JSON object with ``fx``, ``fy``, ``cx``, ``cy``, ``width``, ``height``, all
  required; the photo must be exactly ``width x height`` px (a same-aspect size is refused with the factor to
  scale by). Optional lens distortion: a list of 4, 5, 8, 12 or 14 OpenCV coefficients under one of the
  distortion keys of ``KEY_ALIASES`` (``dist``, ``distortion``, ``distortion_coefficients``, ...), or named
  coefficients ``k1``, ``k2``, ``p1``, ``p2``, ``k3``, ``k4``, ``k5``, ``k6`` (accepted in the other kinds too).
  Any other key is ignored, with a note (so are the unused keys of the other kinds).
- **OpenCV calibration**, as ``cv2.FileStorage`` writes it in YAML (``%YAML:1.0`` / ``%YAML 1.2``,
  ``!!opencv-matrix`` nodes), XML or JSON, e.g. OpenCV's ``camera_calibration`` sample or ROS ``camera_info``
  YAML: the camera matrix (``camera_matrix``, ``cameraMatrix``, ``K``, ``intrinsic_matrix``; 3 x 3 row-major, as
  ``rows``/``cols``/``data`` or as a list of rows), the distortion coefficients (``distortion_coefficients``,
  ``dist_coeffs``, ``distCoeffs``, ``D``) and the image size (``image_width`` + ``image_height``, or
  ``image_size`` / ``imageSize`` as ``[w, h]``). A fisheye calibration (``fisheye_model: 1``, or a ROS
  ``distortion_model`` other than ``plumb_bob`` / ``rational_polynomial``) is refused.
- **ARKit intrinsics**: JSON with ``intrinsics`` as a 3 x 3 list, row-major ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``
  or column-major as ``simd_float3x3`` serialises (``[[fx, 0, 0], [0, fy, 0], [cx, cy, 1]]``), or as 9 numbers;
  the image size from ``imageResolution`` (``{"width", "height"}`` or ``[w, h]``), ``width``/``height`` or ``w``/``h``.
- **Record3D metadata**: JSON with ``K`` as 9 numbers in column-major order ``[fx, 0, 0, 0, fy, 0, cx, cy, 1]``
  and the RGB size in ``w``, ``h``.

The layout of a list (row- or column-major) is read from where the ``1`` and ``cx``, ``cy`` sit; an OpenCV
``rows``/``cols``/``data`` matrix is row-major by definition. Files other than K.json may be for another size of
the same aspect ratio (ARKit's capture resolution, a calibration at video size): their intrinsics are scaled to
the photo, with a note. Without an image size they are taken to be for this photo only when their principal point
lies near its centre (``CENTRE_TOLERANCE``). Anything wrong or inconsistent raises ``footmesh.load.LoadError``
with one line naming the file.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from footmesh.load import (
    INTRINSICS_KEYS,
    MAX_FOV_DEG,
    Intrinsics,
    LoadError,
    _json_float,
    _json_int,
    _json_number,
)

ROLE = "intrinsics file"
"""How messages name the file, as ``footmesh.load`` does."""
KEY_ALIASES: dict[str, tuple[str, ...]] = {
    "camera_matrix": ("camera_matrix", "cameraMatrix", "K", "intrinsic_matrix", "intrinsics"),
    "distortion": ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "dist", "distortion"),
    "width": ("image_width", "width", "w"),
    "height": ("image_height", "height", "h"),
    "size": ("image_size", "imageSize", "imageResolution"),
    "distortion_model": ("distortion_model",),
    "fisheye_model": ("fisheye_model",),
}
"""The accepted spellings of each field of a calibration file (K.json's own six keys: ``INTRINSICS_KEYS``)."""
MATRIX_KINDS: dict[str, str] = {
    "camera_matrix": "OpenCV calibration",
    "cameraMatrix": "OpenCV calibration",
    "K": "OpenCV calibration",
    "intrinsic_matrix": "OpenCV calibration",
    "intrinsics": "ARKit intrinsics",
}
"""The kind of file each camera-matrix key marks; 9 numbers under ``K`` are Record3D's metadata instead."""
FLAT_K_KIND = "Record3D metadata"
"""The kind of a file whose ``K`` is a flat list of 9 numbers (OpenCV writes rows/cols/data, ARKit rows)."""
K_JSON_KIND = "K.json"
"""The kind of a file with the six keys fx, fy, cx, cy, width, height."""
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")
"""OpenCV's distortion coefficients in its order (tx, ty: the tilt τx, τy)."""
NAMED_DISTORTION_KEYS = DISTORTION_NAMES[:8]
"""The coefficients a file may give as keys of their own instead of a list (radial, tangential, rational)."""
DISTORTION_COUNTS = (4, 5, 8, 12, 14)
"""The numbers of coefficients OpenCV's distortion models have (0: no distortion)."""
PINHOLE_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "radtan")
"""ROS / Kalibr ``distortion_model`` names of OpenCV's standard model; any other (equidistant, fov, ...) is refused."""
MAX_SKEW_FRACTION = 0.01
"""A camera-matrix skew up to this fraction of fx is numerical noise of a calibration and is dropped; more refuses."""
ASPECT_TOLERANCE = 0.005
"""A file for another image size is scaled to the photo when their aspect ratios differ by at most this (0.5 %)."""
CENTRE_TOLERANCE = 0.10
"""Without an image size, a file is for this photo only if its principal point is within this fraction of the
photo's width / height of the photo's centre."""
DISTORTION_RADIUS_RATIO = (0.5, 2.0)
"""A plausible lens moves no point of the image to less than half or more than twice its distance from the
principal point (even a phone's ultra-wide stays within ~0.6)."""
MAX_ABS_DISTORTION = 1000.0
"""Distortion coefficients beyond this magnitude are not a calibration (rational models reach tens, not thousands)."""
MAX_MATRIX_NUMBERS = 64
"""A matrix in a calibration file with more numbers than this is not a camera matrix or distortion vector."""
MAX_NODE_DEPTH = 6
"""How deeply a YAML / XML value of a known key may nest; a camera matrix needs 3."""
IGNORED_KEYS_SHOWN = 8
"""How many ignored keys a note names before it only counts the rest."""
_RAY_SAMPLES = 64
"""Points per ray from the principal point to the image border at which the distortion is checked."""


@dataclass(frozen=True, eq=False)
class CameraFile:
    """Intrinsics read from a calibration file, its lens distortion (OpenCV order) and what was ignored."""

    intrinsics: Intrinsics  # source="file", note names the file and its kind; px of the photo
    distortion: np.ndarray | None  # (N,) float64 k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]; None: none
    kind: str  # "K.json", "OpenCV calibration", "ARKit intrinsics", "Record3D metadata"
    notes: tuple[str, ...] = ()  # e.g. "ignored keys 'depth_unit_mm', 'serial' in K.json"


def parse_camera_file(data: bytes, path: Path, image_size: tuple[int, int], rotated: bool = False) -> CameraFile:
    """Intrinsics (and distortion) for the upright photo of ``image_size`` = (w, h) px from a calibration file."""
    tree, syntax = _read_tree(data, path)
    _check_model(tree, path)
    six = [k for k in ("fx", "fy", "cx", "cy") if k in tree]
    matrix = _lookup(tree, "camera_matrix", path)
    if six and matrix is not None:
        raise LoadError(
            f"{ROLE} {path} gives both {', '.join(six)} and a camera matrix {matrix[0]!r}; keep one of the two"
        )
    if matrix is not None:
        return _from_matrix(tree, syntax, matrix, path, image_size, rotated)
    return _from_k_json(tree, path, image_size, rotated)


def undistort(rgb: np.ndarray, depth_mm: np.ndarray | None, camera: CameraFile) -> tuple[np.ndarray, np.ndarray | None]:
    """The photo (and its aligned depth) with the lens distortion removed, same size and same K."""
    dist = camera.distortion
    if dist is None or not np.any(dist):
        return rgb, depth_mm
    k = camera.intrinsics
    for name, array in (("rgb", rgb), ("depth_mm", depth_mm)):
        if array is not None and array.shape[:2] != (k.height, k.width):
            raise ValueError(
                f"{name} is {array.shape[1]} x {array.shape[0]} px but the camera is {k.width} x {k.height}"
            )
    matrix = k.matrix()
    out = cv2.undistort(rgb, matrix, dist, None, matrix)
    if depth_mm is None:
        return out, None
    map_x, map_y = cv2.initUndistortRectifyMap(matrix, dist, None, matrix, (k.width, k.height), cv2.CV_32FC1)
    # nearest neighbour: blending a foreground and a background depth would invent points floating between them;
    # the values themselves stay, since a point's z does not change with where its pixel lands
    depth = cv2.remap(depth_mm, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, depth


# --- reading the file -----------------------------------------------------------------------------------------


class _NotRead:
    """Stands for the value of a YAML / XML key that nothing uses: only its name is reported."""


_NOT_READ = _NotRead()
_KNOWN_KEYS = frozenset({*INTRINSICS_KEYS, *NAMED_DISTORTION_KEYS, *(k for keys in KEY_ALIASES.values() for k in keys)})
"""The keys whose YAML / XML values are read; the values of all others are skipped (image points, extrinsics)."""


def _read_tree(data: bytes, path: Path) -> tuple[dict[str, Any], str]:
    """The file's top-level mapping and its syntax ("JSON", "YAML", "XML")."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise LoadError(f"{ROLE} {path} is not UTF-8 text (a JSON, YAML or XML calibration file expected)") from exc
    if "\x00" in text:
        # OpenCV's parser would stop at the first NUL and read a truncated file as if it were whole
        raise LoadError(f"{ROLE} {path} holds NUL characters, so it is not a JSON, YAML or XML calibration file")
    head = text.lstrip()
    if not head:
        raise LoadError(f"{ROLE} {path} is empty")
    if head[0] in "{[":
        return _read_json(text, path), "JSON"
    if head[0] == "<":
        # OpenCV recognises XML by its declaration only; without one it would try YAML and fail confusingly
        xml = text if head.startswith("<?xml") else '<?xml version="1.0"?>\n' + head
        return _read_opencv(xml, path, "XML"), "XML"
    return _read_opencv(text, path, "YAML"), "YAML"


def _read_json(text: str, path: Path) -> dict[str, Any]:
    try:
        obj = json.loads(text, parse_int=_json_int, parse_float=_json_float)
    except json.JSONDecodeError as exc:
        raise LoadError(f"{ROLE} {path} is not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from exc
    except RecursionError:
        raise LoadError(f"{ROLE} {path} is not valid JSON: nested too deeply for intrinsics") from None
    if not isinstance(obj, dict):
        raise LoadError(
            f"{ROLE} {path} must hold a JSON object with keys {', '.join(INTRINSICS_KEYS)}, "
            "or an OpenCV, ARKit or Record3D camera matrix"
        )
    return obj


def _read_opencv(text: str, path: Path, syntax: str) -> dict[str, Any]:
    """A YAML or XML file through ``cv2.FileStorage``: the known keys' values, the others' names only."""
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # the binding wraps cv2.error in a SystemError on some versions
        raise LoadError(
            f"{ROLE} {path} is not a JSON, YAML or XML calibration file ({_opencv_reason(exc, syntax)})"
        ) from None
    try:
        if not storage.isOpened():
            raise LoadError(f"{ROLE} {path} is not a JSON, YAML or XML calibration file (OpenCV cannot open it)")
        root = storage.root()
        if not root.isMap():
            raise LoadError(
                f"{ROLE} {path} must hold a {syntax} mapping of keys (fx, fy, ... or camera_matrix, ...), "
                "not a single value or a list"
            )
        return {
            key: _from_node(root.getNode(key), key, path, 0) if key in _KNOWN_KEYS else _NOT_READ for key in root.keys()
        }
    except (cv2.error, SystemError) as exc:
        raise LoadError(
            f"{ROLE} {path} is not a JSON, YAML or XML calibration file ({_opencv_reason(exc, syntax)})"
        ) from None
    finally:
        # the nodes read above point into the storage: it must outlive them, and go once they are converted
        storage.release()


def _from_node(node: cv2.FileNode, key: str, path: Path, depth: int) -> Any:
    """A FileNode as the Python value ``json`` would give (dict, list, int, float, str, None)."""
    if depth > MAX_NODE_DEPTH:
        raise LoadError(f"{ROLE} {path}: {key!r} is nested too deeply for a camera matrix")
    kind = node.type()
    if kind == cv2.FileNode_INT:
        return int(node.real())
    if kind == cv2.FileNode_REAL:
        return node.real()
    if kind == cv2.FileNode_STR:
        return node.string()
    if kind == cv2.FileNode_SEQ:
        return [_from_node(node.at(i), key, path, depth + 1) for i in range(node.size())]
    if kind == cv2.FileNode_MAP:
        return {name: _from_node(node.getNode(name), key, path, depth + 1) for name in node.keys()}
    return None


def _opencv_reason(exc: Exception, syntax: str) -> str:
    """OpenCV's parse error in a few words: its message after the line number, without the quoted buffer."""
    message = str(exc.__cause__ or exc)
    found = list(re.finditer(r"\((\d+)\): ", message))
    if not found:
        return f"OpenCV's {syntax} parser refused it"
    reason = message[found[-1].end() :].strip().rstrip("'").strip()
    reason = "".join(c if c.isprintable() else " " for c in reason)[:120]
    return f"OpenCV's {syntax} parser: {reason} at line {found[-1].group(1)}"


def _lookup(tree: dict[str, Any], field: str, path: Path) -> tuple[str, Any] | None:
    """(key, value) of the one alias of ``field`` the file uses; None if it uses none."""
    found = [(key, tree[key]) for key in KEY_ALIASES[field] if key in tree]
    if not found:
        return None
    first_key, first = found[0]
    for key, value in found[1:]:
        if value != first:
            raise LoadError(f"{ROLE} {path} gives {first_key!r} and {key!r} with different values; keep one")
    return found[0]


def _ignored_note(tree: dict[str, Any], used: set[str], kind: str) -> list[str]:
    ignored = sorted(k for k in tree if k not in used)
    if not ignored:
        return []
    shown = ", ".join(map(repr, ignored[:IGNORED_KEYS_SHOWN]))
    more = f" and {len(ignored) - IGNORED_KEYS_SHOWN} more" if len(ignored) > IGNORED_KEYS_SHOWN else ""
    return [f"ignored key{'s' if len(ignored) > 1 else ''} {shown}{more} in {kind}"]


def _check_model(tree: dict[str, Any], path: Path) -> None:
    """Refuse a fisheye (or other non-pinhole) calibration, whose coefficients would be misread as OpenCV's."""
    fisheye = _lookup(tree, "fisheye_model", path)
    if fisheye is not None and _number(fisheye[1], fisheye[0], path) != 0:
        raise LoadError(
            f"{ROLE} {path} is a fisheye calibration ({fisheye[0]} = {fisheye[1]!r}); only OpenCV's standard "
            "model (pinhole with radial and tangential distortion) can be used"
        )
    model = _lookup(tree, "distortion_model", path)
    if model is not None and str(model[1]).lower() not in PINHOLE_DISTORTION_MODELS:
        raise LoadError(
            f"{ROLE} {path} uses distortion model {str(model[1])[:40]!r}; only OpenCV's standard model "
            f"({', '.join(PINHOLE_DISTORTION_MODELS)}) can be used"
        )


# --- K.json ---------------------------------------------------------------------------------------------------


def _from_k_json(tree: dict[str, Any], path: Path, image_size: tuple[int, int], rotated: bool) -> CameraFile:
    missing = [k for k in INTRINSICS_KEYS if k not in tree]
    if missing:
        raise LoadError(
            f"{ROLE} {path}: missing {', '.join(missing)} (a K.json needs {', '.join(INTRINSICS_KEYS)}; "
            f"an OpenCV, ARKit or Record3D file needs a camera matrix: {', '.join(KEY_ALIASES['camera_matrix'])})"
        )
    v = {k: _number(tree[k], k, path) for k in INTRINSICS_KEYS}
    for k in ("fx", "fy", "width", "height"):
        if v[k] <= 0:
            raise LoadError(f"{ROLE} {path}: {k!r} must be positive, got {tree[k]}")
    for k in ("width", "height"):
        if v[k] != int(v[k]):
            raise LoadError(f"{ROLE} {path}: {k!r} must be a whole number of pixels, got {tree[k]}")
    w, h = int(v["width"]), int(v["height"])
    if (w, h) != tuple(image_size):
        raise _size_mismatch(path, (w, h), image_size, rotated, scale_hint=True)
    for k, size in (("cx", w), ("cy", h)):
        if not -0.5 <= v[k] <= size - 0.5:
            raise LoadError(f"{ROLE} {path}: {k} = {tree[k]} px is outside the image (-0.5 .. {size - 0.5} px)")
    k_out = Intrinsics(v["fx"], v["fy"], v["cx"], v["cy"], w, h, "file", f"from {path.name} ({K_JSON_KIND})")
    _check_fov(k_out, path, f"fx = {tree['fx']}, fy = {tree['fy']}")
    distortion, dist_keys = _distortion(tree, path, k_out)
    used = {*INTRINSICS_KEYS, *dist_keys, *KEY_ALIASES["distortion_model"], *KEY_ALIASES["fisheye_model"]}
    return _finish(k_out, distortion, K_JSON_KIND, _ignored_note(tree, used, K_JSON_KIND))


def _distortion(tree: dict[str, Any], path: Path, k: Intrinsics) -> tuple[np.ndarray | None, set[str]]:
    """The distortion, from a list under a distortion key or from named coefficients, checked; and the keys used."""
    listed = _lookup(tree, "distortion", path)
    named = [key for key in NAMED_DISTORTION_KEYS if key in tree]
    if listed is not None and named:
        raise LoadError(
            f"{ROLE} {path} gives distortion both as {listed[0]!r} and as {', '.join(named)}; keep one of the two"
        )
    if listed is not None:
        coeffs = _distortion_vector(listed[1], listed[0], path)
        used = {key for key in KEY_ALIASES["distortion"] if key in tree}
    elif named:
        values = [_number(tree[key], key, path) if key in tree else 0.0 for key in NAMED_DISTORTION_KEYS]
        # the shortest OpenCV model holding every coefficient given: 5 (k1..k3), else the rational 8
        count = 8 if any(key in tree for key in NAMED_DISTORTION_KEYS[5:]) else 5
        coeffs, used = np.array(values[:count], np.float64), set(named)
    else:
        return None, set()
    if coeffs is not None:
        _check_distortion(coeffs, k, path)
    return coeffs, used


# --- OpenCV, ARKit, Record3D ----------------------------------------------------------------------------------


def _from_matrix(
    tree: dict[str, Any],
    syntax: str,
    matrix: tuple[str, Any],
    path: Path,
    image_size: tuple[int, int],
    rotated: bool,
) -> CameraFile:
    key, value = matrix
    numbers, layout = _matrix_numbers(value, key, path)
    kind = FLAT_K_KIND if key == "K" and layout == "flat" else MATRIX_KINDS[key]
    if layout == "flat":
        if numbers.size != 9:
            raise LoadError(f"{ROLE} {path}: {key!r} has {numbers.size} numbers; a camera matrix has 9 (3 x 3)")
        numbers = numbers.reshape(3, 3)
    elif numbers.shape != (3, 3):
        raise LoadError(f"{ROLE} {path}: {key!r} is {numbers.shape[0]} x {numbers.shape[1]}; a camera matrix is 3 x 3")
    fx, fy, cx, cy, notes = _pinhole(numbers, layout, key, path)
    size = _file_size(tree, path)
    iw, ih = image_size
    if size is None:
        if abs(cx - (iw - 1) / 2) > CENTRE_TOLERANCE * iw or abs(cy - (ih - 1) / 2) > CENTRE_TOLERANCE * ih:
            raise LoadError(
                f"{ROLE} {path} gives no image size and its principal point ({cx:g}, {cy:g}) px is not near the "
                f"centre of this {iw} x {ih} px image, so it is for another size; add the size it was made for "
                "(image_width and image_height, image_size [w, h] or imageResolution)"
            )
        notes.append(
            f"no image size in {path.name}: taken to be this photo's {iw} x {ih} px (principal point near its centre)"
        )
        size = (iw, ih)
    w, h = size
    for name, value_px, extent in (("cx", cx, w), ("cy", cy, h)):
        if not -0.5 <= value_px <= extent - 0.5:
            raise LoadError(
                f"{ROLE} {path}: {name} = {value_px:g} px is outside the {w} x {h} px image it is for "
                f"(-0.5 .. {extent - 0.5} px)"
            )
    k_file = Intrinsics(fx, fy, cx, cy, w, h, "file", f"from {path.name} ({kind}, {syntax})")
    _check_fov(k_file, path, f"fx = {fx:g}, fy = {fy:g}")
    distortion, dist_keys = _distortion(tree, path, k_file)
    used = {alias for aliases in KEY_ALIASES.values() for alias in aliases if alias in tree} | dist_keys
    notes = _ignored_note(tree, used, kind) + notes
    if (w, h) != (iw, ih):
        if abs((w / h) / (iw / ih) - 1) > ASPECT_TOLERANCE:
            raise _size_mismatch(path, (w, h), image_size, rotated, scale_hint=False)
        # distortion coefficients act on normalised coordinates, so only K changes with the image size
        k_file = replace(k_file.resized(iw, ih), note=f"from {path.name} ({kind}, {syntax}, scaled from {w} x {h} px)")
        notes.append(
            f"{path.name} is for {w} x {h} px, the same aspect ratio as this {iw} x {ih} px photo: intrinsics "
            f"scaled by {iw / w:.4g}"
        )
    return _finish(k_file, distortion, kind, notes)


def _pinhole(m: np.ndarray, layout: str, key: str, path: Path) -> tuple[float, float, float, float, list[str]]:
    """fx, fy, cx, cy of a 3 x 3 camera matrix as stored (row- or column-major, told apart by its zeros)."""
    # row-major K has cx, cy in its last column; column-major (simd) in its last row, and zeros where the other has them
    column_major = m[0, 2] == 0 and m[1, 2] == 0 and (m[2, 0] != 0 or m[2, 1] != 0)
    if column_major and layout == "opencv":
        raise LoadError(
            f"{ROLE} {path}: {key!r} is not a pinhole camera matrix: cx, cy sit in its bottom row; it looks "
            "transposed (an OpenCV matrix is row-major)"
        )
    if column_major:
        m = m.T

    def at(r: int, c: int) -> str:
        fr, fc = (c, r) if column_major else (r, c)
        return f"[{3 * fr + fc}]" if layout == "flat" else f"[{fr}][{fc}]"

    for r, c in ((1, 0), (2, 0), (2, 1)):
        if m[r, c] != 0:
            raise LoadError(
                f"{ROLE} {path}: {key!r} is not a pinhole camera matrix: element {at(r, c)} = {m[r, c]:g} must be 0"
            )
    if m[2, 2] != 1:
        raise LoadError(
            f"{ROLE} {path}: {key!r} is not a pinhole camera matrix: element {at(2, 2)} = {m[2, 2]:g} must be 1"
        )
    fx, fy, cx, cy, skew = float(m[0, 0]), float(m[1, 1]), float(m[0, 2]), float(m[1, 2]), float(m[0, 1])
    for name, value in (("fx", fx), ("fy", fy)):
        if value <= 0:
            raise LoadError(f"{ROLE} {path}: {key!r} gives {name} = {value:g}; it must be positive")
    notes = []
    if column_major:
        notes.append(f"{key!r} read as column-major (cx, cy in its last row, as ARKit's simd matrices store them)")
    if abs(skew) > MAX_SKEW_FRACTION * fx:
        raise LoadError(
            f"{ROLE} {path}: {key!r} has a skew of {skew:g} px at {at(0, 1)}, more than {MAX_SKEW_FRACTION:.0%} of "
            f"fx = {fx:g}; only a camera without skew can be used"
        )
    if skew != 0:
        notes.append(f"skew of {skew:g} px in {key!r} ignored (under {MAX_SKEW_FRACTION:.0%} of fx)")
    return fx, fy, cx, cy, notes


def _file_size(tree: dict[str, Any], path: Path) -> tuple[int, int] | None:
    """(w, h) px the file says its camera matrix is for, or None if it does not say."""
    width, height, size = (_lookup(tree, f, path) for f in ("width", "height", "size"))
    for given, other, lacking in ((width, height, "height"), (height, width, "width")):
        if given is not None and other is None:
            raise LoadError(
                f"{ROLE} {path} gives the image size's {given[0]!r} but not its {lacking} "
                f"({', '.join(KEY_ALIASES[lacking])})"
            )
    pair = None
    if width is not None and height is not None:
        pair = (_pixels(width[1], width[0], path), _pixels(height[1], height[0], path))
    if size is None:
        return pair
    key, value = size
    if isinstance(value, dict) and "width" in value and "height" in value:
        from_size = (_pixels(value["width"], f"{key}.width", path), _pixels(value["height"], f"{key}.height", path))
    elif isinstance(value, list) and len(value) == 2:
        from_size = (_pixels(value[0], f"{key}[0]", path), _pixels(value[1], f"{key}[1]", path))
    else:
        raise LoadError(f"{ROLE} {path}: {key!r} must be [width, height] or {{width, height}} in pixels")
    if pair is not None and pair != from_size:
        raise LoadError(
            f"{ROLE} {path} gives two image sizes, {pair[0]} x {pair[1]} px and {key} {from_size[0]} x "
            f"{from_size[1]} px; keep one"
        )
    return from_size


# --- numbers, distortion, checks ------------------------------------------------------------------------------


def _number(value: Any, label: str, path: Path) -> float:
    """A finite number, or a LoadError naming ``label`` (no list or mapping is echoed back in full)."""
    if isinstance(value, list | dict):
        raise LoadError(
            f"{ROLE} {path}: {label!r} must be a number, got a {'list' if isinstance(value, list) else 'mapping'}"
        )
    return _json_number(ROLE, path, label, value)


def _pixels(value: Any, label: str, path: Path) -> int:
    number = _number(value, label, path)
    if number <= 0 or number != int(number):
        raise LoadError(f"{ROLE} {path}: {label!r} must be a positive whole number of pixels, got {number:g}")
    return int(number)


def _matrix_numbers(value: Any, key: str, path: Path) -> tuple[np.ndarray, str]:
    """The numbers of a matrix as stored, 2-D, and its layout: "opencv" (rows/cols/data), "nested" or "flat"."""
    if isinstance(value, dict) and "sizes" in value and "data" in value:
        # !!opencv-nd-matrix: what cv2.FileStorage (OpenCV 5) writes for a 1-D numpy array such as a distortion
        sizes = value["sizes"] if isinstance(value["sizes"], list) else [value["sizes"]]
        if not 1 <= len(sizes) <= 2:
            raise LoadError(f"{ROLE} {path}: {key!r} has {len(sizes)} dimensions; a matrix has 1 or 2")
        dims = [_pixels(n, f"{key}.sizes[{i}]", path) for i, n in enumerate(sizes)]
        value = {"rows": 1 if len(dims) == 1 else dims[0], "cols": dims[-1], **value}
    if isinstance(value, dict):
        missing = [f for f in ("rows", "cols", "data") if f not in value]
        if missing:
            raise LoadError(
                f"{ROLE} {path}: {key!r} lacks {', '.join(missing)} (an OpenCV matrix has rows, cols and data)"
            )
        rows, cols = _pixels(value["rows"], f"{key}.rows", path), _pixels(value["cols"], f"{key}.cols", path)
        # a multi-channel matrix ("2d", "3f") holds that many numbers per element
        channels = re.match(r"\d+", str(value["dt"])) if "dt" in value else None
        per_element = int(channels.group()) if channels else 1
        data = value["data"]
        if not isinstance(data, list):
            data = [data]  # a 1 x 1 matrix is written as a bare number
        if len(data) != rows * cols * per_element:
            raise LoadError(f"{ROLE} {path}: {key!r} has {len(data)} numbers in data but rows x cols = {rows} x {cols}")
        flat = _numbers(data, f"{key}.data", path)
        return flat.reshape(rows, cols * per_element), "opencv"
    if isinstance(value, list) and value and all(isinstance(row, list) for row in value):
        if len({len(row) for row in value}) != 1:
            raise LoadError(f"{ROLE} {path}: {key!r} has rows of different lengths")
        flat = _numbers([x for row in value for x in row], key, path)
        return flat.reshape(len(value), len(value[0])), "nested"
    if isinstance(value, list):
        return _numbers(value, key, path).reshape(1, -1), "flat"
    raise LoadError(
        f"{ROLE} {path}: {key!r} must be a matrix (a list of numbers, a list of rows, or rows / cols / data)"
    )


def _numbers(values: list[Any], label: str, path: Path) -> np.ndarray:
    if len(values) > MAX_MATRIX_NUMBERS:
        raise LoadError(f"{ROLE} {path}: {label!r} has {len(values)} numbers, too many for a camera matrix")
    return np.array([_number(x, f"{label}[{i}]", path) for i, x in enumerate(values)], np.float64)


def _distortion_vector(value: Any, key: str, path: Path) -> np.ndarray | None:
    """OpenCV coefficients from a list, a 1 x N / N x 1 list of lists or an OpenCV matrix; None when empty."""
    numbers, _ = _matrix_numbers(value, key, path)
    if 1 not in numbers.shape and numbers.size:
        raise LoadError(f"{ROLE} {path}: {key!r} is {numbers.shape[0]} x {numbers.shape[1]}; distortion is one row")
    coeffs = numbers.ravel()
    if coeffs.size == 0:
        return None
    if coeffs.size not in DISTORTION_COUNTS:
        raise LoadError(
            f"{ROLE} {path}: {key!r} has {coeffs.size} distortion coefficients; OpenCV's models have "
            f"{', '.join(map(str, DISTORTION_COUNTS))} (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]])"
        )
    return coeffs


def _check_distortion(coeffs: np.ndarray, k: Intrinsics, path: Path) -> None:
    """Refuse a distortion that folds the image over or moves points implausibly far, where the image lies."""
    big = [f"{n} = {c:g}" for n, c in zip(DISTORTION_NAMES, coeffs, strict=False) if abs(c) > MAX_ABS_DISTORTION]
    if big:
        raise LoadError(
            f"{ROLE} {path}: lens distortion has {', '.join(big)}, beyond the {MAX_ABS_DISTORTION:g} of any real lens"
        )
    w, h = k.width, k.height
    border = [(-0.5, -0.5), (w - 0.5, -0.5), (-0.5, h - 0.5), (w - 0.5, h - 0.5)]
    border += [(k.cx, -0.5), (k.cx, h - 0.5), (-0.5, k.cy), (w - 0.5, k.cy)]
    t = np.linspace(0.0, 1.0, _RAY_SAMPLES + 1)[1:]
    what = ""
    for bx, by in border:
        if math.hypot(bx - k.cx, by - k.cy) < 1.0:
            continue  # the principal point sits on this border point: no ray to check
        x = t * (bx - k.cx) / k.fx
        y = t * (by - k.cy) / k.fy
        points = np.stack([x, y, np.ones_like(x)], axis=1).reshape(-1, 1, 3)
        with np.errstate(all="ignore"):
            moved = cv2.projectPoints(points, np.zeros(3), np.zeros(3), np.eye(3), coeffs)[0].reshape(-1, 2)
            r_in, r_out = np.hypot(x, y), np.hypot(moved[:, 0], moved[:, 1])
            ratio = r_out / r_in
        if not np.all(np.isfinite(moved)) or np.any(np.diff(np.concatenate([[0.0], r_out])) <= 0):
            what = "folds the image over (points further from the principal point land nearer to it)"
            break
        lo, hi = DISTORTION_RADIUS_RATIO
        if ratio.min() < lo or ratio.max() > hi:
            worst = ratio.min() if ratio.min() < lo else ratio.max()
            what = (
                f"moves points to {worst:.3g} times their distance from the principal point "
                f"(a lens stays within {lo:g} to {hi:g})"
            )
            break
    if what:
        named = ", ".join(f"{n} = {c:g}" for n, c in zip(DISTORTION_NAMES, coeffs, strict=False) if c != 0)
        raise LoadError(
            f"{ROLE} {path}: lens distortion {named} {what} within the {w} x {h} px image, so it is not a "
            "plausible lens; check that the coefficients are OpenCV's and for this camera"
        )


def _check_fov(k: Intrinsics, path: Path, given: str) -> None:
    fov = max(k.fov_deg())
    if fov > MAX_FOV_DEG:
        raise LoadError(
            f"{ROLE} {path}: {given} give a {fov:.1f} degree field of view; they must be in pixels, not millimetres"
        )


def _size_mismatch(
    path: Path, size: tuple[int, int], image_size: tuple[int, int], rotated: bool, scale_hint: bool
) -> LoadError:
    """The error for a file made for another image size, with what most likely happened."""
    (w, h), (iw, ih) = size, image_size
    # K.json names an exact swap only; the others are also scaled, so a swapped aspect ratio is the same mistake
    swapped_aspect = (w, h) == (ih, iw) if scale_hint else abs((w / h) / (ih / iw) - 1) <= ASPECT_TOLERANCE
    if swapped_aspect and rotated:
        hint = (
            ": the intrinsics look taken before the image's EXIF rotation; give them for the upright image "
            "(swap fx/fy and width/height, and move cx/cy as the rotation does)"
        )
    elif (w, h) == (ih, iw):
        hint = ": its width and height are swapped"
    elif swapped_aspect:
        hint = ": its width and height look swapped (landscape intrinsics for a portrait photo, or the reverse)"
    elif scale_hint and w * ih == h * iw:
        hint = f": same aspect ratio, so scale fx, fy, cx, cy by {iw / w:g} for this image"
    elif scale_hint:
        hint = ""
    else:
        hint = ": their aspect ratios differ, so the photo is cropped or from another camera"
    return LoadError(f"{ROLE} {path} is for a {w} x {h} px image but the image is {iw} x {ih} px{hint}")


def _finish(k: Intrinsics, distortion: np.ndarray | None, kind: str, notes: list[str]) -> CameraFile:
    if distortion is not None and not np.any(distortion):
        distortion = None  # all zeros: the photo needs nothing done
    return CameraFile(intrinsics=k, distortion=distortion, kind=kind, notes=tuple(notes))
