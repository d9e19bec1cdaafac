"""Does the uncertainty budget hold on real images? Leave-one-out on every set in calib_data/real.

For each image set, each pair the full calibration keeps is left out in turn: the stereo pair is
calibrated (joint, with its covariance) from the others, the held-out pair's square is measured,
and its deviation from the nominal square is compared with the budget's u_c and expanded uncertainty U
(k = 2), beside plain OpenCV's leave-one-out error on the same images (tests/real_data.py). The calibration
and the measured board are the same board, so its scale cancels (``BoardScale(same_board=True)``); the rig
does not move within a set, so the structure component is zero by its source. Also the jackknife check of the
calibration's sigmas: abs(T) and fx fy cx cy of each camera, the full calibration's sigma against the scatter
of the leave-one-out calibrations, sqrt((n-1)/n sum (theta_i - mean)^2).

Prints the issue's table and one per set; writes scripts/results/coverage_real.json.

    python scripts/coverage_real.py [SET ...] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.real_data import SETS, caliscope_leave_one_out, leave_one_out, summary, summary_rows  # noqa: E402

#: Held out per synchronised video frame, without the jackknife (tests/real_data.py caliscope_leave_one_out).
CALISCOPE = "caliscope_charuco_2cam"

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sets", nargs="*", metavar="SET",
                        help=f"the sets to run (default all: {', '.join([*SETS, CALISCOPE])})")
    parser.add_argument("--out", type=Path, default=RESULTS / "coverage_real.json",
                        help="results file (default scripts/results/coverage_real.json); a run of some sets keeps "
                             "the other sets' figures it holds")
    args = parser.parse_args(argv)
    names = args.sets or [*SETS, CALISCOPE]
    unknown = [name for name in names if name not in (*SETS, CALISCOPE)]
    if unknown:
        parser.error(f"no set {unknown[0]!r} (the sets: {', '.join([*SETS, CALISCOPE])})")
    start, load_before = time.perf_counter(), os.getloadavg()
    out = args.out
    # A run of some sets keeps the other sets' figures of the last run.
    result = {k: v for k, v in json.loads(out.read_text()).items() if k in SETS or k == CALISCOPE} \
        if out.exists() else {}
    for name in names:
        t0 = time.perf_counter()
        if name == CALISCOPE:
            loo = caliscope_leave_one_out()
            figures = summary_rows(loo)
            print(f"{name}: {figures['pairs']} frames ({time.perf_counter() - t0:.1f} s)")
            for r in loo["rows"]:
                print(f"  {r['pair']:4d} {r['error_mm']:+8.4f} U {r['U_mm']:7.4f} |T| {r['baseline_mm']:7.1f} mm "
                      f"{r['dominant']:>11}{'' if abs(r['error_mm']) <= r['U_mm'] else '  <- outside U'}")
            result[name] = {**figures, "rows": loo["rows"], "opencv_errors_mm": loo["opencv_errors_mm"].tolist()}
            continue
        loo = leave_one_out(name)
        figures = summary(loo)
        rows = loo["rows"]
        print(f"{name}: {figures['pairs']} pairs ({time.perf_counter() - t0:.1f} s)")
        print(f"  {'pair':>4} {'err mm':>8} {'U mm':>7} {'noise':>7} {'calib':>7} {'adequacy':>8} {'random':>7} "
              f"{'system.':>7} {'dominant':>11}")
        for r in rows:
            print(f"  {r['pair']:4d} {r['error_mm']:+8.4f} {r['U_mm']:7.4f} {r['u_noise_mm']:7.4f} "
                  f"{r['u_calibration_mm']:7.4f} {r.get('u_adequacy_mm') or 0.0:8.4f} {r['noise_random_mm']:7.4f} "
                  f"{r['noise_systematic_mm']:7.4f} {r['dominant']:>11}"
                  f"{'' if abs(r['error_mm']) <= r['U_mm'] else '  <- outside U'}")
        print(f"  {'parameter':>12} {'value':>10} {'sigma':>8} {'residuals':>9} {'jackknife':>9} {'linearised':>10} "
              f"{'jack/sigma':>10} {'(residuals)':>11}")
        for p, j in loo["jackknife"].items():
            print(f"  {p:>12} {j['value']:10.3f} {j['sigma']:8.4f} {j['sigma_residuals']:9.4f} {j['scatter']:9.4f} "
                  f"{j['linearised_scatter']:10.4f} {j['scatter'] / j['sigma']:10.2f} "
                  f"{j['scatter'] / j['sigma_residuals']:11.2f}")
        a = loo["adequacy"]
        if a is not None:
            print(f"  adequacy (full calibration, {a['n_views']} held-out views): u_rel {a['u_rel']:.2e} "
                  f"(held-out RMS {a['rms_rel']:.2e}, predicted {a['predicted_rel']:.2e}, bias {a['bias_rel']:+.2e}, "
                  f"dof {a['dof']:.0f})")
        result[name] = {**figures, "adequacy": a, "rows": rows, "jackknife": loo["jackknife"],
                        "opencv_errors_mm": loo["opencv_errors_mm"].tolist()}
    print()
    print("| set | pairs | LOO RMS error mm (stereo-bench / OpenCV) | RMS(err/u_c) | within U "
          "| median U / median |err| (an exact budget's median, 95 % band) "
          "| sigma(abs T) jackknife / reported (residuals only) |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        f = result[name]
        sigma = (f"{f['baseline_sigma_ratio']:.2f} ({f['baseline_sigma_ratio_residuals']:.2f})"
                 if "baseline_sigma_ratio" in f else "not computed")
        print(f"| {name} | {f['pairs']} | {f['rms_error_mm']:.4f} / {f['opencv_rms_error_mm']:.4f} "
              f"| {f['rms_normalised']:.2f} | {f['within_U']:.0%} | {f['inflation']:.1f} "
              f"({f['inflation_exact_median']:.1f}, {f['inflation_exact_95'][0]:.1f}-{f['inflation_exact_95'][1]:.1f}"
              + (f"; the calibration's error shared: {f['inflation_exact_shared_95'][0]:.1f}-"
                 f"{f['inflation_exact_shared_95'][1]:.1f}" if "inflation_exact_shared_95" in f else "")
              + f") | {sigma} |")
    elapsed = time.perf_counter() - start
    print(f"{elapsed:.0f} s; load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"benchmark": "coverage_real", **result, "elapsed_s": elapsed,
                               "load_average_before": load_before, "load_average_after": os.getloadavg(),
                               "opencv": cv2.__version__}, indent=1, default=str) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
