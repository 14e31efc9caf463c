"""Running measurements for the web app: a bounded queue, a fixed number of workers and a time limit.

A request is admitted while fewer than ``workers + queue`` are in; it then waits (first come, first served) for
one of ``workers`` slots. In "process" isolation each measurement runs in one of ``workers`` warm processes,
forked from a forkserver that has the pipeline imported and its networks loaded, which take jobs one after another
(the networks stay loaded, so a request costs what a warm measurement costs); a process whose job runs past the
time limit, crashes, or whose client goes away is killed and replaced, so a stuck or crashing job never takes the
server with it. The request's temporary folder is deleted when the job has really ended (killed or finished).
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing
import shutil
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from footmesh.errors import InternalError, is_users_fault
from footmesh.web.settings import WebSettings
from footmesh.web.store import ResultStore

log = logging.getLogger(__name__)

MeasureFn = Callable[..., dict]
"""``measure(image, out_dir, *, depth, depth_unit, intrinsics, side, reference) -> result dict``
(footmesh.pipeline)."""
PIPELINE_MODULE = "footmesh.pipeline"
WARM_MODULE = "footmesh.web.warm"
"""Imports the pipeline and loads its foot model and networks: the forkserver's preload for the real pipeline."""
EXIT_WAIT_S = 5.0
KILL_GRACE_S = 10.0
JOBS_PER_WORKER = 100
"""A warm measurement process is replaced after this many jobs (whatever a job leaves behind stays bounded)."""
CANCEL_POLL_S = 0.25
"""How often a job in its own process looks whether its client has gone (s)."""
"""In process isolation the worker kills the job at the time limit; the request gives up this much later."""


@dataclass(frozen=True)
class Job:
    """One measurement: checked input files inside ``work_dir`` (the request's temporary folder)."""

    work_dir: Path
    image: Path
    depth: Path | None = None
    depth_unit: str = "mm"
    intrinsics: Path | None = None
    side: str = "auto"
    reference: str = "auto"

    @property
    def out_dir(self) -> Path:
        return self.work_dir / "out"

    def redact(self, message: str) -> str:
        """``message`` with the server's paths of the uploads replaced by their form fields' names."""
        for path, field in ((self.image, "photo"), (self.depth, "depth"), (self.intrinsics, "intrinsics")):
            if path is not None:
                message = message.replace(str(path), f"(upload field '{field}')")
        return message.replace(str(self.work_dir), "(upload)")


class JobError(Exception):
    """A measurement that gave no result: ``status`` is the HTTP status, ``str(exc)`` the user's message."""

    status = 500


class Busy(JobError):
    status = 503


class TimedOut(JobError):
    status = 504


class BadInput(JobError):
    status = 422


class Crashed(JobError):
    status = 500


class Cancelled(JobError):
    """The client went away before its answer: the job was stopped (process isolation) or its result dropped."""

    status = 499


class PipelineMissing(JobError):
    status = 503


def default_measure(image: Path, out_dir: Path, **options: Any) -> dict:
    """``footmesh.pipeline.measure_photo``, imported when a request comes (the server starts without it)."""
    try:
        from footmesh.pipeline import measure_photo
    except ModuleNotFoundError as exc:
        if exc.name != PIPELINE_MODULE:
            raise
        raise PipelineMissing("the measuring pipeline (footmesh.pipeline) is not installed on this server") from None
    return measure_photo(image, out_dir, **options)


def _call(measure: MeasureFn, job: Job) -> dict:
    job.out_dir.mkdir(parents=True, exist_ok=True)
    options = {
        "depth": job.depth,
        "depth_unit": job.depth_unit,
        "intrinsics": job.intrinsics,
        "side": job.side,
        "reference": job.reference,
    }
    result = measure(job.image, job.out_dir, **options)
    if not isinstance(result, dict):
        raise InternalError(f"the measure function returned {type(result).__name__}, not a result dict")
    return result


def _classify(exc: BaseException) -> tuple[str, str]:
    """("input" | "missing" | "crash", message) for an exception raised by the measure function."""
    if isinstance(exc, PipelineMissing):
        return "missing", str(exc)
    if is_users_fault(exc):
        return "input", str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return "crash", "".join(traceback.format_exception(exc))


def _worker_main(measure: MeasureFn, conn: Connection) -> None:
    """Entry point of a warm measurement process: jobs one after another, each answered with ("ok", result) or
    (kind, message), until the server sends None, closes the pipe, or kills the process (time limit, client gone)."""
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        try:
            outcome: tuple[str, Any] = ("ok", _call(measure, job))
        except BaseException as exc:  # everything goes back to the server as a message; the process goes on
            outcome = _classify(exc)
        try:
            conn.send(outcome)
        except Exception as exc:  # e.g. a result that cannot be pickled
            conn.send(("crash", f"the result could not be sent back: {exc!r}"))


class _Worker:
    """A warm measurement process (``_worker_main``) and the server's end of its pipe."""

    def __init__(self, ctx: multiprocessing.context.BaseContext, measure: MeasureFn) -> None:
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_worker_main, args=(measure, child), name="footmesh-measure")
        self.process.daemon = True
        self.process.start()
        child.close()  # only the worker writes to its end; EOF on ours then means the worker is gone
        self.jobs = 0

    def stop(self) -> None:
        """Kill the process (a job past its limit, a client gone, a broken pipe) and wait for it."""
        if self.process.is_alive():
            self.process.kill()
        self.process.join(EXIT_WAIT_S)
        self.conn.close()


class _Slots:
    """``n`` worker slots handed out first come, first served, on the event loop's thread only."""

    def __init__(self, n: int) -> None:
        self.free = n
        self.waiters: deque[asyncio.Future] = deque()

    async def acquire(self, timeout: float) -> bool:
        if self.free > 0 and not self.waiters:
            self.free -= 1
            return True
        waiter = asyncio.get_running_loop().create_future()
        self.waiters.append(waiter)
        try:
            # shield: a timeout must not cancel the waiter itself, or a slot handed over meanwhile is lost
            await asyncio.wait_for(asyncio.shield(waiter), timeout)
            return True
        except (TimeoutError, asyncio.CancelledError) as exc:
            if waiter.done() and not waiter.cancelled():
                self.release()  # the slot came just as we gave up: pass it on
            else:
                waiter.cancel()
                self.waiters.remove(waiter)
            if isinstance(exc, asyncio.CancelledError):
                raise
            return False

    def release(self) -> None:
        while self.waiters:
            waiter = self.waiters.popleft()
            if not waiter.done():
                waiter.set_result(None)
                return
        self.free += 1


class JobRunner:
    """Runs ``Job``s with ``measure`` under the limits of ``settings``; results go into ``store``."""

    def __init__(self, measure: MeasureFn, store: ResultStore, settings: WebSettings) -> None:
        self.measure = measure
        self.store = store
        self.settings = settings
        self._slots = _Slots(settings.workers)
        self._admitted = 0
        self._running = 0
        self._pool = ThreadPoolExecutor(max_workers=settings.workers, thread_name_prefix="footmesh-job")
        self._ctx = _process_context(measure, settings.preload) if settings.isolation == "process" else None
        self._idle: list[_Worker] = []  # warm measurement processes waiting for a job (process isolation)
        self._idle_lock = threading.Lock()

    def start(self) -> None:
        """Start the forkserver and the warm measurement processes now (process isolation), so that the first
        request waits for neither."""
        if self._ctx is None:
            return
        if self._ctx.get_start_method() == "forkserver":
            from multiprocessing import forkserver

            forkserver.ensure_running()
        with self._idle_lock:
            self._idle.extend(_Worker(self._ctx, self.measure) for _ in range(self.settings.workers))

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        with self._idle_lock:
            idle, self._idle = self._idle, []
        for worker in idle:
            worker.stop()

    @property
    def running(self) -> int:
        return self._running

    @property
    def queued(self) -> int:
        return self._admitted - self._running

    @property
    def full(self) -> bool:
        """No room for another measurement: ``workers`` running and ``queue`` waiting."""
        return self._admitted >= self.settings.workers + self.settings.queue

    async def run(self, job: Job, cancelled: threading.Event | None = None) -> tuple[str, dict]:
        """Measure ``job``; returns (result id in the store, result dict). Always deletes ``job.work_dir``.
        ``cancelled``: set when nobody waits for the answer any more (the client disconnected): a job in its own
        process is killed, one in a thread ends but its result is not stored, and the queue place is freed.

        Raises:
            Busy: no room in the queue, or no worker came free within ``queue_wait_s``.
            TimedOut: the measurement ran past ``time_limit_s``.
            BadInput: the pipeline refused the input (its one-line message).
            PipelineMissing, Crashed: no pipeline, or it failed (details in the server log).
        """
        s = self.settings
        if self.full:
            _remove(job.work_dir)
            raise Busy(f"the server is busy ({self._admitted} measurements in progress or waiting); try again soon")
        self._admitted += 1
        try:
            got = await self._slots.acquire(s.queue_wait_s)
        except BaseException:
            self._admitted -= 1
            _remove(job.work_dir)
            raise
        if not got:
            self._admitted -= 1
            _remove(job.work_dir)
            raise Busy(f"no worker came free within {s.queue_wait_s:.0f} s; try again later")
        if cancelled is not None and cancelled.is_set():  # its client left while it waited: not run at all
            self._admitted -= 1
            self._slots.release()
            _remove(job.work_dir)
            raise Cancelled("the client went away before the answer")
        self._running += 1
        future = asyncio.get_running_loop().run_in_executor(self._pool, self._execute, job, cancelled)
        future.add_done_callback(self._finished)
        limit = s.time_limit_s + (KILL_GRACE_S if self._ctx is not None else 0.0)
        try:
            return await asyncio.wait_for(asyncio.shield(future), limit)
        except BadInput as exc:
            raise BadInput(job.redact(str(exc))) from None
        except TimeoutError:
            raise TimedOut(f"the measurement took longer than the limit of {s.time_limit_s:g} s") from None

    def _finished(self, _future: asyncio.Future) -> None:
        self._running -= 1
        self._admitted -= 1
        self._slots.release()

    def _execute(self, job: Job, cancelled: threading.Event | None = None) -> tuple[str, dict]:
        """In a worker thread: measure, store the result files, delete the request's folder."""
        start = time.perf_counter()
        try:
            if self._ctx is None:
                try:
                    result = _call(self.measure, job)
                except Exception as exc:
                    kind, message = _classify(exc)
                    _raise(kind, message)
            else:
                result = self._run_in_process(job, cancelled)
            if cancelled is not None and cancelled.is_set():
                log.info("dropped the result of %s: the client went away", job.image.name)
                raise Cancelled("the client went away before the answer")
            rid = self.store.add(result, job.out_dir)
            log.info("measured %s in %.2f s: result %s", job.image.name, time.perf_counter() - start, rid)
            return rid, result
        finally:
            _remove(job.work_dir)

    def _run_in_process(self, job: Job, cancelled: threading.Event | None = None) -> dict:
        """``job`` in a warm measurement process (one waiting, else a new one); the process is killed when the job
        runs past the time limit or its client goes away, and replaced at the next job; it serves at most
        ``JOBS_PER_WORKER`` jobs."""
        with self._idle_lock:
            worker = self._idle.pop() if self._idle else None
        if worker is None or not worker.process.is_alive():
            if worker is not None:
                worker.stop()
            worker = _Worker(self._ctx, self.measure)
        answered = False
        try:
            worker.conn.send(job)
            deadline = time.monotonic() + self.settings.time_limit_s
            while not worker.conn.poll(min(CANCEL_POLL_S, max(deadline - time.monotonic(), 0.0))):
                if cancelled is not None and cancelled.is_set():
                    raise Cancelled("the client went away before the answer")  # the finally kills the worker
                if time.monotonic() >= deadline:
                    raise TimedOut(f"the measurement took longer than the limit of {self.settings.time_limit_s:g} s")
            try:
                kind, payload = worker.conn.recv()
            except EOFError:
                worker.process.join(EXIT_WAIT_S)
                raise Crashed(f"the measurement process died (exit code {worker.process.exitcode})") from None
            answered = True
        finally:
            worker.jobs += 1
            if answered and worker.jobs < JOBS_PER_WORKER and worker.process.is_alive():
                with self._idle_lock:
                    self._idle.append(worker)
            else:
                worker.stop()
        if kind != "ok":
            _raise(kind, payload)
        return payload


def _raise(kind: str, message: str) -> None:
    if kind == "input":
        raise BadInput(message)
    if kind == "missing":
        raise PipelineMissing(message)
    log.error("measurement failed:\n%s", message)
    raise Crashed("the measurement failed with an internal error (the server log has the details)")


def _process_context(measure: MeasureFn, preload: tuple[str, ...]) -> multiprocessing.context.BaseContext:
    """A forkserver context with the pipeline imported in the server process (fast forks), else spawn."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    # a function's module, or (for a callable object) its class's module; the real pipeline also with its networks
    # loaded (footmesh.web.warm), so that no job loads them again
    module = WARM_MODULE if measure is default_measure else getattr(measure, "__module__", None)
    # "__main__": each child would otherwise import the main script again itself. A module that cannot be imported
    # is skipped by the forkserver (Python 3.11's forkserver also ignores the server's sys.path: test modules
    # outside the package load in each job) and jobs then import it themselves.
    modules = ["__main__", __name__, *preload] + ([module] if module and module != "__main__" else [])
    ctx.set_forkserver_preload(modules)
    return ctx


def _remove(folder: Path) -> None:
    shutil.rmtree(folder, ignore_errors=True)
