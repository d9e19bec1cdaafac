"""Which stereo calibration default measures the square better: intrinsics fixed from mono, or joint?

For several rigs, renders 20 views of a separate calibration board (11x8, 25 mm), calibrates both
ways from the same detections, then measures the 27 mm square on rendered pairs at Z = 500 mm with
each result. Prints the errors in abs(T) and in the square, writes JSON.

    python scripts/bench_extrinsics_mode.py [--views 20] [--seeds 3] [--out bench_extrinsics_mode.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from drivers.sim.render import StereoRenderer, calibration_board_poses
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import calibrate_stereo
from stereo_bench.vision.detect import common_corners, detect
from stereo_bench.vision.pipeline import measure_pair

CALIB_BOARD = Checkerboard(11, 8, 25.0)
TARGET = Checkerboard(9, 6, 27.0)
RIGS = [(100.0, 90.0), (120.0, 90.0), (150.0, 80.0), (100.0, 70.0)]

RESULTS = Path(__file__).resolve().parent / "results"  # where the latest run of each benchmark is kept


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--out", default=str(RESULTS / "bench_extrinsics_mode.json"))
    args = parser.parse_args()
    camera = CameraModel.from_sensor()
    calib_renderer = StereoRenderer(CALIB_BOARD, camera, camera)
    target_renderer = StereoRenderer(TARGET, camera, camera)
    rows = []
    print(f"{'B mm':>5} {'alpha':>5} {'seed':>4} {'mode':>6} {'|T| err mm':>10} {'fx err %':>8} {'square err mm':>13}")
    for baseline, alpha in RIGS:
        rig = RigPose.symmetric(baseline, alpha)
        true_baseline = float(np.linalg.norm(rig.stereo_extrinsics()[1]))
        for seed in range(args.seeds):
            rng = np.random.default_rng(seed)
            objects, lefts, rights = [], [], []
            for T_rig_board in calibration_board_poses(rig, CALIB_BOARD, n_views=args.views, rng=rng):
                pair = calib_renderer.render_pair(rig, T_rig_board, rng)
                left, right = detect(pair.left.image, CALIB_BOARD), detect(pair.right.image, CALIB_BOARD)
                if left is None or right is None:
                    continue
                ids, left_px, right_px = common_corners(left, right)
                objects.append(CALIB_BOARD.object_points[ids])
                lefts.append(left_px)
                rights.append(right_px)
            T_rig_target = board_pose_facing_rig(distance_mm=500.0, board_size_mm=TARGET.grid_size_mm)
            probe = target_renderer.render_pair(rig, T_rig_target, rng)
            for mode in ("fixed", "joint"):
                calib = calibrate_stereo(objects, lefts, rights, camera.image_size, mode=mode)
                square = measure_pair(probe.left.image, probe.right.image, calib, TARGET).square
                row = {"baseline_mm": baseline, "alpha_deg": alpha, "seed": seed, "mode": mode,
                       "views": len(objects), "baseline_error_mm": calib.baseline_mm - true_baseline,
                       "fx_error_pct": 100 * (calib.K1[0, 0] / camera.fx - 1), "square_error_mm": square.error_mm}
                rows.append(row)
                print(f"{baseline:5.0f} {alpha:5.0f} {seed:4d} {mode:>6} {row['baseline_error_mm']:10.3f} "
                      f"{row['fx_error_pct']:8.3f} {row['square_error_mm']:13.4f}")
    summary = {}
    for mode in ("fixed", "joint"):
        chosen = [r for r in rows if r["mode"] == mode]
        summary[mode] = {
            "baseline_error_rms_mm": float(np.sqrt(np.mean([r["baseline_error_mm"] ** 2 for r in chosen]))),
            "square_error_rms_mm": float(np.sqrt(np.mean([r["square_error_mm"] ** 2 for r in chosen]))),
        }
        print(f"{mode}: RMS |T| error {summary[mode]['baseline_error_rms_mm']:.3f} mm, "
              f"RMS square error {summary[mode]['square_error_rms_mm']:.4f} mm")
    with open(args.out, "w") as handle:
        json.dump({"rows": rows, "summary": summary}, handle, indent=1)


if __name__ == "__main__":
    main()
