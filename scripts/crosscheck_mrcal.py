"""mrcal beside stereo-bench on every shared real set: the same corners fitted by both (issue 26 item 2).

For each set, ``calibrate_from_images`` as ``stereo-bench calibrate`` runs it (the checkerboard sets; ChArUco
caliscope: ``calibrate_stereo_lens`` on the synchronised frames' detections, as docs/CALIBRATION.md's table), once
with the lens model auto chooses and once with opencv4 (the model both fit identically: mrcal's LENSMODEL_OPENCV4),
then :func:`stereo_bench.vision.mrcal_bridge.cross_check`: |T| with both standard uncertainties, both RMS (OpenCV's
convention) and mrcal's projection difference over the image beside its projection uncertainty; mrcal with its
board-warp term (its own default) beside. Prints a table; writes scripts/results/crosscheck_mrcal.json.

    python scripts/crosscheck_mrcal.py [SET ...]
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from stereo_bench.vision.calibrate import calibrate_stereo_lens  # noqa: E402
from stereo_bench.vision.detect import common_corners  # noqa: E402
from stereo_bench.vision.mrcal_bridge import cross_check, mrcal_python, unavailable_reason  # noqa: E402
from stereo_bench.vision.pipeline import calibrate_from_images  # noqa: E402
from tests.real_data import (  # noqa: E402
    CALISCOPE_BOARD,
    SETS,
    caliscope_frames,
    caliscope_views,
    detections,
    images,
)

CALISCOPE = "caliscope_charuco_2cam"
RESULTS = Path(__file__).resolve().parent / "results"
MODELS = ("auto", "opencv4")


def corners_and_calibration(name: str, lens_model: str):
    """(calibration, corners of the views it used, board) of one set."""
    if name == CALISCOPE:
        frames, det = caliscope_views()
        objects, lefts, rights = [], [], []
        for i in frames:
            ids, left, right = common_corners(*det[i])
            objects.append(CALISCOPE_BOARD.object_points[ids])
            lefts.append(left)
            rights.append(right)
        size = caliscope_frames()[0][0].shape[1::-1]
        calib = calibrate_stereo_lens(objects, lefts, rights, tuple(size), lens_model=lens_model)
        return calib, tuple((objects[i], lefts[i], rights[i]) for i in calib.views_used), CALISCOPE_BOARD
    left, right = images(name)
    board = SETS[name].board
    result = calibrate_from_images(left, right, board, lens_model=lens_model, detections=detections(name))
    return result.calib, result.corners, board


def px(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def main(argv: list[str]) -> int:
    python = mrcal_python()
    if python is None:
        print(f"skipped: {unavailable_reason()}")
        return 0
    names = argv or [*SETS, CALISCOPE]
    out = RESULTS / "crosscheck_mrcal.json"
    result = json.loads(out.read_text()) if out.exists() else {}
    result = {k: v for k, v in result.get("sets", {}).items() if k in SETS or k == CALISCOPE}
    load_before = os.getloadavg()
    for name in names:
        result[name] = {}
        for model in MODELS:
            t0 = time.perf_counter()
            calib, corners, board = corners_and_calibration(name, model)
            check = cross_check(calib, corners, board.object_points, board.square_mm, python=python)
            check["seconds"] = time.perf_counter() - t0
            result[name][model] = check
            b, r = check["baseline_mm"], check["rms_px"]
            print(f"{name} [{model} -> {check['our_lens_model']} / {check['lensmodel']}] ({check['seconds']:.1f} s): "
                  f"|T| {b['ours']:.3f} +- {b['ours_sigma'] or float('nan'):.3f} vs {b['mrcal']:.3f} +- "
                  f"{b['mrcal_sigma']:.3f} mm (z {b['z']:+.2f}), RMS {r['ours']:.4f} vs {r['mrcal']:.4f} px, "
                  f"projection diff at the corners median {px(check['projection'][0]['corners_diff_median_px'])} / "
                  f"{px(check['projection'][1]['corners_diff_median_px'])} px, agree {check['agree']}", flush=True)
    print()
    print("| set | model (ours / mrcal) | views | abs(T) ours mm (sigma from residuals alone) "
          "| abs(T) mrcal mm | diff (z) "
          "| RMS ours / mrcal (all corners) px | mrcal outliers "
          "| projection diff at the corners, median L / R px (mrcal's uncertainty there) "
          "| over the image: diff / uncertainty, median L / R px | agree | mrcal + board warp: abs(T) mm, RMS px |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, checks in result.items():
        for c in checks.values():
            b, r, (pl, pr), w = c["baseline_mm"], c["rms_px"], c["projection"], c["mrcal_with_board_warp"]
            warp = f"{w['baseline_mm']:.3f}, {w['rms_px']:.4f}" if "baseline_mm" in w else "failed"
            ours_sigma = "?" if b["ours_sigma"] is None else f"{b['ours_sigma']:.3f} ({b['ours_sigma_residuals']:.3f})"
            print(f"| {name} | {c['our_lens_model']} / {c['lensmodel'].removeprefix('LENSMODEL_')} | {c['views']} "
                  f"| {b['ours']:.3f} +- {ours_sigma} | {b['mrcal']:.3f} +- {b['mrcal_sigma']:.3f} "
                  f"| {b['difference']:+.3f} ({b['z']:+.2f}) "
                  f"| {r['ours']:.4f} / {r['mrcal']:.4f} ({r['mrcal_all_corners']:.4f}) "
                  f"| {r['mrcal_outliers']} of {r['corners']} "
                  f"| {px(pl['corners_diff_median_px'])} / {px(pr['corners_diff_median_px'])} "
                  f"({px(pl['corners_uncertainty_median_px'])} / {px(pr['corners_uncertainty_median_px'])}) "
                  f"| {px(pl['diff_median_px'])} / {px(pl['uncertainty_median_px'])}, "
                  f"{px(pr['diff_median_px'])} / {px(pr['uncertainty_median_px'])} "
                  f"| {'yes' if c['agree'] else 'no'} | {warp} |")
    RESULTS.mkdir(exist_ok=True)
    out.write_text(json.dumps({"mrcal": python, "load_average_before": load_before,
                               "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "sets": result},
                              indent=1, default=float) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
