"""The result of measuring one photo, typed: ``MeasureResult`` serialises to the documented ``result.json``.

The JSON contract (docs/measure.md) only ever gains keys. Each field's ``doc`` is its meaning there; the web API
publishes ``json_schema()`` as the schema of ``POST /api/measure``'s answer.
"""

from __future__ import annotations

import types
import typing
from dataclasses import dataclass, field, fields, replace
from typing import Any

RESULT_FORMAT = "footmesh-result-1"


def _doc(text: str, **kwargs: Any) -> Any:
    return field(metadata={"doc": text}, **kwargs)


@dataclass(frozen=True)
class FootEntry:
    """One foot of a photo showing two (``MeasureResult.feet``): measured, or refused with its reason."""

    index: int = _doc("the foot's place among the regions found, largest first")
    measured: bool = _doc("whether this foot was measured")
    error: str | None = _doc("why it was not measured (refused feet only)", default=None)
    primary: bool | None = _doc("whether the result's own keys describe this foot", default=None)
    side: str | None = _doc("left or right", default=None)
    side_source: str | None = _doc("how the side was chosen", default=None)
    scale_source: str | None = _doc("depth, a4, card, marker, letter or none", default=None)
    scaled: bool | None = _doc("whether millimetres are real", default=None)
    measurements: dict[str, Any] | None = _doc("{name: {value_mm, uncertainty_mm}}", default=None)
    sizes: dict[str, Any] | None = _doc("{system: {value, label, exact} or null}", default=None)
    joints2d_px: list[list[float]] | None = _doc("18 x 2 joints in photo pixels", default=None)
    files: dict[str, str] | None = _doc("{mask_png: file name}", default=None)

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: a refused foot has only index, measured and error."""
        if not self.measured:
            return {"index": self.index, "measured": False, "error": self.error}
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "error"}


@dataclass(frozen=True)
class MeasureResult:
    """Everything ``footmesh measure`` says about one photo (the keys of ``result.json``, in its order)."""

    input_sha256: dict[str, str] = _doc("SHA-256 of the image (and depth map, K.json)")
    image: dict[str, int] = _doc("{width, height} of the upright photo")
    intrinsics: dict[str, Any] = _doc(
        "{fx, fy, cx, cy, width, height, source, note}; source: file, exif, default, reference"
    )
    depth: dict[str, Any] | None = _doc("where the depth came from (a --depth file or the photo's own), or null")
    input: str = _doc("networks used: rgb, rgbd or depth")
    side: str = _doc("left or right")
    side_losses: dict[str, float] = _doc("the fit cost of each side tried")
    side_source: str = _doc("how the side was chosen: given, pair, fit, decoder or cues")
    scale_source: str = _doc("depth, a4, card, marker, letter, or none (then every millimetre value is null)")
    scaled: bool = _doc("whether millimetres are real")
    reference: dict[str, Any] | None = _doc(
        "the reference object found: kind, corners_px, size_mm, scale_rel_sd, kind_assumed (a sheet whose proportions "
        "were not seen, taken to be the sheet searched first)"
    )
    measurements: dict[str, dict[str, float | None]] = _doc("{name: {value_mm, uncertainty_mm}}, the eight")
    ratios: dict[str, float] = _doc("scale-free ratios, given even when unscaled")
    sizes: dict[str, Any] = _doc("{system: {value, label, exact} or null}; null values when unscaled")
    joints2d_px: list[list[float]] = _doc("18 x 2 joints in the photo's pixels (DESIGN.md order)")
    joint_confidence: list[float] = _doc("18 probabilities that each joint is visible")
    joints3d_mm: list[list[float]] | None = _doc("18 x 3 fitted joints, camera frame, mm (null when unscaled)")
    angles: dict[str, float] = _doc("the 22 joint angles of the fitted pose, radians")
    shape: list[float] = _doc("PCA shape coefficients, SD units")
    fit: dict[str, Any] = _doc("loss, iterations, terms (cost per term), quality (FitQuality)")
    timings_s: dict[str, float] = _doc("seconds per stage")
    messages: list[str] = _doc("notes: how the intrinsics were chosen, how to get millimetres when unscaled...")
    units: str = _doc("mm, or unscaled")
    files: dict[str, str] = _doc("{key: file name} of the result's files")
    feet: tuple[FootEntry, ...] | None = _doc("each foot, only with two feet in view", default=None)
    request: dict[str, str | bool] | None = _doc(
        "the options asked for: side, depth_unit, input, embedded_depth, reference", default=None
    )
    seconds: float | None = _doc("time in all", default=None)
    version: str = _doc("the footmesh version that measured", default="")
    format: str = _doc(f"{RESULT_FORMAT}", default=RESULT_FORMAT)

    def with_message(self, message: str) -> MeasureResult:
        """A copy with ``message`` appended to ``messages``."""
        return replace(self, messages=[*self.messages, message])

    def to_dict(self) -> dict[str, Any]:
        """The ``result.json`` object (``feet`` only with two feet in view)."""
        out: dict[str, Any] = {"format": self.format, "version": self.version}
        for f in fields(self):
            if f.name in ("format", "version") or (f.name == "feet" and self.feet is None):
                continue
            value = getattr(self, f.name)
            out[f.name] = [foot.to_dict() for foot in value] if f.name == "feet" else value
        return out


def json_schema() -> dict[str, Any]:
    """A JSON Schema (draft 2020-12) of ``result.json``, from the fields' types and docs."""
    feet = {"type": "object", "properties": _properties(FootEntry), "required": ["index", "measured"]}
    props = _properties(MeasureResult)
    props["feet"] = {"type": "array", "items": feet, "description": props["feet"]["description"]}
    required = [f.name for f in fields(MeasureResult) if f.name not in ("feet", "request", "seconds")]
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "type": "object",
        "title": "footmesh result",
        "properties": props,
        "required": required,
    }


def _properties(cls: type) -> dict[str, dict[str, Any]]:
    hints = typing.get_type_hints(cls)
    return {f.name: {**_json_type(hints[f.name]), "description": f.metadata["doc"]} for f in fields(cls)}


_SCALARS = {str: "string", bool: "boolean", int: "integer", float: "number", type(None): "null"}


def _json_type(hint: Any) -> dict[str, Any]:
    """The JSON Schema of a type hint (the few shapes used above)."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return {"anyOf": [_json_type(arg) for arg in typing.get_args(hint)]}
    if origin is dict:
        return {"type": "object"}
    if origin in (list, tuple):
        return {"type": "array"}
    if hint is Any:
        return {}
    return {"type": _SCALARS[hint]}
