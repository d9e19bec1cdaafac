"""How long ``stereo-bench campaign plan`` takes for 100, 1,000 and 10,000 configurations (issue 9: 10,000 took 509 s;
the goal is under 5 s).

Two shapes of plan, each written to a temporary TOML file and planned twice:

- ``baselines``: N distinct baselines (10 mm + k * 340 / N) at Z = 500 mm, alpha = 90 deg: every configuration a
  new calibration-board range (the case the issue measured);
- ``grid``: N / 10 baselines x 2 distances (400, 600 mm) x 5 angles (alpha 70-90 deg): toed-in rigs too.

Per row: the whole command as a user runs it (``python -m stereo_bench campaign plan FILE --json`` in a new
process: start-up, TOML, validation, the checks ``run`` makes, the plan, the JSON), wall seconds; and in this
process the expansion alone (:func:`stereo_bench.campaign.plan.expand_plan`), wall and CPU seconds. Each row
records ``os.getloadavg()`` before it ran (the machine is shared: compare CPU seconds across loads).

    python scripts/bench_plan.py [--sizes 100 1000 10000] [--out scripts/results/bench_plan.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def plan_text(shape: str, n: int) -> str:
    if shape == "baselines":
        baselines = [round(10.0 + k * 340.0 / n, 6) for k in range(n)]
        distances, alphas = [500.0], [90.0]
    else:
        baselines = [round(10.0 + k * 340.0 / (n // 10), 6) for k in range(n // 10)]
        distances, alphas = [400.0, 600.0], [70.0, 75.0, 80.0, 85.0, 90.0]
    return (f"name = \"bench-{shape}-{n}\"\n[plan]\nbaseline_mm = {baselines!r}\ndistance_mm = {distances!r}\n"
            f"alpha_deg = {alphas!r}\n")


def bench(shape: str, n: int, directory: Path) -> dict:
    from stereo_bench.campaign.config import load_campaign
    from stereo_bench.campaign.plan import expand_plan

    path = directory / f"{shape}_{n}.toml"
    path.write_text(plan_text(shape, n))
    load = os.getloadavg()
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "stereo_bench", "campaign", "plan", str(path), "--json"],
                          capture_output=True, text=True, cwd=ROOT, check=False)
    command_s = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"campaign plan {path} failed ({done.returncode}): {done.stderr.strip()}")
    summary = json.loads(done.stdout)
    config = load_campaign(path)
    wall, cpu = time.perf_counter(), time.process_time()
    configurations = expand_plan(config)
    expand_wall, expand_cpu = time.perf_counter() - wall, time.process_time() - cpu
    assert len(configurations) == summary["n_configurations"] == n
    return {"shape": shape, "configurations": n, "command_s": command_s, "expand_wall_s": expand_wall,
            "expand_cpu_s": expand_cpu, "runnable": summary["runnable"], "infeasible": summary["infeasible"],
            "loadavg_before": list(load), "loadavg_after": list(os.getloadavg())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument("--out", type=Path, default=ROOT / "scripts" / "results" / "bench_plan.json")
    args = parser.parse_args()
    rows = []
    print(f"{'shape':<10} {'configs':>8} {'command s':>10} {'expand s':>9} {'expand CPU s':>12} {'runnable':>9}  load")
    with tempfile.TemporaryDirectory() as tmp:
        for shape in ("baselines", "grid"):
            for n in args.sizes:
                row = bench(shape, n, Path(tmp))
                rows.append(row)
                print(f"{shape:<10} {n:>8} {row['command_s']:>10.2f} {row['expand_wall_s']:>9.2f} "
                      f"{row['expand_cpu_s']:>12.2f} {row['runnable']:>9}  {row['loadavg_before'][0]:.1f}",
                      flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"benchmark": "campaign plan", "python": platform.python_version(),
                                    "machine": platform.machine(), "cpus": os.cpu_count(), "rows": rows},
                                   indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
