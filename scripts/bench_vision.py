"""Per-pair latency and corner accuracy of the detection + measurement pipeline at 1920x1080.

Checkerboard: compares stereo-bench's pipeline (reduced-resolution search with FAST_CHECK,
full-resolution cornerSubPix, triangulation and square measurement) with a plain baseline
(full-resolution findChessboardCorners + cornerSubPix 11x11 per view), on rendered pairs with
ground truth. Board absent: the plain baseline without FAST_CHECK can search for minutes on a
board-less frame and cannot be interrupted, so it runs once in a worker process that is killed
after --timeout s.

ChArUco (per view): stereo-bench's ``detect`` against OpenCV's plain default
``cv2.aruco.CharucoDetector(board).detectBoard``, in the same run, on the exp2 presets' calibration
board (12x9 squares of 15 mm, DICT_5X5_1000) rendered whole at Z = 300, 500, 700 mm, tilted as for
calibration at toe-in 5-35 deg, partial at toe-in 45 and 55 deg, and on frames without it (the wall;
the 9x6 checkerboard target). Each view is timed --charuco-runs times per detector, alternating, with
OpenCV's default thread count and with one thread (the analysis thread may run single-threaded).
Reports median and worst per-view time, whether ids and corners are the default's, and corner RMS
against the renderer's truth. The load average is recorded: other jobs share the machine.

    python scripts/bench_vision.py [--runs 20] [--charuco-runs 5] [--only charuco|checkerboard]
        [--out scripts/results/bench_vision.json]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import time

import cv2
import numpy as np

from drivers.sim.render import StereoRenderer, calibration_board_poses
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.detect import detect
from stereo_bench.vision.pipeline import BoardNotFoundError, measure_pair

BOARD = Checkerboard(9, 6, 27.0)
CHARUCO = CharucoTarget(12, 9, 15.0, 11.25)  # the exp2 presets' calibration board
CHARUCO_TARGETS_MS = {"present": 40.0, "absent": 15.0}
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


def charuco_views(seed: int = 0) -> list[tuple[str, str, np.ndarray, np.ndarray | None]]:
    """(group, name, image, true corners (N, 2) or None) for the ChArUco rows, seeded."""
    camera = CameraModel.from_sensor()
    renderer = StereoRenderer(CHARUCO, camera, camera)
    rng = np.random.default_rng(seed)
    views = []
    parallel = RigPose.symmetric(100.0, 90.0)
    for z in (300.0, 500.0, 700.0):
        pair = renderer.render_pair(parallel, board_pose_facing_rig(distance_mm=z, board_size_mm=CHARUCO.grid_size_mm),
                                    rng)
        views += [("whole board, Z 300-700 mm", f"Z={z:g} {side}", view.image, view.corners_px)
                  for side, view in (("left", pair.left), ("right", pair.right))]
    for toe_in in (5.0, 25.0, 35.0):
        rig = RigPose.symmetric(100.0, 90.0 - toe_in)
        poses = calibration_board_poses(rig, CHARUCO, n_views=2, rng=rng, min_fraction_visible=0.5,
                                        distance_mm=(300.0, 650.0))
        for i, pose in enumerate(poses):
            pair = renderer.render_pair(rig, pose, rng)
            views += [("calibration views, toe-in 5-35 deg", f"toe-in {toe_in:g} #{i} {side}", view.image,
                       view.corners_px) for side, view in (("left", pair.left), ("right", pair.right))]
    for toe_in, z in ((45.0, 500.0), (55.0, 300.0)):
        rig = RigPose.symmetric(100.0, 90.0 - toe_in)
        pair = renderer.render_pair(rig, board_pose_facing_rig(distance_mm=z, board_size_mm=CHARUCO.grid_size_mm), rng)
        views += [("partial, toe-in 45-55 deg", f"toe-in {toe_in:g} Z={z:g} {side}", view.image, view.corners_px)
                  for side, view in (("left", pair.left), ("right", pair.right))]
    wall = renderer.render_pair(parallel, board_pose_facing_rig(distance_mm=-500.0, board_size_mm=CHARUCO.grid_size_mm),
                                rng)
    views.append(("no board: the wall", "wall", wall.left.image, None))
    target = StereoRenderer(BOARD, camera, camera)
    for z in (300.0, 500.0):
        pair = target.render_pair(parallel, board_pose_facing_rig(distance_mm=z, board_size_mm=BOARD.grid_size_mm), rng)
        views.append(("no ChArUco: 9x6 checkerboard target", f"checkerboard Z={z:g}", pair.left.image, None))
    return views


def bench_charuco(runs: int) -> dict:
    """Per-view time (ms), agreement and corner RMS of stereo-bench's ChArUco detection vs the plain default."""
    default = cv2.aruco.CharucoDetector(CHARUCO.cv_board)

    def plain(image):
        corners, ids, _, _ = default.detectBoard(image)
        if ids is None or len(ids) == 0:
            return np.zeros(0, int), np.zeros((0, 2))
        ids = np.asarray(ids).reshape(-1)
        order = np.argsort(ids)
        return ids[order], np.asarray(corners, np.float64).reshape(-1, 2)[order]

    def ours(image):
        found = detect(image, CHARUCO)
        return (np.zeros(0, int), np.zeros((0, 2))) if found is None else (found.ids, found.corners_px)

    views = charuco_views()
    threads = cv2.getNumThreads()
    groups: dict[str, dict] = {}
    per_view = []
    for group, name, image, truth in views:
        row = groups.setdefault(group, {"views": 0, "corners": 0, "same_ids": True, "max_corner_diff_px": 0.0,
                                        "sq_err": {"stereo_bench": [], "plain": []},
                                        "ms": {f"{who}_{n}thread": [] for who in ("stereo_bench", "plain")
                                               for n in (threads, 1)}})
        (our_ids, our_corners), (plain_ids, plain_corners) = ours(image), plain(image)
        row["views"] += 1
        row["corners"] += len(our_ids)
        same = np.array_equal(our_ids, plain_ids)
        row["same_ids"] &= bool(same)
        if same and len(our_ids):
            row["max_corner_diff_px"] = max(row["max_corner_diff_px"], float(np.abs(our_corners - plain_corners).max()))
        if truth is not None:
            row["sq_err"]["stereo_bench"] += list(np.sum((our_corners - truth[our_ids]) ** 2, axis=1))
            row["sq_err"]["plain"] += list(np.sum((plain_corners - truth[plain_ids]) ** 2, axis=1))
        for n in (threads, 1):
            cv2.setNumThreads(n)
            for _ in range(runs):  # alternate, so both see the same load
                row["ms"][f"stereo_bench_{n}thread"] += timed(lambda image=image: ours(image), 1)
                row["ms"][f"plain_{n}thread"] += timed(lambda image=image: plain(image), 1)
        cv2.setNumThreads(threads)
        per_view.append({"group": group, "view": name, "corners": len(our_ids), "same_ids": bool(same),
                         **{f"ms_{key}": float(np.median(values[-runs:]) * 1000) for key, values in row["ms"].items()}})
    result = {}
    for group, row in groups.items():
        sq_err = row.pop("sq_err")
        times = row.pop("ms")
        row["ms_median"] = {key: float(np.median(values) * 1000) for key, values in times.items()}
        row["ms_worst_view_median"] = {}
        for key, values in times.items():  # the slowest view's median: runs are grouped per view
            by_view = np.asarray(values).reshape(row["views"], runs)
            row["ms_worst_view_median"][key] = float(np.median(by_view, axis=1).max() * 1000)
        row["corner_rms_px"] = {who: float(np.sqrt(np.mean(errors))) if errors else None
                                for who, errors in sq_err.items()}
        result[group] = row
    return {"board": "charuco 12x9 squares, 15 mm, marker 11.25 mm, DICT_5X5_1000", "runs_per_view": runs,
            "opencv_threads": threads, "groups": result, "views": per_view, "targets_ms": CHARUCO_TARGETS_MS}


def print_charuco(results: dict) -> None:
    threads = results["opencv_threads"]
    print(f"\nChArUco, per 1080p view ({results['board']}); ms = median over views x {results['runs_per_view']} runs "
          "(worst view's median)")
    header = (f"{'':38s} {'views':>5s} {'corners':>7s} {'same ids':>8s} {'max |d| px':>10s}"
              f" {'ours ' + str(threads) + ' thr':>16s} {'plain ' + str(threads) + ' thr':>16s}"
              f" {'ours 1 thr':>16s} {'plain 1 thr':>16s} {'RMS ours':>9s} {'RMS plain':>9s}")
    print(header)
    for group, row in results["groups"].items():
        cells = []
        for key in (f"stereo_bench_{threads}thread", f"plain_{threads}thread", "stereo_bench_1thread", "plain_1thread"):
            cells.append(f"{row['ms_median'][key]:7.1f} ({row['ms_worst_view_median'][key]:6.1f})")
        rms = row["corner_rms_px"]
        rms_text = (f"{rms['stereo_bench']:9.4f} {rms['plain']:9.4f}" if rms["stereo_bench"] is not None
                    else f"{'-':>9s} {'-':>9s}")
        print(f"{group:38s} {row['views']:5d} {row['corners']:7d} {str(row['same_ids']):>8s} "
              f"{row['max_corner_diff_px']:10.2g} {' '.join(cells)} {rms_text}")
    print(f"(targets: <= {CHARUCO_TARGETS_MS['present']:g} ms with the board, <= {CHARUCO_TARGETS_MS['absent']:g} ms "
          "without; plain = cv2.aruco.CharucoDetector(board).detectBoard with default parameters)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--timeout", type=float, default=30.0, help="limit for one plain search without a board")
    parser.add_argument("--charuco-runs", type=int, default=5, help="timed runs per ChArUco view and detector")
    parser.add_argument("--only", choices=("checkerboard", "charuco"),
                        help="run one half of the benchmark and replace only that half in an existing --out file")
    parser.add_argument("--out", default="scripts/results/bench_vision.json")
    args = parser.parse_args()
    results = {}
    if args.only and os.path.exists(args.out):
        with open(args.out) as handle:
            results = json.load(handle)
    results["machine"] = {"cpus": multiprocessing.cpu_count(), "opencv": cv2.__version__,
                          "python": platform.python_version()}
    load_before = [round(v, 2) for v in os.getloadavg()]
    if args.only != "charuco":
        results.update(bench_checkerboard(args))
        results["load_average_checkerboard"] = load_before
    if args.only != "checkerboard":
        results["charuco"] = bench_charuco(args.charuco_runs)
        print_charuco(results["charuco"])
        results["charuco"]["load_average_before_after"] = [load_before, [round(v, 2) for v in os.getloadavg()]]
    print(f"load average before {load_before}, after {[round(v, 2) for v in os.getloadavg()]}")
    with open(args.out, "w") as handle:
        json.dump(results, handle, indent=1)
    print(f"wrote {args.out}")


def bench_checkerboard(args) -> dict:
    """Per-pair latency and corner accuracy on the 9x6 checkerboard target, stereo-bench vs the plain baseline."""
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
    return results


if __name__ == "__main__":
    main()
