"""V4L2 camera driver over ``cv2.VideoCapture(path, cv2.CAP_V4L2)``.

Layers: the capture object (``cv2.VideoCapture`` or anything with its ``isOpened/set/get/grab/retrieve/release``
methods, injected through ``capture_factory``) is the transport; this module holds the logic: settings applied
in the order the V4L2 backend needs and each one read back, failures diagnosed into one-line errors, flushing,
timestamps.

OpenCV does not tell Python *why* a V4L2 call failed (busy device, "No space left on device"); it logs it from
native code. ``native_log()`` captures that log for the few calls where the reason matters (open, first grab) and
passes everything the user would have seen anyway back to the terminal.

Control units (OpenCV's V4L2 backend passes raw V4L2 values unless ``OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED`` is set,
which this driver does not support):

* ``CAP_PROP_AUTO_EXPOSURE`` = V4L2_CID_EXPOSURE_AUTO menu: 1 = manual, 3 = aperture priority (UVC "auto").
* ``CAP_PROP_EXPOSURE`` = V4L2_CID_EXPOSURE_ABSOLUTE in units of 100 us.
* ``CAP_PROP_AUTO_WB``/``CAP_PROP_WB_TEMPERATURE``, ``CAP_PROP_AUTOFOCUS``/``CAP_PROP_FOCUS``, ``CAP_PROP_GAIN``:
  the V4L2 controls of the same names, device units. ``get()`` returns -1 for a control the device lacks.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from drivers.camera.base import (
    CameraAccessDenied,
    CameraBandwidthError,
    CameraBase,
    CameraBusy,
    CameraError,
    CameraGone,
    CameraNotFound,
    CameraSettings,
    CaptureFailed,
    ControlNotAccepted,
    Frame,
)

log = logging.getLogger(__name__)

V4L2_EXPOSURE_MANUAL = 1
V4L2_EXPOSURE_APERTURE_PRIORITY = 3
EXPOSURE_UNIT_US = 100.0
# A kernel buffer stamp further than this from time.monotonic() is not a CLOCK_MONOTONIC stamp (file backends
# report a media position there), so the host clock is used instead.
BUFFER_STAMP_PLAUSIBLE_S = 2.0
FPS_TOLERANCE = 0.005  # relative: drivers report 30 fps as 10000000/333333


class VideoCaptureLike(Protocol):
    """The part of ``cv2.VideoCapture`` the driver uses; test fakes implement exactly this."""

    def isOpened(self) -> bool: ...
    def set(self, prop_id: int, value: float) -> bool: ...
    def get(self, prop_id: int) -> float: ...
    def grab(self) -> bool: ...
    def retrieve(self) -> tuple[bool, np.ndarray | None]: ...
    def release(self) -> None: ...


CaptureFactory = Callable[[str, int], VideoCaptureLike]


def fourcc_to_int(code: str) -> int:
    return int(cv2.VideoWriter_fourcc(*code))


def fourcc_to_str(value: float) -> str | None:
    number = int(value)
    if number <= 0:
        return None
    text = "".join(chr((number >> (8 * i)) & 0xFF) for i in range(4))
    return text if text.isprintable() and text.strip() else None


# --- native log capture -------------------------------------------------------------------------------------------

_NATIVE_LOG_LOCK = threading.Lock()
_OPENCV_LEVEL_TAGS = {"[FATAL:": 1, "[ERROR:": 2, "[ WARN:": 3, "[ INFO:": 4, "[DEBUG:": 5, "[VERBOSE:": 6}


def _opencv_line_level(line: str) -> int | None:
    for tag, level in _OPENCV_LEVEL_TAGS.items():
        if line.startswith(tag):
            return level
    return None


@dataclass
class NativeLog:
    """Text that native code wrote to fd 1 and fd 2 while ``native_log()`` was active."""

    text: str = ""

    def has(self, pattern: str) -> bool:
        return re.search(pattern, self.text, flags=re.IGNORECASE) is not None


@contextmanager
def native_log(enabled: bool = True) -> Iterator[NativeLog]:
    """Capture OpenCV's native log (at DEBUG level) for the duration of the block.

    Lines the user would have seen at the previous log level, and anything that is not an OpenCV log line
    (another thread's output), are written back to the original fds afterwards, so nothing visible is lost.
    Serialised by a lock: fds 1 and 2 are process-wide.
    """
    captured = NativeLog()
    if not enabled:
        yield captured
        return
    with _NATIVE_LOG_LOCK:
        try:
            saved = (os.dup(1), os.dup(2))
        except OSError:  # no stdout/stderr (daemon): nothing to capture
            yield captured
            return
        logging_api = cv2.utils.logging
        previous_level = logging_api.getLogLevel()
        sinks = (tempfile.TemporaryFile(), tempfile.TemporaryFile())
        try:
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except (AttributeError, ValueError, OSError):
                    pass
            os.dup2(sinks[0].fileno(), 1)
            os.dup2(sinks[1].fileno(), 2)
            logging_api.setLogLevel(max(previous_level, logging_api.LOG_LEVEL_DEBUG))
            yield captured
        finally:
            logging_api.setLogLevel(previous_level)
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            texts = []
            for fd, sink in zip((1, 2), sinks, strict=True):
                sink.seek(0)
                text = sink.read().decode("utf-8", errors="replace")
                sink.close()
                texts.append(text)
                visible = [line for line in text.splitlines(keepends=True)
                           if (_opencv_line_level(line) or 0) <= previous_level]
                if visible:
                    os.write(fd, "".join(visible).encode())
            for fd in saved:
                os.close(fd)
            captured.text = "".join(texts)


# --- diagnosis helpers --------------------------------------------------------------------------------------------


def probe_node(path: str) -> int:
    """Try to open the device node the way the V4L2 backend does; return 0 or the errno of the failure."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
    except OSError as error:
        return error.errno or errno.EIO
    os.close(fd)
    return 0


def device_holders(path: str, proc_root: str | os.PathLike[str] = "/proc") -> list[str]:
    """Processes with ``path`` open, as 'name (pid N)'; best effort, empty when /proc is not readable."""
    try:
        target = os.path.realpath(path)
        entries = os.listdir(proc_root)
    except OSError:
        return []
    holders = []
    for pid in sorted((entry for entry in entries if entry.isdigit()), key=int):
        fd_dir = os.path.join(proc_root, pid, "fd")
        try:
            fds = os.listdir(fd_dir)
        except OSError:
            continue
        for fd in fds:
            try:
                link = os.readlink(os.path.join(fd_dir, fd))
            except OSError:
                continue
            if link == target or os.path.realpath(link) == target:
                try:
                    name = Path(proc_root, pid, "comm").read_text().strip()
                except OSError:
                    name = "?"
                holders.append(f"{name} (pid {pid})")
                break
    return holders


# --- the driver ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Control:
    field: str
    prop: int
    to_device: Callable[[Any], float]
    from_device: Callable[[float], Any]
    # True when a device without the control satisfies the request (an auto switch asked off: a camera that
    # cannot auto-adjust is as locked as one with auto turned off).
    absent_ok: Callable[[Any], bool] = lambda asked: False


def _auto_exposure_from_device(value: float) -> bool | None:
    return None if value < 0 else int(round(value)) != V4L2_EXPOSURE_MANUAL


def _switch_from_device(value: float) -> bool | None:
    return None if value < 0 else bool(int(round(value)))


def _raw_from_device(value: float) -> float | None:
    return None if value < 0 else float(round(value))


_CONTROLS = (
    _Control("auto_exposure", cv2.CAP_PROP_AUTO_EXPOSURE,
             lambda on: V4L2_EXPOSURE_APERTURE_PRIORITY if on else V4L2_EXPOSURE_MANUAL,
             _auto_exposure_from_device, absent_ok=lambda asked: not asked),
    _Control("exposure_us", cv2.CAP_PROP_EXPOSURE, lambda us: round(us / EXPOSURE_UNIT_US),
             lambda value: None if value < 0 else float(round(value)) * EXPOSURE_UNIT_US),
    _Control("gain", cv2.CAP_PROP_GAIN, lambda gain: round(gain), _raw_from_device),
    _Control("auto_white_balance", cv2.CAP_PROP_AUTO_WB, lambda on: 1 if on else 0, _switch_from_device,
             absent_ok=lambda asked: not asked),
    _Control("white_balance_k", cv2.CAP_PROP_WB_TEMPERATURE, lambda kelvin: round(kelvin), _raw_from_device),
    _Control("autofocus", cv2.CAP_PROP_AUTOFOCUS, lambda on: 1 if on else 0, _switch_from_device,
             absent_ok=lambda asked: not asked),
    _Control("focus", cv2.CAP_PROP_FOCUS, lambda value: round(value), _raw_from_device),
)


class V4L2Camera(CameraBase):
    """A UVC/V4L2 camera through OpenCV.

    ``path``: the device node to open; pass a stable name (``/dev/v4l/by-id/...``, or a node resolved by
    ``drivers.camera.usb_identity.resolve_camera``), never a bare ``/dev/videoN`` chosen by hand.
    ``settings``: what to set and verify at ``open()``; ``None`` fields are left as the device has them.
    ``capture_factory``/``api_preference``: how the capture object is made (tests inject fakes; a file or image
    sequence can be read with ``cv2.CAP_IMAGES``/``cv2.CAP_FFMPEG``). ``probe``/``proc_root``: how a failed open
    is diagnosed. ``clock``: the host clock (seconds, monotonic).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        settings: CameraSettings | None = None,
        *,
        name: str | None = None,
        capture_factory: CaptureFactory = cv2.VideoCapture,
        api_preference: int = cv2.CAP_V4L2,
        probe: Callable[[str], int] = probe_node,
        proc_root: str | os.PathLike[str] = "/proc",
        capture_native_log: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.path = os.fspath(path)
        self.requested_settings = settings if settings is not None else CameraSettings()
        self.name = name or self.path
        self._factory = capture_factory
        self._api = api_preference
        self._probe = probe
        self._proc_root = proc_root
        self._capture_native_log = capture_native_log
        self._clock = clock
        self._cap: VideoCaptureLike | None = None
        self._in_force: CameraSettings | None = None
        self._sequence = 0
        self._streaming = False
        self._pending: tuple[float, str, int] | None = None
        self._gone_error: CameraGone | None = None

    # -- identity --------------------------------------------------------------------------------------------------

    @property
    def source(self) -> str:
        return f"v4l2:{self.name}"

    @property
    def is_open(self) -> bool:
        return self._cap is not None

    @property
    def settings(self) -> CameraSettings:
        """Read back at the last ``open()`` (kept after ``close()`` for the record); requested before any open."""
        return self._in_force if self._in_force is not None else self.requested_settings

    def __repr__(self) -> str:
        return f"V4L2Camera({self.path!r}, open={self.is_open})"

    # -- open / close ----------------------------------------------------------------------------------------------

    def open(self) -> None:
        if self._cap is not None:
            return
        self._gone_error = None
        self._in_force = None
        if self._api == cv2.CAP_V4L2 and os.environ.get("OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED", "0").lower() not in (
                "0", "false", "off", "no", ""):
            # Normalised [0, 1) control values would make every raw V4L2 value set here wrong.
            raise CameraError(f"{self.path}: unset OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED; this driver sets raw V4L2 "
                              f"control values", device=self.path)
        with native_log(self._capture_native_log) as native:
            cap = self._factory(self.path, self._api)
            opened = bool(cap.isOpened())
        if not opened:
            cap.release()
            raise self._open_failure(native)
        self._cap = cap
        self._sequence = 0
        self._streaming = False
        self._pending = None
        try:
            self._in_force = self._apply_settings(cap)
        except BaseException:
            self.close()
            raise
        log.info("%s: opened, settings in force %s", self.source, self._in_force.model_dump(exclude_none=True))

    def close(self) -> None:
        cap, self._cap = self._cap, None
        self._pending = None
        if cap is not None:
            try:
                cap.release()
            except Exception as error:  # a vanished device must not stop cleanup
                log.warning("%s: release failed: %s", self.source, error)

    def _open_failure(self, native: NativeLog) -> CameraError:
        path = self.path
        code = self._probe(path)
        if code == errno.ENOENT:
            return CameraNotFound(
                f"{path}: no such camera; check it is plugged in and run `stereo-bench devices` for stable names",
                device=path)
        if code in (errno.EACCES, errno.EPERM):
            return CameraAccessDenied(
                f"{path}: permission denied; add your user to the 'video' group "
                f"(sudo usermod -aG video $USER, then log in again)", device=path)
        if code == errno.EBUSY or native.has(r"device is busy|errno=16\b|Device or resource busy"):
            return self._busy(path)
        if native.has(r"No space left on device|errno=28\b"):
            return self._bandwidth(path)
        if code == errno.ENODEV or code == errno.ENXIO:
            return CameraGone(f"{path}: the node exists but its device is gone; replug the camera", device=path)
        if native.has(r"Inappropriate ioctl|errno=25\b|unable to capture video|Unable to query capability"):
            return CameraNotFound(
                f"{path}: not a V4L2 video-capture device (a metadata node or not a camera?); "
                f"use the camera's '-video-index0' link from `stereo-bench devices`", device=path)
        if native.has(r"Pixel format of incoming image is unsupported"):
            return CameraNotFound(f"{path}: the camera offers no pixel format OpenCV can decode", device=path)
        return CameraError(
            f"{path}: could not open the camera with V4L2 (no reason reported); "
            f"check it with `v4l2-ctl -d {path} --all`", device=path)

    def _busy(self, path: str) -> CameraBusy:
        holders = device_holders(path, self._proc_root)
        who = f"held by {', '.join(holders)}" if holders else "another program is using it"
        return CameraBusy(f"{path}: device is busy ({who}); close that program and retry", device=path)

    @staticmethod
    def _bandwidth(path: str) -> CameraBandwidthError:
        return CameraBandwidthError(
            f"{path}: not enough USB bandwidth to stream (No space left on device); use MJPG, a lower resolution "
            f"or frame rate, or put each camera on its own USB controller", device=path)

    # -- settings --------------------------------------------------------------------------------------------------

    def _apply_settings(self, cap: VideoCaptureLike) -> CameraSettings:
        """Set what was asked, in the order the V4L2 backend needs, verifying each read-back.

        Format (FourCC, then size, then fps, then buffers) first: each of those restarts the stream inside
        OpenCV and some cameras reset their controls when the format changes. Auto switches go before the
        manual values they would otherwise overwrite.
        """
        asked = self.requested_settings
        path = self.name
        formats = f"list what the camera supports with `v4l2-ctl -d {self.path} --list-formats-ext`"
        controls = f"list the camera's controls and ranges with `v4l2-ctl -d {self.path} --list-ctrls`"

        if asked.pixel_format is not None:
            cap.set(cv2.CAP_PROP_FOURCC, fourcc_to_int(asked.pixel_format))
            got = fourcc_to_str(cap.get(cv2.CAP_PROP_FOURCC))
            if got != asked.pixel_format:
                raise ControlNotAccepted("pixel_format", asked.pixel_format, got, device=path, remedy=formats)
        if asked.width_px is not None and asked.height_px is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, asked.width_px)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, asked.height_px)
            got_size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            if got_size != (asked.width_px, asked.height_px):
                raise ControlNotAccepted("frame size", f"{asked.width_px}x{asked.height_px}",
                                         f"{got_size[0]}x{got_size[1]}", device=path, remedy=formats)
        if asked.fps is not None:
            cap.set(cv2.CAP_PROP_FPS, asked.fps)
            got_fps = cap.get(cv2.CAP_PROP_FPS)
            if abs(got_fps - asked.fps) > FPS_TOLERANCE * asked.fps:
                raise ControlNotAccepted("fps", asked.fps, round(got_fps, 3) if got_fps > 0 else None,
                                         device=path, remedy=formats)
        if asked.buffer_count is not None:
            cap.set(cv2.CAP_PROP_BUFFERSIZE, asked.buffer_count)
            got_buffers = int(cap.get(cv2.CAP_PROP_BUFFERSIZE))
            # More buffers than asked is survivable (flush() drains however many there are); fewer cannot happen.
            if got_buffers > asked.buffer_count:
                log.warning("%s: driver keeps %d buffers (asked %d); flush() drains them all",
                            path, got_buffers, asked.buffer_count)

        for control in _CONTROLS:
            value = getattr(asked, control.field)
            if value is None:
                continue
            device_value = control.to_device(value)
            cap.set(control.prop, device_value)
            raw = cap.get(control.prop)
            if raw < 0 and control.absent_ok(value):
                continue
            if raw < 0 or round(raw) != round(device_value):
                raise ControlNotAccepted(control.field, value, control.from_device(raw), device=path, remedy=controls)

        return self._read_back(cap)

    def _read_back(self, cap: VideoCaptureLike) -> CameraSettings:
        width, height = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = cap.get(cv2.CAP_PROP_FPS)
        buffers = int(cap.get(cv2.CAP_PROP_BUFFERSIZE))
        values: dict[str, Any] = {
            "pixel_format": fourcc_to_str(cap.get(cv2.CAP_PROP_FOURCC)),
            "width_px": width if width > 0 and height > 0 else None,
            "height_px": height if width > 0 and height > 0 else None,
            "fps": fps if fps > 0 else None,
            "buffer_count": buffers if 1 <= buffers <= 10 else None,
        }
        for control in _CONTROLS:
            values[control.field] = control.from_device(cap.get(control.prop))
        # Read-backs from a device in an auto mode can contradict the model's "manual value needs auto off" rule
        # (e.g. the exposure an auto loop chose): record them as they are.
        return CameraSettings.model_construct(**values)

    # -- frames ----------------------------------------------------------------------------------------------------

    def grab(self) -> float:
        cap = self._require_cap()
        first = not self._streaming
        with native_log(self._capture_native_log and first) as native:
            ok = bool(cap.grab())
        host_s = self._clock()
        if not ok:
            self._pending = None
            raise self._grab_failure(native, first)
        self._streaming = True
        stamp_ms = cap.get(cv2.CAP_PROP_POS_MSEC)
        if stamp_ms > 0 and abs(stamp_ms / 1000.0 - host_s) < BUFFER_STAMP_PLAUSIBLE_S:
            timestamp_s, stamp_source = stamp_ms / 1000.0, "v4l2-buffer"
        else:
            timestamp_s, stamp_source = host_s, "host"
        self._sequence += 1
        self._pending = (timestamp_s, stamp_source, self._sequence)
        return timestamp_s

    def retrieve(self) -> Frame:
        cap = self._require_cap()
        if self._pending is None:
            raise CameraError(f"{self.source}: retrieve() needs a successful grab() first", device=self.path)
        timestamp_s, stamp_source, sequence = self._pending
        self._pending = None
        ok, image = cap.retrieve()
        if not ok or image is None or image.size == 0:
            if not os.path.exists(self.path):
                raise self._gone()
            raise CaptureFailed(f"{self.path}: frame {sequence} could not be decoded (corrupt MJPG data?); "
                                f"check the cable, or capture again", device=self.path)
        return Frame(image=image, timestamp_s=timestamp_s, sequence=sequence, settings=self.settings,
                     source=self.source, timestamp_source=stamp_source)

    def flush(self) -> None:
        """Drop every queued buffer, then one more frame.

        The extra frame is the one whose exposure may have started before the flush (the sensor exposes
        continuously), so the next ``capture()`` is exposed entirely after this call. Costs about
        (buffers + 1) frame periods.
        """
        self._require_cap()
        buffers = self.settings.buffer_count or 4  # OpenCV's default when the backend does not report it
        for _ in range(buffers + 1):
            self.grab()
        self._pending = None

    def _grab_failure(self, native: NativeLog, first: bool) -> CameraError:
        path = self.path
        if native.has(r"No space left on device|errno=28\b"):
            return self._bandwidth(path)
        if not os.path.exists(path):
            return self._gone()
        if first and native.has(r"device is busy|errno=16\b|Device or resource busy"):
            return self._busy(path)
        return CaptureFailed(
            f"{path}: no frame (timed out or dropped); if it repeats, check the cable and power "
            f"or USB-reset the camera (drivers.camera.usb_identity.usb_reset)", device=path)

    def _gone(self) -> CameraGone:
        self.close()
        # Remembered so every later call says "gone" rather than "not open" until the camera is reopened.
        self._gone_error = CameraGone(
            f"{self.path}: camera disappeared (unplugged or reset); reconnect it and find it again "
            f"with `stereo-bench devices`", device=self.path)
        return self._gone_error

    def _require_cap(self) -> VideoCaptureLike:
        if self._cap is None:
            raise self._gone_error or self._not_open()
        return self._cap
