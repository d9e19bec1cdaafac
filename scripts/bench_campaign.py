"""Campaign overhead on the simulated rig, and replay throughput, with where the time goes per stereo pair.

Runs a campaign in real time (realistic motion speeds: the GRBL emulator's default axis rates and
accelerations, time scale 1) and divides its wall time by the unavoidable hardware time: motion +
settle + exposures as stereo_bench.campaign.plan.estimate_duration predicts them (it times moves
exactly as the emulator does), plus the homing as it happened. Processing (rendering stands in for the sensor and runs
inside the exposure; PNG encoding, detection, calibration, measurement) is overhead unless it
overlaps the hardware time. Then replays the recorded session and reports pairs per second.

Where the time goes is measured by timing the real functions in place (wrapped by this script, not
changed): for each activity, the CPU time it took on every thread (``time.thread_time`` of the
thread that called it: work OpenCV spreads over its own worker threads is not in it; the process
CPU time is), and how much of the runner's own thread (the critical path: what the wall time is
made of) it held.

    python scripts/bench_campaign.py [--profiles ideal lab] [--out FILE] [--keep DIR] [--ui [--repeat N]]
    python scripts/bench_campaign.py --replay SESSION [SESSION ...] [--repeat N] [--out FILE]

--replay replays sessions already recorded (e.g. kept with --keep) and reports the CPU per stereo pair
beside the rate: the CPU does not depend on what else loads the machine, and 2 x pairs / CPU is the
rate two quiet cores allow.

--ui also measures the live page's cost: runs of the default campaign without and with the page
served and a headless client attached (wall and process CPU medians), and the live preview rate
while the cameras are lent.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import shutil
import statistics
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import httpx

from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.execute import CampaignPlan, RunControl, replay_session, run_campaign
from stereo_bench.campaign.operator import SimulatedOperator
from stereo_bench.campaign.plan import estimate_duration
from stereo_bench.campaign.session import SessionReader

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = {
    "name": "bench-campaign",
    "seed": 1,
    "rig": {"time_scale": 1.0},
    "capture": {"calibration_views": 12, "frames_per_config": 3, "settle_s": 0.5},
    "plan": {"baseline_mm": [50, 150, 250], "distance_mm": [400, 600], "alpha_deg": [90]},
}


class Spans:
    """Times named functions in place: per activity, wall and thread-CPU seconds, and the exclusive share
    of each thread (nested activities are subtracted from the one that called them)."""

    def __init__(self):
        self._undo: list[tuple[object, str, object]] = []
        self._local = threading.local()
        self._lock = threading.Lock()
        # (thread name, label) -> [calls, wall_s, exclusive wall_s, cpu_s, exclusive cpu_s]
        self.totals: dict[tuple[str, str], list[float]] = defaultdict(lambda: [0, 0.0, 0.0, 0.0, 0.0])
        self.counts: dict[str, int] = {}

    def wrap(self, owner: object, name: str, label: str) -> None:
        original = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        if isinstance(original, staticmethod):
            raise TypeError(f"{owner}.{name}: static methods are not wrapped")
        spans = self
        # A singledispatchmethod (the runner's step dispatcher) is a descriptor, not a callable: call it bound.
        call = ((lambda *args, **kwargs: original.__get__(args[0], owner)(*args[1:], **kwargs))
                if isinstance(original, functools.singledispatchmethod) else original)

        @functools.wraps(original)
        def timed(*args, **kwargs):
            stack = spans._stack()
            child = [0.0, 0.0]  # time of nested timed calls
            stack.append(child)
            wall0, cpu0 = time.monotonic(), time.thread_time()
            try:
                return call(*args, **kwargs)
            finally:
                wall, cpu = time.monotonic() - wall0, time.thread_time() - cpu0
                stack.pop()
                if stack:
                    stack[-1][0] += wall
                    stack[-1][1] += cpu
                with spans._lock:
                    entry = spans.totals[(threading.current_thread().name, label)]
                    entry[0] += 1
                    entry[1] += wall
                    entry[2] += wall - child[0]
                    entry[3] += cpu
                    entry[4] += cpu - child[1]

        self._undo.append((owner, name, original))
        setattr(owner, name, timed)

    def count(self, owner: type, name: str, label: str) -> None:
        """Count the calls of ``owner.name`` that return something (not None) under ``label``."""
        original = owner.__dict__[name]
        spans = self

        @functools.wraps(original)
        def counted(*args, **kwargs):
            result = original(*args, **kwargs)
            if result is not None:
                with spans._lock:
                    spans.counts[label] = spans.counts.get(label, 0) + 1
            return result

        self._undo.append((owner, name, original))
        setattr(owner, name, counted)

    def _stack(self) -> list:
        if not hasattr(self._local, "stack"):
            self._local.stack = []
        return self._local.stack

    def restore(self) -> None:
        for owner, name, original in reversed(self._undo):
            setattr(owner, name, original)
        self._undo.clear()

    def by_label(self, *, main: str = "MainThread") -> dict[str, dict[str, float]]:
        """Per label: calls, CPU on all threads (exclusive), and exclusive wall time on the main thread."""
        out: dict[str, dict[str, float]] = {}
        for (thread, label), (calls, _wall, excl_wall, _cpu, excl_cpu) in self.totals.items():
            entry = out.setdefault(label, {"calls": 0, "cpu_s": 0.0, "main_thread_s": 0.0})
            entry["calls"] += calls
            entry["cpu_s"] += excl_cpu
            if thread == main:
                entry["main_thread_s"] += excl_wall
        return out


class ThreadCpu:
    """CPU seconds of every thread of this process by Python thread name (Linux /proc), sampled while it runs:
    threads that are not Python's (OpenCV's workers) are summed as one; pools' ``_N`` suffixes are dropped."""

    def __init__(self, period_s: float = 0.1):
        self.period_s = period_s
        self._cpu: dict[int, float] = {}
        self._before: dict[int, float] = {}
        self._names: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-thread-cpu", daemon=True)
        self._tick = os.sysconf("SC_CLK_TCK")

    def __enter__(self) -> ThreadCpu:
        self._sample()
        self._before = dict(self._cpu)  # threads that already ran (the main thread, OpenCV's workers)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    def _sample(self) -> None:
        for thread in threading.enumerate():
            if thread.native_id is not None:
                self._names[thread.native_id] = thread.name.rsplit("_", 1)[0] if thread.name[-1:].isdigit() \
                    else thread.name
        for task in Path("/proc/self/task").iterdir():
            try:
                fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:  # the thread ended
                continue
            self._cpu[int(task.name)] = (int(fields[11]) + int(fields[12])) / self._tick

    def by_name(self) -> dict[str, float]:
        out: dict[str, float] = defaultdict(float)
        for tid, cpu in self._cpu.items():
            out[self._names.get(tid, "other (OpenCV workers, ...)")] += cpu - self._before.get(tid, 0.0)
        return dict(sorted(out.items(), key=lambda item: -item[1]))


def instrument_campaign(spans: Spans) -> None:
    """The activities of a live campaign (see the module docstring)."""
    from drivers.camera.synthetic import SyntheticCamera
    from drivers.rig.rig import GrblRig
    from drivers.rig.status import RigStatus
    from drivers.sim.bench import BenchSimulator
    from drivers.sim.render import StereoRenderer
    from stereo_bench.campaign import session
    from stereo_bench.campaign.bench import Clock

    spans.wrap(GrblRig, "home", "homing (hardware)")
    # move_to only queues the move and returns its status; the motion is the time spent waiting on that status
    spans.wrap(RigStatus, "wait", "motion (hardware)")
    spans.wrap(Clock, "wait", "settle (hardware)")
    spans.wrap(SyntheticCamera, "grab", "exposure wait (hardware)")  # what is left of a grab once the render is out
    spans.wrap(StereoRenderer, "render_view", "render")
    spans.wrap(BenchSimulator, "render", "render (snapshot, other camera's)")
    if hasattr(BenchSimulator, "_prerendered"):  # pairs served from a render ahead (BenchSimulator.stage)
        spans.count(BenchSimulator, "_prerendered", "pairs rendered ahead")
    spans.wrap(StereoRenderer, "__init__", "renderer setup")
    spans.wrap(session.writer, "encode_frame", "encode")  # the name the writer calls (session/ re-exports it)
    spans.wrap(session.SessionWriter, "record", "record/fsync")  # minus the encoding inside it
    instrument_runner(spans)


def instrument_replay(spans: Spans) -> None:
    from stereo_bench.campaign import session

    spans.wrap(session.reader, "decode_frame", "decode")  # the name the reader calls
    spans.wrap(session.SessionReader, "read_bytes", "read")
    instrument_runner(spans)


def instrument_runner(spans: Spans) -> None:
    """What the runner does in a campaign and in a replay alike."""
    from stereo_bench.campaign import runner

    spans.wrap(runner, "detect", "detect (calibration views ahead, measurement frames)")
    spans.wrap(runner.CampaignRunner, "_analyse", "analysis")
    spans.wrap(runner.CampaignRunner, "_calibrate", "analysis")  # per-config: started as the views are taken
    spans.wrap(runner.CampaignRunner, "_sync_recording", "waiting for the recorder")
    spans.wrap(runner.CampaignRunner, "_collect", "waiting for analyses")
    spans.wrap(runner.CampaignRunner, "_execute", "runner (other)")
    spans.wrap(runner.CampaignRunner, "run", "runner (other)")


def per_pair(table: dict[str, dict[str, float]], pairs: int) -> dict[str, dict[str, float]]:
    return {label: {"calls": entry["calls"], "cpu_ms_per_pair": 1e3 * entry["cpu_s"] / pairs,
                    "main_thread_ms_per_pair": 1e3 * entry["main_thread_s"] / pairs}
            for label, entry in sorted(table.items(), key=lambda item: -item[1]["cpu_s"])}


def print_breakdown(title: str, table: dict[str, dict[str, float]], wall_s: float, pairs: int) -> None:
    print(f"  {title + ': per stereo pair, ms':46s} {'CPU (all threads)':>18s} {'runner thread':>14s}")
    accounted = 0.0
    for label, entry in table.items():
        accounted += entry["main_thread_ms_per_pair"]
        print(f"    {label:44s} {entry['cpu_ms_per_pair']:18.1f} {entry['main_thread_ms_per_pair']:14.1f}")
    rest = 1e3 * wall_s / pairs - accounted
    print(f"    {'outside the runner (open, close)':44s} {'':18s} {rest:14.1f}")
    print(f"    {'wall time':44s} {'':18s} {1e3 * wall_s / pairs:14.1f}")


def print_threads(cpu_s: dict[str, float], pairs: int) -> None:
    print("  CPU by thread, ms per pair: " + ", ".join(f"{name} {1e3 * value / pairs:.1f}"
                                                       for name, value in cpu_s.items() if value > 0))


def timed(spans: Spans, instrument, run):
    """(run(), wall s, process CPU s, CPU by thread) with ``spans`` instrumented by ``instrument`` meanwhile."""
    instrument(spans)
    try:
        cpu0, started = time.process_time(), time.monotonic()
        with ThreadCpu() as threads:
            result = run()
        return result, time.monotonic() - started, time.process_time() - cpu0, threads
    finally:
        spans.restore()


def bench_profile(profile: str, keep: Path | None) -> dict:
    config = campaign_from_dict({**CAMPAIGN, "sim": {"profile": profile}})
    plan = CampaignPlan.of(config)
    estimate = estimate_duration(config, plan.configurations, plan.steps)
    workdir = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    session = keep / profile if keep else workdir / "session"
    load_before = list(os.getloadavg())
    try:
        spans = Spans()
        summary, wall_s, cpu_s, threads = timed(spans, instrument_campaign,
                                                lambda: run_campaign(config, session, yes=True, plan=plan))
        reader = SessionReader(session)
        pairs = stereo_pairs(reader)
        # Homing as it happened (the estimate assumes a full travel; the emulator starts near home): from
        # the transcript event (the rig is open) to the home event.
        homing_s = reader.events(kind="home")[0].monotonic - reader.events(kind="transcript")[0].monotonic
        session_mb = sum(p.stat().st_size for p in session.rglob("*") if p.is_file()) / 1e6
        campaign_table = spans.by_label()
        replayed = bench_replay(session, pairs)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    hardware_s = homing_s + estimate.motion_s + estimate.settle_s + estimate.capture_s
    return {
        "profile": profile, "configurations": len(plan.configurations),
        "measured": summary.counts().get("measured", 0), "stereo_pairs": pairs,
        "wall_s": wall_s, "process_cpu_s": cpu_s, "hardware_s": hardware_s,
        "hardware_breakdown_s": {"homing_measured": homing_s, "motion": estimate.motion_s,
                                 "settle": estimate.settle_s, "exposures": estimate.capture_s},
        "wall_over_hardware": wall_s / hardware_s, "target": 1.10, "session_mb": session_mb,
        "campaign_per_pair": per_pair(campaign_table, pairs), "campaign_counts": spans.counts,
        "campaign_thread_cpu_s": threads.by_name(), **replayed,
        "loadavg_before_1_5_15": load_before,
        "loadavg_after_1_5_15": list(os.getloadavg()),  # others share the machine: read the figures with this
    }


def stereo_pairs(reader: SessionReader) -> int:
    return sum(1 for e in reader.events() if e.kind in ("calibration_view", "measurement_frame"))


def bench_replay(session: Path, pairs: int) -> dict:
    """Replay ``session`` once (compared, nothing written): wall, process CPU (per pair: what bounds the rate
    on a given number of quiet cores whatever the load now), the breakdown, and the load beside them."""
    spans = Spans()
    load = list(os.getloadavg())
    replay, replay_s, cpu_s, threads = timed(spans, instrument_replay, lambda: replay_session(session))
    return {
        "replay_s": replay_s, "replay_process_cpu_s": cpu_s, "replay_pairs_per_s": pairs / replay_s,
        "replay_cpu_ms_per_pair": 1e3 * cpu_s / pairs, "replay_cpu_over_wall": cpu_s / replay_s,
        # 2 quiet cores fully used: the rate the CPU per pair allows (the target is >= 60 pairs/s)
        "replay_pairs_per_s_on_2_quiet_cores": 2 * pairs / cpu_s,
        "replay_identical": f"{replay.identical}/{replay.compared}",
        "replay_per_pair": per_pair(spans.by_label(), pairs), "replay_thread_cpu_s": threads.by_name(),
        "replay_loadavg_1_5_15": load,
    }


def print_replay(result: dict, pairs: int) -> None:
    print(f"{'replay':32s} {result['replay_s']:7.2f} s, {result['replay_pairs_per_s']:.1f} pairs/s "
          f"(process CPU {result['replay_process_cpu_s']:.1f} s), {result['replay_identical']} "
          "configurations identical")
    print(f"{'replay CPU per pair':32s} {result['replay_cpu_ms_per_pair']:7.1f} ms (CPU / wall "
          f"{result['replay_cpu_over_wall']:.2f}; 2 quiet cores: "
          f"{result['replay_pairs_per_s_on_2_quiet_cores']:.0f} pairs/s; load at start "
          f"{result['replay_loadavg_1_5_15'][0]:.2f})")
    print_breakdown("replay", result["replay_per_pair"], result["replay_s"], pairs)
    print_threads(result["replay_thread_cpu_s"], pairs)


def replay_only(sessions: list[Path], repeat: int) -> dict:
    """--replay: replay kept sessions ``repeat`` times each; the run with the median CPU per pair is reported."""
    out = {}
    for session in sessions:
        pairs = stereo_pairs(SessionReader(session))
        runs = [bench_replay(session, pairs) for _ in range(repeat)]
        median = sorted(runs, key=lambda run: run["replay_cpu_ms_per_pair"])[len(runs) // 2]
        out[str(session)] = {"stereo_pairs": pairs, **median,
                             "runs_cpu_ms_per_pair": [run["replay_cpu_ms_per_pair"] for run in runs],
                             "runs_pairs_per_s": [run["replay_pairs_per_s"] for run in runs]}
        print(f"[{session}]  {pairs} stereo pairs, {repeat} runs: CPU ms per pair "
              + " ".join(f"{run['replay_cpu_ms_per_pair']:.1f}" for run in runs) + ", pairs/s "
              + " ".join(f"{run['replay_pairs_per_s']:.1f}" for run in runs) + "; the median run:")
        print_replay(median, pairs)
    return out


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
            bench.rig.move_to(
                **{q: v for q, v in configuration.move_request().items() if q != "target_distance_mm"}).wait()
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
    parser.add_argument("--profiles", nargs="+", default=["ideal", "lab"], choices=["ideal", "lab"])
    parser.add_argument("--out", default=str(ROOT / "scripts" / "results" / "bench_campaign.json"))
    parser.add_argument("--keep", metavar="DIR", type=Path, help="keep the recorded sessions here (DIR/<profile>)")
    parser.add_argument("--ui", action="store_true", help="also measure the live page's cost (see the docstring)")
    parser.add_argument("--repeat", type=int, default=3,
                        help="--ui: pairs of runs without and with the page; --replay: runs per session")
    parser.add_argument("--replay", nargs="+", metavar="SESSION", type=Path,
                        help="only replay these recorded sessions (e.g. kept with --keep), --repeat times each")
    args = parser.parse_args()
    if args.replay:
        results = {"cpu_count": os.cpu_count(), "process_nice": os.getpriority(os.PRIO_PROCESS, 0),
                   "replays": replay_only(args.replay, args.repeat)}
        with open(args.out, "w") as handle:
            json.dump(results, handle, indent=1)
        return
    # Recorded because a run at a higher priority (nice -n -15 python scripts/bench_campaign.py) keeps other
    # processes of the machine from preempting it (not other machines sharing its host).
    results = {"cpu_count": os.cpu_count(), "process_nice": os.getpriority(os.PRIO_PROCESS, 0), "profiles": {}}
    for profile in args.profiles:
        result = bench_profile(profile, args.keep)
        results["profiles"][profile] = result
        pairs = result["stereo_pairs"]
        breakdown = result["hardware_breakdown_s"]
        print(f"[{profile}]  (process nice {results['process_nice']})")
        print(f"{'configurations':32s} {result['configurations']} ({result['measured']} measured), "
              f"{pairs} stereo pairs, session {result['session_mb']:.0f} MB")
        print(f"{'hardware time':32s} {result['hardware_s']:7.1f} s  (homing {breakdown['homing_measured']:.1f} "
              f"measured; predicted: motion {breakdown['motion']:.1f}, settle {breakdown['settle']:.1f}, "
              f"exposures {breakdown['exposures']:.1f})")
        print(f"{'wall time':32s} {result['wall_s']:7.1f} s  (process CPU {result['process_cpu_s']:.1f} s)")
        print(f"{'wall / hardware':32s} {result['wall_over_hardware']:7.2f}   (target <= 1.10)")
        print_breakdown("campaign", result["campaign_per_pair"], result["wall_s"], pairs)
        for label, count in result["campaign_counts"].items():
            print(f"    {label:44s} {count}")
        print_threads(result["campaign_thread_cpu_s"], pairs)
        print_replay(result, pairs)
        before, after = (" ".join(f"{v:.2f}" for v in result[key])
                         for key in ("loadavg_before_1_5_15", "loadavg_after_1_5_15"))
        print(f"{'load average (1, 5, 15 min)':32s} before {before}, after {after}")
    if args.ui:
        config = campaign_from_dict(CAMPAIGN)
        workdir = Path(tempfile.mkdtemp(prefix="bench-campaign-ui-"))
        try:
            ui = ui_overhead(config, CampaignPlan.of(config), workdir, args.repeat)
            ui_rate = live_preview_rate(config)
        finally:
            shutil.rmtree(workdir, ignore_errors=True)
        results["ui"] = {**ui, "idle_previews": ui_rate}
        print(f"{'wall without the page':32s} {' '.join(f'{w:.1f}' for w in ui['wall_s_without_page'])} s")
        last = ui["client"][-1]
        print(f"{'wall with page + client':32s} {' '.join(f'{w:.1f}' for w in ui['wall_s_with_page'])} s  "
              f"({last['previews_fetched']} preview pairs fetched, {last['events']} events)")
        print(f"{'with / without (medians)':32s} {ui['median_ratio']:7.3f}   (target <= 1.05)")
        print(f"{'CPU s without / with the page':32s} {statistics.median(ui['cpu_s_without_page']):.1f} / "
              f"{statistics.median(ui['cpu_s_with_page']):.1f} s  (ratio {ui['cpu_median_ratio']:.3f})")
        print(f"{'live previews while idle':32s} {ui_rate['live_previews_per_s']:7.1f} /s at "
              f"{ui_rate['image_size'][0]}x{ui_rate['image_size'][1]} (client fetched "
              f"{ui_rate['fetched_by_client_per_s']:.1f}/s; target >= 5)")
    with open(args.out, "w") as handle:
        json.dump(results, handle, indent=1)


if __name__ == "__main__":
    main()
