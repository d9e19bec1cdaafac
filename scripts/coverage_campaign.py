"""Coverage of the campaign's uncertainty budget, per extrinsics mode, against the simulated bench's truth.

For each bench profile (``lab``, ``ideal``) and seed, three campaigns over the same 5 configurations
spanning B, Z and alpha (rendered frames through the real GRBL driver and emulator, as ``campaign run``):

- ``kinematic``: the design's visits, one joint fit, then each configuration measured with the model's
  prediction at the reported axes;
- ``per-config``: 12 calibration views at every configuration (with the kinematic campaign's model as
  ``kinematic_file``, so the same frames are also measured with its prediction, for comparison);
- ``nominal``: one calibration for the intrinsics, R and T from the commanded B and alpha.

The error is against the board as it is really printed (the truth's ``square_true_mm``): the printed
board's own scale error is not a measurement error, and the budget's matching part (``target_print_mm``:
the measured board's stated scale uncertainty) is left out of u (``combined_vs_true``). The ideal bench is a
rig built exactly: it is run with its stated tolerances and repeatability 0 (what its builder would state).
``lab-builds`` is the lab bench with its as-built geometry drawn per seed from the stated tolerances: the
lab bench is one build, fixed over the seeds, so over ``lab`` the nominal budget is judged on that one
build; over ``lab-builds`` on the class of builds the tolerances describe.

Prints, per bench and mode: RMS of (measured - true) / u, the share within U = 2 u, per configuration the
RMS, and the old figure |error| / sigma_mm (image noise only). Writes JSON with the load average.

    .venv/bin/python scripts/coverage_campaign.py [--seeds 20] [--benches lab ideal] [--half] [--jobs 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sim.profile import LAB, drawn_build  # noqa: E402
from stereo_bench.campaign.config import RigTolerances, campaign_from_dict  # noqa: E402
from stereo_bench.campaign.execute import CampaignPlan, run_campaign  # noqa: E402
from stereo_bench.campaign.plan import expand_plan  # noqa: E402
from stereo_bench.campaign.session import SessionReader  # noqa: E402
from stereo_bench.executors import make_executor  # noqa: E402
from stereo_bench.kinematics import TOLERANCE_NAMES  # noqa: E402

#: (B mm, Z mm, toe-in deg): 5 configurations spanning the three; the inner three lie between the kinematic
#: design's levels (B 60/150/240 mm, toe-in 0/6.5/13 deg), so the model predicts where it was not fitted.
CONFIGURATIONS = [(60.0, 400.0, 0.0), (110.0, 550.0, 9.0), (170.0, 700.0, 4.0), (140.0, 600.0, 12.0),
                  (240.0, 450.0, 13.0)]
MODES = ("per-config", "kinematic", "nominal")
STRUCTURE_KEYS = ("baseline_mm", "alpha_left_deg", "alpha_right_deg", "rotation_deg")
EXACT_RIG = {"tolerances": dict.fromkeys(TOLERANCE_NAMES, 0.0), "repeatability_mm": 0.0, "repeatability_deg": 0.0}
#: The simulated boards' scales are known exactly: the calibration board is printed exactly on both profiles and
#: the error is taken against the measured board's true print; their stated scale uncertainty is 0 here (on a
#: real bench it is the boards' certificate, a component no simulation can test: one fixed draw per board).
EXACT_BOARDS = {"scale_u_rel": 0.0}


def rows_with_structure(reader) -> list[dict]:
    """Per result row of a session (a SessionReader) its stored row and its configuration's structure event."""
    structures = {e.config_id: e.data.model_dump(mode="json", exclude_unset=True)
                  for e in reader.events(kind="structure")}
    return [{"row": row.stored(), "structure": structures.get(row.config_id)} for row in reader.results()]

def sim_table(bench: str, seed: int) -> dict:
    """The [sim] table of a bench: ``lab-builds`` is the lab bench with its as-built geometry drawn, per seed,
    from the rig's stated tolerances (a sample of the class of builds the nominal budget describes)."""
    if bench != "lab-builds":
        return {"profile": bench}
    drawn = drawn_build(LAB, RigTolerances().sigmas(), np.random.default_rng([seed, 5]))
    return {"profile": "lab", **{section: getattr(drawn, section).model_dump()
                                 for section in ("slide", "left_head", "right_head")}}


def campaign(bench: str, seed: int, mode: str, *, half: bool, views: int, kinematic_file: Path | None = None):
    optics = {"width_px": 960, "height_px": 540, "pixel_um": 6.0} if half else {}
    extrinsics = {"mode": mode, **(EXACT_RIG if bench == "ideal" else {})}
    if kinematic_file is not None:
        extrinsics["kinematic_file"] = str(kinematic_file)
    data = {"name": f"coverage-{bench}-{mode}-{seed}", "seed": seed, "rig": {"time_scale": 50.0},
            "cameras": {"optics": optics}, "capture": {"calibration_views": views, "frames_per_config": 3},
            "target": EXACT_BOARDS, "calibration_board": {"cols": 11, "rows": 8, "square_mm": 25.0, **EXACT_BOARDS},
            "extrinsics": extrinsics, "sim": sim_table(bench, seed),
            "plan": {"baseline_mm": [100.0], "distance_mm": [500.0], "toe_in_deg": [0.0]}}
    config = campaign_from_dict(data)
    configurations = []
    for b, z, t in CONFIGURATIONS:
        one = config.model_copy(update={"plan": config.plan.model_copy(update={
            "baseline_mm": [b], "distance_mm": [z], "toe_in_deg": [t], "alpha_deg": None})})
        configurations.append(dataclasses.replace(expand_plan(one)[0], index=len(configurations)))
    return config, CampaignPlan.of(config, configurations)


def one_seed(job: tuple) -> dict:
    bench, seed, half, views, keep, modes = job
    root = Path(tempfile.mkdtemp(prefix=f"coverage-{bench}-{seed}-"))
    out = {"bench": bench, "seed": seed, "rows": {}, "times_s": {}}
    try:
        model_file = None
        for mode in [m for m in ("kinematic", "per-config", "nominal") if m in modes]:
            config, plan = campaign(bench, seed, mode, half=half, views=views,
                                    kinematic_file=model_file if mode == "per-config" else None)
            started = time.perf_counter()
            run_campaign(config, root / mode, yes=True, plan=plan)
            out["times_s"][mode] = time.perf_counter() - started
            reader = SessionReader(root / mode)
            if mode == "kinematic":
                relative = reader.events(kind="kinematic_model", attempt=None)[-1].files[
                    "kinematic_model.toml"]
                model_file = root / "kinematic_model.toml"
                model_file.write_bytes(reader.read_bytes(relative))
            out["rows"][mode] = rows_with_structure(reader)
    finally:
        if keep:
            print(f"kept {root}", file=sys.stderr)
        else:
            shutil.rmtree(root, ignore_errors=True)
    return out


def figures(samples: list[dict]) -> dict:
    """RMS of the normalised errors, share within U, per configuration; the old |error|/sigma for comparison;
    the RMS error against the true print (mm), and per configuration its mean."""
    z = np.array([s["z"] for s in samples])
    errors = np.array([s["error_mm"] for s in samples])
    within = np.array([s["within"] for s in samples])
    ratio = np.array([s["old_ratio"] for s in samples if s["old_ratio"] is not None])
    per_config = {}
    for cid in sorted({s["config_id"] for s in samples}):
        zz = np.array([s["z"] for s in samples if s["config_id"] == cid])
        ee = np.array([s["error_mm"] for s in samples if s["config_id"] == cid])
        per_config[cid] = {"rms": float(np.sqrt(np.mean(zz**2))), "mean": float(zz.mean()), "n": len(zz),
                           "error_mean_mm": float(ee.mean()), "error_rms_mm": float(np.sqrt(np.mean(ee**2)))}
    return {"n": len(z), "rms": float(np.sqrt(np.mean(z**2))), "mean": float(z.mean()),
            "error_rms_mm": float(np.sqrt(np.mean(errors**2))), "error_max_abs_mm": float(np.max(np.abs(errors))),
            "within_U": float(within.mean()), "max_abs_z": float(np.max(np.abs(z))),
            "old_abs_error_over_sigma": [float(ratio.min()), float(np.median(ratio)), float(ratio.max())]
            if len(ratio) else None, "per_configuration": per_config}


def samples_of(results: list[dict], bench: str, mode: str, source: str | None = None) -> list[dict]:
    """Normalised errors of ``mode``'s campaigns: the used source, or ``source`` measured on its frames."""
    out = []
    for result in results:
        if result["bench"] != bench:
            continue
        for entry in result["rows"][mode]:
            row, structure = entry["row"], entry["structure"]
            if row.get("status") != "measured":
                continue
            record = structure["sources"][source or structure["used"]]
            budget = record["uncertainty"]
            u = budget["combined_vs_true"]
            error = record["error_true_mm"]
            truth = (structure.get("truth") or {}).get("structure") or {}
            deviation = {key: record["structure"][key] - truth[key] for key in STRUCTURE_KEYS if key in truth}
            out.append({"config_id": row["config_id"], "seed": result["seed"], "error_mm": error, "u_mm": u,
                        "structure_error": deviation, "structure_sigma": record.get("structure_sigma"),
                        "z": error / u, "within": abs(error) <= budget["k"] * u,
                        "old_ratio": abs(error) / row["sigma_mm"] if source is None else None,
                        "components": {k: budget[k] for k in ("noise", "calibration", "structure", "target")}})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--benches", nargs="+", default=["lab", "ideal"], choices=["lab", "ideal", "lab-builds"],
                        help="lab-builds: the lab bench with its geometry drawn per seed from the stated tolerances")
    parser.add_argument("--half", action="store_true", help="960x540 cameras (same field of view) instead of 1080p")
    parser.add_argument("--views", type=int, default=12, help="calibration views per visit and per configuration")
    parser.add_argument("--jobs", type=int, default=1, help="seeds run in parallel (processes)")
    parser.add_argument("--keep", action="store_true", help="keep the sessions (printed)")
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES, help="extrinsics modes to run")
    parser.add_argument("--out", type=Path, default=Path("scripts/results/coverage_campaign.json"))
    args = parser.parse_args()
    load_before = os.getloadavg()
    started = time.perf_counter()
    jobs = [(bench, seed, args.half, args.views, args.keep, tuple(args.modes)) for bench in args.benches
            for seed in range(args.seeds)]
    with make_executor("serial" if args.jobs == 1 else "local", max_workers=args.jobs) as pool:
        results = list(pool.map(one_seed, jobs))
    total = time.perf_counter() - started
    load_after = os.getloadavg()

    table = {}
    print(f"coverage over {args.seeds} seeds x {len(CONFIGURATIONS)} configurations, "
          f"{'960x540' if args.half else '1920x1080'}; load average {load_before[0]:.1f} -> {load_after[0]:.1f}; "
          f"{total:.0f} s")
    print(f"{'bench':<6} {'mode':<11} {'measured with':<13} {'n':>4} {'RMS z':>6} {'mean z':>7} {'within U':>9} "
          f"{'max|z|':>7}   old |err|/sigma_mm (min, median, max)")
    for bench in args.benches:
        for mode in args.modes:
            sources = [None] + {"per-config": ["kinematic", "nominal"], "kinematic": ["nominal"],
                                "nominal": []}[mode]
            for source in sources:
                if source == "kinematic" and "kinematic" not in args.modes:
                    continue
                samples = samples_of(results, bench, mode, source)
                if not samples:
                    continue
                f = figures(samples)
                key = f"{bench}/{mode}" + (f"/{source}" if source else "")
                table[key] = {**f, "samples": samples}
                old = f["old_abs_error_over_sigma"]
                old_text = "" if old is None else f"{old[0]:.1f}, {old[1]:.1f}, {old[2]:.1f}"
                structure = {name: float(np.max(np.abs([s["structure_error"][name] for s in samples
                                                        if name in s["structure_error"]] or [np.nan])))
                             for name in STRUCTURE_KEYS}
                table[key]["structure_max_abs_error"] = structure
                print(f"{bench:<6} {mode:<11} {source or '(used)':<13} {f['n']:>4} {f['rms']:6.2f} {f['mean']:+7.2f} "
                      f"{f['within_U']:9.0%} {f['max_abs_z']:7.2f}   {old_text}")
                print(f"{'':<33}error against the true print: RMS {f['error_rms_mm']:.4f} mm, max "
                      f"{f['error_max_abs_mm']:.4f} mm; used R, T against the truth, max |error|: baseline "
                      f"{structure['baseline_mm']:.4f} mm, alphas {structure['alpha_left_deg']:.4f} / "
                      f"{structure['alpha_right_deg']:.4f} deg, rotation {structure['rotation_deg']:.4f} deg")
                for cid, c in f["per_configuration"].items():
                    print(f"{'':<33}{cid:<16} RMS z {c['rms']:5.2f}  mean {c['mean']:+5.2f}  error mean "
                          f"{c['error_mean_mm']:+.4f} mm")
    times = {mode: float(np.mean([r["times_s"][mode] for r in results])) for mode in args.modes}
    result = {
        "benchmark": "coverage_campaign", "seeds": args.seeds, "configurations": CONFIGURATIONS,
        "image_size": [960, 540] if args.half else [1920, 1080], "views": args.views, "table": table,
        "campaign_s_mean": times, "total_s": total, "load_average": {"before": load_before, "after": load_after},
        "cpu_count": os.cpu_count(), "python": platform.python_version(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
