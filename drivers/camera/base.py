"""The camera contract every driver meets: the ``Camera`` protocol, ``Frame``, ``CameraSettings`` and the errors.

The campaign runner, the stereo pair and the recorder see cameras only through this module, so the V4L2 driver,
the simulated camera and the replay driver are interchangeable.

Contract (all drivers):

* Constructing a camera does no I/O; ``open()`` does, ``close()`` is idempotent and never raises for a camera
  that is gone (cleanup must always be possible), and the context manager opens and closes.
* ``grab()`` takes the next frame off the device and returns its timestamp; ``retrieve()`` decodes the grabbed
  frame. The split lets a stereo pair grab both cameras back to back before spending time decoding either.
* ``capture()`` is ``grab()`` then ``retrieve()``.
* ``flush()`` discards frames that were queued before it was called (call it after every rig move).
* ``settings`` are the settings *read back from the device*, not the ones asked for.
* Timestamps are seconds on the ``time.monotonic()`` clock (CLOCK_MONOTONIC on Linux, the clock V4L2 stamps
  UVC buffers with), so frames from two cameras compare directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, Protocol, Self, runtime_checkable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

# --- errors -------------------------------------------------------------------------------------------------------


class CameraError(Exception):
    """A camera failure; the message is one line naming the device and the remedy."""

    def __init__(self, message: str, *, device: str | None = None):
        super().__init__(message)
        self.device = device


class CameraNotFound(CameraError):
    """Nothing usable at that path or spec (missing node, not a capture node, no camera with that identity)."""


class CameraAccessDenied(CameraError):
    """The device node exists but this user may not open it."""


class CameraBusy(CameraError):
    """Another program holds the device."""


class CameraBandwidthError(CameraError):
    """The USB controller cannot reserve isochronous bandwidth for the stream (V4L2 "No space left on device")."""


class CameraGone(CameraError):
    """The device disappeared (unplugged, USB reset, driver unbound); every later call fails the same way."""


class CaptureFailed(CameraError):
    """One grab or decode failed (dropped or corrupt frame); the camera may work on the next attempt."""


class ControlNotAccepted(CameraError):
    """A setting read back differently from what was asked: ``set()`` failed, was ignored or was clamped.

    Attributes: ``control`` (settings field name), ``asked`` and ``read_back`` (``None`` when the device does
    not have the control at all).
    """

    def __init__(self, control: str, asked: Any, read_back: Any, *, device: str, remedy: str = ""):
        got = "the device has no such control" if read_back is None else f"read back {read_back!r}"
        message = f"{device}: camera did not accept {control} = {asked!r} ({got})"
        if remedy:
            message += f"; {remedy}"
        super().__init__(message, device=device)
        self.control = control
        self.asked = asked
        self.read_back = read_back


# --- settings -----------------------------------------------------------------------------------------------------


#: Largest image side (px) a camera setting or a command accepts: 20000 x 20000 is a 400-megapixel frame, past any
#: camera this bench drives; larger sizes only allocate memory.
MAX_IMAGE_SIDE_PX = 20_000
#: Longest exposure a camera setting accepts: UVC cameras expose at most 0.2-1 s (V4L2 exposure_time_absolute up to
#: 2047-10000 in 100 us steps), and every frame waits for it.
MAX_EXPOSURE_US = 1_000_000.0


class CameraSettings(BaseModel):
    """Capture format and locked image controls.

    ``None`` means "do not touch": the driver leaves the device's value and records what it reads back. A value
    means "set it and verify the read-back". The ``auto_*`` switches default to ``False`` because a measurement
    camera must not re-adjust between the calibration views and the measurement.

    Control values other than exposure are in the device's own units (V4L2 control values), because UVC cameras
    do not agree on a physical scale for gain or focus.
    """

    # no "30" or true as a number; no NaN or infinity (a control set to inf overflows the driver's int)
    model_config = ConfigDict(frozen=True, extra="forbid", strict=True, allow_inf_nan=False)

    pixel_format: str | None = Field(None, description="FourCC of the stream, e.g. 'MJPG' or 'YUYV'")
    width_px: int | None = Field(None, gt=0, le=MAX_IMAGE_SIDE_PX)
    height_px: int | None = Field(None, gt=0, le=MAX_IMAGE_SIDE_PX)
    fps: float | None = Field(None, gt=0, le=1000, description="frames per second (UVC cameras: 5-120)")
    exposure_us: float | None = Field(None, gt=0, le=MAX_EXPOSURE_US,
                                      description="exposure time, microseconds (V4L2 unit: 100 us)")
    gain: float | None = Field(None, ge=0, description="V4L2 gain control value (device units)")
    white_balance_k: float | None = Field(None, gt=0, description="white-balance colour temperature, kelvin")
    focus: float | None = Field(None, ge=0, description="V4L2 absolute focus control value (device units)")
    auto_exposure: bool | None = False
    auto_white_balance: bool | None = False
    autofocus: bool | None = False
    buffer_count: int | None = Field(1, ge=1, le=10, description="V4L2 buffers queued by the driver")

    @field_validator("pixel_format")
    @classmethod
    def _fourcc(cls, value: str | None) -> str | None:
        if value is None:
            return None
        if len(value) != 4 or not value.isascii():
            raise ValueError(f"pixel_format must be a 4-character FourCC such as 'MJPG' or 'YUYV', got {value!r}")
        return value.upper()

    @model_validator(mode="after")
    def _manual_value_needs_auto_off(self) -> CameraSettings:
        for value_field, auto_field in (
            ("exposure_us", "auto_exposure"),
            ("white_balance_k", "auto_white_balance"),
            ("focus", "autofocus"),
        ):
            if getattr(self, value_field) is not None and getattr(self, auto_field):
                raise ValueError(f"{value_field} is set but {auto_field} is on: the camera would overwrite it")
        if (self.width_px is None) != (self.height_px is None):
            raise ValueError("width_px and height_px go together: set both or neither")
        return self


# --- frames -------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Frame:
    """One image and where it came from.

    ``image``: (H, W, 3) uint8 BGR, or (H, W) for monochrome sources.
    ``timestamp_s``: when the frame was taken, seconds on the ``time.monotonic()`` clock (a simulated camera's:
    on its simulator's clock, e.g. the simulated bench's bench clock, ``drivers/sim/clock.py``).
    ``sequence``: frames taken off this camera since it was opened, 1-based; gaps mean discarded frames.
    ``settings``: the settings in force (read back), ``source``: a human-readable device description.
    ``timestamp_source``: 'v4l2-buffer' (kernel buffer stamp), 'host' (stamped when grab returned) or 'simulated'.
    """

    image: np.ndarray
    timestamp_s: float
    sequence: int
    settings: CameraSettings
    source: str
    timestamp_source: str = "host"
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.image.shape)

    def describe(self) -> dict[str, Any]:
        """A JSON-ready description without the pixels (for event streams)."""
        return {
            "source": self.source,
            "sequence": self.sequence,
            "timestamp_s": self.timestamp_s,
            "timestamp_source": self.timestamp_source,
            "shape": list(self.image.shape),
            "dtype": str(self.image.dtype),
            "settings": self.settings.model_dump(),
            **({"meta": self.meta} if self.meta else {}),
        }


# --- protocol -----------------------------------------------------------------------------------------------------


@runtime_checkable
class Camera(Protocol):
    """What the runner needs from a camera. See the module docstring for the contract."""

    @property
    def source(self) -> str:
        """Human-readable description of the device, e.g. 'v4l2:/dev/v4l/by-id/usb-...-video-index0'."""
        ...

    @property
    def is_open(self) -> bool: ...

    @property
    def settings(self) -> CameraSettings:
        """Settings in force, as read back from the device at the last ``open()``.

        Never raises (``isinstance(x, Camera)`` reads it on Python 3.11): before the first ``open()`` nothing has
        been read back, and it returns the requested settings.
        """
        ...

    def open(self) -> None: ...

    def close(self) -> None: ...

    def __enter__(self) -> Self: ...

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...

    def grab(self) -> float:
        """Take the next frame off the device; return its ``timestamp_s``. Raises ``CaptureFailed``/``CameraGone``."""
        ...

    def retrieve(self) -> Frame:
        """Decode the frame taken by the last ``grab()``."""
        ...

    def capture(self) -> Frame:
        """``grab()`` then ``retrieve()``."""
        ...

    def flush(self) -> None:
        """Discard every frame queued before this call, so the next capture shows the scene as it is now."""
        ...


class CameraBase:
    """Shared plumbing for drivers: context manager, ``capture()``, and the not-open guard."""

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def capture(self) -> Frame:
        self.grab()
        return self.retrieve()

    # Subclasses provide these.
    source: str

    def open(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def grab(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def retrieve(self) -> Frame:  # pragma: no cover - abstract
        raise NotImplementedError

    def _not_open(self) -> CameraError:
        return CameraError(f"{self.source}: camera is not open; call open() or use it as a context manager",
                           device=self.source)
