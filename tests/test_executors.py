"""Executors: order kept, identical results whatever runs them, dask optional with a clear message."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from stereo_bench.errormodel.montecarlo import monte_carlo, monte_carlo_samples
from stereo_bench.errormodel.rigorous import Setup
from stereo_bench.errormodel.surfaces import surface_bz
from stereo_bench.executors import (
    DaskExecutor,
    Executor,
    ExecutorUnavailable,
    LocalExecutor,
    SerialExecutor,
    group,
    make_executor,
    spawn_seeds,
)

SETUP = Setup.make(100.0, 500.0, 85.0)


def square(x: int) -> int:
    return x * x


def draw(seed: np.random.SeedSequence) -> float:
    return float(np.random.default_rng(seed).normal())


def test_serial_executor_and_protocol():
    with SerialExecutor() as ex:
        assert isinstance(ex, Executor)
        assert ex.map(square, range(5)) == [0, 1, 4, 9, 16]
        assert ex.map(square, []) == []


def test_group_keeps_order_and_covers_everything():
    items = list(range(10))
    for n in (1, 3, 4, 10, 50):
        groups = group(items, n)
        assert [x for g in groups for x in g] == items
        assert all(groups) and len(groups) == min(n, 10)


def test_spawn_seeds_is_repeatable_and_does_not_advance_a_given_sequence():
    root = np.random.SeedSequence(42)
    a, b = spawn_seeds(root, 3), spawn_seeds(root, 3)
    assert [draw(s) for s in a] == [draw(s) for s in b] == [draw(s) for s in spawn_seeds(42, 3)]
    assert len({draw(s) for s in a}) == 3


@pytest.fixture(scope="module")
def local_executor():
    with LocalExecutor(max_workers=2) as ex:
        yield ex


def test_local_executor_keeps_order(local_executor):
    assert local_executor.map(square, range(20)) == [i * i for i in range(20)]
    assert local_executor.describe()["workers"] == 2


def test_monte_carlo_identical_on_serial_and_local(local_executor):
    serial = monte_carlo_samples(SETUP, 0.1, 1500, seed=11, executor=SerialExecutor())
    local = monte_carlo_samples(SETUP, 0.1, 1500, seed=11, executor=local_executor, n_tasks=3)
    np.testing.assert_array_equal(serial[0], local[0])
    np.testing.assert_array_equal(serial[1], local[1])


def test_local_executor_validates():
    with pytest.raises(ValueError, match="max_workers"):
        LocalExecutor(0)


@pytest.fixture(scope="module")
def dask_executor(dask_cluster):
    with DaskExecutor(dask_cluster) as ex:
        yield ex


def test_dask_executor_by_scheduler_address(dask_cluster):
    with DaskExecutor(dask_cluster.scheduler_address) as ex:
        assert ex.map(square, [3, 1, 2]) == [9, 1, 4]
        assert ex.scheduler_address == dask_cluster.scheduler_address


def test_a_local_dask_cluster_serves_its_pages_on_this_machine_only_on_a_free_port():
    """The cluster DaskExecutor starts itself (no scheduler given): its scheduler's HTTP server on the loopback
    address and not on dask's fixed 8787 (with dashboard_address=None it was 0.0.0.0:8787 and [::]:8787)."""
    pytest.importorskip("distributed")
    with DaskExecutor(n_workers=1, processes=False) as ex:
        assert ex.map(square, [2]) == [4]
        sockets = [s.getsockname() for s in ex._owned_cluster.scheduler.http_server._sockets.values()]
    assert sockets and all(address[0] == "127.0.0.1" and address[1] != 8787 for address in sockets), sockets


def test_dask_executor_keeps_order(dask_executor):
    assert dask_executor.map(square, range(20)) == [i * i for i in range(20)]
    assert dask_executor.describe()["executor"] == "dask"


def test_monte_carlo_identical_on_dask_and_local(dask_executor, local_executor):
    """The same seed gives the same samples, bit for bit, on the Dask cluster and the process pool."""
    on_dask = monte_carlo_samples(SETUP, 0.1, 1500, seed=3, executor=dask_executor, n_tasks=2)
    on_pool = monte_carlo_samples(SETUP, 0.1, 1500, seed=3, executor=local_executor, n_tasks=3)
    np.testing.assert_array_equal(on_dask[0], on_pool[0])
    np.testing.assert_array_equal(on_dask[1], on_pool[1])
    assert monte_carlo(SETUP, 0.1, 600, seed=3, executor=dask_executor) == monte_carlo(SETUP, 0.1, 600, seed=3)


def test_surface_identical_on_dask_and_serial(dask_executor):
    kwargs = {"alpha": "converge", "with_sensitivities": False, "points_per_task": 2}
    assert (surface_bz([100.0, 200.0], [400.0, 600.0], executor=dask_executor, **kwargs)
            == surface_bz([100.0, 200.0], [400.0, 600.0], **kwargs))


def test_missing_dask_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    with pytest.raises(ExecutorUnavailable, match=r"pip install 'stereo-bench\[dask\]'"):
        make_executor("dask")


def test_unreachable_scheduler_is_a_clear_error():
    pytest.importorskip("distributed")
    with pytest.raises(ExecutorUnavailable, match="cannot reach the Dask scheduler"):
        DaskExecutor("tcp://127.0.0.1:9", timeout_s=1.0)


def test_make_executor_validates():
    assert isinstance(make_executor("serial"), SerialExecutor)
    with pytest.raises(ValueError, match="executor must be one of"):
        make_executor("ray")
    with pytest.raises(ValueError, match="dask executor only"):
        make_executor("local", scheduler="tcp://x:1")
