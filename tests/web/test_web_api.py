"""The web API with the fake pipeline: good and bad uploads, limits, queue, time limit, isolation, downloads."""

from __future__ import annotations

import hashlib
import io
import json
import multiprocessing
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from _fake_pipeline import FakeMeasure, fake_measure  # noqa: E402
from _photos import png_bytes  # noqa: E402
from _stub_pipeline import StubMeasure  # noqa: E402
from PIL import Image

from footmesh.errors import Refusal

MEASURE = "/api/measure"


def post_photo(client, data: bytes, name: str = "foot.jpg", content_type: str = "image/jpeg", **fields):
    return client.post(MEASURE, files={"photo": (name, data, content_type)}, data=fields)


def upload_dirs(tmp_path) -> list:
    """Request folders still on disk (each request's uploads live in one)."""
    return [p for p in tmp_path.glob("footmesh-uploads-*/*")]


def wait_until(condition, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.01)


# ----------------------------------------------------------------------------------------------------------
# Good input
# ----------------------------------------------------------------------------------------------------------


def test_good_photo_gives_result_and_downloads(make_client, demo_photo, tmp_path):
    client = make_client()
    response = post_photo(client, demo_photo, side="right")
    assert response.status_code == 200, response.text
    result = response.json()
    assert result["side"] == "right"
    assert result["scale_source"] == "a4"
    assert result["input_sha256"] == hashlib.sha256(demo_photo).hexdigest()  # the pipeline got the bytes unchanged
    for m in result["measurements"].values():
        assert m["value_mm"] > 0 and m["uncertainty_mm"] > 0
    assert np.asarray(result["joints3d_mm"]).shape == (18, 3)
    assert result["sizes"]["eu"]["label"].startswith("EU ")

    rid = response.headers["X-Result-Id"]
    files = result["files"]
    mesh = client.get(f"/api/results/{rid}/{files['mesh_obj']}")
    assert mesh.status_code == 200 and "attachment" in mesh.headers["content-disposition"]
    obj = trimesh.load(io.BytesIO(mesh.content), file_type="obj", process=False)
    assert len(obj.vertices) > 1000 and len(obj.faces) > 1000
    glb = client.get(f"/api/results/{rid}/{files['mesh_glb']}")
    assert glb.content[:4] == b"glTF" and glb.headers["content-type"] == "model/gltf-binary"
    overlay = client.get(f"/api/results/{rid}/{files['overlay_png']}")
    assert overlay.headers["content-type"] == "image/png"
    assert Image.open(io.BytesIO(overlay.content)).size == Image.open(io.BytesIO(demo_photo)).size
    stored = client.get(f"/api/results/{rid}/{files['result_json']}")
    assert stored.json() == result == client.get(f"/api/results/{rid}").json()
    assert upload_dirs(tmp_path) == []  # the request's uploads are gone


def test_type_is_checked_by_content_not_name(make_client, demo_photo):
    response = post_photo(make_client(), demo_photo, name="notes.txt", content_type="text/plain")
    assert response.status_code == 200, response.text


def test_depth_map_and_intrinsics_are_passed_on(make_client, demo_photo):
    depth = png_bytes(np.full((320, 320), 600, np.uint16))  # 16-bit PNG, mm
    intrinsics = json.dumps({"fx": 350.0, "fy": 350.0, "cx": 160.0, "cy": 160.0}).encode()
    files = {
        "photo": ("foot.jpg", demo_photo, "image/jpeg"),
        "depth": ("depth.png", depth, "image/png"),
        "intrinsics": ("k.json", intrinsics, "application/json"),
    }
    response = make_client().post(MEASURE, files=files, data={"depth_unit": "mm"})
    assert response.status_code == 200, response.text
    assert response.json()["scale_source"] == "depth"


def test_empty_optional_file_fields_are_ignored(make_client, demo_photo):
    # what a browser sends for a file input left empty: a part with no name and no bytes
    files = {"photo": ("foot.jpg", demo_photo, "image/jpeg"), "depth": ("", b"", "application/octet-stream")}
    response = make_client().post(MEASURE, files=files)
    assert response.status_code == 200, response.text
    assert response.json()["scale_source"] == "a4"


def test_unscaled_result_has_no_millimetres(make_client, demo_photo):
    response = post_photo(make_client(FakeMeasure(scale_source="none")), demo_photo)
    assert response.status_code == 200
    result = response.json()
    assert all(m["value_mm"] is None for m in result["measurements"].values())
    assert result["sizes"]["eu"] is None and result["ratios"]
    assert any("A4" in m for m in result["messages"])


# ----------------------------------------------------------------------------------------------------------
# Bad input: a 4xx with a readable message, and the server keeps serving
# ----------------------------------------------------------------------------------------------------------


def test_corrupt_photo(make_client, demo_photo):
    client = make_client()
    truncated = post_photo(client, demo_photo[: len(demo_photo) // 2])
    assert truncated.status_code == 400
    assert "corrupt or truncated" in truncated.json()["detail"]
    garbage = post_photo(client, demo_photo[:20] + bytes(range(256)) * 20)
    assert garbage.status_code == 400, garbage.text
    assert "starts like a JPEG file but could not be read" in garbage.json()["detail"]
    assert post_photo(client, demo_photo).status_code == 200


def test_huge_file_refused(make_client, demo_photo):
    client = make_client(max_upload_bytes=20_000)
    assert len(demo_photo) > 20_000
    response = post_photo(client, demo_photo)
    assert response.status_code == 413
    assert "larger than the limit of 20 KB" in response.json()["detail"]


def test_huge_chunked_upload_refused_while_streaming(make_client, demo_photo):
    # no Content-Length: the limit must be enforced on the bytes as they arrive
    client = make_client(max_upload_bytes=20_000)
    boundary = "footmeshboundary"
    head = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="photo"; filename="a.jpg"\r\n'
        "Content-Type: image/jpeg\r\n\r\n"
    ).encode()
    parts = [head, demo_photo, f"\r\n--{boundary}--\r\n".encode()]
    response = client.post(
        MEASURE, content=iter(parts), headers={"Content-Type": f"multipart/form-data; boundary={boundary}"}
    )
    assert response.status_code == 413, response.text


def test_too_many_pixels_refused_before_decoding(make_client):
    client = make_client(max_pixels=1_000_000)
    big = png_bytes(np.zeros((1000, 1500, 3), np.uint8))  # 1.5 megapixels in a few kilobytes
    response = post_photo(client, big, name="big.png", content_type="image/png")
    assert response.status_code == 413
    assert "1.5 megapixels" in response.json()["detail"]


@pytest.mark.parametrize(
    ("data", "looks_like"),
    [
        (b"%PDF-1.7\n%\xe2\xe3\xcf\xd3\n1 0 obj\n<<>>\nendobj\n", "PDF"),
        (b"Hello, this is not a photo.\n", "text file"),
        (b"GIF89a\x01\x00\x01\x00\x00\x00\x00;", "GIF"),
        (b"\x00\x00\x00\x18ftypmp42\x00\x00\x00\x00isommp42", "video"),
    ],
)
def test_non_image_refused(make_client, data, looks_like):
    response = post_photo(make_client(), data)  # named foot.jpg, declared image/jpeg: neither is trusted
    assert response.status_code == 415
    detail = response.json()["detail"]
    assert "JPEG, PNG, WebP, TIFF, HEIC or BMP" in detail and looks_like in detail


def test_photo_without_a_foot(make_client, blank_photo, demo_photo):
    client = make_client()
    response = post_photo(client, blank_photo, name="floor.png", content_type="image/png")
    assert response.status_code == 422
    assert response.json()["detail"].startswith("no foot found in the photo")
    assert post_photo(client, demo_photo).status_code == 200  # still serving


def test_the_reference_object_named_reaches_the_measurement_and_an_unknown_one_is_refused(make_client, demo_photo):
    asked = {}

    def measure(image, out_dir, **options):
        asked.update(options)
        return fake_measure(image, out_dir, **options)

    client = make_client(measure=measure)
    assert post_photo(client, demo_photo, reference="letter").status_code == 200
    assert asked["reference"] == "letter"
    unknown = post_photo(client, demo_photo, reference="legal")
    assert unknown.status_code == 422 and unknown.json()["detail"].startswith("reference: Input should be")
    page = client.get("/").text
    assert '<option value="letter">a US letter sheet</option>' in page
    assert "&#34;letter&#34;: &#34;the US letter sheet&#34;" in page  # for the result's "Scale from ..."


def test_bad_fields_and_side_files(make_client, demo_photo):
    client = make_client()
    photo = ("foot.jpg", demo_photo, "image/jpeg")
    missing = client.post(MEASURE, data={"side": "left"})
    assert missing.status_code == 400 and missing.json()["detail"] == "photo: Field required"  # docs/web.md
    as_text = client.post(MEASURE, data={"photo": "x" * 5000})  # a photo sent as a text field
    assert as_text.status_code == 422 and "x" * 100 not in as_text.text  # the value is not echoed back
    side = client.post(MEASURE, files={"photo": photo}, data={"side": "middle"})
    assert side.status_code == 422 and side.json()["detail"].startswith("side: Input should be")
    depth = client.post(MEASURE, files={"photo": photo, "depth": ("d.png", b"not a depth map", "image/png")})
    assert depth.status_code == 415 and "depth map" in depth.json()["detail"]
    k = client.post(MEASURE, files={"photo": photo, "intrinsics": ("k.json", b"{fx: 1", "application/json")})
    assert k.status_code == 400 and "not valid JSON" in k.json()["detail"]
    nan = client.post(MEASURE, files={"photo": photo, "intrinsics": ("k.json", b'{"fx": NaN}', "application/json")})
    assert nan.status_code == 400 and "NaN" in nan.json()["detail"]
    deep = client.post(MEASURE, files={"photo": photo, "intrinsics": ("k.json", b"[" * 60000, "application/json")})
    assert deep.status_code == 400 and "not valid JSON" in deep.json()["detail"]


def _refuse_naming_the_files(image, out_dir, *, depth=None, intrinsics=None, **options):
    raise Refusal(f"image {image} is only 1 x 1 px; depth map {depth}; in {Path(image).parent}")


def test_only_the_hosts_served_are_answered_and_cross_site_posts_are_refused(make_client, demo_photo):
    client = make_client()  # the default: this machine's names only
    assert client.get("/", headers={"Host": "evil.example"}).status_code == 400  # DNS rebinding
    assert client.get("/api/health", headers={"Host": "127.0.0.1:8000"}).status_code == 200
    assert client.get("/api/health", headers={"Host": "[::1]:8000"}).status_code == 200
    local = {"Host": "localhost:8000"}
    photo = {"photo": ("f.jpg", demo_photo, "image/jpeg")}
    forged = client.post(MEASURE, files=photo, headers={**local, "Origin": "https://evil.example"})
    assert forged.status_code == 403 and "other sites" in forged.json()["detail"]
    assert client.post(MEASURE, files=photo, headers={**local, "Sec-Fetch-Site": "cross-site"}).status_code == 403
    assert client.post(MEASURE, files=photo, headers={**local, "Origin": "http://[bad"}).status_code == 403
    assert client.post(MEASURE, files=photo, headers={**local, "Origin": "null"}).status_code == 403
    same = client.post(MEASURE, files=photo, headers={**local, "Origin": "http://localhost:8000"})
    assert same.status_code == 200  # the page's own form
    assert client.post(MEASURE, files=photo, headers=local).status_code == 200  # curl sends no Origin


def test_refusals_name_the_upload_fields_never_server_paths(make_client, demo_photo, tmp_path):
    client = make_client(_refuse_naming_the_files)
    depth = png_bytes(np.full((320, 320), 600, np.uint16))
    files = {"photo": ("f.jpg", demo_photo, "image/jpeg"), "depth": ("d.png", depth, "image/png")}
    response = client.post(MEASURE, files=files)
    detail = response.json()["detail"]
    assert response.status_code == 422
    assert "(upload field 'photo')" in detail and "(upload field 'depth')" in detail
    assert str(tmp_path) not in detail and "/tmp" not in detail


def test_pipeline_crash_is_500_and_server_keeps_serving(make_client, demo_photo, tmp_path):
    calls = []

    def crashing(image, out_dir, **options):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("bug in the pipeline")
        return fake_measure(image, out_dir, **options)

    client = make_client(crashing)
    response = post_photo(client, demo_photo)
    assert response.status_code == 500
    assert "internal error" in response.json()["detail"] and "bug" not in response.json()["detail"]
    assert post_photo(client, demo_photo).status_code == 200
    assert upload_dirs(tmp_path) == []


# ----------------------------------------------------------------------------------------------------------
# Capacity and time limits
# ----------------------------------------------------------------------------------------------------------


def test_queue_then_503_beyond_capacity(make_client, demo_photo):
    gate = threading.Event()

    def blocking(image, out_dir, **options):
        gate.wait(10.0)
        return fake_measure(image, out_dir, **options)

    client = make_client(blocking, workers=1, queue=1)
    answers = {}

    def send(key: str) -> None:
        answers[key] = post_photo(client, demo_photo)

    threads = [threading.Thread(target=send, args=(k,)) for k in "ab"]
    threads[0].start()
    wait_until(lambda: client.get("/api/health").json()["running"] == 1)
    threads[1].start()
    wait_until(lambda: client.get("/api/health").json()["queued"] == 1)
    refused = post_photo(client, demo_photo)
    assert refused.status_code == 503
    assert "busy" in refused.json()["detail"] and int(refused.headers["Retry-After"]) > 0
    assert "queue place taken" in refused.json()["detail"]  # by the middleware, before the upload was read
    gate.set()
    for t in threads:
        t.join(20.0)
    assert [answers[k].status_code for k in "ab"] == [200, 200]  # the queued one was not lost
    assert client.get("/api/health").json()["running"] == 0


def test_time_limit_in_thread_isolation(make_client, demo_photo, tmp_path):
    client = make_client(FakeMeasure(delay_s=1.0), time_limit_s=0.2)
    start = time.monotonic()
    response = post_photo(client, demo_photo)
    assert response.status_code == 504 and "0.2 s" in response.json()["detail"]
    assert time.monotonic() - start < 1.0
    # the thread cannot be stopped: it keeps its worker until it ends, then everything is cleaned up
    wait_until(lambda: client.get("/api/health").json()["running"] == 0)
    assert upload_dirs(tmp_path) == []


def test_process_isolation_measures_and_kills_at_the_time_limit(make_client, demo_photo, blank_photo, tmp_path):
    # a measure function without torch and no preloading: the forkserver starts in a moment
    client = make_client(StubMeasure(), isolation="process", time_limit_s=60.0, preload=())
    assert post_photo(client, demo_photo).status_code == 200
    refused = post_photo(client, blank_photo, name="x.png", content_type="image/png")
    assert refused.status_code == 422 and refused.json()["detail"].startswith("no foot")
    # the same warm process answered both (a refusal does not cost it), and the server's shutdown stops it
    assert len(multiprocessing.active_children()) == 1
    client.__exit__(None, None, None)
    assert multiprocessing.active_children() == []

    slow = make_client(StubMeasure(delay_s=60.0), isolation="process", time_limit_s=1.0, preload=())
    start = time.monotonic()
    response = post_photo(slow, demo_photo)
    assert response.status_code == 504
    assert time.monotonic() - start < 8.0
    assert multiprocessing.active_children() == []  # the job was killed, not left running
    assert slow.get("/api/health").json()["running"] == 0
    assert upload_dirs(tmp_path) == []


def test_warm_processes_serve_job_after_job_and_a_crash_costs_only_its_own(make_client, demo_photo, tmp_path):
    """Process isolation keeps its measurement processes (the networks stay loaded): two jobs, one process; a job
    that kills its process gets 500 and the next job gets a fresh process."""
    client = make_client(StubMeasure(), isolation="process", time_limit_s=60.0, preload=())
    first, second = (post_photo(client, demo_photo).json()["pid"] for _ in range(2))
    assert first == second
    crashing = make_client(StubMeasure(crash=True), isolation="process", time_limit_s=60.0, preload=())
    for _ in range(2):  # the dead process is replaced: the next job runs (and dies) in a fresh one
        died = post_photo(crashing, demo_photo)
        assert died.status_code == 500 and "process died" in died.json()["detail"]
    assert crashing.get("/api/health").json()["running"] == 0
    assert post_photo(client, demo_photo).json()["pid"] == first  # the other server's process is untouched
    assert upload_dirs(tmp_path) == []


# ----------------------------------------------------------------------------------------------------------
# Paths, result store, documents
# ----------------------------------------------------------------------------------------------------------


def test_client_paths_never_reach_the_disk(make_client, demo_photo, tmp_path):
    client = make_client()
    response = post_photo(client, demo_photo, name="../../../../tmp/evil.jpg")
    assert response.status_code == 200
    assert not list(tmp_path.parent.rglob("evil*"))
    rid = response.headers["X-Result-Id"]
    for url in (
        f"/api/results/{rid}/..%2F..%2Fetc%2Fpasswd",
        f"/api/results/{rid}/other.obj",
        "/api/results/not-a-result-id/mesh.obj",
        "/api/results/AAAAAAAAAAAAAAAAAAAAAA",
    ):
        assert client.get(url).status_code == 404, url


def test_results_expire(make_client, demo_photo, tmp_path):
    client = make_client(result_ttl_s=0.3)
    rid = post_photo(client, demo_photo).headers["X-Result-Id"]
    assert client.get(f"/api/results/{rid}").status_code == 200
    time.sleep(0.4)
    gone = client.get(f"/api/results/{rid}/mesh.obj")
    assert gone.status_code == 404 and "kept for" in gone.json()["detail"]
    assert not list(tmp_path.glob(f"footmesh-results-*/{rid}"))


def test_temporary_folders_removed_at_shutdown(demo_photo, tmp_path):
    from fastapi.testclient import TestClient

    from footmesh.web.app import create_app
    from footmesh.web.settings import WebSettings

    app = create_app(FakeMeasure(), WebSettings(isolation="thread", work_dir=tmp_path))
    with TestClient(app, base_url="http://localhost") as client:
        assert post_photo(client, demo_photo).status_code == 200
        assert list(tmp_path.glob("footmesh-results-*/*"))
    assert list(tmp_path.iterdir()) == []


def test_page_openapi_and_docs_are_served_locally(make_client):
    client = make_client()
    page = client.get("/")
    assert page.status_code == 200
    html = page.text
    for field in ("photo", "depth", "depth_unit", "intrinsics"):
        assert f'<label for="{field}"' in html and f'id="{field}"' in html
    assert "script-src 'self' 'sha256-" in page.headers["content-security-policy"]
    assert "https://" not in html  # nothing from a CDN
    spec = client.get("/openapi.json").json()
    assert "multipart/form-data" in spec["paths"][MEASURE]["post"]["requestBody"]["content"]
    docs = client.get("/docs").text
    assert "/static/vendor/swagger-ui/swagger-ui-bundle.js" in docs
    for asset in (
        "/static/vendor/swagger-ui/swagger-ui-bundle.js",
        "/static/vendor/three/build/three.module.min.js",
        "/static/vendor/three/build/three.core.min.js",
        "/static/vendor/three/examples/jsm/controls/OrbitControls.js",
        "/static/vendor/three/examples/jsm/loaders/GLTFLoader.js",
        "/static/app.js",
        "/static/viewer.js",
        "/static/guide.svg",
    ):
        assert client.get(asset).status_code == 200, asset
    health = client.get("/api/health").json()
    assert health["status"] == "ok" and health["pipeline"] == "custom"


def test_default_pipeline_missing_is_a_clear_503(make_client, demo_photo, monkeypatch):
    """A server installed without the measuring pipeline (the web extra alone) answers 503 saying so: the pipeline's
    import made to fail as it would there."""
    import builtins

    from footmesh.web.jobs import default_measure

    real_import = builtins.__import__

    def without_pipeline(name, *args, **kwargs):
        if name == "footmesh.pipeline":
            raise ModuleNotFoundError("No module named 'footmesh.pipeline'", name="footmesh.pipeline")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", without_pipeline)
    client = make_client(default_measure)
    response = post_photo(client, demo_photo)
    assert response.status_code == 503
    assert "footmesh.pipeline" in response.json()["detail"]
