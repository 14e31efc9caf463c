"""Web app under load: N concurrent uploads of the demo photo on loopback; every one answered, none lost or mixed up.

Starts the app in this process (uvicorn thread, free port on 127.0.0.1) with the fake pipeline of the tests
(``tests/web/_fake_pipeline.py``, a mean foot measured for real, optional extra delay) or the real one
(``footmesh.pipeline``), or loads a server that is already running (``--url``, loopback only). Prints the
status counts and the latency of each request from the start of its upload to the end of its answer.

Run: ``python benchmarks/bench_web.py [--n 16] [--concurrency 8] [--pipeline fake|real] [--workers 1]``
(or ``python -m benchmarks bench_web``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import hashlib
import io
import sys
import time
from collections import Counter
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

REPO = Path(__file__).resolve().parents[1]
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def demo_photo(size: int = 480) -> bytes:
    """The demo photo (a synthetic foot on an A4 sheet, as in tests/web) as JPEG bytes."""
    from PIL import Image

    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    config = SynthConfig(size=size, reference="a4", lifted_fraction=0.0, elevation_deg=(55.0, 80.0))
    buffer = io.BytesIO()
    Image.fromarray(Renderer(config).render(1, 6)["rgb"]).save(buffer, format="JPEG", quality=90)
    return buffer.getvalue()


async def post_all(url: str, photo: bytes, n: int, concurrency: int, timeout_s: float) -> list[dict]:
    """Send ``n`` uploads, at most ``concurrency`` at a time; one record per upload, in order."""
    import httpx

    gate = asyncio.Semaphore(concurrency)
    limits = httpx.Limits(max_connections=concurrency, max_keepalive_connections=concurrency)
    async with httpx.AsyncClient(base_url=url, timeout=timeout_s, limits=limits) as client:

        async def one(i: int) -> dict:
            async with gate:
                start = time.perf_counter()
                try:
                    files = {"photo": (f"foot-{i}.jpg", photo, "image/jpeg")}
                    response = await client.post("/api/measure", files=files)
                except httpx.HTTPError as exc:
                    return {"i": i, "status": None, "error": repr(exc), "seconds": time.perf_counter() - start}
                record = {"i": i, "status": response.status_code, "seconds": time.perf_counter() - start}
                if response.status_code == 200:
                    record["rid"] = response.headers.get("X-Result-Id")
                    hashes = response.json().get("input_sha256")
                    # the real pipeline names each input file's hash, the fake one gives the photo's
                    record["sha256"] = hashes.get("image") if isinstance(hashes, dict) else hashes
                return record

        return await asyncio.gather(*(one(i) for i in range(n)))


def in_process_seconds(photo: bytes, runs: int = 5) -> float:
    """Median seconds of ``measure_photo`` on ``photo`` in this process, after one warm-up run."""
    import statistics
    import tempfile

    from footmesh.pipeline import measure_photo

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "photo.jpg"
        path.write_bytes(photo)
        measure_photo(path, Path(tmp) / "warm")
        times = []
        for i in range(runs):
            start = time.perf_counter()
            measure_photo(path, Path(tmp) / f"out{i}")
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=16, help="uploads (default 16)")
    parser.add_argument("--concurrency", type=int, default=8, help="uploads in flight at once (default 8)")
    parser.add_argument("--pipeline", choices=("fake", "real"), default="fake", help="measure function (default fake)")
    parser.add_argument("--fake-delay", type=float, default=0.0, help="extra seconds per fake measurement")
    parser.add_argument("--workers", type=int, default=1, help="measurements at once in the server (default 1)")
    parser.add_argument("--isolation", choices=("process", "thread"), default="process")
    parser.add_argument("--queue", type=int, help="server queue (default: --n, so that none is refused)")
    parser.add_argument("--time-limit", type=float, default=120.0, help="seconds per measurement (default 120)")
    parser.add_argument("--url", help="load this running server instead (loopback addresses only)")
    args = parser.parse_args(argv)
    if not 1 <= args.n <= 1000 or not 1 <= args.concurrency <= 256:
        parser.error("--n must be 1..1000 and --concurrency 1..256")

    photo = demo_photo()
    if args.url:
        if urlparse(args.url).hostname not in LOOPBACK:
            parser.error("--url must be a loopback address (127.0.0.1, localhost, ::1)")
        server = contextlib.nullcontext(args.url.rstrip("/"))
        what = f"server at {args.url}"
    else:
        from footmesh.web.server import running_server
        from footmesh.web.settings import WebSettings

        if args.pipeline == "fake":
            sys.path.insert(0, str(REPO / "tests" / "web"))  # the fake is test scaffolding; forkserver gets sys.path
            from _fake_pipeline import FakeMeasure

            measure = FakeMeasure(delay_s=args.fake_delay)
        else:
            import importlib.util

            if importlib.util.find_spec("footmesh.pipeline") is None:
                print("footmesh.pipeline is not installed yet: use --pipeline fake")
                return 2
            measure = None
        queue = args.n if args.queue is None else args.queue
        settings = WebSettings(
            workers=args.workers, queue=queue, isolation=args.isolation, time_limit_s=args.time_limit
        )
        server = running_server(measure, settings)
        what = f"{args.pipeline} pipeline, {args.workers} worker(s), {args.isolation} isolation, queue {queue}"

    timeout_s = args.time_limit * (args.n / max(args.workers, 1) + 2)
    with server as url:
        start = time.perf_counter()
        warm = asyncio.run(post_all(url, photo, 1, 1, timeout_s))[0]  # first job: forkserver start, imports
        warm_s = time.perf_counter() - start
        start = time.perf_counter()
        records = asyncio.run(post_all(url, photo, args.n, args.concurrency, timeout_s))
        wall = time.perf_counter() - start

    statuses = Counter(r["status"] for r in records)
    ok = [r for r in records if r["status"] == 200]
    lost = [r for r in records if r["status"] is None]
    expected = hashlib.sha256(photo).hexdigest()
    mixed = [r for r in ok if r.get("sha256") != expected]
    distinct = len({r.get("rid") for r in ok})
    seconds = np.array([r["seconds"] for r in ok]) if ok else np.zeros(1)
    print(f"web load: {args.n} uploads of {len(photo) / 1024:.0f} KB, {args.concurrency} at a time; {what}")
    print(f"  first request (warm-up): status {warm['status']}, {warm_s:.2f} s")
    print(f"  answers: {dict(statuses)}; lost (no answer): {len(lost)}; distinct result ids: {distinct}/{len(ok)}")
    print(f"  wrong input hash: {len(mixed)}")
    print(
        f"  latency s: p50 {np.percentile(seconds, 50):.2f}, p95 {np.percentile(seconds, 95):.2f}, "
        f"max {seconds.max():.2f}; wall {wall:.2f} s, {len(ok) / wall:.2f} results/s"
    )
    for r in lost[:5]:
        print(f"  lost #{r['i']}: {r['error']}")
    if args.pipeline == "real" and not args.url and ok:
        warm_in_process = in_process_seconds(photo)
        print(
            f"  the same photo measured in this process, warm: median {warm_in_process:.2f} s; a web request "
            f"costs {np.percentile(seconds, 50) / warm_in_process:.2f}x that (issue 21: <= 1.2x)"
        )
    good = len(ok) + statuses.get(503, 0) == args.n and not lost and not mixed and distinct == len(ok)
    print("  all answered, none lost" if good else "  PROBLEM: some uploads were lost or mixed up")
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main())
