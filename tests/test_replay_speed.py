"""The replay's fast paths give bit-identical numbers to the plain computations they replace; OpenCV and
OpenBLAS threads that would only spin beside the replay's own pools.

(The PNG decoder's own fast path is checked against OpenCV's reader in tests/test_frame_reading.py and
tests/test_frames.py; the replay as a whole against the recorded numbers in tests/test_campaign_run.py.)
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import cv2
import numpy as np
import pytest

from stereo_bench.vision import calibrate
from stereo_bench.vision.calibrate import StereoCalibration, single_threaded_opencv
from stereo_bench.vision.detect import image_noise_dn
from stereo_bench.vision.triangulate import triangulate, triangulation_jacobian
from tests.campaigns import SAMPLE_SESSION, sample_session_frames


def plain_image_noise_dn(gray: np.ndarray, *, tile_px: int = 128, tiles_per_side: int = 4) -> float:
    """The estimator tile by tile, as it was computed before the tiles were filtered as one stack."""
    height, width = gray.shape
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    tile_px = min(tile_px, height, width)
    estimates = []
    for y in np.linspace(0, height - tile_px, tiles_per_side).astype(int):
        for x in np.linspace(0, width - tile_px, tiles_per_side).astype(int):
            tile = gray[y : y + tile_px, x : x + tile_px].astype(np.float32)
            response = cv2.filter2D(tile, -1, kernel)[1:-1, 1:-1]
            estimates.append(np.sqrt(np.pi / 2) * np.abs(response).mean() / 6.0)
    return float(np.median(estimates))


def rendered_frames() -> list[np.ndarray]:
    frames = list(sample_session_frames(5))
    assert len(frames) >= 4
    return frames


def random_frames() -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    return [rng.integers(0, 256, shape, dtype=np.uint8) for shape in ((1080, 1920), (480, 640), (100, 90), (37, 300))]


def test_noise_estimate_is_bit_identical_to_the_tile_by_tile_one():
    for image in rendered_frames() + random_frames():
        assert image_noise_dn(image) == plain_image_noise_dn(image), image.shape
    image = random_frames()[1]
    assert image_noise_dn(image, tile_px=64, tiles_per_side=3) == plain_image_noise_dn(image, tile_px=64,
                                                                                       tiles_per_side=3)


def plain_triangulation_jacobian(calib, left_px, right_px, *, step_px: float = 1e-3) -> np.ndarray:
    """Central differences with one pair of triangulations per pixel coordinate, as before."""
    jac = np.zeros((len(left_px), 3, 4))
    for k in range(4):
        delta = np.zeros((len(left_px), 4))
        delta[:, k] = step_px
        plus = triangulate(calib, left_px + delta[:, :2], right_px + delta[:, 2:])
        minus = triangulate(calib, left_px - delta[:, :2], right_px - delta[:, 2:])
        jac[:, :, k] = (plus - minus) / (2 * step_px)
    return jac


@pytest.mark.parametrize("n_points", [1, 7, 54, 130])
def test_triangulation_jacobian_in_one_call_is_bit_identical_to_one_call_per_coordinate(n_points):
    rng = np.random.default_rng(n_points)
    K1 = np.array([[1333.0, 0, 960], [0, 1331, 541], [0, 0, 1]])
    K2 = np.array([[1340.0, 0, 955], [0, 1338, 537], [0, 0, 1]])
    D1, D2 = np.array([[-0.05, 0.02, 0.001, -0.0005, 0.003]]), np.array([[-0.04, 0.015, -0.001, 0.0004, 0.0]])
    R, _ = cv2.Rodrigues(np.array([0.01, -0.2, 0.003]))
    T = np.array([-150.0, 1.0, 2.0])
    calib = StereoCalibration(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=(1920, 1080))
    points = np.c_[rng.uniform(-200, 200, (n_points, 2)), rng.uniform(300, 700, n_points)]
    left, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K1, D1)
    right, _ = cv2.projectPoints(points, cv2.Rodrigues(R)[0], T, K2, D2)
    left = left.reshape(-1, 2) + rng.normal(0, 0.3, (n_points, 2))
    right = right.reshape(-1, 2) + rng.normal(0, 0.3, (n_points, 2))
    fast = triangulation_jacobian(calib, left, right)
    assert fast.shape == (n_points, 3, 4)
    np.testing.assert_array_equal(fast, plain_triangulation_jacobian(calib, left, right))
    # every point moves with every pixel coordinate: no entry is left at zero
    assert np.all(np.abs(fast) > 0) and np.all(np.isfinite(fast))


def test_single_threaded_opencv_pins_one_thread_and_restores_the_previous_count():
    before = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        with single_threaded_opencv():
            assert cv2.getNumThreads() == 1
            with single_threaded_opencv():
                assert cv2.getNumThreads() == 1
            assert cv2.getNumThreads() == 1  # the inner end leaves the outer setting
            with calibrate._deterministic():
                pass
            assert cv2.getNumThreads() == 1  # a solve inside does not restore 2 behind the block's back
        assert cv2.getNumThreads() == 2
    finally:
        cv2.setNumThreads(before)


def test_the_recorded_opencv_thread_count_is_the_setting_not_a_solve_s_moment():
    # A session's numeric environment read while another thread solves (or a replay's pool holds OpenCV on one
    # thread) records the process's setting, as one read at any other moment does.
    import threading

    before = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        assert calibrate.opencv_threads() == 2
        with single_threaded_opencv():
            assert cv2.getNumThreads() == 1 and calibrate.opencv_threads() == 2
        inside, done = threading.Event(), threading.Event()

        def solve():
            with calibrate._deterministic():
                inside.set()
                done.wait(5)

        thread = threading.Thread(target=solve)
        thread.start()
        assert inside.wait(5) and cv2.getNumThreads() == 1
        read = []
        reader = threading.Thread(target=lambda: read.append(calibrate.opencv_threads()))
        reader.start()
        done.set()
        thread.join(5)
        reader.join(5)
        assert read == [2]
    finally:
        cv2.setNumThreads(before)


def test_solves_inside_single_threaded_opencv_do_not_queue_for_the_solver_lock():
    """Outside the block a solve waits for the lock another solve holds; inside it runs at once."""

    def solve_on_a_thread() -> tuple[bool, threading.Thread]:
        done = threading.Event()

        def solve() -> None:
            with calibrate._deterministic():
                done.set()

        thread = threading.Thread(target=solve, daemon=True)
        thread.start()
        finished = done.wait(timeout=1.0)
        return finished, thread

    with single_threaded_opencv(), calibrate._SINGLE_THREAD:  # another solve holds the lock
        finished, _ = solve_on_a_thread()
        assert finished
    with calibrate._SINGLE_THREAD:
        finished, thread = solve_on_a_thread()
        assert not finished  # queued behind the lock, as it must be while OpenCV may use several threads
    thread.join(timeout=5.0)
    assert not thread.is_alive()


def _in_a_fresh_interpreter(code: str, **env: str) -> str:
    environment = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"} | env
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, timeout=120,
                          check=True)
    return done.stdout.strip()


def test_openblas_workers_sleep_at_once_unless_the_user_says_otherwise():
    """Set before numpy or cv2 loads OpenBLAS (it reads the variable once, then): importing stereo_bench loads
    neither, so whatever the program imports next sees it."""
    code = ("import os, sys, stereo_bench; print(os.environ['OPENBLAS_THREAD_TIMEOUT'], "
            "'numpy' in sys.modules or 'cv2' in sys.modules)")
    assert _in_a_fresh_interpreter(code) == "4 False"
    assert _in_a_fresh_interpreter(code, OPENBLAS_THREAD_TIMEOUT="28") == "28 False"


_FRAMES_FREED_AND_TAKEN_AGAIN = """
import platform, resource, sys
import numpy as np
from stereo_bench.frames import keep_freed_frame_memory
kept = keep_freed_frame_memory() if sys.argv[1] == "keep" else False
def configuration():  # a configuration's frames decoded, then freed together once it is analysed
    frames = [np.ones((1080, 1920), np.uint8) for _ in range(20)]
    del frames
configuration()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    configuration()
print(platform.libc_ver()[0] == "glibc", kept, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _freed_frames_run(mode: str, **env: str) -> tuple[bool, bool, int]:
    environment = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    done = subprocess.run([sys.executable, "-c", _FRAMES_FREED_AND_TAKEN_AGAIN, mode], capture_output=True, text=True,
                          env=environment | env, timeout=120, check=True)
    glibc, kept, faults = done.stdout.split()
    return glibc == "True", kept == "True", int(faults)


def test_freed_frames_are_reused_rather_than_given_back_and_faulted_in_again():
    """keep_freed_frame_memory (a replay calls it): 20 freed 1080p frames are not returned to the kernel and
    faulted in page by page the next time (~10,000 faults a configuration with glibc's defaults)."""
    glibc, kept, faults_default = _freed_frames_run("default")
    if not glibc:
        pytest.skip("glibc's allocator only")
    _, kept, faults_kept = _freed_frames_run("keep")
    assert kept and faults_default > 5 * 20 * 256  # every frame faulted in again, 5 times
    assert faults_kept < faults_default / 10
    # A user's own malloc tuning is left alone.
    _, kept, _ = _freed_frames_run("keep", MALLOC_TRIM_THRESHOLD_="131072")
    assert not kept


@pytest.mark.replay
def test_a_configuration_is_calibrated_while_its_measurement_frames_are_captured(monkeypatch):
    """Per-config extrinsics: the calibration starts once the views are taken, not after the measurement frames
    (a replay's last configuration then waits for less, a run shows its result sooner); the numbers are the same."""
    from stereo_bench.campaign import runner as runner_module
    from stereo_bench.campaign.execute import replay_session

    started: dict[int, threading.Event] = {}
    overlapped: list[bool] = []
    calibrate = runner_module.calibrate_configuration
    capture_measurement = runner_module.CampaignRunner._capture_measurement

    def calibrating(pairs, *args, **kwargs):
        started.setdefault(id(pairs), threading.Event()).set()
        return calibrate(pairs, *args, **kwargs)

    def capturing(self, n_frames, captured):
        # Old behaviour: the calibration could only start after this returns, so the wait would time out.
        overlapped.append(started.setdefault(id(captured.calibration_pairs), threading.Event()).wait(timeout=20))
        return capture_measurement(self, n_frames, captured)

    monkeypatch.setattr(runner_module, "calibrate_configuration", calibrating)
    monkeypatch.setattr(runner_module.CampaignRunner, "_capture_measurement", capturing)
    summary = replay_session(SAMPLE_SESSION)
    assert overlapped == [True, True]
    # The shipped session was recorded on another CPU: identical or within the replay tolerance (docs/REPLAY.md).
    assert summary.compared == 2 and summary.identical + summary.reproduced == 2 and summary.differences == []
