"""What the calibration covariance costs: a 12-view stereo calibration with and without it.

The views are the simulated campaign's (calibration board 11x8, 25 mm, placed by
drivers.sim.render.calibration_board_poses at B 100 mm, Z 500 mm, parallel rig), projected exactly
with 0.05 px of corner noise: the solver's work is the same as on detected corners, and detection
(which the covariance does not touch) stays out of the figure. Per mode, ``--runs`` times in turn:
the calibration without its covariance, and the covariance computation alone on that solver's
outputs (the very call calibrate_stereo makes after the solver). The overhead is covariance /
calibration, each the fastest of its runs: on a shared machine the minimum is the figure least
disturbed by other work (medians are printed too; the difference of two whole-calibration timings
drowns in that noise). Target: the covariance adds at most 10 % (issue 12).

    python scripts/bench_covariance.py [--runs 30] [--views 12]

Prints a table; writes scripts/results/bench_covariance.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from drivers.sim.render import calibration_board_poses
from stereo_bench.geometry import CameraModel, RigPose, invert_transform, transform_points
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import CRITERIA, DEFAULT_FLAGS, calibrate_mono, calibrate_stereo
from stereo_bench.vision.covariance import stereo_covariance

BOARD = Checkerboard(11, 8, 25.0)
CAMERA = CameraModel.from_sensor()
TARGET_OVERHEAD = 0.10
RESULTS = Path(__file__).resolve().parent / "results"


def views(n_views: int, seed: int = 0):
    rig = RigPose.symmetric(100.0, 90.0)
    rng = np.random.default_rng(seed)
    points = np.asarray(BOARD.object_points, float)
    lefts, rights = [], []
    for pose in calibration_board_poses(rig, BOARD, n_views=n_views, rng=rng, distance_mm=(300.0, 650.0)):
        for T_rig_cam, out in ((rig.T_rig_left, lefts), (rig.T_rig_right, rights)):
            pixels, _ = CAMERA.project(transform_points(invert_transform(T_rig_cam) @ pose, points))
            out.append(pixels + rng.normal(0.0, 0.05, pixels.shape))
    return [BOARD.object_points] * n_views, lefts, rights


def covariance_job(objects, lefts, rights, mode: str):
    """A function computing the covariance as calibrate_stereo does, on captured solver outputs (no solver)."""
    size = CAMERA.image_size
    monos = [calibrate_mono(objects, side, size, covariance=False) for side in (lefts, rights)]
    flags = DEFAULT_FLAGS | (cv2.CALIB_FIX_INTRINSIC if mode == "fixed" else cv2.CALIB_USE_INTRINSIC_GUESS)
    *_, K1, D1, K2, D2, R, T, _, _, rvecs, tvecs, _ = (None, *cv2.stereoCalibrateExtended(
        [np.float32(o).reshape(-1, 1, 3) for o in objects], [np.float32(p).reshape(-1, 1, 2) for p in lefts],
        [np.float32(p).reshape(-1, 1, 2) for p in rights], monos[0].K.copy(), monos[0].dist.copy(),
        monos[1].K.copy(), monos[1].dist.copy(), size, None, None, flags=flags, criteria=CRITERIA))
    views = list(range(len(objects)))

    def job():
        # As calibrate_stereo: fixed intrinsics from mono fits of these same views.
        return stereo_covariance(objects, lefts, rights, K1, D1.reshape(1, -1), K2, D2.reshape(1, -1), R,
                                 np.ravel(T), rvecs, tvecs, flags=flags, view_indices=views,
                                 intrinsics_from="these views" if mode == "fixed" else None)
    return job


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--views", type=int, default=12)
    args = parser.parse_args()
    objects, lefts, rights = views(args.views)
    load_before = os.getloadavg()
    rows = []
    print(f"{'mode':>6} {'views':>5} {'without ms':>10} {'with ms':>8} {'added ms':>8} {'overhead':>8} "
          f"{'(medians:':>9} {'without':>7} {'with':>6})")
    for mode in ("joint", "fixed"):
        job = covariance_job(objects, lefts, rights, mode)
        reference = calibrate_stereo(objects, lefts, rights, CAMERA.image_size, mode=mode).covariance
        np.testing.assert_allclose(job().matrix, reference.matrix, rtol=1e-6)  # the same computation
        timings = {"calibration": [], "covariance": []}
        for _ in range(args.runs):
            start = time.perf_counter()
            calib = calibrate_stereo(objects, lefts, rights, CAMERA.image_size, mode=mode, covariance=False)
            timings["calibration"].append(time.perf_counter() - start)
            assert calib.covariance is None
            start = time.perf_counter()
            job()
            timings["covariance"].append(time.perf_counter() - start)
        without, added = (float(np.min(timings[k])) * 1e3 for k in ("calibration", "covariance"))
        median_without, median_added = (float(np.median(timings[k])) * 1e3 for k in ("calibration", "covariance"))
        with_ = without + added
        row = {"mode": mode, "views": args.views, "without_ms": without, "with_ms": with_,
               "added_ms": added, "overhead": added / without,
               "median_without_ms": median_without, "median_with_ms": median_without + median_added,
               "calibration_ms_all": [t * 1e3 for t in timings["calibration"]],
               "covariance_ms_all": [t * 1e3 for t in timings["covariance"]]}
        rows.append(row)
        print(f"{mode:>6} {args.views:5d} {without:10.1f} {with_:8.1f} {with_ - without:8.1f} {row['overhead']:8.1%} "
              f"{'':>9} {median_without:7.1f} {median_without + median_added:6.1f}")
    load_after = os.getloadavg()
    worst = max(r["overhead"] for r in rows)
    print(f"worst overhead {worst:.1%} (target <= {TARGET_OVERHEAD:.0%}); load average before "
          f"{load_before[0]:.2f}, after {load_after[0]:.2f} (other work on the machine inflates both columns)")
    out = RESULTS / "bench_covariance.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "benchmark": "calibration covariance overhead", "runs": args.runs, "rows": rows, "worst_overhead": worst,
        "target_overhead": TARGET_OVERHEAD, "meets_target": worst <= TARGET_OVERHEAD,
        "load_average_before": load_before, "load_average_after": load_after, "opencv": cv2.__version__,
        "numpy": np.__version__, "python": platform.python_version(), "cpu_count": os.cpu_count(),
    }, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
