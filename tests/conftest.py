"""Test tiers: everything runs by default except the hardware tier, which a lab opts into.

    pytest --camera /dev/v4l/by-id/usb-...-video-index0     # real V4L2 camera tests
    pytest --serial-port /dev/ttyUSB0                        # real GRBL controller tests
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

# One BLAS thread per test process: pytest-xdist already puts a worker on every core, and OpenBLAS (numpy's,
# OpenCV's) would start a thread per core in each and spin them in every small product and solve. On the 2-core
# machines the suite runs on, the caliscope leave-one-out test took 49 s of CPU that way and 32 s with one thread.
# Thread counts move numbers in their last digits only, which every replay tolerance holds (docs/REPLAY.md); set
# OPENBLAS_NUM_THREADS yourself to run the suite with another count. Subprocesses (the CLI tests) inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
if "numpy" in sys.modules:  # a plugin loaded numpy (and its OpenBLAS) before this file: limit it at run time
    from threadpoolctl import threadpool_limits

    threadpool_limits(int(os.environ["OPENBLAS_NUM_THREADS"]), user_api="blas")


# Bytecode for the test processes even where PYTHONDONTWRITEBYTECODE is set (many container images set it): without
# it every CLI test's subprocess compiled the package from source (0.3 s each) and every worker rewrote every test
# module's asserts anew (a collection of the suite: 19 s, 7 s with the cache). It goes under a prefix in the
# temporary directory, never into the checkout.
if os.environ.pop("PYTHONDONTWRITEBYTECODE", None) is not None or sys.dont_write_bytecode:
    import tempfile

    sys.dont_write_bytecode = False
    prefix = os.path.join(tempfile.gettempdir(), f"stereo-bench-pycache-{os.getuid()}")
    os.environ.setdefault("PYTHONPYCACHEPREFIX", prefix)
    sys.pycache_prefix = os.environ["PYTHONPYCACHEPREFIX"]


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("stereo-bench hardware tier")
    group.addoption("--camera", action="append", default=[], metavar="PATH",
                    help="run camera hardware tests on this V4L2 device (repeat for a stereo pair)")
    group.addoption("--serial-port", default=None, metavar="PATH",
                    help="run rig-controller hardware tests on this GRBL serial port (the rig WILL move)")


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto`` (pyproject's addopts): the suite on up to 4 processes (2 on the project's 2-core machines:
    4:48 -> 2:56, since many tests wait on simulated motion and subprocesses), and the hardware tier in one
    process, so that no two workers open the same camera or serial port."""
    if config.getoption("--camera") or config.getoption("--serial-port"):
        return 0
    return max(1, min(4, os.cpu_count() or 1))


@pytest.fixture
def camera_paths(request: pytest.FixtureRequest) -> list[str]:
    paths = request.config.getoption("--camera")
    if not paths:
        pytest.skip("hardware tier: pass --camera PATH to run")
    return paths


@pytest.fixture
def serial_port(request: pytest.FixtureRequest) -> str:
    port = request.config.getoption("--serial-port")
    if not port:
        pytest.skip("hardware tier: pass --serial-port PATH to run")
    return port


@pytest.fixture(scope="session")
def small_reference(tmp_path_factory) -> Path:
    """The small campaign (tests/campaigns.py) recorded once per test session. Read it; copy it to change it."""
    from stereo_bench.campaign.execute import run_campaign
    from tests.campaigns import small_config

    out = tmp_path_factory.mktemp("reference") / "small"
    summary = run_campaign(small_config(), out, yes=True)
    assert summary.exit_status == "success", summary
    return out


@pytest.fixture
def small_copy(small_reference, tmp_path) -> Path:
    """A copy of the small reference session this test may resume or change."""
    copy = tmp_path / "small"
    shutil.copytree(small_reference, copy)
    return copy


@pytest.fixture(scope="session")
def dask_cluster():
    """One in-process Dask LocalCluster for every test that needs one (starting one takes seconds)."""
    pytest.importorskip("distributed")
    from dask.distributed import LocalCluster

    cluster = LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None)
    try:
        yield cluster
    finally:
        cluster.close()


@pytest.fixture(scope="session")
def dask_scheduler(dask_cluster) -> str:
    """The shared cluster's scheduler address (for ``--executor dask --scheduler ADDRESS``)."""
    return dask_cluster.scheduler_address
