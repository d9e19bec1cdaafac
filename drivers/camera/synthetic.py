"""A simulated camera that meets the ``Camera`` protocol: frames come from a ``render()`` callable.

The simulated rig passes a function that renders the target from the emulator's current rig pose, so a frame
shows the scene as it was when it was *grabbed*, like a real camera. Faults are injected the way they appear on
a real V4L2 camera, so the runner's handling of them is exercised by the very same code paths:

* ``CameraFault.DROPPED_FRAME``: the next ``grab()`` raises ``CaptureFailed`` (a select timeout / lost frame).
* ``CameraFault.STALE_FRAME``: the next ``grab()`` returns the previous frame again, with its old sequence number
  and timestamp, as a buffer queued before a rig move would. ``flush()`` clears pending stale frames, which is
  exactly what it is for.
* ``CameraFault.DEVICE_GONE``: from the next call on, ``open/grab/retrieve/capture/flush`` raise ``CameraGone``;
  ``close()`` still works.
"""

from __future__ import annotations

import enum
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.camera.base import CameraBase, CameraError, CameraGone, CameraSettings, CaptureFailed, Frame


class CameraFault(enum.Enum):
    DROPPED_FRAME = "dropped_frame"
    STALE_FRAME = "stale_frame"
    DEVICE_GONE = "device_gone"


class SyntheticCamera(CameraBase):
    """A camera whose frames are ``render()`` outputs.

    ``render``: returns an (H, W, 3) uint8 BGR or (H, W) image of the scene now, or ``(image, meta)`` where
    ``meta`` is a dict (e.g. the ground-truth rig pose) that the frame carries as ``Frame.meta``.
    ``settings``: reported as the settings in force (a simulated device accepts everything); width/height, when
    given, must match what ``render`` returns. ``exposure_s``/``readout_s``: simulated time a grab takes
    (exposure, then sensor readout), seconds, multiplied by ``time_scale`` (0 makes grabs instantaneous; tests
    and fast simulations use a scale < 1). ``clock``/``sleep``: injectable time source (seconds, monotonic).
    ``ready_at``: when the frame being grabbed is read out (``time.monotonic()`` seconds), for cameras
    that share a trigger: the second camera of a hardware-triggered pair exposed at the same time as
    the first, so its grab waits for that exposure's end, not for an exposure of its own. Default: the
    (scaled) exposure + readout after the grab starts.
    """

    def __init__(
        self,
        render: Callable[[], np.ndarray | tuple[np.ndarray, dict[str, Any]]],
        *,
        name: str = "synthetic",
        settings: CameraSettings | None = None,
        exposure_s: float = 0.0,
        readout_s: float = 0.0,
        time_scale: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        ready_at: Callable[[], float] | None = None,
    ):
        if exposure_s < 0 or readout_s < 0 or time_scale < 0:
            raise ValueError("exposure_s, readout_s and time_scale must be >= 0")
        self._render = render
        self.name = name
        self.requested_settings = settings if settings is not None else CameraSettings()
        self.exposure_s = exposure_s
        self.readout_s = readout_s
        self.time_scale = time_scale
        self._clock = clock
        self._sleep = sleep
        self._ready_at = ready_at
        self._lock = threading.Lock()
        self._open = False
        self._gone = False
        self._faults: deque[CameraFault] = deque()
        self._sequence = 0
        self._last: Frame | None = None
        self._pending: Frame | None = None
        self.grabs = 0  # successful grabs, including stale ones (for tests and statistics)

    # -- identity --------------------------------------------------------------------------------------------------

    @property
    def source(self) -> str:
        return f"synthetic:{self.name}"

    @property
    def is_open(self) -> bool:
        return self._open and not self._gone

    @property
    def settings(self) -> CameraSettings:
        """A simulated device accepts every setting, so what is in force is what was asked."""
        return self.requested_settings

    # -- faults ----------------------------------------------------------------------------------------------------

    def inject(self, fault: CameraFault | str, count: int = 1) -> None:
        """Queue ``count`` faults; each applies to one future ``grab()`` (``DEVICE_GONE`` applies at once)."""
        fault = CameraFault(fault)
        with self._lock:
            if fault is CameraFault.DEVICE_GONE:
                self._gone = True
                return
            self._faults.extend([fault] * count)

    @property
    def pending_faults(self) -> list[CameraFault]:
        return list(self._faults)

    # -- lifecycle -------------------------------------------------------------------------------------------------

    def open(self) -> None:
        self._check_gone()
        self._open = True

    def close(self) -> None:
        self._open = False
        self._pending = None

    # -- frames ----------------------------------------------------------------------------------------------------

    def grab(self) -> float:
        self._check_alive()
        with self._lock:
            fault = self._faults.popleft() if self._faults else None
        if fault is CameraFault.DROPPED_FRAME:
            self._pending = None
            raise CaptureFailed(f"{self.source}: no frame (injected dropped frame)", device=self.source)
        if fault is CameraFault.STALE_FRAME and self._last is not None:
            self.grabs += 1
            self._pending = self._last
            return self._last.timestamp_s
        # Render at the start of the exposure: the frame shows the scene as it was then. The render
        # stands for the sensor's physics, so it counts against the exposure time, not on top of it.
        started = time.monotonic()  # the real time the render takes, whatever clock stamps the frames
        rendered = self._render()
        meta: dict[str, Any] = {}
        if isinstance(rendered, tuple):
            rendered, meta = rendered
        image = np.asarray(rendered)
        self._check_shape(image)
        if self._ready_at is not None:
            delay_s = self._ready_at() - time.monotonic()
        else:
            delay_s = (self.exposure_s + self.readout_s) * self.time_scale - (time.monotonic() - started)
        if delay_s > 0:
            self._sleep(delay_s)
        self._check_gone()  # the device may vanish mid-exposure
        self._sequence += 1
        self.grabs += 1
        frame = Frame(image=image, timestamp_s=self._clock(), sequence=self._sequence,
                      settings=self.requested_settings, source=self.source, timestamp_source="simulated",
                      meta=dict(meta))
        self._last = frame
        self._pending = frame
        return frame.timestamp_s

    def retrieve(self) -> Frame:
        self._check_alive()
        if self._pending is None:
            raise CameraError(f"{self.source}: retrieve() needs a successful grab() first", device=self.source)
        frame, self._pending = self._pending, None
        return frame

    def flush(self) -> None:
        """Discard queued (stale) frames; a simulated sensor has nothing else buffered."""
        self._check_alive()
        with self._lock:
            self._faults = deque(f for f in self._faults if f is not CameraFault.STALE_FRAME)
        self._pending = None

    # -- guards ----------------------------------------------------------------------------------------------------

    def _check_gone(self) -> None:
        if self._gone:
            raise CameraGone(f"{self.source}: camera disappeared (injected); reconnect it", device=self.source)

    def _check_alive(self) -> None:
        self._check_gone()
        if not self._open:
            raise self._not_open()

    def _check_shape(self, image: np.ndarray) -> None:
        settings = self.requested_settings
        if settings.width_px is None or settings.height_px is None:
            return
        if image.shape[:2] != (settings.height_px, settings.width_px):
            raise CameraError(
                f"{self.source}: render() returned {image.shape[1]}x{image.shape[0]} but the settings say "
                f"{settings.width_px}x{settings.height_px}; make the renderer and the camera settings agree",
                device=self.source)
