"""The live page's previews: live grabs on a thread of their own (normal priority, never behind the captured
frames and the coverage), small and cheap (rendered at the preview's width, the overlay's detection reused
while the view has not changed), never overlapping a capture, and a late frame never shown over a newer one."""

from __future__ import annotations

import os
import threading
import time

import cv2
import numpy as np
import pytest

from stereo_bench.campaign.camera_gate import CameraGate
from stereo_bench.live import preview as preview_module
from stereo_bench.live.preview import PREVIEW_WIDTH_PX, WORKER_NICE, Pair, Previews, thumbnail, unchanged
from stereo_bench.vision.detect import detect
from tests.campaigns import small_config

TARGET = small_config().target.build()  # 9 x 6 corners


def board_frame(shift_px: float = 0.0, *, seed: int = 0, noise_dn: float = 2.0) -> np.ndarray:
    """A 640x360 grey frame with the small campaign's target, moved right by ``shift_px``, and sensor noise."""
    texture = TARGET.texture(px_per_square=30).image.astype(np.float32)
    frame = np.full((360, 640), 128, np.float32)
    height, width = texture.shape
    frame[40:40 + height, 120:120 + width] = texture
    frame = cv2.warpAffine(frame, np.float32([[1, 0, shift_px], [0, 1, 0]]), (640, 360), flags=cv2.INTER_LINEAR,
                           borderValue=128)
    frame += np.random.default_rng(seed).normal(0.0, noise_dn, frame.shape)
    return np.clip(np.round(frame), 0, 255).astype(np.uint8)


class StillBench:
    """A bench whose cameras see ``self.frame`` (fresh noise at every grab) and are lent for good."""

    def __init__(self, frame_of=board_frame):
        self.camera_gate = CameraGate()
        self.frame_of = frame_of
        self.shift_px = 0.0
        self.grabs = 0
        self.widths: list[int | None] = []

    def grab_preview(self, width_px: int | None = None):
        self.grabs += 1
        self.widths.append(width_px)
        image = self.frame_of(self.shift_px, seed=self.grabs)
        return image, image, 0.0


def wait_for(condition, timeout_s: float = 10.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out{' waiting for ' + what if what else ''}"
        time.sleep(0.01)


@pytest.fixture
def watched_previews():
    """Previews of a StillBench (cameras lent), with a browser watching; yields (previews, bench, encoded)."""
    encoded = []
    previews = Previews({"target": TARGET, "calibration": small_config().calibration_board.build()},
                        on_encoded=encoded.append, live_fps=50).start()
    bench = StillBench()
    previews.bench = bench
    previews.watchers(+1)
    with bench.camera_gate.lent():
        yield previews, bench, encoded
    previews.stop()


def _nice_of(thread: threading.Thread) -> int:
    return os.getpriority(os.PRIO_PROCESS, thread.native_id)


@pytest.mark.skipif(not hasattr(os, "getpriority") or not os.path.isdir("/proc/self/task"),
                    reason="per-thread nice values are Linux's")
def test_live_grabs_run_at_the_process_priority_and_the_captured_frames_lower(watched_previews):
    previews, _, encoded = watched_previews
    wait_for(lambda: encoded)
    threads = {thread.name: thread for thread in previews._threads}
    process_nice = os.getpriority(os.PRIO_PROCESS, 0)
    assert _nice_of(threads["live-previews"]) == process_nice  # was nice 10, shared with everything else
    assert _nice_of(threads["live-captured"]) == min(19, process_nice + WORKER_NICE)


def test_a_slow_coverage_detection_does_not_hold_up_the_live_previews(watched_previews, monkeypatch):
    previews, bench, encoded = watched_previews
    slow, release, done = threading.Event(), threading.Event(), threading.Event()

    def slow_coverage(config_id, index, pair):
        slow.set()
        release.wait(120)  # a loaded machine, a big board: it lasts until the test has seen what it waits for
        done.set()

    monkeypatch.setattr(previews, "_coverage", slow_coverage)
    wait_for(lambda: encoded)

    class View:
        kind, config_id = "calibration_view", "B100_Z450_A90"

        class data:  # noqa: N801 - stands in for the document's data model
            index, dt_s = 0, 0.0

    previews.captured(View(), {"left": board_frame(), "right": board_frame()})
    try:
        assert slow.wait(30), "the coverage detection never started"
        live_before = previews.stats["live"]
        # Counted while the detection still runs, not over a fixed sleep (a loaded machine grabs fewer in one).
        wait_for(lambda: previews.stats["live"] - live_before >= 5, timeout_s=30,
                 what="5 live previews during the coverage detection")  # one thread: none until it was done
        assert not done.is_set()
    finally:
        release.set()


def test_the_overlay_is_detected_again_only_when_the_view_changes(watched_previews):
    previews, bench, encoded = watched_previews
    wait_for(lambda: previews.stats["live"] >= 10)
    assert previews.stats["live_detections"] == 1  # noise alone is no change: the first detection is reused
    first = encoded[-1]
    assert first.meta["corners"] == {"left": 54, "right": 54} and bench.widths[-1] == PREVIEW_WIDTH_PX
    before = previews._last_live.detections["left"].corners_px.copy()
    bench.shift_px = 1.0  # the board moves by one preview pixel
    wait_for(lambda: previews.stats["live_detections"] >= 2)
    after = previews._last_live.detections["left"].corners_px
    np.testing.assert_allclose(after - before, np.tile([1.0, 0.0], (54, 1)), atol=0.15)  # the corners follow
    wait_for(lambda: previews.stats["live"] >= 25)
    assert previews.stats["live_detections"] == 2


class SteppedClock:
    """The previews' clock (``preview.time``), moved by the test alone: a live grab is due each time it is moved on
    by more than a period, and a second has passed when the test has moved it a second on, not the wall clock."""

    def __init__(self, now_s: float = 1000.0):
        self.now_s = now_s
        self.thread_time, self.time, self.sleep = time.thread_time, time.time, time.sleep

    def monotonic(self) -> float:
        return self.now_s


def test_a_view_without_a_board_is_searched_again_once_a_second(monkeypatch):
    clock = SteppedClock()
    monkeypatch.setattr(preview_module, "time", clock)
    encoded = []
    previews = Previews({"target": TARGET}, on_encoded=encoded.append, live_fps=50).start()
    bench = StillBench(frame_of=lambda shift, seed: np.random.default_rng(seed).normal(128, 2, (360, 640))
                       .astype(np.uint8))
    previews.bench = bench
    previews.watchers(+1)
    step_s = 0.25  # a frame every quarter second of the previews' clock (exact in binary: 4 steps are 1 s)
    try:
        with bench.camera_gate.lent():
            wait_for(lambda: len(encoded) == 1, timeout_s=30, what="the first live preview")
            for n in range(2, 14):  # 3 s more: a frame each time the clock is moved on, shown before the next
                clock.now_s += step_s
                wait_for(lambda n=n: len(encoded) >= n, timeout_s=30, what=f"live preview {n}")
    finally:
        previews.stop()
    # Frames keep coming while the search for a board is retried only once a second: searched at 0, 1, 2 and 3 s
    # (RETRY_MISS_S), the 9 frames between show the miss again; by the previews' clock, so no machine's load counts.
    assert preview_module.RETRY_MISS_S == 4 * step_s
    assert encoded[-1].meta["board"] is None and previews.stats["live"] == len(encoded) == 13
    assert previews.stats["live_detections"] == 4


def test_thumbnails_tell_noise_from_a_moved_board():
    still = thumbnail(board_frame(seed=1, noise_dn=5.0))
    assert unchanged(still, thumbnail(board_frame(seed=2, noise_dn=5.0)))  # a noisy camera, nothing moved
    assert not unchanged(still, thumbnail(board_frame(0.34, seed=2, noise_dn=5.0)))  # a third of a pixel
    assert not unchanged(still, thumbnail(board_frame(seed=2) // 2))  # the light went down


def test_a_captured_pair_older_than_the_live_preview_shown_is_not_shown():
    encoded = []
    previews = Previews({"target": TARGET}, on_encoded=encoded.append)  # not started: called directly
    earlier = Pair(left=board_frame(), right=board_frame(), dt_s=0.0, source="captured", label="measurement frame 1",
                   board="target")
    later = Pair(left=board_frame(3.0), right=board_frame(3.0), dt_s=0.0, source="live", label="live")
    assert earlier.stamp <= later.stamp
    previews._encode(later)
    previews._encode(earlier)  # the low-priority thread got to it late
    assert [e.meta["source"] for e in encoded] == ["live"] and previews.stats["stale"] == 1
    assert previews.encoded.meta["source"] == "live"


def test_the_simulated_bench_renders_a_preview_at_the_preview_width():
    from drivers.sim.bench import BenchSimulator
    from stereo_bench.geometry import CameraModel, board_pose_facing_rig

    camera = CameraModel.from_sensor()  # 1920 x 1080
    with BenchSimulator(left=camera, right=camera) as sim:
        sim.show(TARGET, board_pose_facing_rig(distance_mm=600.0, board_size_mm=TARGET.grid_size_mm))
        full, small = sim.preview("left"), sim.preview("left", width_px=640)
        frames_rendered = dict(sim._scene.frames_rendered)
    assert full.shape == (1080, 1920) and small.shape == (360, 640)
    assert frames_rendered == {"left": 0, "right": 0}  # previews are not frames of the scene
    # The same view in a third of the pixels: the corners where the full frame has them, divided by 3.
    in_full, in_small = detect(full, TARGET), detect(small, TARGET)
    np.testing.assert_allclose(in_small.corners_px, (in_full.corners_px + 0.5) / 3 - 0.5, atol=0.1)


class UnhurriedOperator:
    """Takes ``seconds`` over every prompt (the live page's previews run meanwhile), then continues. Given
    ``grabs`` (how many live grabs were made so far), it also waits for one made during the prompt (on a loaded
    machine ``seconds`` may pass before the previews' first grab); after ``timeout_s`` without one it counts the
    prompt in ``missed`` and waits no more at the prompts that follow."""

    name = "unhurried"

    def __init__(self, seconds: float, grabs=None, timeout_s: float = 30.0):
        self.seconds, self.grabs, self.timeout_s = seconds, grabs, timeout_s
        self.missed = 0

    def offer(self, ticket) -> None:
        before = None if self.grabs is None else self.grabs()
        time.sleep(self.seconds)
        deadline = time.monotonic() + self.timeout_s
        while self.grabs is not None and not self.missed and self.grabs() == before:
            if time.monotonic() > deadline:
                self.missed += 1
            time.sleep(0.01)
        ticket.answer(self.name, "continue")

    def withdraw(self, ticket) -> None:
        return None


@pytest.mark.slow  # the small campaign, with 0.2 s at each of its ~20 prompts (~10 s)
def test_a_campaign_watched_live_records_what_one_without_a_page_records(tmp_path, small_reference):
    """The page's own live thread, at every prompt: its grabs never overlap a capture and change nothing."""
    from stereo_bench.campaign.execute import RunControl, run_campaign
    from stereo_bench.campaign.session import SessionReader
    from stereo_bench.live.page import LivePage
    from tests.campaigns import numbers
    from tests.test_runner_controls import prompting_bench

    grabbing = threading.Event()
    widths, overlaps = [], []

    def factory(config, **options):
        bench = prompting_bench(config, **options)  # a prompt before each calibration view, and a review
        real_grab, real_capture = bench.grab_preview, bench.cameras.capture_pair

        def grab_preview(width_px=None):
            grabbing.set()
            try:
                time.sleep(0.02)  # a slow camera: a grab the runner could run into
                widths.append(width_px)
                return real_grab(width_px)
            finally:
                grabbing.clear()

        def capture_pair():
            overlaps.append(grabbing.is_set())
            return real_capture()

        bench.grab_preview, bench.cameras.capture_pair = grab_preview, capture_pair
        return bench

    out, control = tmp_path / "watched", RunControl()
    page = LivePage.for_campaign(small_config(), session_dir=out, control=control).start()
    page.previews.watchers(+1)  # a browser is connected
    try:
        operator = UnhurriedOperator(0.2, grabs=lambda: len(widths))
        summary = run_campaign(small_config(), out, operators=[operator], subscribers=[page.state],
                               frame_subscribers=[page.previews.captured], control=control, bench_factory=factory)
    finally:
        page.stop()
    assert summary.exit_status == "success" and page.previews.last_error is None
    assert operator.missed == 0, "a prompt passed without a live grab"
    assert page.previews.stats["live"] >= 10 and set(widths) == {PREVIEW_WIDTH_PX}
    assert overlaps and not any(overlaps)
    assert numbers(out) == numbers(small_reference)
    recorded, reference = SessionReader(out), SessionReader(small_reference)
    for ours, theirs in zip(recorded.events(kind="calibration_view"), reference.events(kind="calibration_view"),
                            strict=True):
        assert np.array_equal(recorded.frame(ours.frames["right"]), reference.frame(theirs.frames["right"]))
