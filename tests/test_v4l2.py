"""V4L2Camera: the driver's logic against a fake VideoCapture, and real cv2.VideoCapture on files.

The fake replaces only the capture object (what ``cv2.VideoCapture(path, cv2.CAP_V4L2)`` returns): settings order,
read-back checks, failure diagnosis, flushing and timestamps all run the real driver code. Where OpenCV reports a
reason only in its native log (busy, "No space left on device"), the fake writes the same log line to the same
file descriptor, so the driver's log capture is exercised too.
"""

from __future__ import annotations

import errno
import os
from collections import deque
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.camera import (
    Camera,
    CameraAccessDenied,
    CameraBandwidthError,
    CameraBusy,
    CameraError,
    CameraGone,
    CameraNotFound,
    CameraSettings,
    CaptureFailed,
    ControlNotAccepted,
    V4L2Camera,
)
from drivers.camera.v4l2 import device_holders, fourcc_to_int, native_log

ABSENT = -1.0


class FakeDevice:
    """The state of one fake V4L2 camera, shared by every capture object opened on it.

    ``behaviour[prop]``: 'accept' (default), 'ignore' (set() says True, value unchanged: the silent failure),
    'refuse' (set() says False, value unchanged), ('clamp', lo, hi), or 'absent' (get() -1, set() False).
    ``grab_script``: queued (ok, native_log_line) results for grab(); when empty, grabs succeed.
    """

    def __init__(self) -> None:
        self.props: dict[int, float] = {
            cv2.CAP_PROP_FOURCC: fourcc_to_int("YUYV"),
            cv2.CAP_PROP_FRAME_WIDTH: 640,
            cv2.CAP_PROP_FRAME_HEIGHT: 480,
            cv2.CAP_PROP_FPS: 30.0,
            cv2.CAP_PROP_BUFFERSIZE: 4,
            cv2.CAP_PROP_AUTO_EXPOSURE: 3,
            cv2.CAP_PROP_EXPOSURE: 156,
            cv2.CAP_PROP_GAIN: 0,
            cv2.CAP_PROP_AUTO_WB: 1,
            cv2.CAP_PROP_WB_TEMPERATURE: 4600,
            cv2.CAP_PROP_AUTOFOCUS: 1,
            cv2.CAP_PROP_FOCUS: 30,
        }
        self.behaviour: dict[int, object] = {}
        self.opens = True
        self.open_log = ""
        self.grab_script: deque[tuple[bool, str]] = deque()
        self.set_calls: list[tuple[int, float]] = []
        self.grabs = 0
        self.released = 0
        self.stamp_ms: float | None = None
        self.decode_ok = True

    def factory(self, path: str, api: int) -> FakeVideoCapture:
        assert api == cv2.CAP_V4L2
        return FakeVideoCapture(self, path)


class FakeVideoCapture:
    def __init__(self, device: FakeDevice, path: str):
        self.device, self.path = device, path
        if device.open_log:
            os.write(1, device.open_log.encode())

    def isOpened(self) -> bool:
        return self.device.opens

    def set(self, prop: int, value: float) -> bool:
        device = self.device
        device.set_calls.append((prop, value))
        behaviour = device.behaviour.get(prop, "accept")
        if behaviour == "accept":
            device.props[prop] = value
            return True
        if behaviour == "ignore":
            return True
        if isinstance(behaviour, tuple) and behaviour[0] == "clamp":
            device.props[prop] = min(max(value, behaviour[1]), behaviour[2])
            return True
        return False

    def get(self, prop: int) -> float:
        if self.device.behaviour.get(prop) == "absent":
            return ABSENT
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.device.stamp_ms if self.device.stamp_ms is not None else 0.0
        return float(self.device.props.get(prop, ABSENT))

    def grab(self) -> bool:
        if self.device.grab_script:
            ok, line = self.device.grab_script.popleft()
            if line:
                os.write(1, line.encode())
            if not ok:
                return False
        self.device.grabs += 1
        return True

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        if not self.device.decode_ok:
            return False, None
        width = int(self.device.props[cv2.CAP_PROP_FRAME_WIDTH])
        height = int(self.device.props[cv2.CAP_PROP_FRAME_HEIGHT])
        return True, np.full((height, width, 3), self.device.grabs % 256, np.uint8)

    def release(self) -> None:
        self.device.released += 1


LOCKED = CameraSettings(pixel_format="MJPG", width_px=1920, height_px=1080, fps=30, exposure_us=8000, gain=4,
                        white_balance_k=5000, focus=0, buffer_count=1)


@pytest.fixture
def device() -> FakeDevice:
    return FakeDevice()


@pytest.fixture
def node(tmp_path: Path) -> Path:
    """A path that exists, standing in for /dev/v4l/by-id/usb-...-video-index0."""
    path = tmp_path / "usb-Cam_SN1-video-index0"
    path.write_text("")
    return path


def make(node: Path, device: FakeDevice, settings: CameraSettings = LOCKED, **kwargs) -> V4L2Camera:
    return V4L2Camera(node, settings, capture_factory=device.factory, **kwargs)


def one_line(error: BaseException) -> str:
    text = str(error)
    assert "\n" not in text
    return text


# --- construction and settings ------------------------------------------------------------------------------------


def test_construction_does_no_io(tmp_path):
    def factory(path, api):
        raise AssertionError("opened during construction")

    camera = V4L2Camera(tmp_path / "nope", LOCKED, capture_factory=factory,
                        probe=lambda path: pytest.fail("probed during construction"))
    assert isinstance(camera, Camera)
    assert not camera.is_open
    assert camera.settings == LOCKED  # requested: nothing read back yet
    with pytest.raises(CameraError, match="not open"):
        camera.grab()


def test_open_sets_every_control_in_order_in_device_units_and_reads_back(node, device):
    with make(node, device) as camera:
        in_force = camera.settings
    props = [prop for prop, _ in device.set_calls]
    assert props == [cv2.CAP_PROP_FOURCC, cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT, cv2.CAP_PROP_FPS,
                     cv2.CAP_PROP_BUFFERSIZE, cv2.CAP_PROP_AUTO_EXPOSURE, cv2.CAP_PROP_EXPOSURE, cv2.CAP_PROP_GAIN,
                     cv2.CAP_PROP_AUTO_WB, cv2.CAP_PROP_WB_TEMPERATURE, cv2.CAP_PROP_AUTOFOCUS, cv2.CAP_PROP_FOCUS]
    values = dict(device.set_calls)
    assert values[cv2.CAP_PROP_AUTO_EXPOSURE] == 1  # V4L2_EXPOSURE_MANUAL
    assert values[cv2.CAP_PROP_EXPOSURE] == 80  # 8000 us in 100-us units
    assert values[cv2.CAP_PROP_AUTO_WB] == 0 and values[cv2.CAP_PROP_AUTOFOCUS] == 0
    assert in_force.model_dump() == LOCKED.model_dump()
    assert device.released == 1


def test_untouched_fields_are_left_alone_and_recorded_as_read(node, device):
    with make(node, device, CameraSettings(auto_exposure=None, auto_white_balance=None, autofocus=None,
                                           buffer_count=None)) as camera:
        in_force = camera.settings
    assert device.set_calls == []
    assert in_force.pixel_format == "YUYV" and (in_force.width_px, in_force.height_px) == (640, 480)
    assert in_force.auto_exposure is True and in_force.exposure_us == 15600
    assert in_force.autofocus is True and in_force.focus == 30 and in_force.buffer_count == 4


def test_silently_ignored_control_is_caught_by_read_back(node, device):
    device.behaviour[cv2.CAP_PROP_EXPOSURE] = "ignore"
    camera = make(node, device)
    with pytest.raises(ControlNotAccepted) as caught:
        camera.open()
    error = caught.value
    assert (error.control, error.asked, error.read_back) == ("exposure_us", 8000, 15600)
    assert "did not accept exposure_us = 8000" in one_line(error)
    assert "--list-ctrls" in str(error)
    assert not camera.is_open and device.released == 1


def test_clamped_control_names_the_value_read_back(node, device):
    device.behaviour[cv2.CAP_PROP_WB_TEMPERATURE] = ("clamp", 2800, 4500)
    with pytest.raises(ControlNotAccepted, match=r"white_balance_k = 5000.0 \(read back 4500.0\)"):
        make(node, device).open()


def test_missing_manual_control_is_an_error_but_missing_auto_switch_is_locked_enough(node, device):
    device.behaviour[cv2.CAP_PROP_AUTOFOCUS] = "absent"
    device.behaviour[cv2.CAP_PROP_FOCUS] = "absent"
    with pytest.raises(ControlNotAccepted, match="focus = 0.0 \\(the device has no such control\\)") as caught:
        make(node, device).open()
    assert caught.value.control == "focus" and caught.value.read_back is None

    fixed_focus = LOCKED.model_copy(update={"focus": None})
    with make(node, device, fixed_focus) as camera:
        assert camera.settings.autofocus is None and camera.settings.focus is None


def test_refused_frame_size(node, device):
    device.behaviour[cv2.CAP_PROP_FRAME_WIDTH] = "refuse"
    device.behaviour[cv2.CAP_PROP_FRAME_HEIGHT] = "refuse"
    with pytest.raises(ControlNotAccepted, match=r"frame size = '1920x1080' \(read back '640x480'\).*list-formats"):
        make(node, device).open()


def test_refused_pixel_format(node, device):
    device.behaviour[cv2.CAP_PROP_FOURCC] = "refuse"
    with pytest.raises(ControlNotAccepted, match=r"pixel_format = 'MJPG' \(read back 'YUYV'\)"):
        make(node, device).open()


def test_fps_read_back_allows_the_drivers_rounding_but_not_another_rate(node, device):
    device.behaviour[cv2.CAP_PROP_FPS] = ("clamp", 30.00003, 30.00003)
    with make(node, device) as camera:
        assert camera.settings.fps == pytest.approx(30.00003)
    with pytest.raises(ControlNotAccepted, match="fps = 25.0"):
        make(node, device, LOCKED.model_copy(update={"fps": 25.0})).open()


def test_driver_with_more_buffers_than_asked_is_accepted_and_flush_drains_them(node, device, caplog):
    device.behaviour[cv2.CAP_PROP_BUFFERSIZE] = ("clamp", 2, 10)
    with make(node, device) as camera:
        assert camera.settings.buffer_count == 2
        camera.flush()
        assert device.grabs == 3
        frame = camera.capture()
    assert frame.sequence == 4  # the three flushed frames count: gaps show discarded frames
    assert "keeps 2 buffers" in caplog.text


def test_settings_model_rejects_contradictions():
    with pytest.raises(ValueError, match="exposure_us is set but auto_exposure is on"):
        CameraSettings(exposure_us=1000, auto_exposure=True)
    with pytest.raises(ValueError, match="width_px and height_px go together"):
        CameraSettings(width_px=640)
    with pytest.raises(ValueError, match="4-character FourCC"):
        CameraSettings(pixel_format="MJPEG")
    assert CameraSettings(pixel_format="mjpg").pixel_format == "MJPG"


# --- open failures ------------------------------------------------------------------------------------------------


def test_missing_device(tmp_path, device):
    device.opens = False
    camera = V4L2Camera(tmp_path / "usb-Gone-video-index0", LOCKED, capture_factory=device.factory)
    with pytest.raises(CameraNotFound, match="no such camera.*stereo-bench devices") as caught:
        camera.open()
    assert str(tmp_path) in one_line(caught.value)


def test_busy_device_names_the_program_holding_it(node, device, tmp_path, capfd):
    device.opens = False
    device.open_log = f"[ INFO:0@0.101] global cap_v4l.cpp:812 VIDEOIO(V4L2:{node}): device is busy\n"
    proc = tmp_path / "proc"
    (proc / "4242" / "fd").mkdir(parents=True)
    (proc / "4242" / "comm").write_text("cheese\n")
    os.symlink(node, proc / "4242" / "fd" / "7")
    (proc / "self").mkdir()
    with pytest.raises(CameraBusy, match=r"device is busy \(held by cheese \(pid 4242\)\); close that program"):
        make(node, device, proc_root=proc).open()
    assert "device is busy" not in capfd.readouterr().out  # INFO lines stay hidden at the default log level


def test_busy_from_the_kernel(node, device):
    device.opens = False
    with pytest.raises(CameraBusy, match="another program is using it"):
        make(node, device, probe=lambda path: errno.EBUSY, proc_root=node.parent / "no-proc").open()


def test_permission_denied(node, device):
    device.opens = False
    with pytest.raises(CameraAccessDenied, match="'video' group"):
        make(node, device, probe=lambda path: errno.EACCES).open()


def test_unknown_open_failure_still_gives_one_line_with_a_next_step(node, device):
    device.opens = False
    with pytest.raises(CameraError, match="v4l2-ctl -d") as caught:
        make(node, device).open()
    one_line(caught.value)


def test_bandwidth_error_at_open(node, device):
    device.opens = False
    device.open_log = "VIDIOC_STREAMON: No space left on device\n"
    with pytest.raises(CameraBandwidthError, match="USB bandwidth.*own USB controller"):
        make(node, device).open()


# --- frames -------------------------------------------------------------------------------------------------------


def test_capture_returns_a_described_frame(node, device):
    with make(node, device, clock=lambda: 500.0) as camera:
        frame = camera.capture()
    assert frame.image.shape == (1080, 1920, 3)
    assert frame.sequence == 1 and frame.timestamp_s == 500.0 and frame.timestamp_source == "host"
    assert frame.settings == camera.settings and frame.source == f"v4l2:{node}"


def test_kernel_buffer_timestamp_is_used_when_it_is_on_the_monotonic_clock(node, device):
    device.stamp_ms = 499_987.5
    with make(node, device, clock=lambda: 500.0) as camera:
        assert camera.grab() == pytest.approx(499.9875)
        frame = camera.retrieve()
    assert frame.timestamp_source == "v4l2-buffer"
    device.stamp_ms = 33.3  # a file backend's media position, not a clock
    with make(node, device, clock=lambda: 500.0) as camera:
        assert camera.capture().timestamp_source == "host"


def test_bandwidth_error_on_first_grab(node, device, capfd):
    device.grab_script.append((False, f"[DEBUG:0@1.2] global cap_v4l.cpp:1040 VIDEOIO(V4L2:{node}): failed "
                                      f"VIDIOC_STREAMON: errno=28 (No space left on device)\n"))
    with make(node, device) as camera:
        with pytest.raises(CameraBandwidthError, match="No space left on device") as caught:
            camera.grab()
        one_line(caught.value)
    assert "STREAMON" not in capfd.readouterr().out


def test_dropped_frame_then_recovery(node, device):
    device.grab_script.append((False, ""))
    with make(node, device) as camera:
        with pytest.raises(CaptureFailed, match="no frame"):
            camera.grab()
        with pytest.raises(CameraError, match="grab"):
            camera.retrieve()
        assert camera.capture().sequence == 1


def test_undecodable_frame(node, device):
    device.decode_ok = False
    with make(node, device) as camera, pytest.raises(CaptureFailed, match="could not be decoded"):
        camera.capture()


def test_unplugged_camera_is_gone_for_every_later_call(node, device):
    with make(node, device) as camera:
        camera.capture()
        node.unlink()
        device.grab_script.append((False, ""))
        with pytest.raises(CameraGone, match="disappeared.*stereo-bench devices"):
            camera.grab()
        for call in (camera.grab, camera.retrieve, camera.capture, camera.flush):
            with pytest.raises(CameraGone):
                call()
        assert not camera.is_open
    assert device.released == 1


def test_normalised_opencv_control_ranges_are_refused(node, monkeypatch):
    monkeypatch.setenv("OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED", "1")
    with pytest.raises(CameraError, match="unset OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED"):
        V4L2Camera(node, capture_factory=lambda path, api: pytest.fail("opened")).open()


def test_open_twice_and_close_twice_are_harmless(node, device):
    camera = make(node, device)
    camera.open()
    camera.open()
    camera.close()
    camera.close()
    assert device.released == 1
    assert camera.settings.pixel_format == "MJPG"  # the last read-back is kept for the record


# --- native log capture -------------------------------------------------------------------------------------------


def test_native_log_hides_opencv_debug_but_passes_everything_else_through(capfd):
    with native_log() as captured:
        os.write(1, b"[DEBUG:0@0.1] global x.cpp:1 detail\n")
        os.write(2, b"[ WARN:0@0.1] global x.cpp:2 something the user should see\n")
        os.write(1, b"another thread's output\n")
    out, err = capfd.readouterr()
    assert "detail" in captured.text and "another thread" in captured.text
    assert "detail" not in out and "another thread's output" in out
    assert "something the user should see" in err
    assert cv2.utils.logging.getLogLevel() == cv2.utils.logging.LOG_LEVEL_WARNING


def test_device_holders_without_proc(tmp_path):
    assert device_holders(str(tmp_path / "x"), tmp_path / "missing") == []


# --- real cv2.VideoCapture ----------------------------------------------------------------------------------------


def test_real_videocapture_missing_device(tmp_path):
    with pytest.raises(CameraNotFound, match="no such camera"):
        V4L2Camera(tmp_path / "video-index0").open()


def test_real_videocapture_on_something_that_is_not_a_camera(tmp_path):
    not_a_camera = tmp_path / "usb-Fake-video-index0"
    not_a_camera.write_bytes(b"\0" * 64)
    with pytest.raises(CameraNotFound, match="not a V4L2 video-capture device"):
        V4L2Camera(not_a_camera).open()


@pytest.fixture
def mjpg_clip(tmp_path: Path) -> Path:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (64, 48))
    assert writer.isOpened()
    for i in range(8):
        writer.write(np.full((48, 64, 3), 30 * i, np.uint8))
    writer.release()
    return path


def test_reads_an_mjpg_stream_through_real_videocapture(mjpg_clip):
    settings = CameraSettings(pixel_format="MJPG", width_px=64, height_px=48, fps=30)
    with V4L2Camera(mjpg_clip, settings, api_preference=cv2.CAP_OPENCV_MJPEG) as camera:
        assert camera.settings.pixel_format == "MJPG"
        assert camera.settings.auto_exposure is None  # a file has no controls: nothing auto to turn off
        first = camera.capture()
        second = camera.capture()
        camera.flush()  # buffer count unknown for files: drains OpenCV's default 4 + 1
        last = camera.capture()
        with pytest.raises(CaptureFailed, match="no frame"):
            camera.capture()  # end of the clip
    assert first.image.shape == (48, 64, 3)
    assert (first.sequence, second.sequence, last.sequence) == (1, 2, 8)
    assert abs(int(last.image.mean()) - 210) <= 3
    assert abs(int(second.image.mean()) - 30) <= 3
    assert second.timestamp_s >= first.timestamp_s and second.timestamp_source == "host"


def test_image_sequence_through_real_videocapture_reads_back_its_true_size(tmp_path):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"frame_{i:03d}.png"), np.full((48, 64, 3), i, np.uint8))
    sequence = tmp_path / "frame_%03d.png"
    camera = V4L2Camera(sequence, CameraSettings(width_px=1920, height_px=1080), api_preference=cv2.CAP_IMAGES)
    with pytest.raises(ControlNotAccepted, match=r"frame size = '1920x1080' \(read back '64x48'\)"):
        camera.open()
    with V4L2Camera(sequence, CameraSettings(width_px=64, height_px=48), api_preference=cv2.CAP_IMAGES) as camera:
        frames = [camera.capture() for _ in range(3)]
    assert [int(frame.image[0, 0, 0]) for frame in frames] == [0, 1, 2]
