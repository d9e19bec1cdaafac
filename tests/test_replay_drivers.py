"""Replay drivers: recorded pairs served in the order asked, loaded ahead in the recorded order."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.replay import ReplayMismatch, ReplayStereoCamera

KEYS = [f"c0/calibration_view/{i}" for i in range(6)]


class Recording:
    """load_pair for a fake recording: pair i is filled with i; records which keys were loaded, on which thread."""

    def __init__(self, missing: str | None = None):
        self.loaded: list[tuple[str, str]] = []
        self.missing = missing
        self.lock = threading.Lock()

    def __call__(self, key: str):
        with self.lock:
            self.loaded.append((key, threading.current_thread().name))
        if key == self.missing:
            raise KeyError(f"recording holds no {key}")
        value = KEYS.index(key) if key in KEYS else 99
        return np.full((4, 4), value, np.uint8), np.full((4, 4), value + 100, np.uint8), {"dt_s": 0.001 * value}


def capture(camera: ReplayStereoCamera, key: str):
    camera.expect(key)
    return camera.capture_pair()


def test_pairs_are_loaded_ahead_in_the_recorded_order_and_served_as_asked():
    recording = Recording()
    with ReplayStereoCamera(recording, order=KEYS, ahead=3, workers=2) as camera:
        for i, key in enumerate(KEYS):
            pair = capture(camera, key)
            assert pair.left.image[0, 0] == i and pair.right.image[0, 0] == i + 100 and pair.dt_s == 0.001 * i
            assert pair.left.source == f"replay:left:{key}"
    assert sorted(key for key, _ in recording.loaded) == sorted(KEYS)  # each pair read once
    assert all(thread.startswith("replay-load") for _, thread in recording.loaded)


def test_a_pair_asked_out_of_order_is_loaded_then_and_the_skipped_ones_are_not_kept():
    recording = Recording()
    with ReplayStereoCamera(recording, order=KEYS, ahead=2, workers=1) as camera:
        assert capture(camera, KEYS[0]).left.image[0, 0] == 0
        assert capture(camera, KEYS[4]).left.image[0, 0] == 4  # 1..3 skipped
        # The skipped pairs loaded ahead (1, 2) are dropped, and loading ahead goes on after the one asked.
        assert list(camera._loading) == [KEYS[5]]
        assert capture(camera, KEYS[5]).left.image[0, 0] == 5
        assert capture(camera, KEYS[2]).left.image[0, 0] == 2  # asked again later: loaded when asked
        assert capture(camera, "c9/measurement_frame/0/0").left.image[0, 0] == 99  # not in the order at all
    # Loaded on the asking thread: the jump (4), the pair asked again (its load ahead was dropped, not kept and
    # served) and the one outside the order. 5 was loaded ahead after the jump, 3 (skipped) never.
    caller = threading.current_thread().name
    assert [key for key, thread in recording.loaded if thread == caller] == [KEYS[4], KEYS[2],
                                                                              "c9/measurement_frame/0/0"]
    assert KEYS[3] not in [key for key, _ in recording.loaded]


def test_a_missing_pair_fails_the_capture_that_asks_for_it_not_the_ones_before():
    recording = Recording(missing=KEYS[3])
    with ReplayStereoCamera(recording, order=KEYS, ahead=4) as camera:
        for key in KEYS[:3]:
            capture(camera, key)
        with pytest.raises(KeyError, match="holds no"):
            capture(camera, KEYS[3])
        with pytest.raises(ReplayMismatch):
            camera.capture_pair()  # nothing expected
