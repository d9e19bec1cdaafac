"""Is the simulated lab bench a function of its seed and the plan only? (issue 19, item 2)

Runs one plan on the lab bench (backlash, landing and placement errors, heads ringing 0.24 s after a move) with
a settle of 0.1 s, shorter than the ringing, through ``stereo-bench campaign run`` as a user would, with two CPU
hogs (``python -c 'while True: pass'``) beside every run:

- a reference run at ``time_scale`` 50, then more uninterrupted runs at 50 and at the other time scales;
- runs killed with SIGKILL at a random moment (seeded: once the session's document stream has reached a
  random number of lines, drawn uniformly below the reference's count, so the moment falls anywhere in the
  run however loaded the machine is) and resumed with ``--resume`` (under the same load), at a random one of
  the time scales.

Each run's results.csv (every column but ``time`` and ``attempt``) and the truth the bench recorded at each
measurement (all of it but its bench time ``sim_time_s``, which a resume reaches by other moves) are compared
with the reference's: identical or not, and the largest |difference| of ``square_mean_mm``.

    python scripts/bench_determinism.py [--runs 2] [--kills 4] [--time-scales 50 10] [--seed 1]
        [--source DIR] [--out scripts/results/bench_determinism.json]

``--source DIR``: run the CLI of another checkout (its PYTHONPATH), e.g. an older commit, to compare.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.campaigns import LAB  # noqa: E402 - the repository's root is on the path from here on

# The small campaign of tests/campaigns.py on the lab bench (settle 0.1 s: shorter than the heads' 0.24 s
# ringing, so the captures see it), at two target distances: eight configurations, two manual target placements,
# moves of the slide and both heads in both directions.
PLAN = LAB.replace("distance_mm = [450]", "distance_mm = [450, 550]").replace('name = "small"', 'name = "determinism"')


def outcome(session: Path) -> tuple[dict, dict]:
    """(results.csv rows without time and attempt, truths without their bench time), per configuration."""
    from stereo_bench.campaign.session import SessionReader

    with open(session / "results.csv", newline="") as handle:
        rows = {row["config_id"]: {k: v for k, v in row.items() if k not in ("time", "attempt")}
                for row in csv.DictReader(handle)}
    truths = {event.config_id: {k: v for k, v in event.data.model_dump(mode="json", exclude_unset=True).items()
                               if k != "sim_time_s"}
              for event in SessionReader(session).events(kind="truth")}
    return rows, truths


def compare(session: Path, reference: tuple[dict, dict]) -> dict:
    rows, truths = outcome(session)
    ref_rows, ref_truths = reference
    deltas = [abs(float(rows[c]["square_mean_mm"]) - float(ref_rows[c]["square_mean_mm"]))
              for c in ref_rows if c in rows and rows[c]["square_mean_mm"] and ref_rows[c]["square_mean_mm"]]
    differing = sorted(c for c in set(rows) | set(ref_rows) if rows.get(c) != ref_rows.get(c))
    return {"identical_results": not differing, "identical_truth": truths == ref_truths,
            "configurations_differing": differing, "max_abs_square_diff_mm": max(deltas, default=None)}


class Hogs:
    """``n`` busy processes beside the runs (started and killed by pid here)."""

    def __init__(self, n: int):
        self.processes = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]

    def close(self) -> None:
        for process in self.processes:
            process.kill()
        for process in self.processes:
            process.wait()


def command(plan: Path, out: Path, time_scale: float, *more: str) -> list[str]:
    return [sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan), "--out", str(out), "--yes", "--quiet",
            "--time-scale", f"{time_scale:g}", *more]


def _lines(path: Path) -> int:
    try:
        with open(path, "rb") as handle:
            return sum(1 for _ in handle)
    except FileNotFoundError:
        return 0


def run(argv: list[str], env: dict, kill_at_line: int | None = None, stream: Path | None = None, *,
        cwd: Path = ROOT) -> dict:
    """Run ``argv``; with ``kill_at_line``, SIGKILL it once ``stream`` holds that many lines (if it still runs)."""
    load = os.getloadavg()[0]
    started = time.perf_counter()
    process = subprocess.Popen(argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    killed, seen = False, None
    if kill_at_line is not None:
        while process.poll() is None:
            seen = _lines(stream)
            if seen >= kill_at_line:
                os.kill(process.pid, signal.SIGKILL)
                killed = True
                break
            time.sleep(0.002)
    _, stderr = process.communicate(timeout=1800)
    if not killed and process.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {process.returncode}: {stderr.strip()}")
    out = {"seconds": time.perf_counter() - started, "load_before": load, "killed": killed}
    if killed:
        out["killed_at_line"] = seen
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=2, help="uninterrupted runs per time scale besides the reference")
    parser.add_argument("--kills", type=int, default=4, help="runs killed at a random moment and resumed")
    parser.add_argument("--time-scales", type=float, nargs="+", default=[50.0, 10.0])
    parser.add_argument("--hogs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--source", type=Path, default=ROOT, help="the checkout whose CLI runs (default: this one)")
    parser.add_argument("--out", type=Path, default=ROOT / "scripts" / "results" / "bench_determinism.json")
    args = parser.parse_args()

    from stereo_bench.campaign.session import SessionReader

    source = args.source.resolve()  # python -m puts the working directory first on the path: run from there
    env = {**os.environ, "PYTHONPATH": str(source)}
    rng = random.Random(args.seed)
    work = Path(tempfile.mkdtemp(prefix="bench-determinism-"))
    plan = work / "plan.toml"
    plan.write_text(PLAN)
    rows: list[dict] = []
    hogs = Hogs(args.hogs)
    try:
        reference = work / "reference"
        timing = run(command(plan, reference, 50.0), env, cwd=source)
        expected = outcome(reference)
        reference_lines = _lines(reference / "documents.jsonl")
        rows.append({"run": "reference", "time_scale": 50.0, **timing, "identical_results": True,
                     "identical_truth": True, "configurations_differing": [], "max_abs_square_diff_mm": 0.0})
        print(f"reference: {timing['seconds']:.1f} s, {len(expected[0])} configurations, {reference_lines} documents",
              flush=True)
        cases = [("uninterrupted", scale, None) for scale in args.time_scales for _ in range(args.runs)]
        for _ in range(args.kills):
            scale = rng.choice(args.time_scales)
            cases.append(("kill -9 + resume", scale, rng.randrange(2, reference_lines)))
        for k, (kind, scale, kill_at) in enumerate(cases):
            out = work / f"run{k}"
            timing = run(command(plan, out, scale), env, kill_at_line=kill_at, stream=out / "documents.jsonl",
                         cwd=source)
            row = {"run": kind, "time_scale": scale, **timing}
            if kill_at is not None:
                row["kill_at_line"] = kill_at
                row["completed_before_kill"] = len(SessionReader(out).completed_config_ids()) if (
                    out / "documents.jsonl").exists() else 0
                if timing["killed"]:
                    resumed = run(command(plan, out, scale, "--resume"), env, cwd=source)
                    row["resume_seconds"] = resumed["seconds"]
                    row["approach_moves"] = len(SessionReader(out).events(kind="approach", attempt=None))
            row.update(compare(out, expected))
            rows.append(row)
            killed = f"killed at document {kill_at}, " if row.get("killed") else ""
            print(f"{kind:17s} x{scale:<4g} {killed}"
                  f"results {'identical' if row['identical_results'] else 'DIFFERENT'}, truth "
                  f"{'identical' if row['identical_truth'] else 'DIFFERENT'}", flush=True)
            shutil.rmtree(out, ignore_errors=True)
    finally:
        hogs.close()
        shutil.rmtree(work, ignore_errors=True)

    print()
    print(f"{'run':17s} {'scale':>5s} {'killed at':>12s} {'done':>4s} {'approach':>8s} {'results':>9s} {'truth':>9s}"
          f" {'max |d square| mm':>17s} {'load':>5s}")
    for row in rows:
        killed = (f"doc {row['kill_at_line']}/{reference_lines}" if row.get("killed")
                  else "-" if "kill_at_line" not in row else "finished")
        diff = row["max_abs_square_diff_mm"]
        print(f"{row['run']:17s} {row['time_scale']:5g} {killed:>12s} {row.get('completed_before_kill', '-')!s:>4s} "
              f"{row.get('approach_moves', '-')!s:>8s} "
              f"{'identical' if row['identical_results'] else 'different':>9s} "
              f"{'identical' if row['identical_truth'] else 'different':>9s} "
              f"{'-' if diff is None else f'{diff:.3g}':>17s} {row['load_before']:5.1f}")
    identical = sum(row["identical_results"] and row["identical_truth"] for row in rows[1:])
    print(f"\n{identical} of {len(rows) - 1} runs identical to the reference (results.csv and truth), "
          f"{args.hogs} CPU hogs beside them, {os.cpu_count()} cores")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "plan": PLAN, "source": str(source), "seed": args.seed, "hogs": args.hogs,
        "reference_documents": reference_lines,
        "time_scales": args.time_scales, "cpu_count": os.cpu_count(), "python": platform.python_version(),
        "machine": platform.machine(), "runs": rows, "identical": identical, "compared": len(rows) - 1,
    }, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
