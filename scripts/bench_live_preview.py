"""The live page's preview rate while the bench is idle, and where one preview's time goes.

Opens the benchmark campaign's simulated bench (``scripts/bench_campaign.py``'s CAMPAIGN: two
1920x1080 cameras, the ``lab`` profile's defaults), lends its cameras as the runner does while it
waits for the operator, serves the live page with a headless client attached (what the page's script
does, without a browser: it reads the state stream and fetches every new preview pair), and counts
over ``--seconds`` the live previews made and fetched, for three scenes: a calibration view, the
measured target, and no board at all. ``--busy N`` adds N CPU-bound processes meanwhile, each in a
session of its own (as another user's jobs: the kernel's autogroups share the CPU between sessions),
to see the rate on a loaded machine. Then times each stage of one preview on this thread: the render
at the camera's size and at the preview's width, shrinking, the overlay's detection (board found,
board missing), the unchanged-view check, drawing and JPEG.

    python scripts/bench_live_preview.py [--seconds 10] [--busy 0] [--out scripts/results/bench_live_preview.json]
    PYTHONPATH=OTHER_CHECKOUT python scripts/bench_live_preview.py --rates-only --out ...   # the same, other code

Besides the load average, the number of threads runnable on the machine is sampled while measuring
(``procs_running``): the load average lags by a minute.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import time
from pathlib import Path

import cv2
from bench_campaign import CAMPAIGN, HeadlessClient

from stereo_bench.campaign.bench import open_bench
from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.execute import CampaignPlan
from stereo_bench.live import preview as P
from stereo_bench.live.page import LivePage

SCENES = ("calibration view", "target", "no board")


def _burn(stop_at: float) -> None:
    os.setsid()  # a session (and so an autogroup) of its own, as another user's job
    while time.monotonic() < stop_at:
        pass


def show(bench, configuration, scene: str) -> None:
    presenter = bench.presenter
    presenter.begin_configuration(configuration)
    if scene == "calibration view":
        presenter.prepare_calibration(12)
        presenter.present_calibration_view(0)
    elif scene == "target":
        presenter.present_target(0)
    else:
        presenter.bench.show(None)


def idle_rate(page: LivePage, seconds: float, busy: int) -> dict:
    """Live previews made and fetched per second with the cameras lent and a client attached."""
    client = HeadlessClient(f"http://127.0.0.1:{page.server.port}").start()
    burners = []
    try:
        time.sleep(1.0)  # the client connected, the preview renderers built
        if busy:
            context = multiprocessing.get_context("fork")
            burners = [context.Process(target=_burn, args=(time.monotonic() + seconds + 2.0,)) for _ in range(busy)]
            for burner in burners:
                burner.start()
            time.sleep(1.0)
        stats = page.previews.stats
        before = {key: stats.get(key, 0) for key in ("live", "live_cpu_s", "live_detections", "live_reused")}
        fetched, load_before = client.previews, os.getloadavg()
        started, running = time.monotonic(), []
        while time.monotonic() - started < seconds:
            time.sleep(0.25)
            running.append(procs_running())
        elapsed = time.monotonic() - started
        after = {key: stats.get(key, 0) - value for key, value in before.items()}
        fetched = client.previews - fetched
    finally:
        client.stop()
        for burner in burners:
            burner.join()
    return {"live_previews_per_s": after["live"] / elapsed, "fetched_by_client_per_s": fetched / elapsed,
            "cpu_ms_per_preview": 1e3 * after["live_cpu_s"] / max(after["live"], 1),
            "overlay_detections": after["live_detections"], "overlay_reused": after["live_reused"],
            "busy_processes": busy, "runnable_threads_median": statistics.median(running),
            "loadavg_before": list(load_before), "loadavg_after": list(os.getloadavg())}


def procs_running() -> int:
    """Threads running or ready to run on the whole machine now (the load average is its 1-minute mean)."""
    with open("/proc/stat") as stat:
        return next(int(line.split()[1]) for line in stat if line.startswith("procs_running"))


def median_ms(work, repeat: int = 15) -> float:
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        work()
        times.append(time.perf_counter() - started)
    return 1e3 * statistics.median(times)


def stages(bench, boards) -> dict:
    """Milliseconds per stage of one preview pair (medians), on this thread."""
    full_left, _, _ = bench.grab_preview()
    small_left, _, _ = bench.grab_preview(P.PREVIEW_WIDTH_PX)
    grey = P._grey(small_left)
    shrunk, _ = P._small(full_left, gray=True)
    thumbnail = P.thumbnail(grey)
    bgr = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    found = P._detect_or_none(grey, boards["calibration"])
    assert found is not None, "the calibration board should be in view"

    def draw_and_encode():
        image = bgr.copy()
        P.draw_detection(image, found, found, boards["calibration"], P.PREVIEW_WIDTH_PX / full_left.shape[1])
        cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, P.JPEG_QUALITY])

    return {
        "render_pair_full_size": median_ms(lambda: bench.grab_preview(), 7),
        "render_pair_preview_width": median_ms(lambda: bench.grab_preview(P.PREVIEW_WIDTH_PX)),
        "shrink_full_to_preview_per_side": median_ms(lambda: P._small(full_left, gray=True)),
        "detect_found_per_side_preview_width": median_ms(lambda: P._detect_or_none(grey, boards["calibration"])),
        "detect_found_per_side_full_size": median_ms(lambda: P._detect_or_none(full_left, boards["calibration"]), 7),
        "detect_missing_per_side_preview_width": median_ms(lambda: P._detect_or_none(grey, boards["target"]), 7),
        "unchanged_check_per_side": median_ms(lambda: P.unchanged(thumbnail, P.thumbnail(grey))),
        "draw_and_jpeg_per_side": median_ms(draw_and_encode),
        "shrunk_size": [int(shrunk.shape[1]), int(shrunk.shape[0])],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring time per scene")
    parser.add_argument("--busy", type=int, default=0, help="CPU-bound processes (own sessions) while measuring")
    parser.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    parser.add_argument("--rates-only", action="store_true",
                        help="no stage timings (they need this branch's functions): to measure another checkout, "
                             "PYTHONPATH=CHECKOUT python scripts/bench_live_preview.py --rates-only")
    parser.add_argument("--out", default="scripts/results/bench_live_preview.json")
    args = parser.parse_args()
    config = campaign_from_dict(CAMPAIGN)
    configuration = CampaignPlan.of(config).configurations[0]
    boards = {"calibration": config.calibration_board.build(), "target": config.target.build()}
    page = LivePage.for_campaign(config, session_dir=None).start()
    rates = {}
    try:
        with open_bench(config, operators=[]) as bench:
            bench.rig.home()
            bench.rig.move_to(
                **{q: v for q, v in configuration.move_request().items() if q != "target_distance_mm"}).wait()
            page.use_bench(bench)
            with bench.camera_gate.lent():
                for scene in args.scenes:
                    show(bench, configuration, scene)
                    rates[scene] = idle_rate(page, args.seconds, args.busy)
                breakdown = {}
                if not args.rates_only:
                    show(bench, configuration, "calibration view")
                    with bench.camera_gate.borrowed():
                        breakdown = stages(bench, boards)
    finally:
        page.stop()
    width, height = config.cameras.optics.camera_model("left").image_size
    result = {"code": str(Path(P.__file__).parents[2]), "image_size": [width, height],
              "preview_width_px": P.PREVIEW_WIDTH_PX, "live_fps_asked": P.LIVE_FPS,
              "target_per_s": 5.0, "seconds_per_scene": args.seconds, "idle": rates, "stage_ms": breakdown,
              "cpu_count": os.cpu_count(), "loadavg_1_5_15": list(os.getloadavg())}
    print(f"live previews while idle, {width}x{height} cameras, client attached, {args.busy} busy processes:")
    for scene, rate in rates.items():
        print(f"  {scene:18s} {rate['live_previews_per_s']:5.1f} /s made, {rate['fetched_by_client_per_s']:5.1f} /s "
              f"fetched, {rate['cpu_ms_per_preview']:5.1f} ms CPU each ({rate['overlay_detections']} detections, "
              f"{rate['overlay_reused']} reused); {rate['runnable_threads_median']:g} runnable, load "
              f"{rate['loadavg_before'][0]:.1f} -> {rate['loadavg_after'][0]:.1f}")
    if breakdown:
        print("one preview, by stage (ms, median):")
    for stage, value in breakdown.items():
        if stage != "shrunk_size":
            print(f"  {stage:40s} {value:7.1f}")
    print(f"load average (1, 5, 15 min): {' '.join(f'{v:.2f}' for v in result['loadavg_1_5_15'])}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=1)


if __name__ == "__main__":
    main()
