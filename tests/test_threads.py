"""footmesh.threads: a stage's thread count is fixed and the caller's restored."""

from __future__ import annotations

import pytest
import torch
from threadpoolctl import threadpool_info

from footmesh.threads import fixed_threads


def _blas_threads() -> set[int]:
    return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}


def test_fixed_threads_sets_torch_and_blas_and_restores_them():
    before, blas_before = torch.get_num_threads(), _blas_threads()
    with fixed_threads(1):
        assert torch.get_num_threads() == 1
        assert _blas_threads() <= {1}
    assert torch.get_num_threads() == before and _blas_threads() == blas_before


def test_fixed_threads_restores_after_an_error():
    before = torch.get_num_threads()
    with pytest.raises(RuntimeError), fixed_threads(1):
        raise RuntimeError("inside")
    assert torch.get_num_threads() == before
