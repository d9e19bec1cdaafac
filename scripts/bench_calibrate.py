"""How long ``stereo-bench calibrate`` takes beside plain OpenCV (and mrcal where installed) on the real sets.

Per set (present_cjn 30 pairs, smiler488_box 20, opencv_sample 13), ``--runs`` times in turn on the same image
files, each timing from reading the images to the finished calibration:

- ``opencv``: the plain pipeline of ../shared/data/README.md: cv2.imread, findChessboardCorners + cornerSubPix
  (5x5 half-window, 30 iterations, 1e-3), calibrateCamera for each camera, stereoCalibrate with
  CALIB_FIX_INTRINSIC;
- ``one model``: ``stereo-bench calibrate --lens-model opencv4`` in-process (the CLI's ``main``: reading,
  detection, calibration, its covariance, rectification and the files written);
- ``auto``: the same with ``--lens-model auto`` (every model fitted and compared on held-out pairs);
- ``opencv 1t``: the same plain pipeline on one BLAS thread (the ratios are to ``opencv``; the checks print both);
- mrcal: ``mrcal-calibrate-cameras`` when mrcal is importable; here it prints "mrcal: not installed".

``stereo-bench calibrate`` runs its calibration on one BLAS thread (numpy's OpenBLAS and OpenCV's, threadpoolctl;
its own threads spread the work); plain OpenCV runs as a user runs it, with the libraries' default threads.

Wall time and process CPU time (all threads) are both recorded, each the fastest of the runs (on a shared machine
the minimum is the figure least disturbed by other work; the ratio of the medians is printed too). ``ratio`` is of
wall time (what a user waits: stereo-bench detects on several threads, plain OpenCV's loop on one), ``cpu`` of
CPU time (the work done). The load average is printed before and after. Targets (issue
22 item 7, 20-30 pairs): one model <= 1.2x OpenCV, auto <= 3x. ``--profile`` prints where the time went
(cProfile, top functions by own time) for one run of each stereo-bench variant.

    python scripts/bench_calibrate.py [--runs 5] [--profile] [--sets present_cjn,smiler488_box,opencv_sample]

Prints a table; writes scripts/results/bench_calibrate.json (``--out`` to write elsewhere, e.g. for the
figures of an older checkout run with PYTHONPATH pointing at it).
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import glob
import importlib.util
import io
import json
import os
import platform
import pstats
import tempfile
import time
from functools import partial
from pathlib import Path

import cv2
import numpy as np

SHARED = Path(os.environ.get("STEREO_BENCH_SHARED_DATA", "/work/shared/data"))
REAL = Path(__file__).resolve().parents[1] / "calib_data" / "real"
RESULTS = Path(__file__).resolve().parent / "results"
TARGET_ONE, TARGET_AUTO = 1.2, 3.0
#: (folder candidates, left glob, right glob, (cols, rows), square mm)
SETS = {
    "present_cjn": ((REAL / "present_cjn", SHARED / "present_cjn"), "leftPic*.jpg", "rightPic*.jpg", (8, 11), 12.0),
    "smiler488_box": ((REAL / "smiler488_box", SHARED / "smiler488_box"), "L_*.png", "R_*.png", (8, 5), 15.0),
    "opencv_sample": ((REAL / "opencv_sample", SHARED / "opencv_sample"), "left*.jpg", "right*.jpg", (9, 6), 30.0),
}
SUBPIX = ((5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3))


def plain_opencv(lefts: list[str], rights: list[str], pattern: tuple[int, int], square_mm: float) -> dict:
    cols, rows = pattern
    board = np.zeros((rows * cols, 3), np.float32)
    board[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_mm
    objects, left_points, right_points = [], [], []
    size = None
    for left_path, right_path in zip(lefts, rights, strict=True):
        left, right = cv2.imread(left_path, cv2.IMREAD_GRAYSCALE), cv2.imread(right_path, cv2.IMREAD_GRAYSCALE)
        size = left.shape[::-1]
        found_left, corners_left = cv2.findChessboardCorners(left, pattern, None)
        found_right, corners_right = cv2.findChessboardCorners(right, pattern, None)
        if not (found_left and found_right):
            continue
        left_points.append(cv2.cornerSubPix(left, corners_left.reshape(-1, 1, 2), *SUBPIX))
        right_points.append(cv2.cornerSubPix(right, corners_right.reshape(-1, 1, 2), *SUBPIX))
        objects.append(board)
    _, K1, D1, _, _ = cv2.calibrateCamera(objects, left_points, size, None, None)
    _, K2, D2, _, _ = cv2.calibrateCamera(objects, right_points, size, None, None)
    rms, *_, T, _, _ = cv2.stereoCalibrate(objects, left_points, right_points, K1, D1, K2, D2, size,
                                          flags=cv2.CALIB_FIX_INTRINSIC)
    return {"pairs": len(objects), "rms_px": float(rms), "baseline_mm": float(np.linalg.norm(T))}


def _supports_lens_model() -> bool:
    from stereo_bench.cli import vision

    return hasattr(vision, "LENS_CHOICES")


def stereo_bench(lefts_glob: str, rights_glob: str, pattern: tuple[int, int], square_mm: float,
                 lens_model: str | None) -> dict:
    from stereo_bench.cli import main

    with tempfile.TemporaryDirectory(prefix="bench_calibrate_") as out:
        args = ["calibrate", "--board", f"{pattern[0]}x{pattern[1]}", "--square", f"{square_mm:g}", "--left",
                lefts_glob, "--right", rights_glob, "--out", str(Path(out) / "calib"), "--json"]
        if lens_model is not None:
            args += ["--lens-model", lens_model]
        with contextlib.redirect_stdout(io.StringIO()) as text:
            status = main(args)
        if status:
            raise SystemExit(f"stereo-bench calibrate exited {status}")
    report = json.loads(text.getvalue())
    lens = report.get("lens_model") or {}
    return {"pairs": report["views_used"], "rms_px": report["rms_px"], "baseline_mm": report["baseline_mm"],
            "lens_model": lens.get("chosen")}


def _one_blas_thread(job) -> dict:
    """``job()`` on one BLAS thread (threadpoolctl), as ``stereo-bench calibrate`` runs its calibration."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return job()


def _timed(job) -> tuple[float, float, dict]:
    wall, cpu = time.perf_counter(), time.process_time()
    result = job()
    return time.perf_counter() - wall, time.process_time() - cpu, result


def _profile(job, label: str) -> None:
    profile = cProfile.Profile()
    profile.enable()
    job()
    profile.disable()
    out = io.StringIO()
    pstats.Stats(profile, stream=out).sort_stats("tottime").print_stats(12)
    print(f"--- profile: {label} (own time, top 12)")
    print("\n".join(line for line in out.getvalue().splitlines()[6:] if line.strip()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--sets", default=",".join(SETS))
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_calibrate.json")
    args = parser.parse_args()
    mrcal = importlib.util.find_spec("mrcal") is not None
    print("mrcal: installed (not run by this script yet)" if mrcal else "mrcal: not installed")
    variants = {"opencv": None, "one model": "opencv4", "auto": "auto"} if _supports_lens_model() else \
        {"opencv": None, "one model": None}
    load_before = os.getloadavg()
    rows = []
    print(f"{'set':14s} {'pairs':>5s} {'variant':>9s} {'wall s':>7s} {'cpu s':>7s} {'ratio':>6s} {'cpu':>6s} "
          f"{'median':>6s} {'|T| mm':>8s} {'RMS px':>7s} model")
    for name in args.sets.split(","):
        folders, left_glob, right_glob, pattern, square_mm = SETS[name]
        folder = next((f for f in folders if (f / "SOURCE.md").exists() and glob.glob(str(f / left_glob))), None)
        if folder is None:
            print(f"{name}: not found in {', '.join(map(str, folders))}")
            continue
        lefts_glob, rights_glob = str(folder / left_glob), str(folder / right_glob)
        lefts, rights = sorted(glob.glob(lefts_glob)), sorted(glob.glob(rights_glob))
        jobs = {"opencv": partial(plain_opencv, lefts, rights, pattern, square_mm),
                "opencv 1t": partial(_one_blas_thread, partial(plain_opencv, lefts, rights, pattern, square_mm))}
        for variant, model in variants.items():
            if variant != "opencv":
                jobs[variant] = partial(stereo_bench, lefts_glob, rights_glob, pattern, square_mm, model)
        for job in jobs.values():  # warm up: imports, first-call costs, the file cache
            job()
        timings: dict[str, list[tuple[float, float]]] = {v: [] for v in jobs}
        results: dict[str, dict] = {}
        for _ in range(args.runs):
            for variant, job in jobs.items():
                wall, cpu, results[variant] = _timed(job)
                timings[variant].append((wall, cpu))
        reference = float(np.min([w for w, _ in timings["opencv"]]))
        reference_cpu = float(np.min([c for _, c in timings["opencv"]]))
        reference_median = float(np.median([w for w, _ in timings["opencv"]]))
        for variant in jobs:
            wall = float(np.min([w for w, _ in timings[variant]]))
            cpu = float(np.min([c for _, c in timings[variant]]))
            median = float(np.median([w for w, _ in timings[variant]]))
            result = results[variant]
            row = {"set": name, "images": len(lefts), "variant": variant, "wall_s": wall, "cpu_s": cpu,
                   "median_wall_s": median, "ratio_to_opencv": wall / reference,
                   "cpu_ratio_to_opencv": cpu / reference_cpu, "median_ratio_to_opencv": median / reference_median,
                   "wall_s_all": [w for w, _ in timings[variant]], "cpu_s_all": [c for _, c in timings[variant]],
                   **result}
            rows.append(row)
            print(f"{name:14s} {result['pairs']:5d} {variant:>9s} {wall:7.3f} {cpu:7.3f} {wall / reference:6.2f} "
                  f"{cpu / reference_cpu:6.2f} {median / reference_median:6.2f} {result['baseline_mm']:8.3f} "
                  f"{result['rms_px']:7.3f} {result.get('lens_model') or ''}")
        if args.profile:
            for variant, job in jobs.items():
                if not variant.startswith("opencv"):
                    _profile(job, f"{name} {variant}")
    load_after = os.getloadavg()
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (other work inflates every column)")
    checks = {}
    for row in rows:
        target = {"one model": TARGET_ONE, "auto": TARGET_AUTO}.get(row["variant"])
        if target is not None and row["images"] >= 20:
            one = next(r for r in rows if r["set"] == row["set"] and r["variant"] == "opencv 1t")
            checks[f"{row['set']} {row['variant']}"] = {
                "ratio": row["ratio_to_opencv"], "median_ratio": row["median_ratio_to_opencv"],
                "ratio_to_opencv_1t": row["wall_s"] / one["wall_s"],
                "median_ratio_to_opencv_1t": row["median_wall_s"] / one["median_wall_s"], "target": target,
                "meets": row["ratio_to_opencv"] <= target}
    for label, check in checks.items():
        print(f"{label}: {check['ratio']:.2f}x OpenCV (median {check['median_ratio']:.2f}x; against OpenCV on one "
              f"BLAS thread {check['ratio_to_opencv_1t']:.2f}x, median {check['median_ratio_to_opencv_1t']:.2f}x) "
              f"(target <= {check['target']:g}x): {'meets' if check['meets'] else 'MISSES'}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "benchmark": "calibrate vs plain OpenCV", "runs": args.runs, "rows": rows, "checks": checks,
        "mrcal": "installed" if mrcal else "not installed", "load_average_before": load_before,
        "load_average_after": load_after, "opencv": cv2.__version__, "numpy": np.__version__,
        "python": platform.python_version(), "cpu_count": os.cpu_count(),
    }, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
