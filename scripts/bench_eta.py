"""The progress line's ETA over a whole campaign on the wall clock (issue 24: with the old bar it swung from 44 s to
8 min during paper-exp1): at every configuration's move, the ETA the line shows and the time the run then actually
took to finish, and their relative difference.

Runs the preset (default ``paper-exp1``, ``--time-scale 10`` as the README does) on the simulated bench with
``--yes`` through the CLI's own progress display (``stereo_bench.cli.progress.Progress``, quiet), on the wall clock.
The machine is shared: each run records ``os.getloadavg()`` before and after.

    python scripts/bench_eta.py [--preset paper-exp1] [--time-scale 10] [--out scripts/results/bench_eta.json]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import tempfile
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper-exp1")
    parser.add_argument("--time-scale", type=float, default=10.0)
    parser.add_argument("--out", default="scripts/results/bench_eta.json")
    args = parser.parse_args()

    from stereo_bench.campaign.config import load_preset
    from stereo_bench.campaign.execute import CampaignPlan, run_campaign
    from stereo_bench.cli.progress import Progress

    config = load_preset(args.preset)
    config = config.model_copy(update={"rig": config.rig.model_copy(update={"time_scale": args.time_scale})})
    plan = CampaignPlan.of(config)
    load_before = os.getloadavg()
    progress = Progress(plan, config, quiet=True, stream=io.StringIO(), refresh_s=None)
    with tempfile.TemporaryDirectory() as workdir:
        summary = run_campaign(config, Path(workdir) / "session", yes=True, plan=plan, subscribers=[progress])
    total_s = time.monotonic() - progress.started_s
    rows = [{"configuration": i + 1, "elapsed_s": round(elapsed, 2), "eta_s": round(eta, 2),
             "left_s": round(total_s - elapsed, 2),
             "relative_error": round((eta - (total_s - elapsed)) / (total_s - elapsed), 3)}
            for i, (elapsed, eta) in enumerate(progress.etas)]
    print(f"{'config':>6} {'elapsed s':>9} {'ETA s':>8} {'left s':>8} {'error':>7}")
    for row in rows:
        print(f"{row['configuration']:6d} {row['elapsed_s']:9.1f} {row['eta_s']:8.1f} {row['left_s']:8.1f} "
              f"{row['relative_error']:+7.2f}")
    later = rows[2:]
    rises = [r["configuration"] for previous, r in zip(later, later[1:], strict=False)
             if r["eta_s"] > previous["eta_s"]]
    worst = max(abs(r["relative_error"]) for r in later) if later else None
    print(f"total {total_s:.1f} s ({summary.exit_status}); from the third configuration on: worst |error| "
          f"{worst:.2f}, ETA rose at {rises or 'no configuration'}")
    result = {"preset": args.preset, "time_scale": args.time_scale, "total_s": round(total_s, 2),
              "exit_status": summary.exit_status, "rows": rows, "worst_relative_error_from_third": worst,
              "rises_from_third": rises, "load_before": load_before, "load_after": os.getloadavg(),
              "machine": platform.platform(), "cpus": os.cpu_count()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
