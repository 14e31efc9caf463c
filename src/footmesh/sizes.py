"""Shoe sizes from foot length and ball width (formulas, sources and conventions: docs/sizes.md).

All inputs are FOOT dimensions in mm (stick length and ball width of ``footmesh.measure``), not last or shoe
dimensions. Each system turns the foot length into its size through the allowance it assumes between the foot
and the shoe last:

=============  ==================================  ===========================================  ==============
system         size from foot length L             convention                                   step sold
=============  ==================================  ===========================================  ==============
Mondopoint     L (mm)                              foot length itself (ISO 9407)                5 mm
EU (Paris)     1.5 (L[cm] + 1.5)                   last = foot + 15 mm, 1 size = 2/3 cm         1/2 size
UK adult       3 L[in] - 23                        last = foot + 2/3 in, 1 size = 1/3 in        1/2 size
UK child       3 L[in] - 10  (0 ... 13.5)          same scale, child 13.5 is followed by 1      1/2 size
US men         3 L[in] - 22                        Brannock men's scale: size 1 = 7 2/3 in      1/2 size
US women       3 L[in] - 21  (= men + 1)           Brannock women's scale (DESIGN.md)           1/2 size
US child       3 L[in] - 9 2/3  (0 ... 13.5)       US children's scale                          1/2 size
=============  ==================================  ===========================================  ==============

Sizes are rounded to the nearest step (ties upwards). A result without scale is unscaled: every size is None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

MM_PER_INCH = 25.4
MONDOPOINT_STEP_MM = 5.0
"""Mondopoint length step reported (ISO 9407 also grades some footwear in 7.5 mm steps; docs/sizes.md)."""
EU_ALLOWANCE_MM = 15.0
"""EU: last length = foot length + 15 mm (DESIGN.md: EU = 1.5 (L[cm] + 1.5))."""
PARIS_POINT_MM = 20.0 / 3.0
"""One EU size: 2/3 cm."""
EU_STEP = 0.5
"""EU sizes are sold in whole and half sizes (e.g. Nike's and adidas' charts); we round to the half size."""
BARLEYCORN_MM = MM_PER_INCH / 3.0
"""One UK/US size: 1/3 inch = 8.47 mm."""
HALF_SIZE_MM = BARLEYCORN_MM / 2.0
"""Half a UK/US size, the step they are sold in: 4.23 mm."""
UK_ADULT_OFFSET = 23.0
UK_CHILD_OFFSET = 10.0
US_MEN_OFFSET = 22.0
US_WOMEN_OFFSET = 21.0
US_CHILD_OFFSET = 29.0 / 3.0
"""Size = 3 L[in] - offset on each barleycorn scale (docs/sizes.md: the last-length forms and sources)."""
CHILD_RANGE = (0.0, 13.5)
"""Children's sizes run from 0 to 13.5 (UK and US); above comes adult size 1."""
FOOT_LENGTH_RANGE_MM = (50.0, 500.0)
"""A foot length outside this range is not a foot in millimetres."""


@dataclass(frozen=True)
class Size:
    """One shoe size: the rounded ``value`` customers buy, its ``label`` and the ``exact`` unrounded size."""

    value: float
    label: str
    exact: float

    def to_dict(self) -> dict[str, float | str]:
        return {"value": self.value, "label": self.label, "exact": self.exact}


@dataclass(frozen=True)
class ShoeSizes:
    """Sizes in every system for one foot; a field is None where the system has no size for this foot (a
    child's foot has no adult size) or the foot is unscaled."""

    foot_length_mm: float | None
    ball_width_mm: float | None
    mondopoint: Size | None
    eu: Size | None
    uk: Size | None
    uk_child: Size | None
    us_men: Size | None
    us_women: Size | None
    us_child: Size | None

    @property
    def scaled(self) -> bool:
        return self.foot_length_mm is not None

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = value.to_dict() if isinstance(value, Size) else value
        return out

    def labels(self) -> list[str]:
        """The labels of the defined sizes, e.g. ``["Mondopoint 270/102", "EU 43", "UK 8.5", ...]``."""
        return [v.label for f in fields(self) if isinstance(v := getattr(self, f.name), Size)]


def round_to_step(x: float, step: float) -> float:
    """Nearest multiple of ``step``; ties go up (a foot exactly between two sizes gets the larger shoe)."""
    return math.floor(x / step + 0.5) * step


def _fmt(x: float) -> str:
    return f"{x:g}"


def mondopoint(length_mm: float, ball_width_mm: float | None = None) -> Size:
    """Mondopoint (ISO 9407): foot length in mm to the 5 mm step; with the width, label "length/width"."""
    value = round_to_step(length_mm, MONDOPOINT_STEP_MM)
    label = f"Mondopoint {value:.0f}"
    if ball_width_mm is not None:
        label += f"/{round(ball_width_mm):.0f}"
    return Size(value, label, float(length_mm))


def eu_size(length_mm: float) -> Size:
    """EU (Paris point): last length (foot + 15 mm) in units of 2/3 cm, to the half size (``EU_STEP``)."""
    exact = (length_mm + EU_ALLOWANCE_MM) / PARIS_POINT_MM
    value = round_to_step(exact, EU_STEP)
    return Size(value, f"EU {_fmt(value)}", exact)


def _barleycorn(length_mm: float, offset: float) -> float:
    return 3.0 * length_mm / MM_PER_INCH - offset


def _adult(length_mm: float, offset: float, prefix: str, smallest: float = 1.0) -> Size | None:
    exact = _barleycorn(length_mm, offset)
    value = round_to_step(exact, 0.5)
    return Size(value, f"{prefix} {_fmt(value)}", exact) if value >= smallest else None


def _child(length_mm: float, offset: float, prefix: str) -> Size | None:
    exact = _barleycorn(length_mm, offset)
    value = round_to_step(exact, 0.5)
    lo, hi = CHILD_RANGE
    return Size(value, f"{prefix} {_fmt(value)}", exact) if lo <= value <= hi else None


def length_advice(uncertainty_mm: float | None, limit_mm: float | None) -> str | None:
    """What a result whose foot length is known only to more than ``limit_mm`` (+- one uncertainty) says, or None."""
    if uncertainty_mm is None or limit_mm is None or uncertainty_mm <= limit_mm:
        return None
    return (
        f"the length is known to +- {uncertainty_mm:.1f} mm, more than half a shoe size ({limit_mm:.1f} mm): for a "
        "closer figure measure more photos of the same foot together (footmesh measure --same-foot), best from the "
        "side and above with the heel in view"
    )


def shoe_sizes(length_mm: float | None, ball_width_mm: float | None = None) -> ShoeSizes:
    """Shoe sizes of a foot.

    Args:
        length_mm: foot (stick) length, mm; None for an unscaled foot (every size None).
        ball_width_mm: foot (ball) width, mm, for the Mondopoint width; optional.

    Raises:
        ValueError: a length or width that is not a finite foot dimension in mm.
    """
    if length_mm is None:
        return ShoeSizes(None, None, None, None, None, None, None, None, None)
    length = float(length_mm)
    lo, hi = FOOT_LENGTH_RANGE_MM
    if not math.isfinite(length) or not lo <= length <= hi:
        hint = " (metres? give millimetres)" if 0 < length < 1 else ""
        raise ValueError(f"foot length {length_mm!r} is not a foot length in mm in [{lo:.0f}, {hi:.0f}]{hint}")
    width = None
    if ball_width_mm is not None:
        width = float(ball_width_mm)
        if not math.isfinite(width) or not 0.2 * length <= width <= 0.7 * length:
            raise ValueError(
                f"ball width {ball_width_mm!r} mm is not plausible for a {length:.0f} mm foot "
                "(expected 20-70 % of the length, in mm)"
            )
    return ShoeSizes(
        foot_length_mm=length,
        ball_width_mm=width,
        mondopoint=mondopoint(length, width),
        eu=eu_size(length),
        uk=_adult(length, UK_ADULT_OFFSET, "UK"),
        uk_child=_child(length, UK_CHILD_OFFSET, "UK child"),
        us_men=_adult(length, US_MEN_OFFSET, "US M"),
        us_women=_adult(length, US_WOMEN_OFFSET, "US W"),
        us_child=_child(length, US_CHILD_OFFSET, "US child"),
    )
