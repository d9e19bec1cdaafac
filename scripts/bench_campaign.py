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
import statistics
import tempfile
import threading
import time
from pathlib import Path

import httpx

from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.execute import CampaignPlan, RunControl, replay_session, run_campaign
from stereo_bench.campaign.operator import SimulatedOperator
from stereo_bench.campaign.plan import estimate_duration
from stereo_bench.campaign.session import SessionReader

CAMPAIGN = {
    "name": "bench-campaign",
    "seed": 1,
    "rig": {"time_scale": 1.0},
    "capture": {"calibration_views": 12, "frames_per_config": 3, "settle_s": 0.5},
    "plan": {"baseline_mm": [50, 150, 250], "distance_mm": [400, 600], "alpha_deg": [90]},
}


class HeadlessClient:
    """What the page's script does, without a browser: read the state stream, fetch each new preview pair."""

    def __init__(self, base_url: str):
        self.base_url = base_url
        self.events = self.previews = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> HeadlessClient:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def _run(self) -> None:
        shown = 0
        with httpx.Client(base_url=self.base_url, timeout=10) as fetch, \
                httpx.Client(base_url=self.base_url, timeout=None) as stream_client, \
                stream_client.stream("GET", "/api/events") as stream:
            event = "state"
            for line in stream.iter_lines():
                if self._stop.is_set():
                    return
                if line.startswith("event: "):
                    event = line[7:]
                if not line.startswith("data: "):
                    continue
                self.events += 1
                data = json.loads(line[6:])
                preview = (data if event == "preview" else data.get("preview")) or {}  # a preview event: its meta
                if preview.get("version", 0) > shown:
                    shown = preview["version"]
                    for side in ("left", "right"):
                        fetch.get(f"/preview/{side}.jpg?v={shown}")
                    self.previews += 1


def run_with_page(config, session: Path, plan) -> tuple:
    """The campaign with the live page served and a headless client attached; (summary, client, page stats)."""
    from stereo_bench.live.page import LivePage

    control = RunControl()
    page = LivePage.for_campaign(config, session_dir=session, control=control).start()
    client = HeadlessClient(f"http://127.0.0.1:{page.server.port}").start()
    try:
        while not page.previews.watched:
            time.sleep(0.01)
        summary = run_campaign(config, session, plan=plan, control=control, subscribers=[page.state],
                               frame_subscribers=[page.previews.captured],
                               operators=[SimulatedOperator(), page.operator])
    finally:
        client.stop()
        page.stop()
    return summary, client, dict(page.previews.stats)


def live_preview_rate(config, seconds: float = 5.0) -> dict:
    """Live previews per second while the cameras are lent (as while the runner waits for the operator)."""
    from stereo_bench.campaign.bench import open_bench
    from stereo_bench.live.page import LivePage

    plan = CampaignPlan.of(config)
    configuration = plan.configurations[0]
    page = LivePage.for_campaign(config, session_dir=None).start()
    try:
        with open_bench(config, operators=[]) as bench:
            bench.rig.home()
            bench.rig.move_to(**{q: v for q, v in configuration.move_request().items() if q != "target_distance_mm"})
            bench.presenter.begin_configuration(configuration)
            bench.presenter.prepare_calibration(config.capture.calibration_views)
            bench.presenter.present_calibration_view(0)
            page.use_bench(bench)
            client = HeadlessClient(f"http://127.0.0.1:{page.server.port}").start()
            with bench.camera_gate.lent():
                time.sleep(1.0)  # renderers warm, client connected
                first, started = page.previews.stats["live"], time.monotonic()
                fetched = client.previews
                time.sleep(seconds)
                grabbed = page.previews.stats["live"] - first
                elapsed = time.monotonic() - started
                fetched = client.previews - fetched
            client.stop()
    finally:
        page.stop()
    return {"live_previews_per_s": grabbed / elapsed, "fetched_by_client_per_s": fetched / elapsed,
            "image_size": list(config.cameras.optics.camera_model("left").image_size), "target": 5.0}


def ui_overhead(config, plan, workdir: Path, repeat: int) -> dict:
    walls: dict[str, list[float]] = {"without": [], "with": []}
    cpus: dict[str, list[float]] = {"without": [], "with": []}  # this process, all threads: the load-proof part
    clients, loads = [], []
    for i in range(repeat):
        for mode in ("without", "with"):
            session = workdir / f"{mode}-{i}"
            loads.append((mode, os.getloadavg()[0]))  # others share the machine: the load each run started at
            started, cpu_started = time.monotonic(), time.process_time()
            if mode == "with":
                summary, client, stats = run_with_page(config, session, plan)
                clients.append({"events": client.events, "previews_fetched": client.previews, **stats})
            else:
                summary = run_campaign(config, session, yes=True, plan=plan)
            walls[mode].append(time.monotonic() - started)
            cpus[mode].append(time.process_time() - cpu_started)
            assert summary.exit_status == "success", summary
            shutil.rmtree(session, ignore_errors=True)
    ratio = statistics.median(walls["with"]) / statistics.median(walls["without"])
    cpu_ratio = statistics.median(cpus["with"]) / statistics.median(cpus["without"])
    return {"wall_s_without_page": walls["without"], "wall_s_with_page": walls["with"], "median_ratio": ratio,
            "cpu_s_without_page": cpus["without"], "cpu_s_with_page": cpus["with"], "cpu_median_ratio": cpu_ratio,
            "target": 1.05, "client": clients, "loadavg_1min_at_start": loads}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench_campaign.json")
    parser.add_argument("--keep", metavar="DIR", help="keep the recorded session here")
    parser.add_argument("--ui", action="store_true", help="also measure the live page's cost (see the docstring)")
    parser.add_argument("--repeat", type=int, default=3, help="--ui: pairs of runs without and with the page")
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
        ui = ui_overhead(config, plan, workdir, args.repeat) if args.ui else None
        ui_rate = live_preview_rate(config) if args.ui else None
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
    if ui is not None:
        result["ui"] = {**ui, "idle_previews": ui_rate}
    print(f"{'configurations':32s} {len(configurations)} ({result['measured']} measured), {pairs} stereo pairs")
    print(f"{'hardware time':32s} {hardware_s:7.1f} s  (homing {homing_s:.1f} measured; predicted: motion "
          f"{estimate.motion_s:.1f}, settle {estimate.settle_s:.1f}, exposures {estimate.capture_s:.1f})")
    print(f"{'wall time':32s} {wall_s:7.1f} s")
    print(f"{'wall / hardware':32s} {result['wall_over_hardware']:7.2f}   (target <= 1.10)")
    print(f"{'replay':32s} {replay_s:7.1f} s, {result['replay_pairs_per_s']:.1f} pairs/s, "
          f"{result['replay_identical']} configurations identical")
    if ui is not None:
        print(f"{'wall without the page':32s} {' '.join(f'{w:.1f}' for w in ui['wall_s_without_page'])} s")
        print(f"{'wall with page + client':32s} {' '.join(f'{w:.1f}' for w in ui['wall_s_with_page'])} s  "
              f"({ui['client'][-1]['previews_fetched']} preview pairs fetched, {ui['client'][-1]['events']} events)")
        print(f"{'with / without (medians)':32s} {ui['median_ratio']:7.3f}   (target <= 1.05)")
        print(f"{'CPU s without / with the page':32s} {statistics.median(ui['cpu_s_without_page']):.1f} / "
              f"{statistics.median(ui['cpu_s_with_page']):.1f} s  (ratio {ui['cpu_median_ratio']:.3f})")
        print(f"{'live previews while idle':32s} {ui_rate['live_previews_per_s']:7.1f} /s at "
              f"{ui_rate['image_size'][0]}x{ui_rate['image_size'][1]} (client fetched "
              f"{ui_rate['fetched_by_client_per_s']:.1f}/s; target >= 5)")
    print(f"{'load average (1, 5, 15 min)':32s} {' '.join(f'{v:.2f}' for v in result['loadavg_1_5_15'])}")
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=1)


if __name__ == "__main__":
    main()
