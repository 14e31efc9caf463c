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
RENDER_THREADS = 1
"""The synthetic renderer's foot-model passes (``synth.render.Renderer.geometry``): one thread, as the dataset's
workers run, so that an eval photo rendered in any process is the dataset's sample on any machine. The IK poses'
redundant toe chains tie to within rounding: with two threads 6-9 of 60 guided eval photos took other toe angles."""


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run torch's intra-op work on exactly ``n`` threads, then restore it; torch alone (no BLAS), cheap enough to
    wrap every sample of a renderer."""
    before = torch.get_num_threads()
    if before != n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


@contextlib.contextmanager
def fixed_threads(n: int) -> Iterator[None]:
    """Run torch's intra-op work and the BLAS on exactly ``n`` threads, then restore the settings."""
    with torch_threads(n), threadpool_limits(limits=n):
        yield
