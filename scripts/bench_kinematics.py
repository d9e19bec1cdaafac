"""The kinematic rig model on the lab bench: how well it is recovered and how well it predicts.

Runs the lab bench (drivers/sim, profile ``lab``) through the real GRBL driver: the design of
stereo_bench.kinematics.kinematic_design (B 50-250 mm x toe-ins 0-20 deg, 9 visits), 12 rendered
calibration views per visit (108 board presentations), detection, one joint fit. Then it visits
configurations NOT in the design, where the simulated operator places the 27 mm target at 500 mm,
and compares with the bench's truth:

- each fitted parameter against the simulator's mechanics in the model's parametrisation (z = error
  / stated sigma);
- the predicted optical baseline, alphas and R against the true ones, and against the truth without
  that move's random landing error (what any model can know);
- the square measured with the kinematic prediction, the nominal geometry and (at three of them) a
  per-configuration calibration from 12 fresh views, against the true printed square.

Prints tables and writes JSON (with the load average).

    .venv/bin/python scripts/bench_kinematics.py [--half] [--out scripts/results/bench_kinematics.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.rig.rig import GrblRig  # noqa: E402
from drivers.sim.bench import BenchSimulator  # noqa: E402
from drivers.sim.mechanics import kinematic_parameters  # noqa: E402
from drivers.sim.profile import LAB  # noqa: E402
from drivers.sim.render import calibration_board_poses  # noqa: E402
from stereo_bench.campaign.operator import OperatorDesk, SimulatedOperator, move_and_ask
from stereo_bench.geometry import CameraModel, RigPose  # noqa: E402
from stereo_bench.kinematics import (  # noqa: E402
    NAMES,
    ConfigurationViews,
    approach_directions,
    fit_kinematics,
    kinematic_design,
    nominal_extrinsics,
    predict,
)
from stereo_bench.targets import Checkerboard  # noqa: E402
from stereo_bench.vision.calibrate import StereoCalibration  # noqa: E402
from stereo_bench.vision.detect import detect  # noqa: E402
from stereo_bench.vision.pipeline import calibrate_from_images, measure_pair  # noqa: E402

CALIBRATION_BOARD = Checkerboard(11, 8, 25.0)
TARGET = Checkerboard(9, 6, 27.0)
TIME_SCALE = 20.0
SETTLE_S = 0.4
UNSEEN = [(75.0, 5.0, 5.0), (125.0, 15.0, 10.0), (175.0, 10.0, 15.0), (225.0, 20.0, 20.0), (100.0, 0.0, 0.0),
          (200.0, 5.0, 15.0), (150.0, 12.0, 8.0), (150.0, 0.0, 0.0), (150.0, 8.0, 8.0), (150.0, 16.0, 16.0)]
PER_CONFIG = {(100.0, 0.0, 0.0), (150.0, 8.0, 8.0), (225.0, 20.0, 20.0)}
KEYS = ("baseline_mm", "alpha_left_deg", "alpha_right_deg")

#: Stands in for the operator at the manual steps (the target distance), as a campaign's simulator does.
OPERATORS = OperatorDesk([SimulatedOperator()])


def _calibration(K1, D1, K2, D2, R, T, size) -> StereoCalibration:
    return StereoCalibration(K1=np.asarray(K1), D1=np.asarray(D1).reshape(1, -1), K2=np.asarray(K2),
                             D2=np.asarray(D2).reshape(1, -1), R=np.asarray(R, float), T=np.asarray(T, float),
                             image_size=size)


def _views(bench, rng, baseline, toe_left, toe_right, n_views, seed_base):
    poses = calibration_board_poses(RigPose(baseline, 90.0 - toe_left, 90.0 - toe_right), CALIBRATION_BOARD,
                                    n_views=n_views, rng=rng, distance_mm=(300.0, 700.0), left=bench.left_model,
                                    right=bench.right_model)
    pairs = []
    for i, T_rig_board in enumerate(poses):
        bench.show(CALIBRATION_BOARD, T_rig_board, seed=seed_base + i)
        pairs.append(tuple(bench.render(side)[0] for side in ("left", "right")))
    return pairs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--half", action="store_true", help="960x540 cameras (same field of view) instead of 1080p")
    parser.add_argument("--out", type=Path, default=Path("scripts/results/bench_kinematics.json"))
    args = parser.parse_args()
    size, pixel_um = ((960, 540), 6.0) if args.half else ((1920, 1080), 3.0)
    cameras = {side: CameraModel.from_sensor(name=side, image_size=size, pixel_um=pixel_um)
               for side in ("left", "right")}
    load_before = os.getloadavg()
    rng = np.random.default_rng(1)
    started = time.perf_counter()
    with BenchSimulator(time_scale=TIME_SCALE, profile=LAB, seed=5, **cameras) as bench:
        bench.warm_up(CALIBRATION_BOARD, TARGET)
        with GrblRig(bench.tty_path, bench.rig_config) as rig:
            home = rig.home()  # Grbl's machine space: homed at B = 349 mm, toe-ins 1 deg (the pull-off)
            # The first design move's direction of approach is from there.
            previous = {"baseline_mm": home.baseline_mm, "toe_in_left_deg": home.toe_in_left_deg,
                        "toe_in_right_deg": home.toe_in_right_deg}
            approach: dict = {}
            configurations = []
            t0 = time.perf_counter()
            for k, config in enumerate(kinematic_design((50.0, 250.0), (0.0, 20.0))):
                rig.move_to(baseline_mm=config.baseline_mm, alpha_left_deg=config.alpha_left_deg,
                            alpha_right_deg=config.alpha_right_deg).wait()
                bench.clock.advance(SETTLE_S)  # the settle, on the bench clock
                approach = approach_directions(previous, config.axes(), approach)
                previous = config.axes()
                pairs = _views(bench, rng, config.baseline_mm, config.toe_in_left_deg, config.toe_in_right_deg, 12,
                               100 * k)
                views = [tuple(detect(image, CALIBRATION_BOARD) for image in pair) for pair in pairs]
                configurations.append(ConfigurationViews(axes=config.axes(), approach=dict(approach), views=views))
            capture_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            fit = fit_kinematics(configurations, CALIBRATION_BOARD.object_points, size,
                                 repeatability_mm=LAB.slide.repeatability_mm,
                                 repeatability_left_deg=LAB.left_head.repeatability_deg,
                                 repeatability_right_deg=LAB.right_head.repeatability_deg)
            fit_s = time.perf_counter() - t0
            model = fit.model
            truth_p = kinematic_parameters(LAB, model.reference_baseline_mm)
            parameters = {name: {"fitted": model.parameters[name].value, "sigma": model.parameters[name].sigma,
                                 "true": truth_p[name],
                                 "z": (model.parameters[name].value - truth_p[name]) / model.parameters[name].sigma}
                          for name in NAMES}
            K1, D1, K2, D2 = model.intrinsics()
            rows = []
            for baseline, toe_left, toe_right in UNSEEN:
                move_and_ask(rig, OPERATORS, baseline_mm=baseline, alpha_left_deg=90.0 - toe_left,
                             alpha_right_deg=90.0 - toe_right, target_distance_mm=500.0)
                bench.clock.advance(SETTLE_S)  # the settle, on the bench clock
                values = {"baseline_mm": baseline, "toe_in_left_deg": toe_left, "toe_in_right_deg": toe_right}
                approach = approach_directions(previous, values, approach)
                previous = values
                bench.place_target(TARGET, distance_mm=500.0, seed=len(rows))
                images = [bench.render(side)[0] for side in ("left", "right")]
                truth = bench.truth()
                without = bench.truth_without_landing()["structure"]
                prediction = predict(model, values, approach)
                square_true = truth["target"]["square_true_mm"]
                kin = measure_pair(*images, _calibration(K1, D1, K2, D2, prediction.R, prediction.T, size), TARGET)
                R_n, T_n = nominal_extrinsics(baseline, 90.0 - toe_left, 90.0 - toe_right)
                nom = measure_pair(*images, _calibration(K1, D1, K2, D2, R_n, T_n, size), TARGET)
                row = {
                    "B_mm": baseline, "toe_in_left_deg": toe_left, "toe_in_right_deg": toe_right,
                    "error": {k: prediction.structure[k] - truth["structure"][k] for k in KEYS},
                    "error_without_landing": {k: prediction.structure[k] - without[k] for k in KEYS},
                    "sigma": {k: prediction.structure_sigma[k] for k in KEYS},
                    "R_error_deg": float(np.degrees(np.linalg.norm(
                        cv2.Rodrigues(prediction.R.T @ np.array(truth["R"]))[0]))),
                    "square_true_mm": square_true,
                    "square_error_kinematic_mm": kin.square.mean_mm - square_true,
                    "square_error_nominal_mm": nom.square.mean_mm - square_true,
                }
                if (baseline, toe_left, toe_right) in PER_CONFIG:
                    pairs = _views(bench, rng, baseline, toe_left, toe_right, 12, 10_000 + len(rows) * 100)
                    bench.place_target(TARGET, distance_mm=500.0, seed=len(rows))
                    calibration = calibrate_from_images([p[0] for p in pairs], [p[1] for p in pairs],
                                                        CALIBRATION_BOARD)
                    per = measure_pair(*images, calibration.calib, TARGET)
                    row["square_error_per_config_mm"] = per.square.mean_mm - square_true
                rows.append(row)
    total_s = time.perf_counter() - started
    load_after = os.getloadavg()

    print(f"lab bench, {size[0]}x{size[1]}, {model.fit.n_views} views at {model.fit.n_configurations} design visits; "
          f"capture {capture_s:.1f} s, fit {fit_s:.1f} s (rms {model.fit.rms_px:.4f} px); load average "
          f"{load_before[0]:.1f} -> {load_after[0]:.1f}")
    z = [p["z"] for p in parameters.values()]
    print(f"parameters: max |z| {max(abs(v) for v in z):.2f}, chi2 {sum(v * v for v in z):.1f} (22 dof)")
    print(f"{'B':>5} {'tL':>4} {'tR':>4} | {'dB mm':>8} {'daL deg':>8} {'daR deg':>8} {'dR deg':>7} | without landing:"
          f" {'dB':>8} {'daL':>8} {'daR':>8} | square err mm: {'kin':>8} {'nominal':>8} {'per-config':>10}")
    for r in rows:
        e, w = r["error"], r["error_without_landing"]
        per = r.get("square_error_per_config_mm")
        print(f"{r['B_mm']:5.0f} {r['toe_in_left_deg']:4.0f} {r['toe_in_right_deg']:4.0f} | {e['baseline_mm']:+8.4f} "
              f"{e['alpha_left_deg']:+8.4f} {e['alpha_right_deg']:+8.4f} {r['R_error_deg']:7.4f} | "
              f"{w['baseline_mm']:+25.4f} {w['alpha_left_deg']:+8.4f} {w['alpha_right_deg']:+8.4f} | "
              f"{r['square_error_kinematic_mm']:+23.4f} {r['square_error_nominal_mm']:+8.3f} "
              f"{'' if per is None else f'{per:+10.4f}'}")
    worst = {k: max(abs(r["error"][k]) for r in rows) for k in KEYS}
    worst_model = {k: max(abs(r["error_without_landing"][k]) for r in rows) for k in KEYS}
    worst["R_deg"] = max(r["R_error_deg"] for r in rows)
    print(f"worst against the truth: {worst}")
    print(f"worst against the truth without the move's landing error: {worst_model}")
    result = {
        "benchmark": "bench_kinematics", "image_size": list(size), "profile": "lab", "design_views": model.fit.n_views,
        "capture_s": capture_s, "fit_s": fit_s, "total_s": total_s, "fit_rms_px": model.fit.rms_px,
        "pixel_sigma_px": model.fit.pixel_sigma_px, "parameters": parameters, "unseen": rows,
        "worst": worst, "worst_without_landing": worst_model,
        "load_average": {"before": load_before, "after": load_after}, "cpu_count": os.cpu_count(),
        "python": platform.python_version(), "opencv": cv2.__version__, "numpy": np.__version__,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
