"""``footmesh measure`` over several photos: one folder each, resumable, failures reported and the rest done."""

from __future__ import annotations

import hashlib
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from footmesh.load import LoadError
from footmesh.pipeline import PipelineError, measure_photo

log = logging.getLogger("footmesh.measure")


def _sha256(path: str | Path) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def output_folders(images: Sequence[str], out: Path) -> list[Path]:
    """``out`` for one photo; ``out/<stem>`` each for several (``<stem>-2``... when stems repeat)."""
    if len(images) == 1:
        return [out]
    seen: dict[str, int] = {}
    folders = []
    for image in images:
        stem = Path(image).stem or "photo"
        seen[stem] = seen.get(stem, 0) + 1
        folders.append(out / (stem if seen[stem] == 1 else f"{stem}-{seen[stem]}"))
    return folders


def _done(folder: Path, image: str) -> dict | None:
    """The result already in ``folder`` for this very photo (same bytes), if any."""
    path = folder / "result.json"
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return result if result.get("input_sha256", {}).get("image") == _sha256(image) else None


def measure_batch(
    images: Sequence[str],
    out: str | Path,
    depths: Sequence[str] | None = None,
    depth_unit: str = "mm",
    intrinsics: Sequence[str] | None = None,
    side: str = "auto",
    print_json: bool = False,
) -> int:
    """Measure every photo (skipping those already measured into their folder); returns the exit code."""
    out = Path(out)
    folders = output_folders(images, out)
    results: list[tuple[str, dict | None, str | None]] = []
    for i, (image, folder) in enumerate(zip(images, folders, strict=True)):
        k = None
        if intrinsics:
            k = intrinsics[0] if len(intrinsics) == 1 else intrinsics[i]
        depth = depths[i] if depths else None
        previous = _done(folder, image) if depth is None and k is None else None
        if previous is not None:
            log.info("%s: already measured in %s (delete it to measure again)", image, folder)
            results.append((image, previous, None))
            continue
        try:
            result = measure_photo(image, folder, depth=depth, depth_unit=depth_unit, intrinsics=k, side=side)
            results.append((image, result, None))
            log.info("%s: %s", image, _one_line(result))
        except (PipelineError, LoadError, FileNotFoundError, ValueError) as exc:
            results.append((image, None, str(exc)))
            print(f"footmesh: error: {image}: {exc}", file=sys.stderr)
    if print_json:
        payload = [r for _, r, _ in results if r is not None]
        print(json.dumps(payload[0] if len(images) == 1 and payload else payload, indent=2))
    if len(images) > 1:
        print(summary_table(results), file=sys.stderr if print_json else sys.stdout)
    elif results[0][1] is not None and not print_json:
        print(summary_table(results))
    return 0 if all(err is None for _, _, err in results) else 2


def _one_line(result: dict) -> str:
    m = result["measurements"]
    length, width = m["stick_length"]["value_mm"], m["ball_width"]["value_mm"]
    if length is None:
        return (
            f"{result['side']} foot, unscaled (width/length {result['ratios'].get('ball_width/stick_length', 0):.3f})"
        )
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
