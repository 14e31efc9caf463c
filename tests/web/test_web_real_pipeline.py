"""The web app with its default measure function, the real pipeline (``footmesh.pipeline.measure_photo``).

The other web tests use the fake pipeline.
"""

from __future__ import annotations

import io

import numpy as np
import trimesh

CONTRACT_KEYS = {"version", "input_sha256", "side", "scale_source", "measurements", "ratios", "sizes"}
CONTRACT_KEYS |= {"joints2d_px", "joints3d_mm", "angles", "files", "messages"}
MEASUREMENTS = {"stick_length", "ball_width", "heel_width", "toe_height", "arch_height", "instep_height"}
MEASUREMENTS |= {"ball_girth", "instep_girth"}


def test_real_pipeline_through_the_api(make_client, demo_photo, blank_photo):
    from footmesh.web.jobs import default_measure

    client = make_client(default_measure, time_limit_s=300.0)  # thread isolation: no forkserver start-up
    response = client.post("/api/measure", files={"photo": ("foot.jpg", demo_photo, "image/jpeg")})
    assert response.status_code == 200, response.text
    result = response.json()
    assert CONTRACT_KEYS <= set(result)
    assert set(result["measurements"]) == MEASUREMENTS
    assert result["scale_source"] in {"depth", "a4", "card", "marker", "declared", "none"}
    if result["scale_source"] == "none":  # no scale evidence: no millimetres invented (docs/measure.md)
        assert result["joints3d_mm"] is None
        assert all(m["value_mm"] is None for m in result["measurements"].values())
    else:
        assert np.asarray(result["joints3d_mm"]).shape == (18, 3)
    rid = response.headers["X-Result-Id"]
    for key in ("mesh_obj", "mesh_glb", "overlay_png", "result_json"):
        assert client.get(f"/api/results/{rid}/{result['files'][key]}").status_code == 200, key
    obj = client.get(f"/api/results/{rid}/{result['files']['mesh_obj']}").content
    assert len(trimesh.load(io.BytesIO(obj), file_type="obj", process=False).faces) > 100

    refused = client.post("/api/measure", files={"photo": ("floor.png", blank_photo, "image/png")})
    assert 400 <= refused.status_code < 500, refused.text
    assert isinstance(refused.json()["detail"], str) and "\n" not in refused.json()["detail"]
