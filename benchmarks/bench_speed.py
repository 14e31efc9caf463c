"""Issue 21's speed targets, all measured in one run on this machine: each beside its goal.

- cold ``footmesh measure`` of a bundled photo / the bare imports of torch, cv2, numpy and scipy (both in fresh
  processes, alternated, medians): goal <= 1.25x;
- warm seconds per photo in one process, 640-px renders, RGB + reference (A4, card, letter in turn) and RGB-D
  (``footmesh.eval.measure``'s photos, with the result files written), for each view set of ``--views``: the
  guided ones and photos unlike them (``ood``: other lenses, distances, poses and skins; ``sweep``, ``tele``),
  which take the slow paths (reference searches that find nothing, refits); median and 90th percentile over
  every photo tried, refused ones included (they cost time too): goal <= 1.0 s median;
- a web request (real pipeline, one warm worker process, one upload at a time) / the same photo measured warm in
  this process: goal <= 1.2x;
- ``footmesh synth`` samples per second at 224 px (render and write, one process; and ``--workers`` processes
  with their start-up): goal >= 100; and read back by ``SynthDataset``, against the recon training's 6-14 images/s
  (docs/recon.md).

Run: ``python benchmarks/bench_speed.py [--photos 12] [--views guided ood] [--cold-runs 3] [--requests 6]
[--synth-n 40] [--parts cold warm web synth]``
(or ``python -m benchmarks bench_speed``).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "src" / "footmesh" / "examples" / "card_right.jpg"
BARE_IMPORTS = "import torch, cv2, numpy, scipy"


def _wall_seconds(command: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def cold_start(runs: int) -> tuple[float, float]:
    """Median wall seconds of the bare imports and of a cold ``footmesh measure`` of EXAMPLE, alternated."""
    footmesh = str(Path(sys.executable).with_name("footmesh"))
    imports, cold = [], []
    with tempfile.TemporaryDirectory() as tmp:
        _wall_seconds([sys.executable, "-c", BARE_IMPORTS])  # the files into the page cache, for both alike
        for i in range(runs):
            imports.append(_wall_seconds([sys.executable, "-c", BARE_IMPORTS]))
            cold.append(_wall_seconds([footmesh, "measure", str(EXAMPLE), "--out", f"{tmp}/{i}"]))
    return statistics.median(imports), statistics.median(cold)


@dataclass(frozen=True)
class WarmTimes:
    """Seconds per photo of one input and view set: median and 90th percentile over every photo tried."""

    median_s: float
    p90_s: float
    measured: int
    tried: int


def warm_per_photo(n: int, views: list[str]) -> dict[tuple[str, str], WarmTimes]:
    """Seconds per photo of RGB + reference and RGB-D at 640 px, per (view set, mode), refused photos included."""
    from footmesh.eval.measure import evaluate_mode

    evaluate_mode("rgbd", 1, 640, views="guided", progress=False)  # networks loaded, kernels compiled
    out = {}
    for view in views:
        for mode in ("rgb_ref", "rgbd"):
            records = evaluate_mode(mode, n, 640, views=view, progress=False).records
            seconds = [r.seconds for r in records]
            measured = sum(r.ok for r in records)
            out[view, mode] = WarmTimes(
                statistics.median(seconds), float(np.percentile(seconds, 90)), measured, len(records)
            )
    return out


def web_request(requests: int) -> tuple[float, float]:
    """Median seconds of a web request (real pipeline, 1 worker process, one at a time) and of the same photo
    measured warm in this process."""
    sys.path.insert(0, str(REPO))
    from benchmarks.bench_web import demo_photo, in_process_seconds, post_all
    from footmesh.web.server import running_server
    from footmesh.web.settings import WebSettings

    photo = demo_photo()
    settings = WebSettings(workers=1, queue=requests, isolation="process", time_limit_s=120.0)
    with running_server(None, settings) as url:
        asyncio.run(post_all(url, photo, 1, 1, 300.0))  # the worker's first job
        records = asyncio.run(post_all(url, photo, requests, 1, 300.0))
    if any(r["status"] != 200 for r in records):
        raise RuntimeError(f"web requests failed: {[r['status'] for r in records]}")
    return statistics.median(r["seconds"] for r in records), in_process_seconds(photo)


def synth_rate(n: int, workers: int) -> dict[str, float]:
    """Samples per second at 224 px: rendered and written by one process, and by ``workers`` processes."""
    from threadpoolctl import threadpool_limits

    from footmesh.synth.dataset import SynthDataset, generate
    from footmesh.synth.scene import SynthConfig

    config = SynthConfig(size=224)
    rates = {}
    with threadpool_limits(1), tempfile.TemporaryDirectory() as tmp:
        generate(f"{tmp}/warm", 2, config=config, progress=False, chunk=2)  # kernels compiled, model loaded
        start = time.perf_counter()
        generate(f"{tmp}/one", n, config=config, progress=False, chunk=n)
        rates["1 process"] = n / (time.perf_counter() - start)
        dataset = SynthDataset(f"{tmp}/one")
        start = time.perf_counter()
        for i in range(len(dataset)):
            dataset[i]
        rates["read back (SynthDataset, every key), 1 process"] = len(dataset) / (time.perf_counter() - start)
        if workers > 1:
            many = 5 * n * workers  # enough that the processes' start-up (a few seconds each) is not most of it
            start = time.perf_counter()
            generate(f"{tmp}/many", many, config=config, workers=workers, progress=False, chunk=n)
            rates[f"{workers} processes, {many} samples (with start-up)"] = many / (time.perf_counter() - start)
    return rates


PARTS = ("cold", "warm", "web", "synth")
"""What ``--parts`` may name: the cold start, the warm time per photo, the web request, synth."""


def main(argv: list[str] | None = None) -> int:
    from footmesh.synth.scene import VIEW_PRESETS

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--photos", type=int, default=12, help="photos per input and view set for the warm time")
    parser.add_argument(
        "--views",
        nargs="+",
        default=["guided", "ood"],
        choices=tuple(VIEW_PRESETS),
        help="view sets of the warm time (footmesh eval measure --views): the guided ones and photos unlike them",
    )
    parser.add_argument("--cold-runs", type=int, default=3)
    parser.add_argument("--requests", type=int, default=6, help="web requests after the first")
    parser.add_argument("--synth-n", type=int, default=40, help="samples per synth measurement")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="synth processes")
    parser.add_argument(
        "--parts", nargs="+", default=list(PARTS), choices=PARTS, help="what to measure (default: everything)"
    )
    args = parser.parse_args(argv)

    rows: list[tuple[str, str, str, bool]] = []  # what, measured, goal, met
    if "cold" in args.parts:
        imports_s, cold_s = cold_start(args.cold_runs)
        ratio = cold_s / imports_s
        rows.append(
            (
                "cold `footmesh measure` / bare imports",
                f"{cold_s:.2f} / {imports_s:.2f} s = {ratio:.2f}x",
                "<= 1.25x",
                ratio <= 1.25,
            )
        )
    for (view, mode), times in warm_per_photo(args.photos, args.views).items() if "warm" in args.parts else ():
        label = {"rgb_ref": "RGB + reference", "rgbd": "RGB-D"}[mode]
        rows.append(
            (
                f"warm per photo, 640 px, {label}, {view} ({times.measured}/{times.tried} measured)",
                f"{times.median_s:.2f} s (p90 {times.p90_s:.2f})",
                "<= 1.0 s",
                times.median_s <= 1.0,
            )
        )
    if "web" in args.parts:
        web_s, warm_s = web_request(args.requests)
        ratio = web_s / warm_s
        rows.append(
            ("web request / warm in process", f"{web_s:.2f} / {warm_s:.2f} s = {ratio:.2f}x", "<= 1.2x", ratio <= 1.2)
        )
    for what, rate in synth_rate(args.synth_n, args.workers).items() if "synth" in args.parts else ():
        if what.startswith("read"):  # training must not wait for its data: the ISM trains at 6-14 images/s
            rows.append((f"synth at 224 px, {what}", f"{rate:.0f} samples/s", ">= 14", rate >= 14))
        else:
            rows.append((f"synth at 224 px, {what}", f"{rate:.1f} samples/s", ">= 100", rate >= 100))

    print(f"speed (issue 21), {os.cpu_count()} cores, all measured in this run")
    print(f"{'what':<70} {'measured':<30} {'goal':<9} met")
    for what, measured, goal, met in rows:
        print(f"{what:<70} {measured:<30} {goal:<9} {'yes' if met else 'no'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
