"""Two cameras as a stereo pair without hardware sync: grab both, then retrieve both, and check the skew.

UVC cameras free-run, each on its own clock. Grabbing left then right returns each camera's *next* frame, so the
left-right time difference is set by the phase between the two frame clocks, not by how fast we call grab():
grabbing again in the same order would give the same skew. What does help is re-grabbing the camera whose frame
is *older*: its next frame is one period later, which turns a skew of phi into phi - T (|T - phi| when phi > T/2).
So ``capture_pair()`` re-grabs the earlier camera until the skew is within ``max_skew_s``, at most
``max_attempts`` extra grabs, and then raises ``StereoSkewError``. The same rule discards a stale frame (its
timestamp is old, so it is the earlier one and gets re-grabbed). A dropped frame (``CaptureFailed``) is retried on
that camera within the same budget; ``CameraGone`` is never retried.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

from drivers.camera.base import Camera, CameraError, CameraSettings, CaptureFailed, Frame

log = logging.getLogger(__name__)


class StereoSkewError(CameraError):
    """No pair within the skew limit after the allowed re-grabs."""


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """A stereo pair: ``dt_s`` = right.timestamp_s - left.timestamp_s (seconds); ``regrabs``: extra grabs used."""

    left: Frame
    right: Frame
    dt_s: float
    regrabs: int = 0

    @property
    def skew_s(self) -> float:
        return abs(self.dt_s)

    def describe(self) -> dict[str, Any]:
        return {"dt_s": self.dt_s, "regrabs": self.regrabs, "left": self.left.describe(),
                "right": self.right.describe()}


class StereoCamera:
    """A left and a right ``Camera``; construction does no I/O.

    ``max_skew_s``: largest accepted |right - left| timestamp difference, seconds. One re-grab always reaches a
    skew of at most half a frame period (min(phi, T - phi) <= T/2), so a limit of at least T/2 always succeeds;
    the default, 20 ms, covers 30 fps (T/2 = 16.7 ms) with margin for timestamp jitter. A tighter limit succeeds
    only when the cameras' phase happens to suit it, and the phase drifts slowly, so it fails for minutes at a
    time: tighten it only with faster cameras. ``max_attempts``: extra grabs allowed per pair (re-grabs for skew
    plus retries after dropped frames).
    """

    def __init__(self, left: Camera, right: Camera, *, max_skew_s: float = 0.020, max_attempts: int = 4):
        if max_skew_s <= 0:
            raise ValueError(f"max_skew_s must be > 0 s, got {max_skew_s}")
        if max_attempts < 0:
            raise ValueError(f"max_attempts must be >= 0, got {max_attempts}")
        self.left = left
        self.right = right
        self.max_skew_s = max_skew_s
        self.max_attempts = max_attempts

    @property
    def source(self) -> str:
        return f"stereo({self.left.source}, {self.right.source})"

    @property
    def is_open(self) -> bool:
        return self.left.is_open and self.right.is_open

    @property
    def settings(self) -> tuple[CameraSettings, CameraSettings]:
        """(left, right) settings in force."""
        return self.left.settings, self.right.settings

    def open(self) -> None:
        self.left.open()
        try:
            self.right.open()
        except BaseException:
            self.left.close()
            raise

    def close(self) -> None:
        try:
            self.left.close()
        finally:
            self.right.close()

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def flush(self) -> None:
        """Flush both cameras (call after every rig move)."""
        self.left.flush()
        self.right.flush()

    def capture_pair(self) -> StereoFrame:
        """Grab left, grab right, re-grab the earlier one while the skew is over the limit, then retrieve both.

        Raises ``StereoSkewError`` (skew still over the limit), ``CaptureFailed`` (frames kept dropping) or
        ``CameraGone`` when the attempts run out or a camera disappears.
        """
        budget = [self.max_attempts]
        t_left = self._grab(self.left, budget)
        t_right = self._grab(self.right, budget)
        skews = [t_right - t_left]
        while abs(t_right - t_left) > self.max_skew_s:
            if budget[0] == 0:
                shown = ", ".join(f"{dt * 1e3:+.1f}" for dt in skews)
                raise StereoSkewError(
                    f"{self.source}: left-right skew over {self.max_skew_s * 1e3:.1f} ms after "
                    f"{self.max_attempts} re-grabs (dt = {shown} ms); the cameras' frame clocks do not line up: "
                    f"raise max_skew_s, use a higher frame rate, or reopen one camera to shift its phase")
            budget[0] -= 1
            if t_left < t_right:
                t_left = self._grab(self.left, budget)
            else:
                t_right = self._grab(self.right, budget)
            skews.append(t_right - t_left)
        left = self.left.retrieve()
        right = self.right.retrieve()
        regrabs = self.max_attempts - budget[0]
        if regrabs:
            log.debug("%s: pair after %d re-grabs, dt history %s", self.source, regrabs, skews)
        return StereoFrame(left=left, right=right, dt_s=right.timestamp_s - left.timestamp_s, regrabs=regrabs)

    @staticmethod
    def _grab(camera: Camera, budget: list[int]) -> float:
        # Re-grabs for skew are charged by the caller; here only retries after a dropped frame cost budget.
        while True:
            try:
                return camera.grab()
            except CaptureFailed:
                if budget[0] == 0:
                    raise
                budget[0] -= 1
                log.info("%s: dropped frame, grabbing again", camera.source)
