"""What a driven tilt adds to the fixed-board fit (issue 25): the same design with and without tilt positions.

On the lab mechanics (drivers.sim.mechanics, the heads' tilt joints with the lab build's errors, landing errors on
every axis), one 9x6 board of 25 mm squares 350 mm away stays put while the rig visits the 32 slide and pan
positions of ``fixed_board_design((60, 240), (0, 13))``; ``with tilt`` visits the same positions with both tilts
stepped through -5, 0, 5 deg (``tilt_ranges_deg``), and ``--wide`` (14 deg) through -7, 0, 7: the widest that
keeps this board in both images (+-10 does not). Corners are projected exactly plus 0.1 px Gaussian noise (no
rendering: tests/test_kinematics_fixed_board.py's views), intrinsics refined jointly from these views alone (no
lens calibration as prior: what the design itself determines).

Per design and seed, from the fit's covariance: the sigma of each principal point (cx, cy), of the right camera's
pitch in the left's frame (``right_rot_x_deg``) and height (``right_y_mm``: T_y at the reference); at two
off-design configurations (B 200, toe-ins 7/5; tilts 0 or 3.5/-2.5 with tilt) the predicted R's pitch (rotation
vector x) and T_y sigma (the parameters' part) and their errors against the truth. Prints a table, writes JSON.

    .venv/bin/python scripts/bench_tilt_identifiability.py [--seeds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sim.mechanics import MOVED, TILTS, MoveHistory, pair_state  # noqa: E402
from drivers.sim.profile import LAB  # noqa: E402
from stereo_bench.geometry import invert_transform  # noqa: E402
from stereo_bench.kinematics import predict  # noqa: E402
from stereo_bench.kinematics.fixed_board import fit_fixed_board, fixed_board_design  # noqa: E402
from stereo_bench.kinematics.model import _rvec  # noqa: E402
from tests.test_kinematics_fixed_board import BOARD, CAMERA, fixed_board_views  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "bench_tilt_identifiability.json"
PRINCIPAL = ("left.cx", "left.cy", "right.cx", "right.cy")
OFF_DESIGN = {"baseline_mm": 200.0, "toe_in_left_deg": 7.0, "toe_in_right_deg": 5.0}
OFF_TILTS = {"tilt_left_deg": 3.5, "tilt_right_deg": -2.5}


def _exact_landing():
    zero = {"repeatability_deg": 0.0, "tilt_repeatability_deg": 0.0}
    return LAB.model_copy(update={"slide": LAB.slide.model_copy(update={"repeatability_mm": 0.0}),
                                  "left_head": LAB.left_head.model_copy(update=zero),
                                  "right_head": LAB.right_head.model_copy(update=zero)})


def one(tilts: tuple[str, ...], seed: int, span_deg: float = 10.0) -> dict:
    design = fixed_board_design((60.0, 240.0), (0.0, 13.0), tilt_ranges_deg={t: (0.0, 0.0) for t in tilts} or None,
                                min_tilt_span_deg=span_deg)
    configurations = fixed_board_views(design, LAB, noise_px=0.1, seed=seed, tilts=tilts)
    K, D = CAMERA.K, np.asarray(CAMERA.dist, float).ravel()[:5].reshape(1, 5)
    started = time.perf_counter()
    fit = fit_fixed_board(configurations, BOARD.object_points, CAMERA.image_size, intrinsics=(K, D, K, D),
                          repeatability_mm=LAB.slide.repeatability_mm,
                          repeatability_left_deg=LAB.left_head.repeatability_deg,
                          repeatability_right_deg=LAB.right_head.repeatability_deg,
                          repeatability_tilt_left_deg=LAB.left_head.tilt_repeatability_deg,
                          repeatability_tilt_right_deg=LAB.right_head.tilt_repeatability_deg)
    fit_s = time.perf_counter() - started
    model = fit.model
    C_i = model.intrinsics_covariance_matrix()
    names = model.intrinsics_covariance_names
    out = {"fit_s": fit_s, "n_parameters": len(model.parameters),
           "identified": sum(r.identified for r in fit.identifiability),
           "rms_px": model.fit.rms_px}
    for name in PRINCIPAL:
        k = names.index(name)
        out[f"sigma_{name}_px"] = float(np.sqrt(C_i[k, k]))
    for name in ("right_rot_x_deg", "right_y_mm"):
        out[f"sigma_{name}"] = model.parameters[name].sigma
    for label, extra in (("tilt0", dict.fromkeys(tilts, 0.0)), ("tilted", {t: OFF_TILTS[t] for t in tilts})):
        if label == "tilted" and not tilts:
            continue
        axes = {**OFF_DESIGN, **extra}
        history = MoveHistory(_exact_landing(), 0, quantities=MOVED + tilts)
        history.moved(axes, end_s=0.0, approach=dict.fromkeys(axes, 1))
        state = pair_state(LAB, axes, history=history, tilting=tilts)
        true = invert_transform(state.T_bench_right) @ state.T_bench_left
        prediction = predict(model, axes, dict.fromkeys(axes, 1))
        J = prediction.parameter_jacobian
        sigma = np.sqrt(np.diag(J @ model.covariance_matrix() @ J.T))
        error = np.concatenate([_rvec(true[:3, :3] @ prediction.R.T), prediction.T - true[:3, 3]])
        out[f"{label}_sigma_pitch_deg"] = float(np.degrees(sigma[0]))
        out[f"{label}_sigma_T_y_mm"] = float(sigma[4])
        out[f"{label}_error_pitch_deg"] = float(np.degrees(error[0]))
        out[f"{label}_error_T_y_mm"] = float(error[4])
        out[f"{label}_error_T_mm"] = float(np.linalg.norm(error[3:]))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--wide", type=float, default=14.0, help="a second tilt span, deg (the design's: 10)")
    args = parser.parse_args()
    wide = f"with tilt +-{args.wide / 2:g}"
    runs = {"without tilt": [], "with tilt": [], wide: []}
    for seed in range(args.seeds):
        for label, tilts, span in (("without tilt", (), 10.0), ("with tilt", TILTS, 10.0), (wide, TILTS, args.wide)):
            runs[label].append(one(tilts, seed, span))
            print(f"seed {seed} {label}: fit {runs[label][-1]['fit_s']:.1f} s", flush=True)
    keys = [k for k in runs["with tilt"][0] if "sigma" in k or k.endswith("_s") or "error" in k]
    summary = {}
    print(f"\n{'quantity':34s} " + " ".join(f"{label:>16s}" for label in runs) + "   (mean over seeds; errors: RMS)")
    for key in keys:
        row = {}
        for label, values in runs.items():
            got = [v[key] for v in values if key in v]
            if got:
                row[label] = float(np.sqrt(np.mean(np.square(got)))) if "error" in key else float(np.mean(got))
        summary[key] = row
        cells = [f"{row[label]:16.4g}" if label in row else f"{'-':>16s}" for label in runs]
        print(f"{key:34s} {' '.join(cells)}")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps({"seeds": args.seeds, "summary": summary, "runs": runs,
                                   "load_average": os.getloadavg(), "machine": platform.node(),
                                   "cpus": os.cpu_count()}, indent=1) + "\n")
    print(f"\nwritten {RESULTS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
