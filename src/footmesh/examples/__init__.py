"""The bundled example photos (synthetic, with known truth) that ``footmesh demo`` measures."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).parent


@dataclass(frozen=True)
class Example:
    """One bundled photo: image, optional depth map and intrinsics, and the true measurements (mm)."""

    name: str
    image: Path
    depth: Path | None
    intrinsics: Path | None
    side: str
    truth_mm: dict[str, float]


def examples() -> list[Example]:
    """The bundled examples, in a fixed order (made by ``python -m footmesh.examples.make_examples``)."""
    truth = json.loads((HERE / "truth.json").read_text())
    out = []
    for name, t in truth.items():
        depth = HERE / f"{name}.depth.png"
        k = HERE / f"{name}.K.json"
        out.append(
            Example(
                name,
                HERE / f"{name}.jpg",
                depth if depth.is_file() else None,
                k if k.is_file() else None,
                t["side"],
                t["measurements_mm"],
            )
        )
    return out
