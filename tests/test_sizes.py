"""Shoe sizes against published charts and the properties of the formulas (docs/sizes.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from footmesh.config import MeasureConfig
from footmesh.sizes import BARLEYCORN_MM, HALF_SIZE_MM, ShoeSizes, length_advice, shoe_sizes

INCH = 25.4

# US retail conversion chart, foot length in inches -> US men's size, as published at
# https://footsizechart.com/men-shoe-size (also reproduced at https://en.razmery.info/clothes/the-sizes-of-shoe.html).
# (US men, UK as printed there, foot length in inches)
US_MEN_CHART = [
    (6, 5.5, 9.25), (6.5, 6, 9.5), (7, 6.5, 9.625), (7.5, 7, 9.75), (8, 7.5, 9.9375), (8.5, 8, 10.125),
    (9, 8.5, 10.25), (9.5, 9, 10.4375), (10, 9.5, 10.5625), (10.5, 10, 10.75), (11, 10.5, 10.9375),
    (11.5, 11, 11.125), (12, 11.5, 11.25), (13, 12.5, 11.5625), (14, 13.5, 11.875), (15, 14.5, 12.1875),
    (16, 15.5, 12.5),
]  # fmt: skip

# Same source (razmery.info), women's chart: (US women, foot length in inches).
US_WOMEN_CHART = [
    (4, 8 + 3 / 16), (4.5, 8.375), (5, 8.5), (5.5, 8.75), (6, 8.875), (6.5, 9 + 1 / 16), (7, 9.25),
    (7.5, 9.375), (8, 9.5), (8.5, 9 + 11 / 16), (9, 9.875), (9.5, 10), (10, 10 + 3 / 16),
    (10.5, 10 + 5 / 16), (11, 10.5), (11.5, 10 + 11 / 16), (12, 10.875),
]  # fmt: skip

# Nike men's size chart (foot length in cm -> EU) as reproduced in "The Ultimate Nike Men's Shoe Sizing Chart"
# (https://visualfoodie.com/the-ultimate-nike-mens-shoe-sizing-chart): (foot length cm, EU).
# Only its EU column is asserted: its US column runs about one size below the Brannock scale (docs/sizes.md).
NIKE_EU_CHART = [
    (24.0, 38.5), (24.5, 39), (25.0, 40), (25.5, 40.5), (26.0, 41), (26.5, 42), (27.0, 42.5), (27.5, 43),
    (28.0, 44), (28.5, 44.5),
]  # fmt: skip

HALF_SIZE = 0.5


@pytest.mark.parametrize(("us", "uk", "inches"), US_MEN_CHART)
def test_us_men_within_half_a_size_of_chart(us, uk, inches):
    s = shoe_sizes(inches * INCH)
    assert abs(s.us_men.value - us) <= HALF_SIZE
    # The chart prints UK = US - 0.5; we follow DESIGN.md (UK = 3 L - 23 = US - 1): at most one size apart.
    assert abs(s.uk.value - uk) <= 1.0


@pytest.mark.parametrize(("us", "inches"), US_WOMEN_CHART)
def test_us_women_within_half_a_size_of_chart(us, inches):
    assert abs(shoe_sizes(inches * INCH).us_women.value - us) <= HALF_SIZE


@pytest.mark.parametrize(("cm", "eu"), NIKE_EU_CHART)
def test_eu_within_half_a_size_of_nike_chart(cm, eu):
    assert abs(shoe_sizes(cm * 10).eu.value - eu) <= HALF_SIZE


def test_brannock_anchor():
    # Brannock scale: men's size 1 is a 7 2/3 inch foot, each size 1/3 inch more.
    for n in range(1, 16):
        s = shoe_sizes((7 + 2 / 3 + (n - 1) / 3) * INCH)
        assert s.us_men.value == n and math.isclose(s.us_men.exact, n, abs_tol=1e-9)
        assert s.us_women.value == n + 1
        if n > 1:
            assert s.uk.value == n - 1


def test_labels_and_dict():
    s = shoe_sizes(270.0, 102.4)
    assert s.mondopoint.label == "Mondopoint 270/102"
    assert s.eu.label == "EU 43"  # 1.5 * (27 + 1.5) = 42.75
    assert s.us_men.label == "US M 10"  # 3 * 10.63 - 22 = 9.89
    assert s.us_women.label == "US W 11"
    assert s.uk.label == "UK 9"
    assert s.uk_child is None and s.us_child is None
    d = s.to_dict()
    assert d["us_men"] == {"value": 10.0, "label": "US M 10", "exact": pytest.approx(9.8898, abs=1e-3)}
    assert d["foot_length_mm"] == 270.0 and d["uk_child"] is None
    assert "EU 43" in s.labels()


def test_children():
    # UK child 13.5 is followed by adult 1 (one barleycorn apart); US child by youth/men's 1.
    child = shoe_sizes((13.5 + 10) / 3 * INCH)
    assert child.uk_child.value == 13.5 and child.uk is None
    adult = shoe_sizes((1 + 23) / 3 * INCH)
    assert adult.uk.value == 1 and adult.uk_child is None
    small = shoe_sizes(120.0)  # a toddler: UK child 4, US child 4.5
    assert small.uk_child.label == "UK child 4" and small.us_child.label == "US child 4.5"
    assert small.us_men is None and small.us_women is None and small.uk is None
    assert shoe_sizes(60.0).uk_child is None  # below UK child size 0


def test_unscaled():
    s = shoe_sizes(None)
    assert isinstance(s, ShoeSizes) and not s.scaled
    assert all(v is None for v in s.to_dict().values())


@pytest.mark.parametrize("bad", [0.27, 27.0, float("nan"), float("inf"), -250.0, 900.0])
def test_bad_length(bad):
    with pytest.raises(ValueError, match="foot length"):
        shoe_sizes(bad)


def test_metres_hint():
    with pytest.raises(ValueError, match="metres"):
        shoe_sizes(0.27)


def test_bad_width():
    with pytest.raises(ValueError, match="ball width"):
        shoe_sizes(270.0, 0.1)


@given(st.floats(215.0, 340.0), st.floats(0.01, 30.0))
def test_monotone_in_length(length, delta):
    a, b = shoe_sizes(length), shoe_sizes(length + delta)
    for name in ("mondopoint", "eu", "uk", "us_men", "us_women"):
        assert getattr(b, name).value >= getattr(a, name).value
        assert getattr(b, name).exact > getattr(a, name).exact


@given(st.floats(215.0, 340.0))
def test_scale_offsets(length):
    s = shoe_sizes(length)
    assert math.isclose(s.us_women.exact - s.us_men.exact, 1.0, abs_tol=1e-9)  # US W = US M + 1 (DESIGN.md)
    assert math.isclose(s.us_men.exact - s.uk.exact, 1.0, abs_tol=1e-9)  # UK = US M - 1
    assert s.us_women.value - s.us_men.value == 1.0 and s.us_men.value - s.uk.value == 1.0
    for name in ("uk", "us_men", "us_women"):
        v = getattr(s, name)
        assert v.value * 2 == round(v.value * 2) and abs(v.value - v.exact) <= 0.25 + 1e-9
    assert abs(s.eu.value - s.eu.exact) <= 0.25 + 1e-9 and s.eu.value * 2 == round(s.eu.value * 2)
    assert s.mondopoint.value % 5 == 0 and abs(s.mondopoint.value - length) <= 2.5 + 1e-9


def test_one_size_steps():
    # One barleycorn more foot is one UK/US size more; 6.67 mm is one EU size.
    base = shoe_sizes(250.0)
    up = shoe_sizes(250.0 + BARLEYCORN_MM)
    assert np.isclose(up.us_men.exact - base.us_men.exact, 1.0)
    assert np.isclose(shoe_sizes(250.0 + 20 / 3).eu.exact - base.eu.exact, 1.0)


def test_a_length_known_to_more_than_half_a_size_says_which_photo_would_narrow_it():
    limit = MeasureConfig().length_advice_mm
    assert limit == HALF_SIZE_MM == BARLEYCORN_MM / 2
    assert length_advice(3.0, limit) is None and length_advice(None, limit) is None
    advice = length_advice(9.5, limit)
    assert advice.startswith("the length is known to +- 9.5 mm, more than half a shoe size (4.2 mm)")
    assert "from the side" in advice and "--same-foot" in advice
    assert length_advice(9.5, MeasureConfig(length_advice_mm=None).length_advice_mm) is None
