"""SyntheticCamera: the Camera contract, simulated timing and injected faults."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from drivers.camera import (
    Camera,
    CameraError,
    CameraFault,
    CameraGone,
    CameraSettings,
    CaptureFailed,
    SyntheticCamera,
)


class Scene:
    """Stands in for the rig emulator: the rendered value is the current 'pose'."""

    def __init__(self) -> None:
        self.pose = 0
        self.renders = 0

    def render(self) -> np.ndarray:
        self.renders += 1
        return np.full((6, 8, 3), self.pose, dtype=np.uint8)


def ticking_clock(step_s: float = 0.01):
    counter = itertools.count(1)
    return lambda: next(counter) * step_s


@pytest.fixture
def scene() -> Scene:
    return Scene()


def test_is_a_camera_and_construction_does_nothing(scene):
    camera = SyntheticCamera(scene.render)
    assert isinstance(camera, Camera)
    assert scene.renders == 0
    assert not camera.is_open
    with pytest.raises(CameraError, match="not open"):
        camera.grab()
    assert camera.settings == CameraSettings()  # nothing read back yet: the requested settings


def test_capture_shows_the_scene_at_grab_time_with_sequence_and_settings(scene):
    settings = CameraSettings(pixel_format="MJPG", width_px=8, height_px=6, fps=30, exposure_us=8000, gain=2)
    with SyntheticCamera(scene.render, name="left", settings=settings, clock=ticking_clock()) as camera:
        first = camera.capture()
        scene.pose = 7
        camera.grab()
        scene.pose = 9  # moving after the grab must not change the frame
        second = camera.retrieve()
        assert camera.settings == settings
    assert (first.sequence, second.sequence) == (1, 2)
    assert second.timestamp_s > first.timestamp_s
    assert second.image[0, 0, 0] == 7
    assert second.settings == settings and second.source == "synthetic:left"
    assert second.timestamp_source == "simulated"
    assert second.describe()["settings"]["exposure_us"] == 8000


def test_render_may_attach_ground_truth_to_the_frame(scene):
    def render():
        return scene.render(), {"pose": {"baseline_mm": 120.0}}

    with SyntheticCamera(render) as camera:
        frame = camera.capture()
    assert frame.meta == {"pose": {"baseline_mm": 120.0}}
    assert frame.describe()["meta"]["pose"]["baseline_mm"] == 120.0


def test_retrieve_without_grab_is_an_error(scene):
    with SyntheticCamera(scene.render) as camera, pytest.raises(CameraError, match="grab"):
        camera.retrieve()


def test_render_size_must_match_the_settings(scene):
    with SyntheticCamera(scene.render, settings=CameraSettings(width_px=1920, height_px=1080)) as camera:
        with pytest.raises(CameraError, match="8x6 but the settings say 1920x1080"):
            camera.capture()


def test_simulated_exposure_and_readout_are_time_scaled(scene):
    slept: list[float] = []
    camera = SyntheticCamera(scene.render, exposure_s=0.02, readout_s=0.03, time_scale=0.5, sleep=slept.append)
    with camera:
        camera.capture()
    # The render counts against the (scaled) exposure + readout of 25 ms.
    assert len(slept) == 1 and 0.015 < slept[0] <= 0.025


def test_real_sleep_makes_grab_take_the_exposure_time(scene):
    import time

    with SyntheticCamera(scene.render, exposure_s=0.02, readout_s=0.0) as camera:
        start = time.monotonic()
        frame = camera.capture()
    assert frame.timestamp_s - start >= 0.019


def test_dropped_frame_fails_one_grab_only(scene):
    with SyntheticCamera(scene.render) as camera:
        camera.inject(CameraFault.DROPPED_FRAME)
        with pytest.raises(CaptureFailed, match="dropped"):
            camera.grab()
        with pytest.raises(CameraError, match="grab"):
            camera.retrieve()  # nothing was grabbed
        frame = camera.capture()
    assert frame.sequence == 1


def test_stale_frame_repeats_the_old_frame_until_flushed(scene):
    with SyntheticCamera(scene.render, clock=ticking_clock()) as camera:
        before = camera.capture()
        scene.pose = 50  # the rig moved
        camera.inject("stale_frame", count=2)
        stale = camera.capture()
        assert stale.image[0, 0, 0] == 0
        assert (stale.sequence, stale.timestamp_s) == (before.sequence, before.timestamp_s)
        camera.flush()
        assert camera.pending_faults == []
        fresh = camera.capture()
    assert fresh.image[0, 0, 0] == 50 and fresh.sequence == 2


def test_flush_keeps_other_pending_faults(scene):
    with SyntheticCamera(scene.render) as camera:
        camera.capture()
        camera.inject(CameraFault.STALE_FRAME)
        camera.inject(CameraFault.DROPPED_FRAME)
        camera.flush()
        assert camera.pending_faults == [CameraFault.DROPPED_FRAME]


def test_device_gone_fails_every_later_call_but_close(scene):
    camera = SyntheticCamera(scene.render)
    camera.open()
    camera.capture()
    camera.inject(CameraFault.DEVICE_GONE)
    for call in (camera.grab, camera.retrieve, camera.capture, camera.flush, camera.open):
        with pytest.raises(CameraGone, match="disappeared"):
            call()
    assert not camera.is_open
    camera.close()


def test_device_gone_during_exposure(scene):
    camera = SyntheticCamera(scene.render, exposure_s=0.01, sleep=lambda s: camera.inject(CameraFault.DEVICE_GONE))
    with camera, pytest.raises(CameraGone):
        camera.grab()


def test_bad_timing_arguments_are_refused(scene):
    with pytest.raises(ValueError):
        SyntheticCamera(scene.render, exposure_s=-1)


def test_a_camera_sharing_a_trigger_waits_for_that_exposure_not_for_one_of_its_own(scene):
    import time

    slept: list[float] = []
    deadline = time.monotonic() + 30.0  # the shared exposure ends then
    camera = SyntheticCamera(scene.render, exposure_s=0.02, sleep=slept.append, ready_at=lambda: deadline)
    with camera:
        camera.capture()
    assert len(slept) == 1 and 29.0 < slept[0] <= 30.0
    slept.clear()
    camera = SyntheticCamera(scene.render, exposure_s=0.02, sleep=slept.append, ready_at=lambda: deadline - 60.0)
    with camera:
        camera.capture()  # that exposure is over: the frame is there
    assert slept == []
