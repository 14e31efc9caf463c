"""Synthetic data speed: samples per second at 224 x 224 beside the goal of 100/s, and where the time goes.

Each rate is measured ``--repeat`` times (default 3); the table shows the best and the spread (other jobs on the
machine slow some runs down). Rows: rendering alone in one thread; ``generate`` (render + write chunks) in one
process with one rendering thread and with one per core (``footmesh synth``'s default); ``--workers`` processes
(with their start-up); reading the dataset back (``SynthDataset``, every key; training needs about 14/s).

Run: ``python benchmarks/bench_synth.py [--n 100] [--size 224] [--repeat 3]`` (or ``python -m benchmarks
bench_synth``).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import tempfile
import time

GOAL = 100.0
READ_GOAL = 14.0
"""Samples per second training reads (it must read at least as fast as it trains)."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=100, help="samples per measurement (default 100)")
    parser.add_argument("--size", type=int, default=224)
    parser.add_argument("--repeat", type=int, default=3, help="measurements of each rate (default 3)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args(argv)

    import torch
    from threadpoolctl import threadpool_limits

    from footmesh.synth.dataset import SynthDataset, generate
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    threadpool_limits(1)
    torch.set_num_threads(1)
    config = SynthConfig(size=args.size)
    start = time.perf_counter()
    renderer = Renderer(config)
    renderer.render(0, 0)  # warm up: loads the model and compiles the kernels (numba)
    startup = time.perf_counter() - start
    n, cores = args.n, os.cpu_count() or 1
    rates: dict[str, list[float]] = {}

    def timed(name: str, count: int, run) -> None:
        start = time.perf_counter()
        run()
        rates.setdefault(name, []).append(count / (time.perf_counter() - start))

    with tempfile.TemporaryDirectory() as tmp:
        generate(f"{tmp}/warm", 4, config=config, progress=False, chunk=2)  # the writer and posing kernels
        for r in range(args.repeat):
            timed("render only, 1 thread", n, lambda: [renderer.render(0, i) for i in range(n)])
            timed(
                "render + write, 1 process, 1 thread",
                n,
                lambda r=r: generate(f"{tmp}/a{r}", n, config=config, progress=False, chunk=n // 2, threads=1),
            )
            timed(
                f"render + write, 1 process, {cores} threads (default)",
                n,
                lambda r=r: generate(f"{tmp}/b{r}", n, config=config, progress=False, chunk=n // 2),
            )
            if args.workers > 1:
                many = 4 * n
                timed(
                    f"render + write, {args.workers} processes (with start-up)",
                    many,
                    lambda r=r, many=many: generate(
                        f"{tmp}/c{r}", many, config=config, workers=args.workers, progress=False, chunk=n
                    ),
                )
            dataset = SynthDataset(f"{tmp}/a{r}")
            timed("read back (SynthDataset, every key)", len(dataset), lambda d=dataset: [d[i] for i in range(n)])
        size = sum(f.stat().st_size for f in os.scandir(f"{tmp}/a0") if f.name.startswith("chunk-"))

    print(f"synthetic samples at {args.size} x {args.size}, {cores} cores, {n} samples a measurement")
    print(f"start-up of one process (model, kernels from numba's cache, first sample): {startup:.1f} s")
    print(f"chunk files: {size / n / 1e3:.0f} kB a sample")
    print(f"{'what':<52} {'samples/s (best)':>16} {'spread':>13} {'goal':>6}")
    for name, values in rates.items():
        goal = READ_GOAL if name.startswith("read") else GOAL
        spread = f"{min(values):.1f}-{max(values):.1f}"
        print(f"{name:<52} {max(values):>16.1f} {spread:>13} {goal:>6.0f}")

    profile = cProfile.Profile()
    profile.enable()
    for i in range(min(n, 40)):
        renderer.render(1, i)
    profile.disable()
    print("\nwhere the time goes (render, one thread, by own time, top 15):")
    pstats.Stats(profile).sort_stats("tottime").print_stats(15)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
