"""Calibration views by hand through the campaign runner: ``[capture] calibration_capture = "auto"`` against "enter".

The simulated lab bench (tests/campaigns.py's LAB: 960x540 cameras, B 100 mm, Z 450 mm, one configuration) with
``[sim] presenter = "hand"`` (drivers/sim/hand.py): the board carried by hand from pose to pose, held 0.6-1.8 s,
trembling, sometimes half out of a view first.

- **auto**: the runner streams the cameras at 10 frames per bench second and keeps a view when the ViewSelector
  says still + settled + new + whole in both views, until ``--views`` are kept (the count gate);
- **enter**: the simulated operator presses Enter once per presentation as the hand stops (uniform from 0.3 s
  before the hold to 0.5 s into it); the runner's quality gates judge the calibration as they would at the bench.

Printed per seed: pairs offered and their decisions, views kept, the calibration's stereo RMS (auto: the runner's;
enter: the runner's verdict, and the RMS of its views calibrated without the gates), the square's error, the
presentation time per view (bench clock). Writes JSON.

    .venv/bin/python scripts/bench_autocapture_runner.py [--seeds 5] [--views 8] [--out bench_autocapture_runner.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stereo_bench.campaign.documents import (  # noqa: E402
    CalibrationEvent,
    CalibrationSelectionEvent,
    PresentationTimeEvent,
)
from stereo_bench.campaign.execute.run import run_campaign  # noqa: E402
from stereo_bench.campaign.stream import Collector  # noqa: E402
from tests.campaigns import lab_config  # noqa: E402
from tests.test_autocapture_runner import ONE, ungated_rms  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"  # where the latest run of each benchmark is kept


def run(mode: str, seed: int, views: int, out: Path) -> dict:
    config = lab_config(seed=seed, capture={"calibration_views": views, "calibration_capture": mode,
                                            "coverage_gate": "count"}, sim={"presenter": "hand"}, plan=ONE)
    collected = Collector()
    started = time.perf_counter()
    summary = run_campaign(config, out / f"{mode}-{seed}", yes=True, subscribers=[collected])
    row = summary.rows[0]
    result = {"status": row["status"], "reason": row.get("reason"), "error_mm": row.get("error_mm"),
              "rms_px": row.get("rms_px"), "wall_s": round(time.perf_counter() - started, 1),
              "ungated_rms_px": round(ungated_rms(out / f"{mode}-{seed}", config), 4)}
    for event in collected.of(CalibrationEvent):
        result["rms_px"] = event.data.rms_px
    for event in collected.of(PresentationTimeEvent):
        result["s_per_view"] = round(event.data.seconds / event.data.views, 3)
    for event in collected.of(CalibrationSelectionEvent):
        result.update(offered=event.data.offered, kept=event.data.kept, tally=event.data.tally,
                      ended_by=event.data.ended_by)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--out", default=str(RESULTS / "bench_autocapture_runner.json"))
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for seed in range(args.seeds):
            row = {"seed": seed, **{mode: run(mode, seed, args.views, Path(work)) for mode in ("auto", "enter")}}
            rows.append(row)
            a, e = row["auto"], row["enter"]
            why = ", ".join(f"{k} {v}" for k, v in a["tally"].items() if k != "kept" and v)
            print(f"seed {seed}: auto {a['kept']}/{a['offered']} kept ({why}), RMS {a['rms_px']:.3f} px, "
                  f"error {a['error_mm']:+.4f} mm, {a['s_per_view']:.2f} s/view | enter {e['status']}"
                  + (f" ({e['reason'][:60]}...)" if e["reason"] else f", RMS {e['rms_px']:.3f} px, "
                     f"error {e['error_mm']:+.4f} mm") + f", ungated RMS {e['ungated_rms_px']:.3f} px, "
                  f"{e['s_per_view']:.2f} s/view", flush=True)
    Path(args.out).write_text(json.dumps({
        "benchmark": "bench_autocapture_runner", "views": args.views, "rows": rows,
        "load_average": os.getloadavg(), "cpu_count": os.cpu_count(), "python": platform.python_version()},
        indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
