"""The forkserver's preload (``footmesh.web.warm``): jobs forked after it must run, on every core."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

# Loads the networks as the server's forkserver does, forks a job, and runs one of torch's parallel kernels in it.
FORKED_JOB = """
import os, sys, torch
torch.set_num_threads(2)
import footmesh.web.warm
pid = os.fork()
if pid == 0:
    torch.ones(4_000_000).mul(2).sum()
    os._exit(0)
_, status = os.waitpid(pid, 0)
sys.exit(os.waitstatus_to_exitcode(status))
"""


def test_a_job_forked_after_the_warm_up_runs_torch_in_parallel():
    # OpenMP's thread team does not survive a fork: a parallel region during the warm-up left every forked job hung
    env = {**os.environ, "OMP_NUM_THREADS": "2"}
    job = subprocess.Popen([sys.executable, "-c", FORKED_JOB], env=env, start_new_session=True)
    try:
        assert job.wait(timeout=120) == 0
    except subprocess.TimeoutExpired:
        os.killpg(job.pid, signal.SIGKILL)  # the parent and its hung child
        job.wait()
        raise AssertionError("a job forked after the warm-up hung in its first parallel torch kernel") from None
