"""StereoCamera: grab both then retrieve both, skew measured, over-limit pairs re-grabbed or rejected."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from drivers.camera import (
    CameraBase,
    CameraFault,
    CameraGone,
    CameraNotFound,
    CameraSettings,
    CaptureFailed,
    Frame,
    StereoCamera,
    StereoSkewError,
    SyntheticCamera,
)


class VirtualTime:
    def __init__(self) -> None:
        self.now_s = 100.0


class FreeRunningCamera(CameraBase):
    """A camera whose sensor delivers frames at phase_s + k * period_s on a shared virtual clock.

    grab() waits (advances the clock) for the first frame at or after 'now' that it has not delivered yet: a
    flushed one-buffer V4L2 camera. This is the timing StereoCamera's re-grab rule is designed around.
    """

    def __init__(self, name: str, clock: VirtualTime, period_s: float, phase_s: float,
                 events: list[str] | None = None):
        self.source = f"free:{name}"
        self._clock, self.period_s, self.phase_s = clock, period_s, phase_s
        self.is_open = False
        self.grabs = 0
        self._events = events if events is not None else []
        self._name = name
        self._last_s = -math.inf
        self._pending: float | None = None
        self.settings = CameraSettings()

    def open(self) -> None:
        self.is_open = True
        self._log("open")

    def close(self) -> None:
        self.is_open = False
        self._log("close")

    def grab(self) -> float:
        # The first frame at or after 'now' that has not been delivered yet.
        k = math.ceil((self._clock.now_s - self.phase_s) / self.period_s - 1e-9)
        t = self.phase_s + k * self.period_s
        while t <= self._last_s + 1e-12:
            t += self.period_s
        self._clock.now_s = t
        self._last_s = t
        self._pending = t
        self.grabs += 1
        self._log("grab")
        return t

    def retrieve(self) -> Frame:
        assert self._pending is not None
        self._log("retrieve")
        t, self._pending = self._pending, None
        return Frame(np.zeros((2, 2), np.uint8), t, self.grabs, self.settings, self.source)

    def flush(self) -> None:
        self._log("flush")

    def _log(self, event: str) -> None:
        self._events.append(f"{self._name}.{event}")


def pair(phase_right_s: float, *, period_s: float = 1 / 30, **kwargs) -> tuple[StereoCamera, list[str]]:
    clock = VirtualTime()
    order: list[str] = []
    left = FreeRunningCamera("L", clock, period_s, 0.0, order)
    right = FreeRunningCamera("R", clock, period_s, phase_right_s, order)
    return StereoCamera(left, right, **kwargs), order


def test_grabs_both_before_retrieving_either():
    stereo, order = pair(0.004)
    with stereo:
        result = stereo.capture_pair()
    assert order == ["L.open", "R.open", "L.grab", "R.grab", "L.retrieve", "R.retrieve", "L.close", "R.close"]
    assert result.dt_s == pytest.approx(0.004)
    assert result.skew_s == pytest.approx(0.004)
    assert result.regrabs == 0
    assert result.describe()["dt_s"] == pytest.approx(0.004)


def test_regrabs_the_earlier_camera_when_the_phase_is_unlucky():
    # Right frames come 25 ms after left ones: re-grabbing left lands 8.3 ms after right.
    stereo, order = pair(0.025, max_skew_s=0.010)
    result = stereo.capture_pair()
    assert result.dt_s == pytest.approx(0.025 - 1 / 30)
    assert result.regrabs == 1
    assert order == ["L.grab", "R.grab", "L.grab", "L.retrieve", "R.retrieve"]
    assert result.left.sequence == 2 and result.right.sequence == 1


def test_default_limit_always_finds_a_pair_at_30_fps():
    for phase_ms in range(0, 34, 3):
        stereo, _ = pair(phase_ms / 1000)
        result = stereo.capture_pair()
        assert result.skew_s <= stereo.max_skew_s
        assert result.regrabs <= 1


def test_rejects_with_the_measured_skews_when_no_phase_fits():
    stereo, _ = pair(0.016, max_skew_s=0.005, max_attempts=3)
    with pytest.raises(StereoSkewError, match=r"skew over 5.0 ms after 3 re-grabs \(dt = \+16.0, -17.3, \+16.0, -17.3"):
        stereo.capture_pair()


def test_flush_flushes_both():
    stereo, order = pair(0.0)
    stereo.flush()
    assert order == ["L.flush", "R.flush"]


def test_open_failure_of_right_closes_left():
    left = SyntheticCamera(lambda: np.zeros((2, 2), np.uint8), name="left")
    right = SyntheticCamera(lambda: np.zeros((2, 2), np.uint8), name="right")
    right.inject(CameraFault.DEVICE_GONE)
    with pytest.raises(CameraGone):
        StereoCamera(left, right).open()
    assert not left.is_open


def test_open_failure_propagates_error_type():
    class Missing(FreeRunningCamera):
        def open(self) -> None:
            raise CameraNotFound("free:R: no such camera")

    clock = VirtualTime()
    left = FreeRunningCamera("L", clock, 1 / 30, 0)
    with pytest.raises(CameraNotFound):
        StereoCamera(left, Missing("R", clock, 1 / 30, 0)).open()
    assert not left.is_open


def synthetic_pair(step_s: float = 0.01):
    counter = itertools.count(1)

    def clock() -> float:
        return next(counter) * step_s

    def scene() -> np.ndarray:
        return np.full((4, 4), 1, np.uint8)

    left = SyntheticCamera(scene, name="left", clock=clock)
    right = SyntheticCamera(scene, name="right", clock=clock)
    return left, right


def test_stale_frame_on_one_camera_is_caught_by_the_skew_check():
    left, right = synthetic_pair()
    with StereoCamera(left, right, max_skew_s=0.015) as stereo:
        first = stereo.capture_pair()
        left.inject(CameraFault.STALE_FRAME)
        second = stereo.capture_pair()
    assert first.left.sequence == 1
    assert second.left.sequence == 2  # the stale frame (sequence 1) was re-grabbed away
    assert second.regrabs == 1
    assert second.skew_s <= 0.015


def test_dropped_frame_is_retried_within_the_budget():
    left, right = synthetic_pair()
    with StereoCamera(left, right) as stereo:
        right.inject(CameraFault.DROPPED_FRAME)
        result = stereo.capture_pair()
    assert result.regrabs == 1
    assert right.grabs == 1


def test_frames_that_keep_dropping_raise_capture_failed():
    left, right = synthetic_pair()
    with StereoCamera(left, right, max_attempts=2) as stereo:
        right.inject(CameraFault.DROPPED_FRAME, count=3)
        with pytest.raises(CaptureFailed):
            stereo.capture_pair()


def test_camera_gone_is_not_retried():
    left, right = synthetic_pair()
    with StereoCamera(left, right) as stereo:
        left.inject(CameraFault.DEVICE_GONE)
        with pytest.raises(CameraGone):
            stereo.capture_pair()
    assert right.grabs == 0


def test_settings_and_source_of_both():
    left, right = synthetic_pair()
    stereo = StereoCamera(left, right)
    assert stereo.settings == (CameraSettings(), CameraSettings())
    assert stereo.source == "stereo(synthetic:left, synthetic:right)"
    assert not stereo.is_open


@pytest.mark.parametrize("kwargs", [{"max_skew_s": 0}, {"max_attempts": -1}])
def test_bad_limits_are_refused(kwargs):
    left, right = synthetic_pair()
    with pytest.raises(ValueError):
        StereoCamera(left, right, **kwargs)
