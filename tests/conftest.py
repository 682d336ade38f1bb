"""Shared test configuration: GPU tests are skipped without CUDA; training tests run torch on
one thread; planner tests run BLAS and OpenMP on one thread."""

from __future__ import annotations

import pytest

from pourbench.fluids.solver import cuda_available


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if any("gpu" in item.keywords for item in items) and not cuda_available():
        skip = pytest.mark.skip(reason="needs a CUDA device")
        for item in items:
            if "gpu" in item.keywords:
                item.add_marker(skip)


@pytest.fixture
def one_torch_thread():
    """One torch thread, as training uses: on a loaded 2-core machine torch's default
    threads make tiny updates 40x slower."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread_for_planners(request: pytest.FixtureRequest):
    """Planner tests compare plans bit for bit, which a threaded BLAS reduction can change in
    the last bit: every BLAS and OpenMP library loaded when a planner module starts (whatever
    earlier tests loaded or raised) is held to one thread for it, its fixtures included."""
    if not request.module.__name__.startswith("test_planners"):
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        yield
