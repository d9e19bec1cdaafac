"""Does the uncertainty budget hold on real images? Leave-one-out on calib_data/real.

For each image set, each pair the full calibration keeps is left out in turn: the stereo pair is
calibrated (joint, with its covariance) from the others, the held-out pair's square is measured,
and its deviation from the nominal square is compared with the budget's expanded uncertainty U
(k = 2). The calibration and the measured board are the same board, so its scale cancels
(``BoardScale(same_board=True)``); the rig does not move within a set, so the structure component
is zero by its source. Prints a table per set; writes scripts/results/coverage_real.json.

    python scripts/coverage_real.py
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import calibrate_stereo
from stereo_bench.vision.detect import common_corners, detect
from stereo_bench.vision.pipeline import measure_pair
from stereo_bench.vision.uncertainty import BoardScale, configuration_budget

REAL = Path(__file__).resolve().parents[1] / "calib_data" / "real"
SETS = {
    "opencv_sample": (REAL / "opencv_sample", "left*.jpg", "right*.jpg", Checkerboard(9, 6, 30.0)),
    "present_cjn": (REAL / "present_cjn", "leftPic*.jpg", "rightPic*.jpg", Checkerboard(8, 11, 12.0)),
}
RESULTS = Path(__file__).resolve().parent / "results"


def leave_one_out(name: str) -> list[dict]:
    folder, left_glob, right_glob, board = SETS[name]
    lefts = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(folder.glob(left_glob))]
    rights = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(folder.glob(right_glob))]
    detections = [(detect(left, board, thorough=True), detect(right, board, thorough=True))
                  for left, right in zip(lefts, rights, strict=True)]
    usable = [i for i, (dl, dr) in enumerate(detections) if dl is not None and dr is not None]
    views = {i: common_corners(*detections[i]) for i in usable}
    size = lefts[0].shape[1::-1]
    rows = []
    for held_out in usable:
        keep = [i for i in usable if i != held_out]
        calib = calibrate_stereo([board.object_points[views[i][0]] for i in keep], [views[i][1] for i in keep],
                                 [views[i][2] for i in keep], size)
        pair = measure_pair(lefts[held_out], rights[held_out], calib, board, detections=detections[held_out])
        budget = configuration_budget([pair], calib, board, board_scale=BoardScale(same_board=True),
                                      structure_covariance=np.zeros((6, 6)), structure_source="unmoved within the set")
        details = budget.details()
        rows.append({
            "pair": held_out, "deviation_mm": budget.error_mm, **{f"u_{k}_mm": v for k, v in budget.as_dict().items()},
            "within_U": abs(budget.error_mm) <= budget.expanded, "normalised": budget.error_mm / budget.combined,
            "dominant": budget.dominant, "noise_random_mm": budget.noise_random_mm,
            "noise_systematic_mm": budget.noise_systematic_mm, "detector_bias_mm": budget.detector_bias_mm,
            "corner_systematic_px": budget.corner_systematic_px, "pixel_locking_px": details["pixel_locking_px"],
            "calibration_sigma_px": calib.covariance.sigma_px, "random_corner_px": list(pair.square.pixel_sigma_px),
            "planar_fit_rms_px": list(pair.planar_fit_rms_px),
        })
    return rows


def main() -> int:
    start, load_before = time.perf_counter(), os.getloadavg()
    result = {}
    for name in SETS:
        rows = leave_one_out(name)
        z = np.array([r["normalised"] for r in rows])
        within = float(np.mean([r["within_U"] for r in rows]))
        result[name] = {"pairs": len(rows), "fraction_within_U": within,
                        "rms_normalised": float(np.sqrt(np.mean(z**2))), "rows": rows}
        print(f"{name}: {len(rows)} pairs, {within:.0%} within U, RMS deviation/u_c {np.sqrt(np.mean(z**2)):.2f}")
        print(f"  {'pair':>4} {'dev mm':>8} {'U mm':>7} {'noise':>7} {'calib':>7} {'random':>7} {'detector':>8} "
              f"{'sigma_fit':>9} {'dominant':>9}")
        for r in rows:
            print(f"  {r['pair']:4d} {r['deviation_mm']:+8.4f} {r['u_expanded_mm']:7.4f} {r['u_noise_mm']:7.4f} "
                  f"{r['u_calibration_mm']:7.4f} {r['noise_random_mm']:7.4f} {r['noise_systematic_mm']:8.4f} "
                  f"{r['calibration_sigma_px']:9.3f} {r['dominant']:>9}{'' if r['within_U'] else '  <- outside U'}")
    elapsed = time.perf_counter() - start
    print(f"{elapsed:.0f} s; load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}")
    out = RESULTS / "coverage_real.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"benchmark": "coverage_real", **result, "elapsed_s": elapsed,
                               "load_average_before": load_before, "load_average_after": os.getloadavg(),
                               "opencv": cv2.__version__}, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
