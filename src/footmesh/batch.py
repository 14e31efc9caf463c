"""``footmesh measure`` over several photos: one folder each, resumable, failures reported and the rest done."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from footmesh import __version__
from footmesh.config import MeasureConfig
from footmesh.errors import InputError, is_users_fault, write_internal_report
from footmesh.load import load_photo
from footmesh.report import request_options
from footmesh.sizes import length_advice

log = logging.getLogger("footmesh.measure")


def _sha256(path: str | Path) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def output_folders(images: Sequence[str], out: Path) -> list[Path]:
    """``out`` for one photo; ``out/<stem>`` each for several, always distinct: a repeated stem gets the first
    free ``<stem>-2``, ``<stem>-3``... that is no other photo's own stem (``a.jpg a.png a-2.jpg``: a, a-3, a-2)."""
    if len(images) == 1:
        return [out]
    stems = [Path(image).stem or "photo" for image in images]
    taken: set[str] = set()
    reserved = set(stems)
    names = []
    for stem in stems:
        name, k = stem, 1
        while name in taken or (k > 1 and name in reserved):
            k += 1
            name = f"{stem}-{k}"
        taken.add(name)
        names.append(name)
    return [out / name for name in names]


def check_output(out: str | Path) -> Path:
    """The output folder, refused before any work when it cannot be one: empty, an existing file, or not
    writable."""
    if str(out).strip() == "":
        raise InputError("--out is empty; give the folder to write the results into")
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise InputError(f"--out {out} is an existing file, not a folder; give a folder to write the results into")
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"--out {out}: {existing} is a file, so the folder cannot be made there")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"--out {out}: no permission to write in {existing}")
    return path


def _wanted(image: str, depth: str | None, intrinsics: str | None, request: dict[str, str | bool]) -> dict | None:
    """What a result must record to be this measurement: the inputs' SHA-256, the options, the version (None
    when an input cannot be read: it is measured, and fails with its own message)."""
    hashes = {"image": _sha256(image)}
    if depth is not None:
        hashes["depth"] = _sha256(depth)
    if intrinsics is not None:
        hashes["intrinsics"] = _sha256(intrinsics)
    if None in hashes.values():
        return None
    return {"input_sha256": hashes, "request": request, "version": __version__}


def _done(folder: Path, wanted: dict | None) -> dict | None:
    """The result already in ``folder`` for this very measurement (same input bytes, options and version)."""
    path = folder / "result.json"
    if wanted is None or not path.is_file():
        return None
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, RecursionError):
        return None
    if not isinstance(result, dict):
        return None
    return result if all(result.get(key) == value for key, value in wanted.items()) else None


def measure_batch(
    images: Sequence[str],
    out: str | Path,
    depths: Sequence[str] | None = None,
    depth_unit: str = "mm",
    intrinsics: Sequence[str] | None = None,
    side: str = "auto",
    print_json: bool = False,
    embedded_depth: bool = True,
    same_foot: bool = False,
    reference: str = "auto",
) -> int:
    """Measure every photo (skipping those already measured into their folder); returns the exit code.

    ``same_foot``: the photos show one foot; also combine them (``same_foot.json`` in ``out``, footmesh.same_foot).
    ``reference``: the kind of reference object in the photos (``auto``: any; ``pipeline.measure_photo``).
    """
    out_dir = check_output(out)
    folders = output_folders(images, out_dir)
    results: list[tuple[str, dict | None, str | None]] = []
    internal = 0  # photos that failed by footmesh's fault, not theirs
    for i, (image, folder) in enumerate(zip(images, folders, strict=True)):
        k = None
        if intrinsics:
            k = intrinsics[0] if len(intrinsics) == 1 else intrinsics[i]
        depth = depths[i] if depths else None
        request = request_options(side, depth_unit, "auto", embedded_depth, reference)
        previous = _done(folder, _wanted(image, depth, k, request))
        if previous is not None:
            log.info("%s: already measured in %s (delete it to measure again)", image, folder)
            results.append((image, previous, None))
            continue
        try:
            start = time.perf_counter()
            # the inputs are checked before the pipeline (torch, the networks) is imported: a bad file is refused
            # in a fraction of a second, not after seconds of loading
            photo = load_photo(image, depth=depth, depth_unit=depth_unit, intrinsics=k, embedded_depth=embedded_depth)
            from footmesh.pipeline import measure_loaded_photo

            result = measure_loaded_photo(photo, folder, request, started=start)
            results.append((image, result, None))
            log.info("%s: %s", image, _one_line(result))
        except Exception as exc:  # the photo's fault, the disk's, or footmesh's (logged): the rest is still done
            message, ours = _failure(exc, folder)
            internal += ours
            results.append((image, None, message))
            print(f"footmesh: error: {_naming(image, message)}", file=sys.stderr)
    if print_json:
        payload = [r if r is not None else {"image": image, "error": error} for image, r, error in results]
        print(json.dumps(payload[0] if len(images) == 1 else payload, indent=2))
    if len(images) > 1:
        print(summary_table(results), file=sys.stderr if print_json else sys.stdout)
    elif results[0][1] is not None and not print_json:
        print(summary_table(results))
    if same_foot:
        from footmesh.report import write_json
        from footmesh.same_foot import combine, format_same_foot

        same = combine(results)
        write_json(out_dir / "same_foot.json", same.to_dict())
        print(format_same_foot(same), file=sys.stderr if print_json else sys.stdout)
    if internal:
        return 1
    return 0 if all(err is None for _, _, err in results) else 2


def _failure(exc: Exception, folder: Path) -> tuple[str, bool]:
    """(message, footmesh's fault) for a photo that gave no result."""
    if is_users_fault(exc):
        return str(exc), False
    if isinstance(exc, OSError) and _inside(exc.filename, folder):
        # writing the results (disk full, permissions changed): the rest can still be done
        return f"could not write its results into {folder}: {exc.strerror or exc}", False
    return write_internal_report(exc, __version__), True


def _inside(filename: object, folder: Path) -> bool:
    """Whether an OSError's file is ``folder`` or lies in it."""
    if not isinstance(filename, str | os.PathLike):
        return False
    path, target = Path(filename).resolve(), Path(folder).resolve()
    return path == target or target in path.parents


def _naming(image: str, message: str) -> str:
    """``message`` about ``image``, naming the photo once (loader messages name it already)."""
    return message if str(image) in message else f"{image}: {message}"


def _one_line(result: dict) -> str:
    m = result["measurements"]
    length, width = m["stick_length"]["value_mm"], m["ball_width"]["value_mm"]
    if length is None:
        ratios = result["ratios"]
        if "ball_width/stick_length" not in ratios:  # withheld: the foot was seen end-on (see its messages)
            return f"{result['side']} foot, unscaled, seen end-on (no width/length ratio)"
        return f"{result['side']} foot, unscaled (width/length {ratios['ball_width/stick_length']:.3f})"
    return f"{result['side']} foot, length {length:.1f} mm, ball width {width:.1f} mm ({result['scale_source']})"


def summary_table(results: list[tuple[str, dict | None, str | None]]) -> str:
    """A plain-text table: photo, side, scale source, length and width +- uncertainty, EU and UK sizes."""
    rows = [("photo", "side", "scale", "length mm", "ball width mm", "EU", "UK", "US men", "note")]
    for image, result, error in results:
        if result is None:
            rows.append((Path(image).name, "-", "-", "-", "-", "-", "-", "-", f"failed: {error}"))
            continue
        m, sizes = result["measurements"], result.get("sizes") or {}

        def mm(name: str, m: dict = m) -> str:
            v, u = m[name]["value_mm"], m[name]["uncertainty_mm"]
            if v is None:
                return "unscaled"
            return f"{v:.1f}" + (f" +- {u:.1f}" if u is not None else "")

        def size(system: str, sizes: dict = sizes) -> str:
            s = sizes.get(system) if isinstance(sizes, dict) else None
            return s.get("label", "-") if isinstance(s, dict) else "-"

        note = "; ".join(msg for msg in result.get("messages", []) if msg.startswith("unscaled"))[:60]
        if length_advice(m["stick_length"]["uncertainty_mm"], MeasureConfig().length_advice_mm) is not None:
            note = "over half a size: more photos narrow it (--same-foot)"  # the result's messages say it whole
        for foot in result.get("feet", []):
            if foot["measured"] and not foot["primary"]:
                other = foot["measurements"]["stick_length"]["value_mm"]
                length = "unscaled" if other is None else f"{other:.1f} mm"
                note = f"two feet: the other ({foot['side']}) {length}" + (f"; {note}" if note else "")
        rows.append(
            (
                Path(image).name,
                result["side"],
                result["scale_source"],
                mm("stick_length"),
                mm("ball_width"),
                size("eu"),
                size("uk"),
                size("us_men"),
                note,
            )
        )
    widths = [max(len(str(r[c])) for r in rows) for c in range(len(rows[0]))]
    return "\n".join("  ".join(str(v).ljust(w) for v, w in zip(r, widths, strict=True)).rstrip() for r in rows)
