"""How far a replay's numbers move under other BLAS kernels: the measurements behind docs/REPLAY.md's constants.

Records two sessions here, under the default kernels (the tests' small campaign on the ideal bench, and a
kinematic campaign on the lab bench: its model fitted again is compared too), takes the shipped sample
session (recorded on another CPU), and replays each in a subprocess under every OpenBLAS core type this CPU
can run (``OPENBLAS_CORETYPE``) and with one BLAS thread. Per column it reports the largest |Δ| / s and
|Δ| / u (s, u: docs/REPLAY.md) and the verdict counts; the tolerance is |Δ| <= 1e-9 s and <= 1e-6 u.

    python scripts/bench_replay_coretypes.py [--out FILE] [--no-kinematic] [--session DIR ...]

A core type whose instructions this CPU lacks dies with SIGILL (SkylakeX without avx512f): it is listed
as not runnable, never run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests.campaigns: the campaigns the tests record

# (name, OPENBLAS_CORETYPE or None, other variables, the vector extensions it needs)
VARIANTS = [
    ("default", None, {}, ()),
    ("default, 1 BLAS thread", None, {"OPENBLAS_NUM_THREADS": "1"}, ()),
    ("Haswell", "Haswell", {}, ("avx2", "fma")),
    ("Zen", "Zen", {}, ("avx2", "fma")),
    ("SkylakeX", "SkylakeX", {}, ("avx512f",)),
    ("Sandybridge", "Sandybridge", {}, ("avx",)),
    ("Nehalem", "Nehalem", {}, ("sse4_2",)),
    ("Barcelona", "Barcelona", {}, ()),
    ("Atom", "Atom", {}, ()),
    ("Core2", "Core2", {}, ()),
    ("Prescott", "Prescott", {}, ()),
]


def child(session: str) -> None:
    """Replay ``session`` in this process; print every compared number's deviation as JSON."""
    from stereo_bench.campaign.environment import numeric_environment
    from stereo_bench.campaign.execute import replay_session

    summary = replay_session(session)
    blas = numeric_environment()["blas"]
    print(json.dumps({
        "core": blas[0]["architecture"] if blas else None, "threads": blas[0]["num_threads"] if blas else None,
        "compared": summary.compared, "identical": summary.identical, "reproduced": summary.reproduced,
        "differences": summary.differences, "kinematic_model": summary.kinematic_model,
        "largest": None if summary.largest is None else {
            "text": summary.largest.text(), "share_of_tolerance": summary.largest.share_of_tolerance},
        "deviations": [{"where": d.where, "name": d.name, "verdict": d.verdict, "abs": d.delta, "scale": d.scale,
                        "u": d.u} for d in summary.deviations if d.verdict != "identical"],
    }))


def record(workdir: Path, kinematic: bool) -> dict[str, Path]:
    from stereo_bench.campaign.execute import run_campaign
    from tests.campaigns import small_config

    sessions = {"sample (shipped)": ROOT / "calib_data" / "sample_session"}
    small = workdir / "small"
    run_campaign(small_config(), small, yes=True)
    sessions["small (ideal bench, recorded here)"] = small
    if kinematic:
        import dataclasses

        from stereo_bench.campaign.execute import CampaignPlan

        config = small_config(**{"name": "lab-kinematic", "seed": 3, "sim": {"profile": "lab"},
                                 "calibration_board": {"cols": 11, "rows": 8, "square_mm": 25},
                                 "capture": {"calibration_views": 4, "settle_s": 0.3},
                                 "extrinsics": {"mode": "kinematic"},
                                 "plan": {"baseline_mm": [80, 200], "distance_mm": [500], "toe_in_deg": [0, 10],
                                          "alpha_deg": None}})
        # tests/test_campaign_extrinsics.py's: two configurations between the design's levels
        plan = CampaignPlan.of(config)
        chosen = [c for c in plan.configurations if (c.baseline_mm, c.toe_in_deg) in {(80.0, 0.0), (200.0, 10.0)}]
        inner = [dataclasses.replace(c, baseline_mm=b, toe_in_deg=t, alpha_deg=90 - t,
                                     config_id=f"B{b:g}_Z500_A{90 - t:g}", index=i)
                 for i, (c, (b, t)) in enumerate(zip(chosen, ((110.0, 3.0), (170.0, 7.0)), strict=True))]
        path = workdir / "kinematic"
        run_campaign(config, path, yes=True, plan=CampaignPlan.of(config, inner, plan.visits))
        sessions["kinematic (lab bench, recorded here)"] = path
    return sessions


def cpu_flags() -> set[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child", metavar="SESSION", help=argparse.SUPPRESS)
    parser.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_replay_coretypes.json"))
    parser.add_argument("--no-kinematic", action="store_true", help="skip the kinematic campaign (~1 min)")
    parser.add_argument("--session", action="append", default=[], help="replay this session too")
    args = parser.parse_args()
    if args.child:
        child(args.child)
        return
    from stereo_bench.campaign.environment import numeric_environment

    flags = cpu_flags()
    workdir = Path(tempfile.mkdtemp(prefix="bench-replay-coretypes-"))
    sessions = record(workdir, kinematic=not args.no_kinematic)
    sessions.update({Path(s).name: Path(s) for s in args.session})
    runs, worst = [], {}
    for variant, core, variables, needs in VARIANTS:
        missing = [flag for flag in needs if flag not in flags]
        if missing:
            runs.append({"variant": variant, "runnable": False,
                         "why": f"this CPU lacks {', '.join(missing)}: the kernels would die with SIGILL"})
            print(f"{variant:24s} not runnable here (no {', '.join(missing)})")
            continue
        env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS")}
        env.update(variables, **({"OPENBLAS_CORETYPE": core} if core else {}))
        for name, session in sessions.items():
            started = time.monotonic()
            done = subprocess.run([sys.executable, __file__, "--child", str(session)], env=env, capture_output=True,
                                  text=True, cwd=ROOT)
            if done.returncode != 0:
                runs.append({"variant": variant, "session": name, "runnable": False,
                             "why": f"exit {done.returncode}: {done.stderr.strip().splitlines()[-1:]}"})
                print(f"{variant:24s} {name}: exit {done.returncode}")
                continue
            result = json.loads(done.stdout.strip().splitlines()[-1])
            columns: dict[str, dict] = {}
            for d in result.pop("deviations"):
                key = d["name"] if d["where"] != "the kinematic model" else f"model: {d['name'].split('[')[0]}"
                entry = columns.setdefault(key, {"abs": 0.0, "relative_to_scale": 0.0, "relative_to_u": None})
                entry["abs"] = max(entry["abs"], d["abs"] or 0.0)
                if d["abs"] is not None and d["scale"]:
                    entry["relative_to_scale"] = max(entry["relative_to_scale"], d["abs"] / d["scale"])
                if d["abs"] is not None and d["u"]:
                    entry["relative_to_u"] = max(entry["relative_to_u"] or 0.0, d["abs"] / d["u"])
                overall = worst.setdefault(key, {"relative_to_scale": 0.0, "relative_to_u": None, "where": None})
                if entry["relative_to_scale"] >= overall["relative_to_scale"]:
                    overall.update(relative_to_scale=entry["relative_to_scale"], where=f"{variant}, {name}")
                if entry["relative_to_u"] is not None:
                    overall["relative_to_u"] = max(overall["relative_to_u"] or 0.0, entry["relative_to_u"])
            runs.append({"variant": variant, "session": name, "runnable": True, "replay_s": time.monotonic() - started,
                         **result, "columns": columns})
            print(f"{variant:24s} {name:40s} core {result['core']}, {result['threads']} threads: "
                  f"{result['identical']} identical, {result['reproduced']} reproduced, "
                  f"{len(result['differences'])} differ" + (f"; model {result['kinematic_model']}"
                                                             if result["kinematic_model"] else ""))
            if result["largest"]:
                print(f"{'':24s}   largest: {result['largest']['text']} "
                      f"({result['largest']['share_of_tolerance']:.2g} of its tolerance)")
    print("\nlargest deviation per column over every core type and session:")
    print(f"{'column':40s} {'|Δ|/s':>9s} {'|Δ|/u':>9s}  where (|Δ|/s)")
    for key, entry in sorted(worst.items(), key=lambda item: -item[1]["relative_to_scale"]):
        u = f"{entry['relative_to_u']:.1e}" if entry["relative_to_u"] is not None else "-"
        print(f"{key:40s} {entry['relative_to_scale']:9.1e} {u:>9s}  {entry['where']}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({
        "what": __doc__.splitlines()[0], "numeric_environment": numeric_environment(),
        "tolerance": {"relative_to_scale": 1e-9, "relative_to_u": 1e-6}, "sessions": {k: str(v) if k.startswith(
            "sample") else "recorded by this script" for k, v in sessions.items()},
        "runs": runs, "largest_per_column": worst}, indent=1) + "\n")
    print(f"\nwritten: {args.out}")


if __name__ == "__main__":
    main()
