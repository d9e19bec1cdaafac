"""Hardware tier: real V4L2 cameras. Skipped unless the lab passes ``--camera PATH`` (twice for a stereo pair).

    pytest tests/test_hw_camera.py --camera /dev/v4l/by-id/usb-...-video-index0 \\
                                   --camera /dev/v4l/by-id/usb-...-video-index0 -s

``STEREO_BENCH_HW_CAMERA_SETTINGS`` may hold a JSON ``CameraSettings`` to open with (e.g.
``{"pixel_format": "MJPG", "width_px": 1280, "height_px": 720, "fps": 30}``); otherwise the cameras keep their
format and only the auto controls are turned off. ``-s`` shows the measured values.
"""

from __future__ import annotations

import json
import os
import time

import pytest

from drivers.camera import (
    CameraRegistry,
    CameraSettings,
    ControlNotAccepted,
    StereoCamera,
    UnstableCameraName,
    V4L2Camera,
)

pytestmark = pytest.mark.hardware


def base_settings() -> CameraSettings:
    text = os.environ.get("STEREO_BENCH_HW_CAMERA_SETTINGS")
    return CameraSettings.model_validate(json.loads(text)) if text else CameraSettings()


def explicit(settings: CameraSettings) -> CameraSettings:
    """The settings read back, asked for explicitly (every control the camera has gets set and verified)."""
    values = {name: value for name, value in settings.model_dump().items() if value is not None}
    return CameraSettings(**values)


def test_open_lock_capture_flush(camera_paths):
    with V4L2Camera(camera_paths[0], base_settings()) as camera:
        in_force = camera.settings
        print(f"\n{camera.source}: settings in force {in_force.model_dump(exclude_none=True)}")
        for switch in ("auto_exposure", "auto_white_balance", "autofocus"):
            assert getattr(in_force, switch) in (False, None), switch
        first = camera.capture()
        assert first.image.shape[:2] == (in_force.height_px, in_force.width_px)
        assert abs(first.timestamp_s - time.monotonic()) < 2.0
        before_flush_s = time.monotonic()
        camera.flush()
        flushed_s = time.monotonic() - before_flush_s
        after = camera.capture()
        print(f"flush took {flushed_s * 1e3:.1f} ms; timestamps from {after.timestamp_source}")
        assert after.sequence > first.sequence
        # The point of flush(): the next frame was taken after it was called, not queued before.
        assert after.timestamp_s > before_flush_s


def test_every_control_reads_back_what_was_set(camera_paths):
    with V4L2Camera(camera_paths[0], base_settings()) as camera:
        current = camera.settings
    asked = explicit(current)
    with V4L2Camera(camera_paths[0], asked) as camera:
        got, want = camera.settings.model_dump(), asked.model_dump()
    got_fps, want_fps = got.pop("fps"), want.pop("fps")
    assert got == want
    assert (got_fps is None and want_fps is None) or got_fps == pytest.approx(want_fps, rel=0.005)


def test_an_impossible_exposure_is_reported_not_ignored(camera_paths):
    with V4L2Camera(camera_paths[0], base_settings()) as camera:
        if camera.settings.exposure_us is None:
            pytest.skip("this camera has no manual exposure control")
    impossible = base_settings().model_copy(update={"exposure_us": 1e9})
    with pytest.raises(ControlNotAccepted) as caught:
        V4L2Camera(camera_paths[0], impossible).open()
    assert caught.value.control == "exposure_us"
    print(f"\n{caught.value}")


def test_the_path_is_a_stable_name(camera_paths):
    registry = CameraRegistry()
    for path in camera_paths:
        try:
            camera = registry.resolve(path)
        except UnstableCameraName as error:
            pytest.fail(f"bind cameras by a stable name: {error}")
        print(f"\n{path} -> {camera.capture_node}, bind as {camera.stable_specs(registry.scan())}")
        assert camera.capture_node and os.path.exists(camera.capture_node)


def test_stereo_pair_skew(camera_paths):
    if len(camera_paths) < 2:
        pytest.skip("pass --camera twice for the stereo tests")
    left, right = (V4L2Camera(path, base_settings()) for path in camera_paths[:2])
    with StereoCamera(left, right) as pair:
        pair.flush()
        pairs = [pair.capture_pair() for _ in range(5)]
    dts_ms = [f"{p.dt_s * 1e3:+.1f}" for p in pairs]
    print(f"\nleft-right dt (ms): {', '.join(dts_ms)}; re-grabs: {[p.regrabs for p in pairs]}")
    for stereo in pairs:
        assert stereo.skew_s <= pair.max_skew_s
        assert stereo.left.image.shape == (left.settings.height_px, left.settings.width_px, 3)
