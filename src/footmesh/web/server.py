"""Running the web app with uvicorn: ``serve`` (the ``footmesh serve`` command) and ``running_server`` (tests)."""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Iterator

from footmesh.web.app import create_app
from footmesh.web.jobs import MeasureFn
from footmesh.web.settings import WebSettings

log = logging.getLogger(__name__)

CONNECTION_LIMIT = 64
"""Open connections uvicorn serves at once; more get 503 from uvicorn itself (a guard behind the app's queue)."""


def serve(
    host: str = "127.0.0.1",
    port: int = 8000,
    settings: WebSettings | None = None,
    measure: MeasureFn | None = None,
    log_level: str = "info",
) -> None:
    """Serve the app at ``http://host:port`` until interrupted (one server process; measurement workers as set)."""
    import uvicorn

    if host not in ("127.0.0.1", "localhost", "::1"):
        log.warning("serving on %s: anyone who can reach this address can upload photos", host)
    uvicorn.run(
        create_app(measure, settings),
        host=host,
        port=port,
        log_level=log_level,
        limit_concurrency=CONNECTION_LIMIT,
        timeout_keep_alive=5,
        server_header=False,
    )


@contextlib.contextmanager
def running_server(
    measure: MeasureFn | None = None, settings: WebSettings | None = None, host: str = "127.0.0.1"
) -> Iterator[str]:
    """Run the app in a background thread on a free port of ``host``; yields its base URL, stops on exit."""
    import uvicorn

    config = uvicorn.Config(
        create_app(measure, settings), host=host, port=0, log_level="warning", limit_concurrency=CONNECTION_LIMIT
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="footmesh-web", daemon=True)
    thread.start()
    deadline = time.monotonic() + 30.0
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("the web server did not start")
        time.sleep(0.02)
    port = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://{host}:{port}"
    finally:
        server.should_exit = True
        thread.join(30.0)
