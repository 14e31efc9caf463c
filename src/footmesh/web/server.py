"""Running the web app with uvicorn: ``serve`` (the ``footmesh serve`` command) and ``running_server`` (tests)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Iterator

from footmesh.web.app import create_app
from footmesh.web.jobs import MeasureFn
from footmesh.web.settings import WebSettings

log = logging.getLogger(__name__)

CONNECTION_LIMIT = 512
"""Open connections uvicorn serves at once; more get 503 from uvicorn itself (a guard behind the app's queue).
Idle and half-sent connections count too: the header time-out and the per-client cap keep slow ones from
filling it (at 64, 70 connections sending a header byte every 2 s got every other client 503)."""
HEADER_TIMEOUT_S = 10.0
"""A request's headers must have arrived this long after the connection opened (or its previous answer was
sent); a connection still sending them then is closed (slow-header attacks hold connections open)."""
PER_CLIENT_WAITING = 16
"""Connections of one client address still sending their headers; one more closes its oldest such one, so that
a client's own prompt request always gets in, however many slow ones it (or a host behind its NAT) holds."""


def guarded_protocol(header_timeout_s: float = HEADER_TIMEOUT_S, per_client: int = PER_CLIENT_WAITING) -> type:
    """uvicorn's h11 protocol with a header time-out and a cap per client address on connections whose headers
    have not arrived (uvicorn has neither); a new class, with its own bookkeeping, per server."""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class GuardedH11Protocol(H11Protocol):
        waiting: dict[str, dict[GuardedH11Protocol, None]] = {}  # client host -> its waiting ones, oldest first
        _header_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport) -> None:  # type: ignore[no-untyped-def]
            super().connection_made(transport)
            self._await_headers()

        def _await_headers(self) -> None:
            self._cycle_awaited = self.cycle
            host = self.client[0] if self.client else ""
            queue = GuardedH11Protocol.waiting.setdefault(host, {})
            queue[self] = None
            self._header_timer = self.loop.call_later(header_timeout_s, self._drop)
            while len(queue) > per_client:
                next(iter(queue))._drop()

        def _headers_done(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None
            host = self.client[0] if self.client else ""
            queue = GuardedH11Protocol.waiting.get(host)
            if queue is not None:
                queue.pop(self, None)
                if not queue:
                    del GuardedH11Protocol.waiting[host]

        def _drop(self) -> None:
            self._headers_done()
            if not self.transport.is_closing():
                self.transport.close()

        def handle_events(self) -> None:
            super().handle_events()
            if self.cycle is not self._cycle_awaited:  # a request's headers arrived
                self._headers_done()
                self._cycle_awaited = self.cycle

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._await_headers()  # the next request on this connection has as long

        def connection_lost(self, exc: Exception | None) -> None:
            self._headers_done()
            super().connection_lost(exc)

    return GuardedH11Protocol


def _config(app, host: str, port: int, log_level: str, header_timeout_s: float = HEADER_TIMEOUT_S):  # type: ignore[no-untyped-def]
    """The uvicorn configuration both ``serve`` and ``running_server`` use."""
    import uvicorn

    return uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level=log_level,
        http=guarded_protocol(header_timeout_s),
        limit_concurrency=CONNECTION_LIMIT,
        timeout_keep_alive=5,
        server_header=False,
    )


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
    uvicorn.Server(_config(create_app(measure, settings), host, port, log_level)).run()


@contextlib.contextmanager
def running_server(
    measure: MeasureFn | None = None,
    settings: WebSettings | None = None,
    host: str = "127.0.0.1",
    header_timeout_s: float = HEADER_TIMEOUT_S,
) -> Iterator[str]:
    """Run the app in a background thread on a free port of ``host``; yields its base URL, stops on exit."""
    import uvicorn

    server = uvicorn.Server(_config(create_app(measure, settings), host, 0, "warning", header_timeout_s))
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
