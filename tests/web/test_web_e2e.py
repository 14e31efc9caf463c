"""End to end in headless Chromium (Debian's ``chromium`` package, driven by Playwright): upload the demo photo,
wait for the result, check the tables and that the 3D view is not blank; the error message; the page without WebGL.

The server is the real app in a uvicorn thread on a free loopback port, measuring with the fake pipeline.
``FOOTMESH_WEB_SCREENSHOT=docs/img/web.png`` also saves a screenshot of the page with its result there;
``FOOTMESH_WEB_PIPELINE=real`` measures with the real pipeline instead (``footmesh.pipeline``).
"""

from __future__ import annotations

import io
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright Python package is not installed")

from _fake_pipeline import FakeMeasure  # noqa: E402
from _photos import render_demo_photo  # noqa: E402


def find_chromium() -> str | None:
    """The system's Chromium: ``$FOOTMESH_CHROMIUM``, Debian's binary, or ``chromium`` on the PATH."""
    candidates = [os.environ.get("FOOTMESH_CHROMIUM"), "/usr/lib/chromium/chromium"]
    candidates += [shutil.which(name) for name in ("chromium", "chromium-browser", "google-chrome")]
    return next((c for c in candidates if c and os.access(c, os.X_OK)), None)


CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(
    CHROMIUM is None,
    reason="no Chromium browser: install Debian's chromium (scripts/install_browser.sh) or set FOOTMESH_CHROMIUM",
)
# software WebGL (SwiftShader) so that the 3D view renders with no GPU; root in containers needs --no-sandbox
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-dev-shm-usage"]
REAL = os.environ.get("FOOTMESH_WEB_PIPELINE") == "real"
RESULT_TIMEOUT_MS = 300_000 if REAL else 30_000
NO_WEBGL = """
const original = HTMLCanvasElement.prototype.getContext;
HTMLCanvasElement.prototype.getContext = function (kind, ...rest) {
  return /webgl/.test(kind) ? null : original.call(this, kind, ...rest);
};
"""


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    from footmesh.web.server import running_server
    from footmesh.web.settings import WebSettings

    settings = WebSettings(isolation="thread", work_dir=tmp_path_factory.mktemp("web"), time_limit_s=300.0)
    with running_server(None if REAL else FakeMeasure(), settings) as url:
        yield url


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    page = context.new_page()
    page.errors = []
    page.on("pageerror", lambda exc: page.errors.append(str(exc)))
    yield page
    context.close()


@pytest.fixture(scope="module")
def photo() -> bytes:
    return render_demo_photo(size=480)


def upload(page, url: str, data: bytes, name: str = "foot.jpg", mime: str = "image/jpeg") -> None:
    page.goto(url)
    page.get_by_label("Photo of the foot").set_input_files(files=[{"name": name, "mimeType": mime, "buffer": data}])
    page.get_by_role("button", name="Measure").click()


def wait_for_result(page, viewer_state: str) -> None:
    """Wait until the 3D view reaches ``viewer_state``, failing at once with the page's message on an error."""
    page.wait_for_selector(f"#viewer[data-state={viewer_state}], #error:not([hidden])", state="attached",
                           timeout=RESULT_TIMEOUT_MS)  # fmt: skip
    error = page.locator("#error")
    assert error.is_hidden(), f"the page shows an error: {error.inner_text()}"


def measurement_rows(page) -> list[list[str]]:
    return [row.split("\t") for row in page.locator("#measurements tbody tr").all_inner_texts()]


def picture(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64)


def test_upload_shows_measurements_and_3d_view(page, server, photo):
    upload(page, server, photo)
    wait_for_result(page, "ready")

    rows = measurement_rows(page)
    assert len(rows) == 8
    for row in rows:
        assert re.fullmatch(r"\d+\.\d mm", row[1].strip()), row
        assert re.fullmatch(r"± \d+\.\d mm", row[2].strip()) or REAL, row
    assert "EU " in page.locator("#sizes").inner_text()
    assert REAL or "A4 sheet" in page.locator("#scale").inner_text()
    assert page.locator("#overlay").evaluate("img => img.complete && img.naturalWidth") == 480
    for link in ("#download-obj", "#download-glb", "#download-json"):
        assert page.locator(link).get_attribute("href").startswith("/api/results/")

    canvas = page.locator("#viewer canvas")
    shot = picture(canvas.screenshot())
    background = np.median(shot.reshape(-1, 3), axis=0)
    drawn = np.abs(shot - background).max(axis=2) > 30
    assert 0.03 < drawn.mean() < 0.9, f"3D view looks blank: {drawn.mean():.3f} of its pixels drawn"

    canvas.focus()  # the view answers the keyboard
    for _ in range(6):
        page.keyboard.press("Shift+ArrowLeft")
    assert np.abs(picture(canvas.screenshot()) - shot).mean() > 1.0
    assert page.errors == []

    target = os.environ.get("FOOTMESH_WEB_SCREENSHOT")
    if target:
        page.locator("#viewer-reset").click()
        page.locator("#results").scroll_into_view_if_needed()
        Path(target).parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=target, full_page=True)


def test_bad_photo_shows_a_readable_message(page, server):
    blank = io.BytesIO()
    Image.new("RGB", (200, 150), (128, 128, 128)).save(blank, format="PNG")
    upload(page, server, blank.getvalue(), name="floor.png", mime="image/png")
    alert = page.get_by_role("alert")
    alert.wait_for(timeout=RESULT_TIMEOUT_MS)
    assert alert.inner_text().startswith("No measurement: ")
    assert REAL or "no foot found in the photo" in alert.inner_text()
    assert page.locator("#results").is_hidden()
    assert page.get_by_role("button", name="Measure").is_enabled()

    upload(page, server, b"%PDF-1.4 not a photo", name="foot.jpg")
    sync_api.expect(alert).to_contain_text("looks like a PDF document", timeout=RESULT_TIMEOUT_MS)
    assert "Not a supported file type" in alert.inner_text()


def test_page_works_without_webgl(page, server, photo):
    page.add_init_script(NO_WEBGL)
    upload(page, server, photo)
    wait_for_result(page, "unavailable")
    assert "needs WebGL" in page.locator("#viewer-fallback").inner_text()
    assert all(re.fullmatch(r"\d+\.\d mm", row[1].strip()) for row in measurement_rows(page))
    assert page.locator("#download-glb").is_visible()
    assert page.errors == []
