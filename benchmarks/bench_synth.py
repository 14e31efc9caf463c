"""Synthetic data speed: samples per second at 224 x 224 beside the goal of 100/s, and where the time goes.

Run: ``python benchmarks/bench_synth.py [--n 40] [--size 224]`` (or ``python -m benchmarks bench_synth``).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import tempfile
import time

GOAL = 100.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=40, help="samples per measurement (default 40)")
    parser.add_argument("--size", type=int, default=224)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args(argv)

    from threadpoolctl import threadpool_limits

    from footmesh.synth.dataset import generate
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    threadpool_limits(1)
    config = SynthConfig(size=args.size)
    start = time.perf_counter()
    renderer = Renderer(config)
    renderer.render(0, 0)  # warm up: loads the model and compiles the kernels (numba)
    startup = time.perf_counter() - start
    rows = []
    start = time.perf_counter()
    for i in range(args.n):
        renderer.render(0, i)
    one = args.n / (time.perf_counter() - start)
    rows.append(("render, 1 process", one))
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        generate(tmp, args.n, config=config, progress=False, chunk=args.n)
        rows.append(("render + write chunk, 1 process", args.n / (time.perf_counter() - start)))
        if args.workers > 1:
            n = args.n * args.workers
            start = time.perf_counter()
            generate(tmp + "/w", n, config=config, workers=args.workers, progress=False, chunk=n)
            rows.append(
                (f"render + write, {args.workers} processes (incl. start-up)", n / (time.perf_counter() - start))
            )

    print(f"synthetic samples at {args.size} x {args.size}, {os.cpu_count()} cores")
    print(f"start-up of one process (model, kernel compilation, first sample): {startup:.1f} s")
    print(f"{'what':<52} {'samples/s':>10} {'goal':>6}")
    for name, rate in rows:
        print(f"{name:<52} {rate:>10.1f} {GOAL:>6.0f}")

    profile = cProfile.Profile()
    profile.enable()
    for i in range(min(args.n, 20)):
        renderer.render(1, i)
    profile.disable()
    print("\nwhere the time goes (one process, cumulative, top 12):")
    pstats.Stats(profile).sort_stats("cumulative").print_stats(12)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
