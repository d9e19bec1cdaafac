"""Test tiers: everything runs by default except the hardware tier, which a lab opts into.

    pytest --camera /dev/v4l/by-id/usb-...-video-index0     # real V4L2 camera tests
    pytest --serial-port /dev/ttyUSB0                        # real GRBL controller tests
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
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
    parser.getgroup("stereo-bench suite").addoption(
        "--record-module-durations", default=None, metavar="PATH",
        help="write each test module's seconds (setup + call + teardown) as JSON, e.g. to "
             "tests/module_durations.json, which orders the modules for pytest-xdist (longest first)")


# The order pytest-xdist hands modules to its workers (``--dist loadscope``: a module's tests on one worker, so its
# module fixtures are built once): the longest first, as measured (tests/module_durations.json, written by
# ``pytest --record-module-durations tests/module_durations.json``). xdist's own order (most tests first) left the
# few-test, long modules (a browser, a leave-one-out, a lab fit) for the end, one worker running them while the
# other stood idle. A module not measured yet counts as the median one.
MODULE_DURATIONS = Path(__file__).with_name("module_durations.json")


def _module_of(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    try:
        durations = {str(k): float(v) for k, v in json.loads(MODULE_DURATIONS.read_text()).items()}
    except (OSError, ValueError, AttributeError):
        return  # no measurement (or a broken one): collection order
    typical = statistics.median(durations.values()) if durations else 0.0
    items.sort(key=lambda item: -durations.get(_module_of(item.nodeid), typical))  # stable within a module


class _ModuleDurations:
    """``--record-module-durations PATH``: each module's setup + call + teardown seconds, summed over its tests
    (on the controller: xdist's workers report theirs), written as JSON when the session ends."""

    def __init__(self, path: Path):
        self.path, self.seconds = path, {}

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        module = _module_of(report.nodeid)
        self.seconds[module] = self.seconds.get(module, 0.0) + float(report.duration)

    def pytest_sessionfinish(self, session: pytest.Session) -> None:
        if hasattr(session.config, "workerinput"):
            return  # a worker: the controller writes the file
        ordered = dict(sorted(((k, round(v, 2)) for k, v in self.seconds.items()), key=lambda kv: -kv[1]))
        self.path.write_text(json.dumps(ordered, indent=1) + "\n")


def pytest_configure(config: pytest.Config) -> None:
    path = config.getoption("--record-module-durations")
    if path and not hasattr(config, "workerinput"):
        config.pluginmanager.register(_ModuleDurations(Path(path)), "stereo-bench-module-durations")


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto`` (pyproject's addopts): one process per core and one more, up to 5 (3 on the project's 2-core
    machines), and the hardware tier in one process, so that no two workers open the same camera or serial port.
    The extra worker has the cores while another waits (on simulated motion, a subprocess, a browser, fsync): one
    per core kept them 90 % busy (17:19 + 1:02 of CPU in a 10:13 run), three workers ran the same suite in 9:34."""
    if config.getoption("--camera") or config.getoption("--serial-port"):
        return 0
    return max(1, min(5, (os.cpu_count() or 1) + 1))


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
    """The small campaign (tests/campaigns.py) recorded once per test run, by whichever pytest-xdist worker asks
    first (the others wait for it; each had recorded its own before). Read it; copy it to change it."""
    from stereo_bench.campaign.execute import run_campaign
    from tests.campaigns import small_config

    def record(directory: Path) -> None:
        summary = run_campaign(small_config(), directory / "small", yes=True)
        assert summary.exit_status == "success", summary

    return _shared_across_workers(tmp_path_factory, "small-reference", record) / "small"


def _shared_across_workers(tmp_path_factory: pytest.TempPathFactory, name: str, build) -> Path:
    """A new directory that ``build(directory)`` fills once per test run, shared by every pytest-xdist worker.

    The first worker to take the lock builds it and marks it done; the others wait on the lock and reuse it. A
    build that fails leaves no mark: each worker that needs it then tries (and fails) for itself, with its own
    traceback.
    """
    import fcntl

    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # the run's directory under xdist
    directory = root / f"shared-{name}"
    done = root / f"shared-{name}.done"
    with open(root / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(directory, ignore_errors=True)  # a failed build's leftovers
            directory.mkdir()
            build(directory)
            done.touch()
    return directory


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

    from stereo_bench.executors import LOCAL_DASHBOARD_ADDRESS

    cluster = LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                           dashboard_address=LOCAL_DASHBOARD_ADDRESS)
    try:
        yield cluster
    finally:
        cluster.close()


@pytest.fixture(scope="session")
def dask_scheduler(dask_cluster) -> str:
    """The shared cluster's scheduler address (for ``--executor dask --scheduler ADDRESS``)."""
    return dask_cluster.scheduler_address


@pytest.fixture(autouse=True)
def _opencv_threads_left_as_found():
    """OpenCV's thread count is process-wide: a test that changes it and leaves it so changes the numeric environment
    of every later test on its worker (a replay of the session another worker had recorded then said "OpenCV
    threads 2 -> 1"). The test that leaves it changed fails at teardown; the count is put back for the next."""
    import cv2

    from stereo_bench.vision.calibrate import opencv_threads

    before = opencv_threads()
    yield
    after = opencv_threads()
    if after != before:
        cv2.setNumThreads(before)
        pytest.fail(f"the test left OpenCV's thread count at {after} (it found {before}): restore what it sets")
