"""Does the uncertainty budget hold on rendered images? Coverage over seeds x configurations.

For each configuration (B, Z, alpha) and seed: render the campaign's calibration views (11x8, 25 mm
board, placed as the simulated presenter places them), detect, stereo-calibrate (with its
covariance), render the 27 mm target facing the rig at Z in a few frames, measure each with the
pipeline, and compute the configuration's budget (``configuration_budget``; the simulated boards are
exact, so the target component is zero by its source). Reports, per configuration and overall: the
RMS of the normalised errors (measured - 27)/u_c, the share of abs(error) <= U, the same with the old
sigma (random image noise only), and, for the calibration itself, the scatter of abs(T) and fx
around the truth against the sigmas the calibrations reported.

    python scripts/coverage_rendered.py [--seeds 20] [--views 12] [--frames 3] [--mode joint] [--workers 2]
        [--calibration-bow-mm 0] [--configurations 5]

``--calibration-bow-mm``: the calibration board bent (a cylindrical bow, the centre that much nearer the
cameras, drivers/sim/render.BoardShape) while the calibration assumes it flat; the measured target stays
flat. Does the budget (its model-adequacy component) still cover what the bend does to the measurement?

Prints a table; writes scripts/results/coverage_rendered[_MODE].json.
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

from drivers.sim.render import BoardShape, StereoRenderer, calibration_board_poses
from stereo_bench.executors import make_executor
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import single_threaded_opencv
from stereo_bench.vision.covariance import extrinsic_sigmas
from stereo_bench.vision.pipeline import calibrate_from_images, measure_pair
from stereo_bench.vision.uncertainty import BoardScale, configuration_budget

CALIB_BOARD = Checkerboard(11, 8, 25.0)
TARGET = Checkerboard(9, 6, 27.0)
CAMERA = CameraModel.from_sensor()
#: (B mm, Z mm, alpha deg): spanning B, Z and alpha, the whole target in both views.
CONFIGURATIONS = ((100.0, 500.0, 90.0), (200.0, 500.0, 80.0), (50.0, 300.0, 90.0), (300.0, 800.0, 80.0),
                  (150.0, 400.0, 75.0))
RESULTS = Path(__file__).resolve().parent / "results"

_renderers: dict = {}


def _renderer(board: Checkerboard) -> StereoRenderer:
    if board not in _renderers:
        _renderers[board] = StereoRenderer(board, CAMERA, CAMERA)
    return _renderers[board]


def run_one(job: tuple) -> dict:
    """One (configuration, seed) run, OpenCV on one thread (one run per worker process and core); the thread count
    is restored after, since a test calls this in its own process."""
    with single_threaded_opencv():
        return _run_one(job)


def _run_one(job: tuple) -> dict:
    (baseline, distance, alpha), seed, n_views, n_frames, mode, bow_mm = job
    rig = RigPose.symmetric(baseline, alpha)
    rng = np.random.default_rng([seed, int(baseline), int(distance), int(alpha)])
    poses = calibration_board_poses(rig, CALIB_BOARD, n_views=n_views, rng=rng,
                                    distance_mm=(max(250.0, 0.6 * distance), 1.3 * distance))
    shape = BoardShape(bow_mm=bow_mm) if bow_mm else None
    pairs = [_renderer(CALIB_BOARD).render_pair(rig, pose, rng, shape=shape) for pose in poses]
    result = calibrate_from_images([p.left.image for p in pairs], [p.right.image for p in pairs], CALIB_BOARD,
                                   mode=mode, thorough=False, accept_poor=bool(bow_mm))  # a bend past the
    # flatness gate (0.5 % of the diagonal) is refused; kept here to see what it would have done
    calib = result.calib
    T_rig_board = board_pose_facing_rig(distance_mm=distance, board_size_mm=TARGET.grid_size_mm)
    frames = []
    for _ in range(n_frames):
        pair = _renderer(TARGET).render_pair(rig, T_rig_board, rng)
        frames.append(measure_pair(pair.left.image, pair.right.image, calib, TARGET, rect=result.rect))
    budget = configuration_budget(frames, calib, TARGET, board_scale=BoardScale(0.0, 0.0))
    R_true, T_true = rig.stereo_extrinsics()
    sig = extrinsic_sigmas(calib.R, calib.T, calib.covariance)
    return {
        "baseline_mm": baseline, "distance_mm": distance, "alpha_deg": alpha, "seed": seed,
        "calibration_bow_mm": bow_mm, "error_mm": budget.error_mm,
        "adequacy_rel": calib.adequacy.u_rel if calib.adequacy is not None else None,
        "adequacy_bias_rel": calib.adequacy.bias_rel if calib.adequacy is not None else None,
        "adequacy_lengthening_rel": calib.adequacy.lengthening_rel if calib.adequacy is not None else None,
        **{f"u_{k}_mm": v for k, v in budget.as_dict().items() if k != "k"}, "k": budget.k,
        "noise_random_mm": budget.noise_random_mm, "noise_bias_mm": budget.noise_bias_mm,
        "calibration_sigma_px": calib.covariance.sigma_px, "rms_px": calib.rms_px,
        "views_used": len(result.views_used),
        "abs_T_error_mm": calib.baseline_mm - float(np.linalg.norm(T_true)), "abs_T_sigma_mm": sig["baseline_mm"],
        "fx_error_px": float(calib.K1[0, 0] - CAMERA.K[0, 0]), "fx_sigma_px": calib.covariance.sigma("left.fx"),
        "rvec_y_error_rad": float(cv2.Rodrigues(calib.R)[0][1, 0] - cv2.Rodrigues(R_true)[0][1, 0]),
        "rvec_y_sigma_rad": calib.covariance.sigma("rvec.y"),
    }


def summarise(rows: list[dict]) -> dict:
    error = np.array([r["error_mm"] for r in rows])
    u_c = np.array([r["u_combined_mm"] for r in rows])
    old = np.array([r["noise_random_mm"] for r in rows])

    def scatter(name: str) -> dict:
        e = np.array([r[f"{name}_error_{unit}"] for r in rows for unit in ("mm", "px", "rad")
                      if f"{name}_error_{unit}" in r])
        s = np.array([r[f"{name}_sigma_{unit}"] for r in rows for unit in ("mm", "px", "rad")
                      if f"{name}_sigma_{unit}" in r])
        return {"rms_error": float(np.sqrt(np.mean(e**2))), "rms_sigma": float(np.sqrt(np.mean(s**2))),
                "ratio": float(np.sqrt(np.mean(e**2)) / np.sqrt(np.mean(s**2)))}
    return {
        "n": len(rows), "rms_normalised_error": float(np.sqrt(np.mean((error / u_c) ** 2))),
        "fraction_within_U": float(np.mean(np.abs(error) <= np.array([r["u_expanded_mm"] for r in rows]))),
        "rms_error_over_old_sigma": float(np.sqrt(np.mean((error / old) ** 2))),
        "fraction_within_2_old_sigma": float(np.mean(np.abs(error) <= 2 * old)),
        "mean_u_mm": {k: float(np.mean([r[f"u_{k}_mm"] for r in rows])) for k in ("noise", "calibration")},
        "rms_error_mm": float(np.sqrt(np.mean(error**2))),
        "abs_T": scatter("abs_T"), "fx": scatter("fx"), "rvec_y": scatter("rvec_y"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--views", type=int, default=12)
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--mode", choices=("joint", "fixed"), default="joint")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--calibration-bow-mm", type=float, default=0.0)
    parser.add_argument("--configurations", type=int, default=len(CONFIGURATIONS), help="the first N of them")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    configurations = CONFIGURATIONS[:args.configurations]
    jobs = [(c, seed, args.views, args.frames, args.mode, args.calibration_bow_mm) for c in configurations
            for seed in range(args.seeds)]
    load_before = os.getloadavg()
    start = time.perf_counter()
    with make_executor("serial" if args.workers == 1 else "local", max_workers=args.workers) as executor:
        rows = executor.map(run_one, jobs)
    elapsed = time.perf_counter() - start
    per_config = {}
    print(f"{'B mm':>5} {'Z mm':>5} {'alpha':>5} {'n':>3} {'RMS e/u_c':>9} {'|e|<=U':>7} {'RMS e/old':>9} "
          f"{'u_noise':>8} {'u_cal':>8} {'RMS e mm':>8} {'|T| e/s':>7} {'fx e/s':>6}")
    for config in configurations:
        sub = [r for r in rows if (r["baseline_mm"], r["distance_mm"], r["alpha_deg"]) == config]
        s = summarise(sub)
        per_config["B{:g}_Z{:g}_a{:g}".format(*config)] = s
        print(f"{config[0]:5g} {config[1]:5g} {config[2]:5g} {s['n']:3d} {s['rms_normalised_error']:9.2f} "
              f"{s['fraction_within_U']:7.0%} {s['rms_error_over_old_sigma']:9.2f} {s['mean_u_mm']['noise']:8.5f} "
              f"{s['mean_u_mm']['calibration']:8.5f} {s['rms_error_mm']:8.5f} {s['abs_T']['ratio']:7.2f} "
              f"{s['fx']['ratio']:6.2f}")
    overall = summarise(rows)
    print(f"all {overall['n']}: RMS (measured - true)/u_c = {overall['rms_normalised_error']:.2f}, "
          f"{overall['fraction_within_U']:.0%} within U; with the old sigma: RMS "
          f"{overall['rms_error_over_old_sigma']:.2f}, {overall['fraction_within_2_old_sigma']:.0%} within 2 sigma")
    print(f"calibration vs truth (RMS error / RMS reported sigma): |T| {overall['abs_T']['ratio']:.2f}, "
          f"fx {overall['fx']['ratio']:.2f}, rvec_y {overall['rvec_y']['ratio']:.2f}")
    load_after = os.getloadavg()
    print(f"{elapsed:.0f} s; load average before {load_before[0]:.2f}, after {load_after[0]:.2f}")
    out = Path(args.out) if args.out else RESULTS / f"coverage_rendered{'' if args.mode == 'joint' else '_fixed'}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "benchmark": "coverage_rendered", "mode": args.mode, "seeds": args.seeds, "views": args.views,
        "frames": args.frames, "calibration_board": "checkerboard 11x8 25 mm",
        "calibration_bow_mm": args.calibration_bow_mm, "target": "checkerboard 9x6 27 mm",
        "overall": overall, "per_configuration": per_config, "rows": rows, "elapsed_s": elapsed,
        "load_average_before": load_before, "load_average_after": load_after, "opencv": cv2.__version__,
        "python": platform.python_version(), "cpu_count": os.cpu_count(),
    }, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
