"""Per-pair latency and corner accuracy of the detection + measurement pipeline at 1920x1080.

Compares stereo-bench's pipeline (reduced-resolution search with FAST_CHECK, full-resolution
cornerSubPix, triangulation and square measurement) with a plain baseline (full-resolution
findChessboardCorners + cornerSubPix 11x11 per view), on rendered pairs with ground truth.

Board absent: the plain baseline without FAST_CHECK can search for minutes on a board-less frame
and cannot be interrupted, so it runs once in a worker process that is killed after --timeout s.

    python scripts/bench_vision.py [--runs 20] [--out bench_vision.json]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import time

import cv2
import numpy as np

from drivers.sim.render import StereoRenderer
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.pipeline import BoardNotFoundError, measure_pair

BOARD = Checkerboard(9, 6, 27.0)
CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
PLAIN_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE


def plain_detect(gray: np.ndarray, flags: int = PLAIN_FLAGS) -> np.ndarray | None:
    found, corners = cv2.findChessboardCorners(gray, BOARD.pattern_size, flags=flags)
    if not found:
        return None
    return cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (11, 11), (-1, -1), CRITERIA).reshape(-1, 2)


def _plain_worker(image: np.ndarray, queue) -> None:
    start = time.perf_counter()
    plain_detect(image)
    queue.put(time.perf_counter() - start)


def timed(function, runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return times


def corner_rms(found: np.ndarray, truth: np.ndarray) -> float:
    """RMS distance (px), allowing the plain detector's either half-turn order."""
    forward = np.linalg.norm(found - truth, axis=1)
    backward = np.linalg.norm(found[::-1] - truth, axis=1)
    best = forward if forward.mean() < backward.mean() else backward
    return float(np.sqrt(np.mean(best**2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--timeout", type=float, default=30.0, help="limit for one plain search without a board")
    parser.add_argument("--out", default="bench_vision.json")
    args = parser.parse_args()

    camera = CameraModel.from_sensor()
    rig = RigPose.symmetric(100.0, 90.0)
    R, T = rig.stereo_extrinsics()
    D = camera.dist.reshape(1, -1)
    calib = StereoCalibration(K1=camera.K, D1=D, K2=camera.K, D2=D, R=R, T=T, image_size=camera.image_size)
    renderer = StereoRenderer(BOARD, camera, camera)
    rng = np.random.default_rng(0)
    pairs = [renderer.render_pair(rig, board_pose_facing_rig(distance_mm=z, board_size_mm=BOARD.grid_size_mm), rng)
             for z in (400.0, 500.0, 600.0)]
    blank = renderer.render_pair(rig, board_pose_facing_rig(distance_mm=-500.0, board_size_mm=BOARD.grid_size_mm),
                                 rng)  # the board behind the rig: a frame of the wall only

    ours_present, plain_present, ours_rms, plain_rms = [], [], [], []
    for pair in pairs:
        ours_present += timed(lambda p=pair: measure_pair(p.left.image, p.right.image, calib, BOARD), args.runs)
        plain_present += timed(lambda p=pair: (plain_detect(p.left.image), plain_detect(p.right.image)), args.runs)
        result = measure_pair(pair.left.image, pair.right.image, calib, BOARD)
        for found, view in ((result.left, pair.left), (result.right, pair.right)):
            ours_rms.append(corner_rms(found.corners_px, view.corners_px))
            plain_rms.append(corner_rms(plain_detect(view.image), view.corners_px))

    def absent_ours():
        try:
            measure_pair(blank.left.image, blank.right.image, calib, BOARD)
        except BoardNotFoundError:
            pass

    ours_absent = timed(absent_ours, args.runs)
    fast_flags = PLAIN_FLAGS | cv2.CALIB_CB_FAST_CHECK
    plain_fast_absent = timed(lambda: (plain_detect(blank.left.image, fast_flags),
                                       plain_detect(blank.right.image, fast_flags)), args.runs)
    queue = multiprocessing.get_context("spawn").Queue()
    worker = multiprocessing.get_context("spawn").Process(target=_plain_worker, args=(blank.left.image, queue))
    worker.start()
    worker.join(args.timeout)
    if worker.is_alive():
        worker.kill()
        worker.join()
        plain_absent_s, plain_absent_note = None, f"> {args.timeout:g} s (killed)"
    else:
        plain_absent_s = queue.get()
        plain_absent_note = f"{plain_absent_s * 1000:.0f} ms (one view, one run)"

    ms = lambda values: float(np.median(values) * 1000)  # noqa: E731
    results = {
        "machine": {"cpus": multiprocessing.cpu_count(), "opencv": cv2.__version__,
                    "python": platform.python_version()},
        "image_size": list(camera.image_size), "runs": args.runs,
        "present_pair_ms": {"stereo_bench": ms(ours_present), "plain": ms(plain_present)},
        "absent_pair_ms": {"stereo_bench": ms(ours_absent), "plain_fast_check": ms(plain_fast_absent),
                           "plain_default_one_view": plain_absent_s * 1000 if plain_absent_s else None,
                           "plain_default_note": plain_absent_note},
        "corner_rms_px": {"stereo_bench": float(np.sqrt(np.mean(np.square(ours_rms)))),
                          "plain": float(np.sqrt(np.mean(np.square(plain_rms))))},
        "targets": {"present_pair_ms": 20.0, "absent_pair_ms": 10.0},
    }
    print(f"{'per stereo pair, 1920x1080':40s} {'stereo-bench':>14s} {'plain':>22s}")
    print(f"{'board present: detect both + measure (ms)':40s} {results['present_pair_ms']['stereo_bench']:14.1f} "
          f"{results['present_pair_ms']['plain']:22.1f}")
    print(f"{'board absent (ms)':40s} {results['absent_pair_ms']['stereo_bench']:14.1f} {plain_absent_note:>22s}")
    print(f"{'board absent, plain with FAST_CHECK (ms)':40s} {'':14s} {ms(plain_fast_absent):22.1f}")
    print(f"{'corner RMS vs ground truth (px)':40s} {results['corner_rms_px']['stereo_bench']:14.4f} "
          f"{results['corner_rms_px']['plain']:22.4f}")
    print("(plain = full-resolution findChessboardCorners + cornerSubPix 11x11, detection only, no measurement)")
    with open(args.out, "w") as handle:
        json.dump(results, handle, indent=1)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
