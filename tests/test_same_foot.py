"""Several photos of one foot combined (``footmesh measure --same-foot``): the arithmetic, the warnings, end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from footmesh.same_foot import DISAGREEMENT_P, combine, combine_values


def result(length: float, u: float = 1.5, side: str = "left", scaled: bool = True) -> dict:
    value = length if scaled else None
    return {
        "side": side,
        "scaled": scaled,
        "measurements": {
            "stick_length": {"value_mm": value, "uncertainty_mm": u if scaled else None},
            "ball_width": {"value_mm": 0.4 * length if scaled else None, "uncertainty_mm": u if scaled else None},
        },
    }


def test_equal_uncertainties_give_the_mean_and_shrink_by_root_n():
    c = combine_values([240.0, 242.0], [2.0, 2.0])
    assert c.value_mm == pytest.approx(241.0) and c.uncertainty_mm == pytest.approx(2.0 / math.sqrt(2))
    assert c.chi2 == pytest.approx(0.5) and c.agree


def test_the_surer_photo_weighs_more():
    c = combine_values([240.0, 250.0], [1.0, 3.0])
    assert c.value_mm == pytest.approx((240 / 1 + 250 / 9) / (1 + 1 / 9))


@given(
    st.lists(
        st.tuples(st.floats(200, 300), st.floats(0.3, 10)),
        min_size=1,
        max_size=6,
    )
)
def test_the_combination_lies_within_the_values_and_is_surer_than_any(pairs):
    values, us = [v for v, _ in pairs], [u for _, u in pairs]
    c = combine_values(values, us)
    assert min(values) - 1e-9 <= c.value_mm <= max(values) + 1e-9
    assert c.uncertainty_mm <= min(us) + 1e-12
    assert 0.0 <= c.p_value <= 1.0


def test_photos_that_agree_within_their_uncertainties_give_no_warning():
    same = combine([("a.jpg", result(240.0), None), ("b.jpg", result(241.5), None), ("c.jpg", result(239.2), None)])
    assert same.warnings == () and same.images == ("a.jpg", "b.jpg", "c.jpg")
    assert same.measurements["stick_length"].agree


def test_photos_far_apart_for_their_uncertainties_are_said_to_disagree():
    same = combine([("a.jpg", result(240.0), None), ("b.jpg", result(262.0), None)])
    assert not same.measurements["stick_length"].agree
    assert same.measurements["stick_length"].p_value < DISAGREEMENT_P
    assert any("disagree beyond their uncertainties on stick length" in w for w in same.warnings)


def test_a_left_and_a_right_foot_are_not_the_same_foot():
    same = combine([("a.jpg", result(240.0), None), ("b.jpg", result(240.5, side="right"), None)])
    assert any("do not show the same foot" in w and "b.jpg a right foot" in w for w in same.warnings)


def test_refused_and_unscaled_photos_are_left_out_and_named():
    same = combine(
        [
            ("a.jpg", result(240.0), None),
            ("b.jpg", None, "the foot is cut off"),
            ("c.jpg", result(0, scaled=False), None),
        ]
    )
    assert same.images == ("a.jpg",) and len(same.left_out) == 2
    assert any("only 1 of 3 photos had millimetres" in w for w in same.warnings)
    assert json.loads(json.dumps(same.to_dict()))["measurements"]["stick_length"]["photos"] == 1


@pytest.mark.slow
def test_one_foot_from_a_depth_file_and_from_its_heic_agree_and_another_foot_does_not(tmp_path, capsys):
    from PIL import Image

    from footmesh.cli import main
    from footmesh.examples import examples
    from footmesh.formats.heif_writer import write_heic

    ex = {e.name: e for e in examples()}
    depth_ex = ex["depth_right"]
    rgb = np.asarray(Image.open(depth_ex.image).convert("RGB"))
    z = np.asarray(Image.open(depth_ex.depth)).astype(np.float64)[::4, ::4] / 1000.0
    near, far = 0.25, 3.1
    codes = np.where(z > 0, np.clip(np.round((z - near) / (far - near) * 1023), 1, 1022), 1023).astype(np.uint16)
    # one foot, two photos: stored upright, and stored sideways with EXIF 6 (as a phone held the other way)
    heic, heic_turned = tmp_path / "same.heic", tmp_path / "turned.heic"
    heic.write_bytes(write_heic(rgb, depth_samples=codes, z_near=near, z_far=far))
    exif = Image.Exif()
    exif[0x0112] = 6
    turned = {"exif": exif.tobytes(), "depth_samples": np.ascontiguousarray(np.rot90(codes, 1))}
    heic_turned.write_bytes(write_heic(np.ascontiguousarray(np.rot90(rgb, 1)), z_near=near, z_far=far, **turned))
    out = tmp_path / "out"
    k = str(depth_ex.intrinsics)
    argv = ["measure", str(heic), str(heic_turned), "--intrinsics", k, "--out", str(out), "--same-foot"]
    assert main(argv) == 0
    same = json.loads((out / "same_foot.json").read_text())
    assert same["images"] == [str(heic), str(heic_turned)] and same["warnings"] == []
    assert abs(same["measurements"]["stick_length"]["value_mm"] - depth_ex.truth_mm["stick_length"]) < 4.23
    assert "same foot, 2 photo(s) combined" in capsys.readouterr().out
    other = ex["a4_left"]
    assert main(["measure", str(heic), str(other.image), "--out", str(tmp_path / "two"), "--same-foot"]) == 0
    two = json.loads((tmp_path / "two" / "same_foot.json").read_text())
    assert any("do not show the same foot" in w for w in two["warnings"])
