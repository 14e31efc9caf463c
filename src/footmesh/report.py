"""Writing results: JSON, meshes and pictures, each written atomically (temporary file, then rename)."""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=target.suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes the file private; results are ordinary files
        os.replace(tmp, target)
    finally:
        Path(tmp).unlink(missing_ok=True)


def _non_finite(data: Any, where: str = "") -> str | None:
    """The key path of the first NaN or infinity in nested dicts and lists, or None."""
    if isinstance(data, float) and not math.isfinite(data):
        return where or "(the value)"
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list | tuple) else ()
    for key, value in items:
        found = _non_finite(value, f"{where}.{key}" if isinstance(key, str) else f"{where}[{key}]")
        if found is not None:
            return found
    return None


def write_json(path: str | os.PathLike, data: dict[str, Any]) -> None:
    """Write ``data`` as indented JSON. NaN is refused (missing values must be null) as a fault of the program,
    never of the input: ``errors.InternalError`` naming the key."""
    from footmesh.errors import InternalError

    try:
        text = json.dumps(data, indent=2, allow_nan=False, default=_to_builtin) + "\n"
    except ValueError as exc:
        raise InternalError(f"{path}: {exc} (at {_non_finite(data)})") from None
    with atomic_path(path) as tmp:
        tmp.write_text(text)


ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)
"""Every member of a written ``.npz`` carries this date, so that writing the same arrays gives the same bytes."""


def add_npy_member(zf: zipfile.ZipFile, name: str, value: np.ndarray, compresslevel: int | None = None) -> None:
    """Add ``value`` to an open zip as ``name.npy`` with the fixed date (``np.load`` reads it as usual)."""
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asanyarray(value), allow_pickle=False)
    info = zipfile.ZipInfo(f"{name}.npy", date_time=ZIP_DATE_TIME)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    zf.writestr(info, buffer.getvalue(), compresslevel=compresslevel)


def write_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray], compresslevel: int | None = None) -> None:
    """Write a compressed ``.npz`` atomically whose bytes depend only on the arrays.

    ``np.savez_compressed`` stamps each member with the current time, so two identical builds would differ.
    """
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, value in arrays.items():
            add_npy_member(zf, name, value, compresslevel)


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a triangle mesh (mm) as OBJ, PLY, STL or GLB, chosen by the suffix."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces), process=False)
    suffix = Path(path).suffix.lower().lstrip(".")
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type=suffix)


def _to_builtin(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "to_dict"):
        return value.to_dict()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def request_options(
    side: str, depth_unit: str, input: str, embedded_depth: bool = True, reference: str = "auto"
) -> dict[str, str | bool]:
    """The options of a measurement that change its result besides the input files (``result["request"]``)."""
    return {
        "side": side,
        "depth_unit": depth_unit,
        "input": input,
        "embedded_depth": embedded_depth,
        "reference": reference,
    }
