"""Replay drivers: a recorded session's rig telemetry and frames, served through the live protocols.

They know nothing of the session format: the caller hands them the recorded readings and a function
that loads a recorded frame pair, so the campaign runner drives them exactly as it drives hardware.
A request that differs from what was recorded is an error, never silently served with other data.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from drivers.camera.base import CameraError, CameraSettings, Frame
from drivers.camera.stereo import StereoFrame
from drivers.rig.rig import RigReading


class ReplayMismatch(RuntimeError):
    """The replayed run asked for something the recording does not hold."""


class ReplayRig:
    """Serves recorded readings in order; each ``move_to`` must request what was recorded."""

    def __init__(self, readings: Iterable[Mapping[str, Any]], *, tolerance: float = 1e-6):
        self._readings = deque(dict(r) for r in readings)
        self._last: RigReading | None = None
        self.tolerance = tolerance

    def open(self) -> ReplayRig:
        return self

    def close(self) -> None:
        return None

    def __enter__(self) -> ReplayRig:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @staticmethod
    def _reading(data: Mapping[str, Any]) -> RigReading:
        fields = {k: data.get(k) for k in RigReading.__dataclass_fields__}
        fields["sources"] = dict(data.get("sources") or {})
        fields["state"] = data.get("state") or "Idle"
        fields["timestamp"] = float(data.get("timestamp") or 0.0)
        return RigReading(**fields)

    def home(self, *, timeout_s: float | None = None) -> RigReading:
        return self.read()

    def move_to(self, *, timeout_s: float | None = None, **request: float | None) -> RigReading:
        if not self._readings:
            raise ReplayMismatch(f"replay: a move to {request} was not recorded")
        recorded = self._readings.popleft()
        for quantity, value in request.items():
            if value is None or recorded.get(quantity) is None:
                continue
            if not math.isclose(float(value), float(recorded[quantity]), abs_tol=self.tolerance):
                raise ReplayMismatch(f"replay: move asks {quantity} = {value:g}, the recording holds "
                                     f"{recorded[quantity]:g}")
        self._last = self._reading(recorded)
        return self._last

    def read(self) -> RigReading:
        if self._last is not None:
            return self._last
        if self._readings:
            return self._reading(self._readings[0])
        raise ReplayMismatch("replay: no rig telemetry recorded")

    def stop(self) -> None:
        return None


class ReplayStereoCamera:
    """Serves recorded frame pairs: the runner ``expect``s a key, then ``capture_pair`` returns it.

    ``load_pair(key)`` returns (left image, right image, meta) where meta may hold the recorded
    ``left``/``right`` frame descriptions (timestamps, sequence numbers) and ``dt_s``.
    """

    def __init__(self, load_pair: Callable[[str], tuple[np.ndarray, np.ndarray, dict]]):
        self._load = load_pair
        self._expected: deque[str] = deque()
        self._open = False

    def open(self) -> ReplayStereoCamera:
        self._open = True
        return self

    def close(self) -> None:
        self._open = False

    def __enter__(self) -> ReplayStereoCamera:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._open

    def expect(self, key: str) -> None:
        """The next ``capture_pair`` serves the recorded pair ``key``."""
        self._expected.append(key)

    def flush(self) -> None:
        return None

    def capture_pair(self) -> StereoFrame:
        if not self._open:
            raise CameraError("replay cameras are not open")
        if not self._expected:
            raise ReplayMismatch("replay: a capture was asked for that the recording does not hold")
        key = self._expected.popleft()
        left, right, meta = self._load(key)
        frames = []
        for side, image in (("left", left), ("right", right)):
            described = meta.get(side) or {}
            frames.append(Frame(
                image=image, timestamp_s=float(described.get("timestamp_s", 0.0)),
                sequence=int(described.get("sequence", 0)), settings=CameraSettings(),
                source=f"replay:{side}:{key}", timestamp_source="replay",
            ))
        return StereoFrame(left=frames[0], right=frames[1], dt_s=float(meta.get("dt_s", 0.0)))
