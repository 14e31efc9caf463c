"""The FastAPI app: the upload page, ``POST /api/measure``, result downloads by id, health and OpenAPI docs.

``create_app(measure, settings)`` builds it; ``measure`` defaults to ``footmesh.pipeline.measure_photo``, imported
when the first request comes. Limits (``WebSettings``): request size (413), pixel count (413), content-checked
types (415), a time limit per measurement (504), a bounded queue (503); bad input gives a 4xx with a one-line
``{"detail": "..."}``. Uploads live in a per-request temporary folder that is deleted when the job ends.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import hashlib
import importlib.util
import json
import logging
import shutil
import tempfile
import threading
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import urlsplit

from fastapi import FastAPI, File, Form, HTTPException, Request, UploadFile
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from starlette.concurrency import run_in_threadpool
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from footmesh import __version__, references
from footmesh.formats import accepted
from footmesh.measure import MEASUREMENT_NAMES
from footmesh.model.skeleton import JOINT_NAMES, PARENTS
from footmesh.result import json_schema
from footmesh.web import uploads
from footmesh.web.jobs import Job, JobError, JobRunner, MeasureFn, default_measure
from footmesh.web.settings import WebSettings
from footmesh.web.store import ResultStore

log = logging.getLogger(__name__)

HERE = Path(__file__).parent
STATIC_DIR = HERE / "static"
TEMPLATE_DIR = HERE / "templates"
REFERENCE_CHOICES = ("auto", *references.NAMES)
"""The form's ``reference``: the reference object in the photo (``footmesh measure --reference``)."""
MEASURE_PATH = "/api/measure"
SWEEP_INTERVAL_S = 60.0
RETRY_AFTER_S = 10
DISCONNECT_POLL_S = 0.5
"""How often a request waiting for its measurement looks whether its client is still there (s)."""
MEDIA_TYPES = {
    ".json": "application/json",
    ".obj": "model/obj",
    ".glb": "model/gltf-binary",
    ".png": "image/png",
    ".ply": "application/octet-stream",
}
IMPORT_MAP = json.dumps(
    {
        "imports": {
            "three": "/static/vendor/three/build/three.module.min.js",
            "three/addons/": "/static/vendor/three/examples/jsm/",
        }
    }
)
"""The page's import map (bare ``three`` -> the vendored build); its hash goes into the page's CSP."""
PAGE_CSP = (
    "default-src 'self'; img-src 'self' data: blob:; style-src 'self'; object-src 'none'; base-uri 'none'; "
    "frame-ancestors 'none'; form-action 'self'; script-src 'self' 'sha256-"
    + base64.b64encode(hashlib.sha256(IMPORT_MAP.encode()).digest()).decode()
    + "'"
)
API_DESCRIPTION = """Measure a foot from one photo: a 3D mesh in millimetres, 18 joints, eight measurements with
uncertainties, and shoe sizes. `POST /api/measure` answers the same JSON as `footmesh measure --json`; the
`X-Result-Id` header names the stored result, whose files (listed in `files`) are served at
`/api/results/{id}/{file name}` until they expire."""


@dataclass(frozen=True)
class _State:
    store: ResultStore
    runner: JobRunner
    upload_root: Path
    settings: WebSettings


def create_app(measure: MeasureFn | None = None, settings: WebSettings | None = None) -> FastAPI:
    """The web app; ``measure(image, out_dir, *, depth, depth_unit, intrinsics, side, reference) -> dict`` does the
    work.

    Args:
        measure: the measuring function (default ``footmesh.pipeline.measure_photo``, imported per request). In
            "process" isolation it must be picklable (a module-level function or an instance of a module-level
            class).
        settings: limits and isolation (default ``WebSettings()``).
    """
    settings = settings or WebSettings()
    measure = measure or default_measure

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = ResultStore(settings.work_dir, settings.result_ttl_s, settings.max_results)
        upload_root = Path(tempfile.mkdtemp(prefix="footmesh-uploads-", dir=settings.work_dir))
        runner = JobRunner(measure, store, settings)
        runner.start()
        app.state.web = _State(store, runner, upload_root, settings)
        sweeper = asyncio.create_task(_sweep_forever(store))
        try:
            yield
        finally:
            sweeper.cancel()
            runner.close()
            store.close()
            shutil.rmtree(upload_root, ignore_errors=True)

    app = FastAPI(
        title="footmesh",
        version=__version__,
        description=API_DESCRIPTION,
        lifespan=lifespan,
        docs_url=None,  # served below from the vendored Swagger UI: no CDN at run time
        redoc_url=None,
    )
    app.add_middleware(
        BodyLimit,
        max_bytes=settings.max_upload_bytes,
        paths=(MEASURE_PATH,),
        idle_timeout_s=settings.upload_idle_timeout_s,
        min_rate_bytes_s=settings.upload_min_rate_bytes_s,
        rate_grace_s=settings.upload_rate_grace_s,
    )
    app.add_middleware(HostGuard, allowed_hosts=settings.allowed_hosts)
    app.add_middleware(SecurityHeaders)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    templates = Jinja2Templates(directory=TEMPLATE_DIR)
    _add_error_handlers(app)
    pipeline = "custom" if measure is not default_measure else None

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    async def page(request: Request) -> Response:
        context = {
            "version": __version__,
            "import_map": IMPORT_MAP,
            "max_upload_bytes": settings.max_upload_bytes,
            "max_upload": uploads.format_bytes(settings.max_upload_bytes),
            "max_megapixels": settings.max_pixels / 1e6,
            "time_limit_s": settings.time_limit_s,
            "viewer_config": json.dumps({"parents": PARENTS, "joints": JOINT_NAMES}),
            "measurement_names": MEASUREMENT_NAMES,
            "references": [(k.name, k.described) for k in references.KINDS],
            "scale_sources": json.dumps({k.name: k.named for k in references.KINDS}),
        }
        response = templates.TemplateResponse(request, "index.html", context)
        response.headers["Content-Security-Policy"] = PAGE_CSP
        return response

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url,
            title="footmesh API",
            swagger_js_url="/static/vendor/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/static/vendor/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/static/vendor/swagger-ui/favicon-32x32.png",
        )

    @app.post(
        MEASURE_PATH,
        summary="Measure a foot from one photo",
        response_description="the result JSON (as `footmesh measure --json`); header `X-Result-Id`",
        responses={
            200: {"content": {"application/json": {"schema": json_schema()}}},
            413: {"description": "request, photo or depth map too large"},
            415: {"description": "not an accepted image type (checked by content)"},
            422: {"description": "the pipeline refused the input (no foot, depth of the wrong size, ...)"},
            503: {"description": "server busy (queue full) or no pipeline installed"},
            504: {"description": "the measurement ran past the time limit"},
        },
    )
    async def measure_endpoint(
        request: Request,
        photo: Annotated[UploadFile, File(description=f"the photo: {accepted.PHOTO_HELP}")],
        depth: Annotated[UploadFile | None, File(description=f"optional depth map: {accepted.DEPTH_HELP}")] = None,
        depth_unit: Annotated[Literal["mm", "m"], Form(description="unit of a float .npy depth map")] = "mm",
        intrinsics: Annotated[UploadFile | None, File(description="optional camera intrinsics (JSON)")] = None,
        side: Annotated[Literal["auto", "left", "right"], Form(description="which foot")] = "auto",
        reference: Annotated[
            Literal[REFERENCE_CHOICES], Form(description="the reference object in the photo (auto: any)")
        ] = "auto",
    ) -> Response:
        web: _State = request.app.state.web
        work = Path(tempfile.mkdtemp(prefix="request-", dir=web.upload_root))
        try:
            job = await run_in_threadpool(
                _prepare_job, work, web.settings, photo, depth, depth_unit, intrinsics, side, reference
            )
        except BaseException as exc:
            shutil.rmtree(work, ignore_errors=True)
            if isinstance(exc, uploads.UploadError):
                raise HTTPException(exc.status, str(exc)) from None
            raise
        cancelled = threading.Event()
        running = asyncio.ensure_future(web.runner.run(job, cancelled))  # deletes `work` when the job has ended
        try:
            while not (await asyncio.wait({running}, timeout=DISCONNECT_POLL_S))[0]:
                if await request.is_disconnected():
                    # nobody will get the answer: stop the job and free its place (issue 23, row 19)
                    cancelled.set()
                    running.add_done_callback(_consume)
                    return Response(status_code=499)
            rid, _ = running.result()
        except JobError as exc:
            headers = {"Retry-After": str(RETRY_AFTER_S)} if exc.status == 503 else None
            raise HTTPException(exc.status, str(exc), headers=headers) from None
        # the body is the stored result.json itself: what the client gets is what it can download
        body = web.store.file(rid, "result.json").read_bytes()
        return Response(body, media_type="application/json", headers={"X-Result-Id": rid, "Cache-Control": "no-store"})

    @app.get("/api/results/{rid}", summary="A stored result's JSON")
    async def result_json(request: Request, rid: str) -> Response:
        path = _state(request).store.file(rid, "result.json")
        if path is None:
            raise HTTPException(404, _gone(_state(request).settings))
        return Response(path.read_bytes(), media_type="application/json")

    @app.get("/api/results/{rid}/{name}", summary="A file of a stored result (a name from its `files`)")
    async def result_file(request: Request, rid: str, name: str) -> Response:
        web = _state(request)
        path = web.store.file(rid, name)
        if path is None:
            raise HTTPException(404, _gone(web.settings))
        suffix = path.suffix.lower()
        disposition = "inline" if suffix == ".png" else "attachment"
        return FileResponse(
            path,
            media_type=MEDIA_TYPES.get(suffix, "application/octet-stream"),
            filename=f"footmesh-{rid[:8]}-{path.name}",
            content_disposition_type=disposition,
            headers={"Cache-Control": "private, max-age=3600"},
        )

    @app.get("/api/health", summary="Liveness, load and whether the pipeline is installed")
    async def health(request: Request) -> dict:
        web = _state(request)
        found = importlib.util.find_spec("footmesh.pipeline") is not None
        return {
            "status": "ok",
            "version": __version__,
            "pipeline": pipeline or ("available" if found else "missing"),
            "running": web.runner.running,
            "queued": web.runner.queued,
            "workers": web.settings.workers,
            "queue": web.settings.queue,
            "stored_results": len(web.store),
        }

    return app


def _prepare_job(
    work: Path,
    settings: WebSettings,
    photo: UploadFile,
    depth: UploadFile | None,
    depth_unit: str,
    intrinsics: UploadFile | None,
    side: str,
    reference: str,
) -> Job:
    """Copy the uploads into ``work`` under our own names and check each by content (runs in a thread)."""
    limit = settings.max_upload_bytes
    if not _present(photo):
        raise uploads.UploadError(400, "no photo was uploaded")
    image = uploads.save_upload(photo.file, work / "photo.upload", limit, "photo")
    image = uploads.check_photo(image, settings.max_pixels)
    depth_file = intrinsics_file = None
    if _present(depth):
        depth_file = uploads.save_upload(depth.file, work / "depth.upload", limit, "depth map")
        depth_file = uploads.check_depth(depth_file, settings.max_pixels)
    if _present(intrinsics):
        path = work / "intrinsics.upload"
        path = uploads.save_upload(intrinsics.file, path, settings.max_intrinsics_bytes, "intrinsics")
        intrinsics_file = uploads.check_intrinsics(path)
    return Job(
        work_dir=work,
        image=image.path,
        depth=depth_file.path if depth_file else None,
        depth_unit=depth_unit,
        intrinsics=intrinsics_file.path if intrinsics_file else None,
        side=side,
        reference=reference,
    )


def _present(upload: UploadFile | None) -> bool:
    # a browser sends an empty part with no file name for a file input left empty
    return upload is not None and bool(upload.filename or upload.size)


def _state(request: Request) -> _State:
    return request.app.state.web


def _gone(settings: WebSettings) -> str:
    return f"no such result: results are kept for {settings.result_ttl_s / 60:.0f} minutes"


async def _sweep_forever(store: ResultStore) -> None:
    while True:
        await asyncio.sleep(SWEEP_INTERVAL_S)
        await run_in_threadpool(store.sweep)


def _add_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        parts, errors, status = [], [], 422
        for err in exc.errors():
            where = ".".join(str(p) for p in err.get("loc", ()) if p not in ("body", "query", "path"))
            if where == "photo" and err.get("type") == "missing":
                status = 400  # as an empty photo part: docs/web.md
            parts.append(f"{where}: {err.get('msg', 'invalid')}" if where else str(err.get("msg", "invalid")))
            # the value sent is never echoed back: it may be a whole photo sent as a text field
            errors.append({k: v for k, v in err.items() if k in ("type", "loc", "msg")})
        detail = "; ".join(parts) or "invalid request"
        return JSONResponse({"detail": detail, "errors": jsonable_encoder(errors)}, status_code=status)


def _consume(task: asyncio.Future) -> None:
    """Retrieve a cancelled request's job outcome, so that asyncio does not log it as never retrieved."""
    if not task.cancelled():
        task.exception()


class _TooLarge(Exception):
    pass


class _Stalled(Exception):
    pass


class BodyLimit:
    """ASGI middleware: refuse request bodies over ``max_bytes`` on ``paths`` with 413, counting as they arrive,
    with 408 when the body stops arriving for ``idle_timeout_s`` or, after ``rate_grace_s``, arrives slower than
    ``min_rate_bytes_s`` on average, and with 503 before reading any when the job queue is full.

    A declared Content-Length over the limit is refused before anything is read; a body that turns out larger
    (chunked, or a lying header) stops being read at the limit and the app's answer is replaced by the 413.
    """

    def __init__(
        self,
        app: ASGIApp,
        max_bytes: int,
        paths: tuple[str, ...],
        idle_timeout_s: float = 30.0,
        min_rate_bytes_s: float = 1024.0,
        rate_grace_s: float = 10.0,
    ) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.paths = paths
        self.idle_timeout_s = idle_timeout_s
        self.min_rate_bytes_s = min_rate_bytes_s
        self.rate_grace_s = rate_grace_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] not in self.paths:
            await self.app(scope, receive, send)
            return
        declared = dict(scope.get("headers") or ()).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            await self._refuse(send)
            return
        web = getattr(scope["app"].state, "web", None)
        if web is not None and web.runner.full:  # refused before the upload is read and decoded
            detail = "the server is busy (every worker and queue place taken); try again soon"
            await _plain_error(send, 503, detail, [(b"retry-after", str(RETRY_AFTER_S).encode())])
            return
        received = 0
        exceeded = False
        stalled: str | None = None  # why the body was given up on
        started = False
        body_done = False
        loop = asyncio.get_running_loop()
        opened = loop.time()

        async def limited_receive() -> Message:
            nonlocal received, exceeded, stalled, body_done
            if body_done:  # only the disconnect is left to wait for, as long as it takes
                return await receive()
            # the next chunk must come before the body falls below the minimum average rate (after the grace)
            behind = opened + self.rate_grace_s + received / self.min_rate_bytes_s - loop.time()
            wait = min(self.idle_timeout_s, max(behind, 0.0))
            try:
                message = await asyncio.wait_for(receive(), wait)
            except TimeoutError:
                if wait < self.idle_timeout_s:
                    rate = received / max(loop.time() - opened, 1e-9)
                    stalled = (
                        f"the upload is too slow ({rate:.0f} bytes/s on average; at least "
                        f"{self.min_rate_bytes_s:.0f} bytes/s are needed)"
                    )
                else:
                    stalled = f"the upload stalled (nothing arrived for {self.idle_timeout_s:g} s)"
                raise _Stalled from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                body_done = not message.get("more_body", False)
                if received > self.max_bytes:
                    exceeded = True
                    raise _TooLarge
            return message

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if exceeded or stalled is not None:
                return  # whatever the app makes of the broken body, the answer is 413 / 408
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, limited_receive, guarded_send)
        except (_TooLarge, _Stalled):
            pass
        if exceeded and not started:
            await self._refuse(send)
        elif stalled is not None and not started:
            await _plain_error(send, 408, stalled, [(b"connection", b"close")])

    async def _refuse(self, send: Send) -> None:
        detail = f"the upload is larger than the limit of {uploads.format_bytes(self.max_bytes)}"
        await _plain_error(send, 413, detail, [(b"connection", b"close")])


def host_name(value: str) -> str | None:
    """The host of a ``Host`` header, or of an ``Origin`` URL (``scheme://host[:port]``), lower case, without port
    or IPv6 brackets; None when it is malformed."""
    try:
        return urlsplit(value if "://" in value else f"//{value}").hostname
    except ValueError:
        return None


class HostGuard:
    """ASGI middleware: answer only requests whose ``Host`` is one of ``allowed_hosts`` (400 otherwise: DNS
    rebinding), and refuse state-changing requests sent by a page of another origin (403: CSRF).

    Written here because Starlette's TrustedHostMiddleware splits IPv6 hosts at their first colon and does not
    look at ``Origin``.
    """

    def __init__(self, app: ASGIApp, allowed_hosts: tuple[str, ...]) -> None:
        self.app = app
        self.any_host = "*" in allowed_hosts
        self.allowed = set(allowed_hosts)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope.get("headers") or ()}
        host = host_name(headers.get("host", ""))
        if not self.any_host and host not in self.allowed:
            await _plain_error(send, 400, "this server does not answer for that host name")
            return
        if scope["method"] not in ("GET", "HEAD", "OPTIONS"):
            origin = headers.get("origin")
            cross_site = headers.get("sec-fetch-site") == "cross-site"
            if cross_site or (origin is not None and host_name(origin) != host):
                await _plain_error(send, 403, "requests from pages of other sites are refused")
                return
        await self.app(scope, receive, send)


async def _plain_error(send: Send, status: int, detail: str, extra: list | None = None) -> None:
    """A JSON error answered by a middleware, before the app sees the request (``extra``: more headers; the
    security headers come from ``SecurityHeaders``, outside every other middleware)."""
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())] + (extra or [])
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


class SecurityHeaders:
    """ASGI middleware: ``nosniff`` and no referrer on every response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers") or ())
                headers += [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer")]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)
