"""Fixtures of the web app tests: photos made on the fly (a rendered foot on an A4 sheet, a blank photo) and
clients of an app that measures with the fake pipeline (``_fake_pipeline.py``)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from _photos import png_bytes, render_demo_photo


@pytest.fixture(scope="session")
def demo_photo() -> bytes:
    return render_demo_photo()


@pytest.fixture(scope="session")
def blank_photo() -> bytes:
    """A photo of nothing: an evenly lit grey floor (the fake pipeline finds no foot in it)."""
    return png_bytes(np.full((120, 160, 3), 128, np.uint8))


@pytest.fixture
def make_client(tmp_path) -> Iterator[Callable]:
    """``make_client(measure=FakeMeasure(), **settings)``: a started TestClient; settings default to thread
    isolation with temporary folders under ``tmp_path``."""
    with warnings.catch_warnings():  # starlette's notice about httpx's successor; nothing of ours to change
        warnings.simplefilter("ignore")
        from fastapi.testclient import TestClient

    from _fake_pipeline import FakeMeasure

    from footmesh.web.app import create_app
    from footmesh.web.settings import WebSettings

    clients = []

    def make(measure=None, **settings):
        settings = {"isolation": "thread", "work_dir": tmp_path, **settings}
        # a host the server answers to by default (WebSettings.allowed_hosts), as a browser on this machine sends
        client = TestClient(create_app(measure or FakeMeasure(), WebSettings(**settings)), base_url="http://localhost")
        client.__enter__()
        clients.append(client)
        return client

    yield make
    for client in clients:
        client.__exit__(None, None, None)
