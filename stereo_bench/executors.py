"""One interface for running many independent jobs: in-process, a local process pool, or a Dask cluster.

Monte Carlo runs, design-space sweeps and batch re-analysis of recorded sessions all hand a
module-level function and a list of picklable items to ``executor.map(fn, items)``, which returns
the results as a list in the order of ``items``. Which executor ran them must not change the
results: jobs that draw random numbers get their seeds from the caller, who splits one seed with
``numpy.random.SeedSequence(seed).spawn(n)`` into per-block children *before* grouping blocks into
tasks (see :func:`spawn_seeds`), so neither the executor nor the grouping changes a single number.

- :class:`SerialExecutor`: in the calling process (small jobs, debugging, tests).
- :class:`LocalExecutor`: ``concurrent.futures.ProcessPoolExecutor`` (the default for the CLI).
  Workers start through ``forkserver``: forking a process that already runs threads (OpenCV's
  pool, a Dask client) can deadlock a child.
- :class:`DaskExecutor`: a ``dask.distributed`` cluster, by scheduler address, or a given
  ``LocalCluster``/``Client``, or a LocalCluster it starts itself. dask is an optional extra
  (``pip install 'stereo-bench[dask]'``), imported only when this executor is made. Workers of a
  remote cluster need stereo-bench installed at the same version.

Every executor is a context manager; ``close()`` releases what it started (pools, clusters) and
nothing it was given.

:func:`background_threads` is the other kind of pool: threads for work that can wait (encoding
recorded frames, detecting calibration views ahead of their analysis) while a capture cannot.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any, Literal, Protocol, TypeVar, runtime_checkable

import numpy as np

T = TypeVar("T")
R = TypeVar("R")

ExecutorKind = Literal["serial", "local", "dask"]
EXECUTOR_KINDS: tuple[str, ...] = ("serial", "local", "dask")
DASK_INSTALL_HINT = "pip install 'stereo-bench[dask]'  (or: pip install 'dask[distributed]')"


class ExecutorUnavailable(RuntimeError):
    """The requested executor cannot run here (a missing optional dependency, an unreachable scheduler)."""


@runtime_checkable
class Executor(Protocol):
    """Runs ``fn`` on every item; results in item order."""

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> list[R]: ...

    def close(self) -> None: ...


class _ContextMixin:
    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SerialExecutor(_ContextMixin):
    """Runs every item in the calling process, one after the other."""

    name = "serial"

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
        return [fn(item) for item in items]

    def close(self) -> None:
        pass

    def describe(self) -> dict:
        return {"executor": self.name}


class LocalExecutor(_ContextMixin):
    """A local process pool (``max_workers`` processes, default: the CPU count), started on first use."""

    name = "local"

    def __init__(self, max_workers: int | None = None, *, start_method: str = "forkserver"):
        if max_workers is not None and max_workers < 1:
            raise ValueError(f"max_workers must be >= 1, not {max_workers}")
        self.max_workers = max_workers or os.cpu_count() or 1
        if start_method not in multiprocessing.get_all_start_methods():
            start_method = "spawn"
        self.start_method = start_method
        self._pool: ProcessPoolExecutor | None = None

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=self.max_workers, mp_context=multiprocessing.get_context(self.start_method)
            )
        return self._pool

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
        items = list(items)
        if not items:
            return []
        return list(self._get_pool().map(fn, items))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def describe(self) -> dict:
        return {"executor": self.name, "workers": self.max_workers, "start_method": self.start_method}


def _import_distributed():
    try:
        import distributed  # noqa: F401  (dask's distributed scheduler)
        from dask import distributed as dd
    except ImportError as error:
        raise ExecutorUnavailable(f"the dask executor needs dask.distributed, which is not installed: "
                                  f"{DASK_INSTALL_HINT}") from error
    return dd


#: Where a LocalCluster this module starts serves its scheduler's HTTP pages (the dashboard): this machine only, on a
#: free port. ``dashboard_address=None`` does not turn them off in distributed 2026.8: they went to 8787 on every
#: interface, open to the network, and a second cluster on the machine warned "Port 8787 is already in use".
LOCAL_DASHBOARD_ADDRESS = "127.0.0.1:0"


class DaskExecutor(_ContextMixin):
    """Runs items as tasks of a Dask distributed cluster.

    Args:
        scheduler: a scheduler address (``"tcp://host:8786"``), a ``LocalCluster`` (or any cluster
            object a ``Client`` accepts), or a ``distributed.Client``. None starts a LocalCluster of
            ``n_workers`` worker processes that :meth:`close` shuts down.
        timeout_s: how long to wait for the scheduler.
    """

    name = "dask"

    def __init__(self, scheduler: Any = None, *, n_workers: int | None = None, processes: bool = True,
                 threads_per_worker: int = 1, timeout_s: float = 10.0):
        dd = _import_distributed()
        self._owned_cluster = None
        self._owned_client = True
        if isinstance(scheduler, dd.Client):
            self.client, self._owned_client = scheduler, False
        else:
            if scheduler is None:
                scheduler = self._owned_cluster = dd.LocalCluster(
                    n_workers=n_workers or os.cpu_count() or 1, processes=processes,
                    threads_per_worker=threads_per_worker, dashboard_address=LOCAL_DASHBOARD_ADDRESS,
                )
            try:
                self.client = dd.Client(scheduler, timeout=timeout_s)
            except (OSError, TimeoutError) as error:
                if self._owned_cluster is not None:
                    self._owned_cluster.close()
                raise ExecutorUnavailable(f"cannot reach the Dask scheduler {scheduler!r}: {error}") from error
        self.scheduler_address = self.client.scheduler.address

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
        items = list(items)
        if not items:
            return []
        futures = self.client.map(fn, items, pure=False)
        return list(self.client.gather(futures))

    def close(self) -> None:
        if self._owned_client and self.client is not None:
            self.client.close()
        if self._owned_cluster is not None:
            self._owned_cluster.close()
            self._owned_cluster = None
        self.client = None

    def describe(self) -> dict:
        workers = self.client.scheduler_info().get("workers", {}) if self.client is not None else {}
        return {"executor": self.name, "scheduler": self.scheduler_address, "workers": len(workers)}


def make_executor(kind: str = "local", *, scheduler: str | None = None, max_workers: int | None = None):
    """The executor a command line asked for: ``kind`` in serial/local/dask; ``scheduler`` for dask only.

    ``dask`` without ``scheduler`` starts a LocalCluster of ``max_workers`` processes on this machine.
    """
    if kind not in EXECUTOR_KINDS:
        raise ValueError(f"executor must be one of {', '.join(EXECUTOR_KINDS)}, not {kind!r}")
    if scheduler is not None and kind != "dask":
        raise ValueError("a scheduler address is for the dask executor only (use --executor dask)")
    if kind == "serial":
        return SerialExecutor()
    if kind == "local":
        return LocalExecutor(max_workers)
    return DaskExecutor(scheduler, n_workers=max_workers)


def spawn_seeds(seed: int | np.random.SeedSequence, n: int) -> list[np.random.SeedSequence]:
    """``n`` independent child seeds of one seed: the i-th child is the same whoever runs it.

    A given SeedSequence is copied, not advanced: calling this twice gives the same children.
    """
    if isinstance(seed, np.random.SeedSequence):
        root = np.random.SeedSequence(seed.entropy, spawn_key=seed.spawn_key, pool_size=seed.pool_size)
    else:
        root = np.random.SeedSequence(seed)
    return root.spawn(n)


def group(items: list[T], n_groups: int) -> list[list[T]]:
    """Split ``items`` into at most ``n_groups`` contiguous, nearly equal, non-empty lists (order kept)."""
    n_groups = max(1, min(n_groups, len(items)))
    bounds = np.linspace(0, len(items), n_groups + 1).round().astype(int)
    return [items[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]


# How much nicer than the thread that starts them background threads run (on Linux nice() applies to
# the calling thread only; a thread may lower its own priority without privileges, never raise it back).
BACKGROUND_NICE = 10


def _lower_thread_priority() -> None:
    with contextlib.suppress(AttributeError, OSError):  # not available, or not allowed: the same priority
        os.nice(BACKGROUND_NICE)


def background_threads(max_workers: int, name: str) -> ThreadPoolExecutor:
    """A thread pool whose threads run at a lower CPU priority (nice +``BACKGROUND_NICE`` on Linux).

    For work that can wait while the rest of the process cannot: on a busy machine the capture,
    its detection and the rendering that stands for a sensor come first, and the background work
    catches up when they wait (while the rig moves). Results do not depend on the priority.
    """
    return ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix=name, initializer=_lower_thread_priority)
