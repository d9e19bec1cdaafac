"""The fixed-board kinematic design (issue 25) against the presented one, on the simulated lab bench.

Per seed, rendered campaigns through the real GRBL driver and emulator (as ``campaign run``) over the 5
configurations of scripts/coverage_campaign.py (spanning B, Z and toe-in, the inner ones between any design's
levels: the model predicts where it was not fitted):

- ``lens``: one per-config calibration (12 presented views at B 150 mm, Z 450 mm): the lens calibration
  ``calib_dir`` holds, made once (its intrinsics and covariance are the fixed-board fit's prior);
- ``fixed-board``: ``[extrinsics] mode = "kinematic"``, ``design = "fixed-board"`` with that ``calib_dir``: the
  simulated operator places the board once (off the requested pose by the placement error), the rig moves
  through the design, one joint fit with one board pose, then the 5 configurations measured with its predictions;
- ``presented``: ``design = "presented"`` (9 visits x 12 presented views), the same 5 configurations.

Per design: the predicted optical baseline, alphas and rotation angle against the bench's truth (max |error|),
the square against the true print (RMS), RMS of (error / u_c), the share within U, the fit time, the board
placements and presentations. Prints a table, writes JSON (with the load average).

    .venv/bin/python scripts/bench_fixed_board.py [--seeds 10] [--half] [--configurations 5] [--quick]
        [--designs fixed-board presented] [--lens-views 12] [--fixed-board-views N]
"""

from __future__ import annotations

import argparse
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
sys.path.insert(0, str(Path(__file__).resolve().parent))

from coverage_campaign import (  # noqa: E402
    CONFIGURATIONS,
    STRUCTURE_KEYS,
    campaign,
    figures,
    rows_with_structure,
    samples_of,
)

from stereo_bench.campaign.config import campaign_from_dict  # noqa: E402
from stereo_bench.campaign.execute import CampaignPlan, run_campaign  # noqa: E402
from stereo_bench.campaign.plan import calibration_presentations  # noqa: E402
from stereo_bench.campaign.session import SessionReader  # noqa: E402

DESIGNS = ("fixed-board", "presented")


def lens_calibration(root: Path, seed: int, *, half: bool, views: int = 12) -> Path:
    """A calib_dir from one per-config calibration of ``views`` presented views (what an operator makes once)."""
    optics = {"width_px": 960, "height_px": 540, "pixel_um": 6.0} if half else {}
    data = {"name": f"lens-{seed}", "seed": 1000 + seed, "rig": {"time_scale": 50.0}, "cameras": {"optics": optics},
            "capture": {"calibration_views": views, "frames_per_config": 1},
            "calibration_board": {"cols": 11, "rows": 8, "square_mm": 25.0, "scale_u_rel": 0.0},
            "plan": {"baseline_mm": [150.0], "distance_mm": [450.0], "toe_in_deg": [6.5]}}
    config = campaign_from_dict(data)
    run_campaign(config, root / "lens", yes=True)
    calib = next((root / "lens" / "calib").glob("*/*"))
    out = root / "calib_dir"
    shutil.copytree(calib, out)
    return out


def pose_errors(rows: list[dict]) -> list[dict]:
    """Per measured configuration the predicted R, T against the bench's truth: |T - T_true| (mm), its components,
    and the angle of R R_true^T (deg)."""
    import cv2

    out = []
    for entry in rows:
        row, structure = entry["row"], entry["structure"]
        if row.get("status") != "measured" or not (structure.get("truth") or {}).get("T"):
            continue
        record = structure["sources"][structure["used"]]
        dT = np.asarray(record["T"], float).ravel() - np.asarray(structure["truth"]["T"], float).ravel()
        dR = np.asarray(record["R"], float) @ np.asarray(structure["truth"]["R"], float).T
        angle = float(np.degrees(np.linalg.norm(cv2.Rodrigues(dR)[0])))
        out.append({"config_id": row["config_id"], "dT_mm": dT.tolist(), "abs_dT_mm": float(np.linalg.norm(dT)),
                    "dR_deg": angle})
    return out


def one_seed(seed: int, *, half: bool, n_configurations: int, keep: bool, designs=DESIGNS,
             lens_views: int = 12, fixed_board: dict | None = None) -> dict:
    root = Path(tempfile.mkdtemp(prefix=f"fixed-board-{seed}-"))
    out = {"seed": seed, "rows": {}, "times_s": {}, "fit_s": {}, "presentations": {}, "identifiability": None}
    try:
        calib_dir = lens_calibration(root, seed, half=half, views=lens_views)
        for design in designs:
            config, plan = campaign("lab", seed, "kinematic", half=half, views=12)
            extrinsics = config.extrinsics.model_copy(update={"design": design})
            if design == "fixed-board":
                extrinsics = extrinsics.model_copy(update={"calib_dir": calib_dir, **(fixed_board or {})})
            config = config.model_copy(update={"extrinsics": extrinsics})
            plan = CampaignPlan.of(config, plan.configurations[:n_configurations])
            counts = calibration_presentations(plan.steps)
            out["presentations"][design] = counts
            started = time.perf_counter()
            run_campaign(config, root / design, yes=True, plan=plan)
            out["times_s"][design] = time.perf_counter() - started
            reader = SessionReader(root / design)
            model = reader.events(kind="kinematic_model", attempt=None)[-1].data
            out["fit_s"][design] = model.fit_s
            if design == "fixed-board":
                out["identifiability"] = model.identifiability
            out["rows"][design] = rows_with_structure(reader)
            out.setdefault("pose_errors", {})[design] = pose_errors(out["rows"][design])
    finally:
        if keep:
            print(f"kept {root}", file=sys.stderr)
        else:
            shutil.rmtree(root, ignore_errors=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--half", action="store_true", help="960x540 cameras (same field of view) instead of 1080p")
    parser.add_argument("--configurations", type=int, default=len(CONFIGURATIONS),
                        help=f"the first N of the {len(CONFIGURATIONS)} configurations")
    parser.add_argument("--keep", action="store_true", help="keep the sessions (printed)")
    parser.add_argument("--designs", nargs="+", default=list(DESIGNS), choices=DESIGNS)
    parser.add_argument("--quick", action="store_true", help="3 seeds, the fixed-board design only")
    parser.add_argument("--lens-views", type=int, default=12, help="presented views of the lens calibration")
    parser.add_argument("--fixed-board-views", type=int, default=None,
                        help="[extrinsics] fixed_board_views (default: the config's)")
    parser.add_argument("--out", type=Path, default=Path("scripts/results/bench_fixed_board.json"))
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.designs = 3, ["fixed-board"]
    designs = tuple(args.designs)
    fixed_board = {} if args.fixed_board_views is None else {"fixed_board_views": args.fixed_board_views}
    load_before = os.getloadavg()
    started = time.perf_counter()
    results = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        results.append(one_seed(seed, half=args.half, n_configurations=args.configurations, keep=args.keep,
                                designs=designs, lens_views=args.lens_views, fixed_board=fixed_board))
        print(f"seed {seed}: {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    total = time.perf_counter() - started
    load_after = os.getloadavg()
    # coverage_campaign's helpers read results[i]["rows"][mode] and ["bench"]
    tagged = [{**r, "bench": "lab"} for r in results]
    table = {}
    print(f"fixed-board vs presented kinematic design, lab bench, {args.seeds} seeds x {args.configurations} "
          f"configurations, {'960x540' if args.half else '1920x1080'}; load average {load_before[0]:.1f} -> "
          f"{load_after[0]:.1f}; {total:.0f} s")
    print(f"{'design':<12} {'n':>3} {'RMS z':>6} {'within U':>9} {'square RMS':>11} {'baseline max':>13} "
          f"{'alpha max':>10} {'rotation max':>13} {'fit s':>6} {'presentations':>14} {'placements':>11}")
    for design in designs:
        samples = samples_of(tagged, "lab", design)
        if not samples:
            continue
        f = figures(samples)
        structure = {name: float(np.max(np.abs([s["structure_error"][name] for s in samples
                                                if name in s["structure_error"]] or [np.nan])))
                     for name in STRUCTURE_KEYS}
        fit_s = float(np.mean([r["fit_s"][design] for r in results if r["fit_s"].get(design) is not None]))
        counts = results[0]["presentations"][design]
        poses = [e for r in results for e in r["pose_errors"][design]]
        abs_dT = np.array([e["abs_dT_mm"] for e in poses])
        dR = np.array([e["dR_deg"] for e in poses])
        dT = np.array([e["dT_mm"] for e in poses])
        pose = {"n": len(poses), "abs_dT_max_mm": float(abs_dT.max()),
                "abs_dT_rms_mm": float(np.sqrt(np.mean(abs_dT**2))),
                "dT_rms_mm_xyz": np.sqrt(np.mean(dT**2, axis=0)).tolist(), "dR_max_deg": float(dR.max()),
                "dR_rms_deg": float(np.sqrt(np.mean(dR**2))),
                "structure_rms_error": {name: float(np.sqrt(np.mean([s["structure_error"][name] ** 2 for s in samples
                                                                     if name in s["structure_error"]])))
                                        for name in STRUCTURE_KEYS}}
        table[design] = {**f, "structure_max_abs_error": structure, "fit_s_mean": fit_s, "presentations": counts,
                         "pose_error": pose, "samples": samples}
        alpha = max(structure["alpha_left_deg"], structure["alpha_right_deg"])
        print(f"{design:<12} {f['n']:>3} {f['rms']:6.2f} {f['within_U']:9.0%} {f['error_rms_mm']:8.4f} mm "
              f"{structure['baseline_mm']:10.4f} mm {alpha:6.4f} deg {structure['rotation_deg']:9.4f} deg "
              f"{fit_s:6.1f} {counts['total']:>14} {counts['placements']:>11}")
        print(f"{'':<12} R, T against the truth: |dT| max {pose['abs_dT_max_mm']:.4f} mm, RMS "
              f"{pose['abs_dT_rms_mm']:.4f} mm (x, y, z RMS {', '.join(f'{v:.4f}' for v in pose['dT_rms_mm_xyz'])}); "
              "angle of dR max "
              f"{pose['dR_max_deg']:.4f} deg, RMS {pose['dR_rms_deg']:.4f} deg; structure RMS: "
              + ", ".join(f"{k} {v:.4f}" for k, v in pose["structure_rms_error"].items()))
    if len(table) == 2:
        ratio = table["fixed-board"]["error_rms_mm"] / table["presented"]["error_rms_mm"]
        print(f"square RMS error, fixed-board / presented: {ratio:.2f}")
        table["square_rms_ratio"] = ratio
    rows = results[0]["identifiability"] or []
    held = [r["name"] for r in rows if not r["identified"]]
    if rows:
        print(f"fixed-board identifiability (seed {results[0]['seed']}): {len(rows) - len(held)} of {len(rows)} "
              "parameters identified" + (f"; held: {', '.join(held)}" if held else ""))
    result = {
        "benchmark": "bench_fixed_board", "seeds": args.seeds, "designs": list(designs),
        "lens_views": args.lens_views, "fixed_board": fixed_board,
        "configurations": CONFIGURATIONS[:args.configurations],
        "image_size": [960, 540] if args.half else [1920, 1080], "table": table,
        "identifiability": [r["identifiability"] for r in results],
        "campaign_s_mean": {d: float(np.mean([r["times_s"][d] for r in results])) for d in designs},
        "total_s": total, "load_average": {"before": load_before, "after": load_after},
        "cpu_count": os.cpu_count(), "python": platform.python_version(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
