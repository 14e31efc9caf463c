"""Several photos of one foot: their measurements combined by inverse variance, and a check that they agree.

``footmesh measure a.jpg b.jpg c.jpg --same-foot`` measures each photo as usual and then
:func:`combine` weighs every scaled measurement by ``1 / u^2`` (``u`` its one-SD uncertainty): the combined value
is ``sum(x / u^2) / sum(1 / u^2)`` with uncertainty ``1 / sqrt(sum(1 / u^2))``. The photos disagree when their
spread is beyond what their uncertainties allow: the chi-square of the values about the combined one, with
``n - 1`` degrees of freedom, has a p-value below ``DISAGREEMENT_P``; or when they see different sides.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from scipy.stats import chi2

DISAGREEMENT_P = 0.01
"""Photos whose spread of a measurement is this unlikely under their own uncertainties are said to disagree."""


@dataclass(frozen=True)
class Combined:
    """One measurement over several photos: the inverse-variance mean, its uncertainty and the agreement test."""

    value_mm: float
    uncertainty_mm: float
    photos: int
    chi2: float  # of the photos' values about value_mm, in their own uncertainties
    p_value: float  # of chi2 with photos - 1 degrees of freedom (1.0 for one photo)

    @property
    def agree(self) -> bool:
        """Whether the photos' values are consistent with their uncertainties."""
        return self.p_value >= DISAGREEMENT_P


@dataclass(frozen=True)
class SameFoot:
    """What photos of one foot say together (``footmesh measure --same-foot``)."""

    measurements: dict[str, Combined]
    images: tuple[str, ...]  # the photos that had millimetres
    sides: tuple[str, ...]  # their sides, in the same order
    left_out: tuple[str, ...]  # photos refused or unscaled, with why
    warnings: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``same_foot.json``)."""
        return {
            "images": list(self.images),
            "sides": list(self.sides),
            "left_out": list(self.left_out),
            "measurements": {
                name: {
                    "value_mm": round(c.value_mm, 2),
                    "uncertainty_mm": round(c.uncertainty_mm, 2),
                    "photos": c.photos,
                    "chi2": round(c.chi2, 3),
                    "p_value": round(c.p_value, 4),
                    "agree": c.agree,
                }
                for name, c in self.measurements.items()
            },
            "warnings": list(self.warnings),
        }


def combine_values(values_mm: list[float], uncertainties_mm: list[float]) -> Combined:
    """The inverse-variance combination of one measurement's values (mm) with their one-SD uncertainties (mm)."""
    if not values_mm or len(values_mm) != len(uncertainties_mm):
        raise ValueError("give one uncertainty per value, and at least one value")
    if any(not (math.isfinite(u) and u > 0) for u in uncertainties_mm):
        raise ValueError(f"uncertainties must be positive and finite, got {uncertainties_mm}")
    weights = [1.0 / u**2 for u in uncertainties_mm]
    total = sum(weights)
    mean = sum(w * x for w, x in zip(weights, values_mm, strict=True)) / total
    spread = sum(w * (x - mean) ** 2 for w, x in zip(weights, values_mm, strict=True))
    dof = len(values_mm) - 1
    return Combined(mean, 1.0 / math.sqrt(total), len(values_mm), spread, float(chi2.sf(spread, dof)) if dof else 1.0)


def combine(results: list[tuple[str, dict | None, str | None]]) -> SameFoot:
    """Combine the scaled results of photos of one foot; (image, result dict or None, error) per photo."""
    used: list[tuple[str, dict]] = []
    left_out = []
    for image, result, error in results:
        if result is None:
            left_out.append(f"{image}: refused ({error})")
        elif not result["scaled"]:
            left_out.append(f"{image}: unscaled (no depth or reference object)")
        else:
            used.append((image, result))
    warnings = []
    measurements: dict[str, Combined] = {}
    if used:
        for name in used[0][1]["measurements"]:
            pairs = [(r["measurements"][name]["value_mm"], r["measurements"][name]["uncertainty_mm"]) for _, r in used]
            pairs = [(v, u) for v, u in pairs if v is not None and u is not None and u > 0]
            if pairs:
                measurements[name] = combine_values([v for v, _ in pairs], [u for _, u in pairs])
    sides = tuple(r["side"] for _, r in used)
    if len(set(sides)) > 1:
        warnings.append(
            "the photos do not show the same foot: "
            + ", ".join(f"{image} a {side} foot" for (image, _), side in zip(used, sides, strict=True))
        )
    disagree = [name for name, c in measurements.items() if not c.agree]
    if disagree:
        warnings.append(
            "the photos disagree beyond their uncertainties on "
            + ", ".join(f"{name.replace('_', ' ')} (p = {measurements[name].p_value:.2g})" for name in disagree)
            + "; retake the one that differs (see each photo's overlay) or check they show the same foot"
        )
    if len(used) < 2:
        warnings.append(f"only {len(used)} of {len(results)} photos had millimetres, so nothing was cross-checked")
    return SameFoot(measurements, tuple(image for image, _ in used), sides, tuple(left_out), tuple(warnings))


def format_same_foot(same: SameFoot) -> str:
    """Plain-text lines: the combined length and ball width, then the warnings."""
    lines = [f"same foot, {len(same.images)} photo(s) combined:"]
    for name in ("stick_length", "ball_width"):
        if name in same.measurements:
            c = same.measurements[name]
            agreement = "agree" if c.agree else f"DISAGREE (p = {c.p_value:.2g})"
            lines.append(f"  {name.replace('_', ' ')}: {c.value_mm:.1f} +- {c.uncertainty_mm:.1f} mm ({agreement})")
    lines += [f"  warning: {w}" for w in same.warnings]
    lines += [f"  left out: {x}" for x in same.left_out]
    return "\n".join(lines)
