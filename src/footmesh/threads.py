"""How many CPU threads a stage's numerical work runs on, whatever the machine has.

Floating-point sums depend on how the work is split between threads, so a network's output, and the fit that
starts from it, would change in its last bits with the machine's core count and could then land in another of the
fit's minima (a real photo measured 205 mm on one thread and 224 mm on two). Each stage fixes its count instead.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from threadpoolctl import threadpool_limits

PIPELINE_THREADS = 2
"""A photo's measurement (networks, reference search, measurements): two threads on every machine, this project's
2-core CPU being the reference."""
SOLVER_THREADS = 1
"""The fit, per start: its arrays are small, and more threads only add synchronisation (a busy machine made a fit
with two 3-10x slower); its starts run ``FitConfig.solver_workers`` at a time instead, one thread each."""


@contextlib.contextmanager
def fixed_threads(n: int) -> Iterator[None]:
    """Run torch's intra-op work and the BLAS on exactly ``n`` threads, then restore the settings."""
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        with threadpool_limits(limits=n):
            yield
    finally:
        torch.set_num_threads(before)
