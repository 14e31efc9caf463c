"""Limits and settings of the web app, one frozen dataclass passed to ``create_app``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

Isolation = Literal["process", "thread"]

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
"""The names of this machine, which the server answers to by default."""


@dataclass(frozen=True)
class WebSettings:
    """What the server accepts and how much work it takes on at once.

    Attributes:
        max_upload_bytes: largest request body (photo + depth map + intrinsics together); larger -> 413.
        max_pixels: largest photo or depth map, width x height; larger -> 413 (checked from the header, before
            anything is decoded: a small file can hold a huge image).
        max_intrinsics_bytes: largest intrinsics JSON file.
        time_limit_s: longest one measurement may run; longer -> 504 (in "process" isolation the job is killed).
        workers: measurements run at once.
        queue: requests that may wait for a worker; beyond ``workers + queue`` -> 503 at once.
        queue_wait_s: longest a request waits in the queue before it gets 503.
        result_ttl_s: how long result files stay downloadable.
        max_results: results kept at most; the oldest go first.
        isolation: "process" runs each measurement in one of ``workers`` warm processes (forked once, reused
            job after job) that is killed and replaced at the time limit or on a crash (the server's default);
            "thread" runs it in a thread of the server (tests, trusted local use: a job past the time limit gets
            504 but keeps its worker until it ends).
        work_dir: parent of the server's temporary folders (uploads, results); None: the system's temp folder.
        preload: modules the forkserver imports once, besides the measure function's own, so that each job
            starts in milliseconds instead of importing torch (process isolation).
        upload_idle_timeout_s: longest pause while a request's body arrives; longer -> 408 and the connection
            closed (a body sent a byte at a time holds a connection; the headers have their own time-out, see
            ``footmesh.web.server``).
        upload_min_rate_bytes_s: after ``upload_rate_grace_s``, a request's body must have arrived at least this
            fast on average, else 408 and the connection closed (a body trickling in just faster than the idle
            time-out would otherwise hold a connection and its memory for hours: 30 MB at one byte per 29 s).
            1 KiB/s is 50 times slower than a phone's worst mobile upload.
        allowed_hosts: the names this server answers to in the ``Host`` header (others get 400: a web page
            elsewhere cannot reach it by DNS rebinding); a form post whose ``Origin`` is another host gets 403
            (cross-site request forgery). ``"*"`` answers any host.
    """

    max_upload_bytes: int = 30 * 1024 * 1024
    max_pixels: int = 50_000_000
    max_intrinsics_bytes: int = 64 * 1024
    time_limit_s: float = 120.0
    workers: int = 1
    queue: int = 8
    queue_wait_s: float = 300.0
    result_ttl_s: float = 3600.0
    max_results: int = 200
    isolation: Isolation = "process"
    work_dir: Path | None = None
    preload: tuple[str, ...] = ("footmesh.model.layer", "footmesh.measure", "footmesh.report", "trimesh", "PIL.Image")
    upload_idle_timeout_s: float = 30.0
    upload_min_rate_bytes_s: float = 1024.0
    upload_rate_grace_s: float = 10.0
    allowed_hosts: tuple[str, ...] = LOCAL_HOSTS

    def __post_init__(self) -> None:
        positive = {
            "max_upload_bytes": self.max_upload_bytes,
            "max_pixels": self.max_pixels,
            "max_intrinsics_bytes": self.max_intrinsics_bytes,
            "time_limit_s": self.time_limit_s,
            "workers": self.workers,
            "queue_wait_s": self.queue_wait_s,
            "result_ttl_s": self.result_ttl_s,
            "max_results": self.max_results,
            "upload_idle_timeout_s": self.upload_idle_timeout_s,
            "upload_min_rate_bytes_s": self.upload_min_rate_bytes_s,
            "upload_rate_grace_s": self.upload_rate_grace_s,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ValueError(f"WebSettings.{name} must be positive, got {value!r}")
        if self.queue < 0:
            raise ValueError(f"WebSettings.queue must be 0 or more, got {self.queue!r}")
        if self.isolation not in ("process", "thread"):
            raise ValueError(f"WebSettings.isolation must be 'process' or 'thread', got {self.isolation!r}")
        object.__setattr__(self, "preload", tuple(str(m) for m in self.preload))
        hosts = tuple(str(h).strip().lower().strip("[]") for h in self.allowed_hosts)
        if not hosts or not all(hosts):
            raise ValueError(f"WebSettings.allowed_hosts must name at least one host, got {self.allowed_hosts!r}")
        object.__setattr__(self, "allowed_hosts", hosts)
        if self.work_dir is not None:
            object.__setattr__(self, "work_dir", Path(self.work_dir))
