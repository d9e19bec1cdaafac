"""Campaign overhead on the simulated rig, and replay throughput.

Runs a campaign in real time (realistic motion speeds: the GRBL emulator's default axis rates and
accelerations, time scale 1) and divides its wall time by the unavoidable hardware time: motion +
settle + exposures as stereo_bench.campaign.plan.estimate_duration predicts them (it times moves
exactly as the emulator does), plus the homing as it happened. Processing (rendering stands in for the sensor and runs
inside the exposure; PNG encoding, detection, calibration, measurement) is overhead unless it
overlaps the hardware time. Then replays the recorded session and reports pairs per second.

    python scripts/bench_campaign.py [--out bench_campaign.json] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.execute import CampaignPlan, replay_session, run_campaign
from stereo_bench.campaign.plan import estimate_duration
from stereo_bench.campaign.session import SessionReader

CAMPAIGN = {
    "name": "bench-campaign",
    "seed": 1,
    "rig": {"time_scale": 1.0},
    "capture": {"calibration_views": 12, "frames_per_config": 3, "settle_s": 0.5},
    "plan": {"baseline_mm": [50, 150, 250], "distance_mm": [400, 600], "alpha_deg": [90]},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench_campaign.json")
    parser.add_argument("--keep", metavar="DIR", help="keep the recorded session here")
    args = parser.parse_args()
    config = campaign_from_dict(CAMPAIGN)
    plan = CampaignPlan.of(config)
    configurations = plan.configurations
    estimate = estimate_duration(config, configurations, plan.steps)
    workdir = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    session = Path(args.keep) if args.keep else workdir / "session"
    try:
        started = time.monotonic()
        summary = run_campaign(config, session, yes=True, plan=plan)
        wall_s = time.monotonic() - started
        reader = SessionReader(session)
        pairs = sum(1 for e in reader.events() if e["kind"] in ("calibration_view", "measurement_frame"))
        # Homing as it happened (the estimate assumes a full travel; the emulator starts near home): from
        # the transcript event (the rig is open) to the home event.
        homing_s = reader.events(kind="home")[0]["monotonic"] - reader.events(kind="transcript")[0]["monotonic"]
        started = time.monotonic()
        replay = replay_session(session)
        replay_s = time.monotonic() - started
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    hardware_s = homing_s + estimate.motion_s + estimate.settle_s + estimate.capture_s
    result = {
        "configurations": len(configurations), "measured": summary.counts().get("measured", 0),
        "stereo_pairs": pairs, "wall_s": wall_s, "hardware_s": hardware_s,
        "hardware_breakdown_s": {"homing_measured": homing_s, "motion": estimate.motion_s,
                                 "settle": estimate.settle_s, "exposures": estimate.capture_s},
        "wall_over_hardware": wall_s / hardware_s, "target": 1.10,
        "replay_s": replay_s, "replay_pairs_per_s": pairs / replay_s,
        "replay_identical": f"{replay.identical}/{replay.compared}",
        "loadavg_1_5_15": list(os.getloadavg()),  # others share the machine: read the figures with this
    }
    print(f"{'configurations':32s} {len(configurations)} ({result['measured']} measured), {pairs} stereo pairs")
    print(f"{'hardware time':32s} {hardware_s:7.1f} s  (homing {homing_s:.1f} measured; predicted: motion "
          f"{estimate.motion_s:.1f}, settle {estimate.settle_s:.1f}, exposures {estimate.capture_s:.1f})")
    print(f"{'wall time':32s} {wall_s:7.1f} s")
    print(f"{'wall / hardware':32s} {result['wall_over_hardware']:7.2f}   (target <= 1.10)")
    print(f"{'replay':32s} {replay_s:7.1f} s, {result['replay_pairs_per_s']:.1f} pairs/s, "
          f"{result['replay_identical']} configurations identical")
    print(f"{'load average (1, 5, 15 min)':32s} {' '.join(f'{v:.2f}' for v in result['loadavg_1_5_15'])}")
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=1)


if __name__ == "__main__":
    main()
