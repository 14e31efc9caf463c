"""``footmesh eval real``: mask scores, and a set of photos with known masks scored end to end."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest

from footmesh.eval.real import evaluate_set, format_table, mask_scores, read_set, summarise


def test_mask_scores_of_overlapping_rectangles():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[0:4, 0:5] = True  # 20 px
    b[2:6, 0:5] = True  # 20 px, 10 shared
    iou, precision, recall = mask_scores(a, b)
    assert iou == pytest.approx(10 / 30)
    assert precision == pytest.approx(0.5) and recall == pytest.approx(0.5)
    assert mask_scores(np.zeros((3, 3), bool), np.zeros((3, 3), bool)) == (1.0, 1.0, 1.0)
    assert mask_scores(a, np.zeros_like(a))[:2] == (0.0, 0.0)


def test_a_rendered_set_with_its_true_masks_scores_high(tmp_path):
    """Renders (the networks' own domain) stand in for real photos: the whole-photo silhouette must land on the
    foot, and a wrongly placed mask must score low, so the scoring cannot pass whatever it is given."""
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    renderer = Renderer(SynthConfig(size=256, frame_reference=True))
    (tmp_path / "photos").mkdir()
    (tmp_path / "masks").mkdir()
    labels = {}
    for i in range(2):
        sample = renderer.render(7, i)
        name = f"{i}.png"
        cv2.imwrite(str(tmp_path / "photos" / name), sample["rgb"][..., ::-1])
        truth = (np.asarray(sample["silhouette"], np.float32) >= 0.5).astype(np.uint8)
        if i == 1:
            truth = np.roll(truth, 128, axis=1)  # the mask of another photo
        cv2.imwrite(str(tmp_path / "masks" / name), truth * (2 if int(sample["side"]) else 1))
        side = "right" if int(sample["side"]) else "left"
        labels[name] = {
            "photo": f"photos/{name}",
            "mask": f"masks/{name}",
            "size": [256, 256],
            "feet": [{"side": side}],
        }
    (tmp_path / "labels.json").write_text(json.dumps(labels))
    sheet = tmp_path / "sheet.png"
    scores = evaluate_set(tmp_path, sheet, progress=False, measure=True)
    assert scores[0].iou > 0.7
    assert scores[1].iou < scores[0].iou - 0.3
    assert len(scores[0].crop_ious) == 1 and scores[0].crop_ious[0] > 0.7  # the crop the fit sees, on the foot
    assert len(scores[0].located_ious) == 1 and scores[0].located_ious[0] > 0.7  # the pipeline's located foot
    assert scores[1].located_ious[0] < 0.3  # on the wrong mask: the scoring tells
    assert scores[0].answered and scores[0].measured_ious[0] > 0.7  # footmesh measure's mask.png, on the foot
    assert scores[1].measured_ious[0] < 0.3
    assert scores[0].measured_sides == scores[0].feet  # the side result.json gives the foot measured there
    assert scores[1].measured_sides == ("",)  # no mask of its on the (wrong) hand-drawn foot
    assert (scores[0].off_feet, scores[0].primary_off_feet) == (0, False)
    assert (scores[1].off_feet, scores[1].primary_off_feet) == (1, True)  # measured on what the drawing says is floor
    assert scores[0].predicted_sides == scores[0].feet  # the shipped RGB network's left/right head
    assert cv2.imread(str(sheet)).shape[:2] == (240, 480)
    table = format_table("renders", summarise(scores))
    assert "2 photos, 2 feet" in table and "mean silhouette IoU" in table and "on the crop" in table
    assert "located foot" in table and re.search(r"photos answered by footmesh measure +2 ", table)
    assert re.search(r"side right, per measured foot +100.0 % of 1 ", table)
    assert re.search(r"measured feet mostly off every drawn foot +1 ", table)


def test_a_folder_without_labels_is_refused_clearly(tmp_path):
    with pytest.raises(ValueError, match="no labels.json"):
        read_set(tmp_path)
    (tmp_path / "labels.json").write_text('{"a": {"photo": "a.jpg"}}')
    with pytest.raises(ValueError, match="lacks feet, mask"):
        read_set(tmp_path)
