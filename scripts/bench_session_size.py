"""Session size of a campaign with [capture] keep_frames = "all", "measurement" and "none", and what replays.

Records the same campaign (default: the paper-exp1 preset on the default lab bench, motion sped up
by --time-scale: the frames and numbers do not depend on it) once per keep_frames value, and
reports the size of each session (all of it, and its frames), whether the results agree, and what a
replay of each reproduces and how fast.

    python scripts/bench_session_size.py [--preset paper-exp1] [--time-scale 20] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from stereo_bench.campaign.config import campaign_from_dict, load_preset
from stereo_bench.campaign.execute import replay_session, run_campaign
from stereo_bench.campaign.session import SessionReader

ROOT = Path(__file__).resolve().parents[1]
KEEP = ("all", "measurement", "none")


def size_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 1e6 if path.exists() else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper-exp1")
    parser.add_argument("--time-scale", type=float, default=20.0)
    parser.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_session_size.json"))
    args = parser.parse_args()
    base = load_preset(args.preset).model_dump(mode="json")
    rows, results = [], {}
    workdir = Path(tempfile.mkdtemp(prefix="bench-session-size-"))
    try:
        for keep in KEEP:
            data = {**base, "rig": {**base["rig"], "time_scale": args.time_scale},
                    "capture": {**base["capture"], "keep_frames": keep}}
            session = workdir / keep
            started = time.monotonic()
            summary = run_campaign(campaign_from_dict(data), session, yes=True)
            campaign_s = time.monotonic() - started
            reader = SessionReader(session)
            pairs = sum(1 for e in reader.events() if e.kind in ("calibration_view", "measurement_frame"))
            started = time.monotonic()
            replay = replay_session(session)
            replay_s = time.monotonic() - started
            results[keep] = {row["config_id"]: row.get("square_mean_mm") for row in summary.rows}
            rows.append({
                "keep_frames": keep, "status": summary.exit_status, "configurations": len(summary.rows),
                "stereo_pairs": pairs, "session_mb": size_mb(session), "frames_mb": size_mb(session / "frames"),
                "campaign_s": campaign_s, "replay_s": replay_s, "replay_compared": replay.compared,
                "replay_identical": replay.identical, "replay_from_detections": len(replay.from_detections),
                "replay_not_reproducible": len(replay.not_reproducible),
            })
            shutil.rmtree(session)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    same = all(results[keep] == results["all"] for keep in KEEP)
    print(f"{args.preset}: results identical across keep_frames: {same}")
    print(f"{'keep_frames':12s} {'session MB':>11s} {'frames MB':>10s} {'pairs':>6s}  replay")
    for row in rows:
        print(f"{row['keep_frames']:12s} {row['session_mb']:11.1f} {row['frames_mb']:10.1f} {row['stereo_pairs']:6d}  "
              f"{row['replay_identical']}/{row['replay_compared']} identical "
              f"({row['replay_from_detections']} calibrated from recorded detections, "
              f"{row['replay_not_reproducible']} not reproducible) in {row['replay_s']:.1f} s")
    load = list(os.getloadavg())
    print(f"load average (1, 5, 15 min): {' '.join(f'{v:.2f}' for v in load)}")
    with open(args.out, "w") as handle:
        json.dump({"preset": args.preset, "time_scale": args.time_scale, "results_identical": same,
                   "rows": rows, "loadavg_1_5_15": load}, handle, indent=1)


if __name__ == "__main__":
    main()
