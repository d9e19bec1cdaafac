"""What ``model predict`` / ``advise`` predict against what the simulated lab bench then measures, per extrinsics mode.

The measured side is a ``scripts/coverage_campaign.py`` result (rendered campaigns through the real GRBL
driver and emulator, 5 configurations, per mode and seed): the RMS over seeds of each configuration's
error against the board as printed. The predicted side is the rigorous model with the rig's stated
tolerances, the campaign's repeatability and the planned 12 calibration views
(:mod:`stereo_bench.errormodel.rig`: what ``model predict --extrinsics MODE`` prints), at the image noise the
bench's calibrations fit to (``--pixel-sigma``: its stereo RMS, docs/SIMULATED_BENCH.md), with the
target's noise averaged over the campaign's frames. The coverage campaigns' boards are printed exactly
(their scale is not in the error), so the target term is 0 here. Prints per mode and configuration the
prediction, its largest term, the measured RMS and the ratio; writes JSON.

    .venv/bin/python scripts/predict_vs_measured.py [--coverage scripts/results/coverage_campaign.json]
        [--calibration-rms 0.032 | --pixel-sigma PX] [--no-joint] [--frames 3] [--out predict_vs_measured.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stereo_bench.campaign.config import RigTolerances  # noqa: E402
from stereo_bench.errormodel.rig import (  # noqa: E402
    PRESENTED_DESIGN_VISITS,
    RigErrors,
    combined,
    dominant_term,
)
from stereo_bench.errormodel.rigorous import CalibrationPlan, Setup, predict  # noqa: E402
from stereo_bench.kinematics import campaign_design  # noqa: E402

MODES = {"per-config": "per-config", "nominal": "nominal", "kinematic": "kinematic"}


@dataclass(frozen=True)
class _Planned:
    baseline_mm: float
    distance_mm: float
    toe_in_deg: float
    runnable: bool = True


def predicted(mode: str, bench: str, baseline_mm: float, distance_mm: float, toe_in_deg: float,
              pixel_sigma_px: float, frames: int, configurations: list[_Planned], joint: bool = True) -> dict:
    visits = PRESENTED_DESIGN_VISITS if mode == "kinematic" else 1
    # The design the coverage campaigns' plan visits (over their configurations), fitted at this noise; without
    # it (--no-joint) the old split: one configuration's intrinsics / sqrt(visits) and R, T apart.
    design, design_distance = campaign_design(configurations) if mode == "kinematic" and joint else (None, None)
    # What each bench's builder states (as coverage_campaign.py runs them): the lab bench the campaign's default
    # tolerances and repeatability, the ideal bench (built exactly) zeros.
    exact = bench == "ideal"
    tolerances = {name: 0.0 for name in RigTolerances().sigmas()} if exact else RigTolerances().sigmas()
    repeatability = {"repeatability_mm": 0.0, "repeatability_deg": 0.0} if exact else {}
    rig = RigErrors(mode=mode, tolerances=tolerances, target_scale_u_rel=0.0, calibration_board_scale_u_rel=0.0,
                    intrinsics_visits=visits, source=f"the {bench} bench's stated tolerances",
                    design=None if design is None else tuple(design), design_distance_mm=design_distance,
                    **repeatability)
    setup = Setup.make(baseline_mm, distance_mm, 90.0 - toe_in_deg)
    p = predict(setup, pixel_sigma_px, calibration=CalibrationPlan(), rig=rig)
    terms = {"noise": None if p.sigma_square_mm is None else p.sigma_square_mm / math.sqrt(frames),
             "bias": p.bias_square_mm, "calibration": p.sigma_calibration_mm, "structure": p.sigma_structure_mm}
    return {"terms_mm": terms, "predicted_mm": combined(terms), "dominant_term": dominant_term(terms)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coverage", type=Path, nargs="+",
                        default=[Path("scripts/results/coverage_campaign.json"),
                                 Path("scripts/results/coverage_campaign_builds.json")])
    noise = parser.add_mutually_exclusive_group()
    noise.add_argument("--pixel-sigma", type=float, default=None,
                       help="image noise per coordinate, px (the model's input; default: --calibration-rms / sqrt 2)")
    noise.add_argument("--calibration-rms", type=float, default=0.032,
                       help="the bench's calibration reprojection RMS, px (a 2-D distance per corner: sqrt 2 x the "
                            "noise per coordinate; lab before issue 22: 0.032, after: 0.214)")
    parser.add_argument("--no-joint", action="store_true",
                        help="kinematic mode as before: one configuration's intrinsics / sqrt(visits), R, T apart")
    parser.add_argument("--frames", type=int, default=3, help="measurement frames per configuration")
    parser.add_argument("--out", default="predict_vs_measured.json")
    args = parser.parse_args()
    if args.pixel_sigma is None:
        args.pixel_sigma = args.calibration_rms / math.sqrt(2.0)
    rows = []
    print(f"{'bench/mode':22s} {'config':15s} {'predicted mm':>12} {'largest':>11} {'measured RMS mm':>15} "
          f"{'ratio':>6}")
    for path in args.coverage:
        result = json.loads(path.read_text())
        planned = [_Planned(b, z, t) for b, z, t in result["configurations"]]
        for key, entry in result["table"].items():
            bench, _, mode = key.partition("/")
            if mode not in MODES:
                continue  # the comparisons with another source of the same frames
            by_config: dict[str, list[float]] = {}
            for sample in entry["samples"]:
                by_config.setdefault(sample["config_id"], []).append(sample["error_mm"])
            for baseline, distance, toe_in in result["configurations"]:
                config_id = f"B{baseline:g}_Z{distance:g}_A{90 - toe_in:g}"
                errors = np.array(by_config.get(config_id, []))
                if not errors.size:
                    continue
                measured = float(np.sqrt(np.mean(errors**2)))
                p = predicted(MODES[mode], bench, baseline, distance, toe_in, args.pixel_sigma, args.frames,
                              planned, joint=not args.no_joint)
                ratio = p["predicted_mm"] / measured if p["predicted_mm"] and measured else None
                rows.append({"coverage": str(path), "bench": bench, "mode": mode, "config_id": config_id,
                             "n": int(errors.size), "measured_rms_mm": measured, **p, "ratio": ratio})
                print(f"{key:22s} {config_id:15s} {p['predicted_mm']:12.4g} {p['dominant_term']:>11} "
                      f"{measured:15.4g} {ratio:6.2f}")
            mine = [r for r in rows if r["coverage"] == str(path) and r["bench"] == bench and r["mode"] == mode]
            if mine:
                pred = math.sqrt(np.mean([r["predicted_mm"] ** 2 for r in mine]))
                meas = math.sqrt(np.mean([r["measured_rms_mm"] ** 2 for r in mine]))
                print(f"{key:22s} {'all (RMS)':15s} {pred:12.4g} {'':>11} {meas:15.4g} {pred / meas:6.2f}")
    out = Path(args.out)
    out.write_text(json.dumps({"benchmark": "predict_vs_measured", "pixel_sigma_px": args.pixel_sigma,
                               "joint_kinematic": not args.no_joint,
                               "frames": args.frames, "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
