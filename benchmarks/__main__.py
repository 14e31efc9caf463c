"""Run every benchmark: ``python -m benchmarks [name ...]``."""

from __future__ import annotations

import importlib
import sys

BENCHMARKS = ("bench_foot_model", "bench_register", "bench_synth", "bench_cues", "bench_first_pass", "bench_web")


def main(argv: list[str] | None = None) -> int:
    names = (argv if argv is not None else sys.argv[1:]) or list(BENCHMARKS)
    for name in names:
        module = importlib.import_module(f"benchmarks.{name}")
        print(f"\n== {name} ==")
        module.main([])
    return 0


if __name__ == "__main__":
    sys.exit(main())
