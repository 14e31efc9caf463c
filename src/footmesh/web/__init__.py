"""The web app (``footmesh serve``): upload a foot photo, see the 3D foot, its measurements and shoe sizes.

Needs the "web" extra (FastAPI, uvicorn, python-multipart, Jinja2); importing this package alone does not.
``create_app(measure, settings)`` builds the ASGI app, ``serve(host, port, settings)`` runs it (docs/web.md).
"""

from __future__ import annotations

from typing import Any

from footmesh.web.settings import WebSettings

__all__ = ["WebSettings", "create_app", "serve"]


def __getattr__(name: str) -> Any:
    # FastAPI and uvicorn load only when the app is wanted, so `footmesh --help` works without the extra
    if name == "create_app":
        from footmesh.web.app import create_app

        return create_app
    if name == "serve":
        from footmesh.web.server import serve

        return serve
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
