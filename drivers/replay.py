"""Replay drivers: a recorded session's rig telemetry and frames, served through the live protocols.

They know nothing of the session format: the caller hands them the recorded readings and a function
that loads a recorded frame pair, so the campaign runner drives them exactly as it drives hardware.
A request that differs from what was recorded is an error, never silently served with other data.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from drivers.camera.base import CameraError, CameraSettings, Frame
from drivers.camera.stereo import StereoFrame
from drivers.rig.rig import RigCapabilities, RigReading
from drivers.rig.status import RigStatus


class ReplayMismatch(RuntimeError):
    """The replayed run asked for something the recording does not hold."""


class ReplayRig:
    """Serves recorded readings in order; each ``move_to`` must request what was recorded (its status is finished
    at once). A recording has no controller to describe, reset or trust: its capabilities say so."""

    capabilities = RigCapabilities()

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

    def move_to(self, *, timeout_s: float | None = None, **request: float | None) -> RigStatus:
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
        return RigStatus.finished(self._last)

    def read(self) -> RigReading:
        if self._last is not None:
            return self._last
        if self._readings:
            return self._reading(self._readings[0])
        raise ReplayMismatch("replay: no rig telemetry recorded")

    def stop(self) -> None:
        return None

    def resume(self, *, timeout_s: float | None = None) -> RigReading:
        """Nothing was held: the recorded moves were served whole."""
        return self.read()

    def reset(self) -> RigReading:
        """Nothing to reset (``capabilities.reset`` is False: a fault's recovery only homes)."""
        return self.read()

    def trust_position(self) -> RigReading:
        """Nothing to trust (``capabilities.trust_position`` is False): the recorded readings are served."""
        return self.read()

    def homing_approach(self) -> dict[str, int]:
        return {}

    def controller_info(self) -> dict[str, Any]:
        return {}

    @property
    def warnings(self) -> list[str]:
        return []


class ReplayStereoCamera:
    """Serves recorded frame pairs: the runner ``expect``s a key, then ``capture_pair`` returns it.

    ``load_pair(key)`` returns (left image, right image, meta) where meta may hold the recorded
    ``left``/``right`` frame descriptions (timestamps, sequence numbers) and ``dt_s``.

    ``order``: the keys in the order they were recorded, which is the order a replay asks for them;
    up to ``ahead`` pairs are then loaded ahead on ``workers`` threads (reading and decoding overlap
    the analysis instead of preceding it). A key asked for out of that order is loaded when asked;
    the pairs loaded ahead of it that were skipped are dropped.
    """

    def __init__(self, load_pair: Callable[[str], tuple[np.ndarray, np.ndarray, dict]], *,
                 order: Sequence[str] = (), ahead: int = 0, workers: int = 2):
        if ahead < 0 or workers < 1:
            raise ValueError(f"ahead must be >= 0 and workers >= 1, got {ahead} and {workers}")
        self._load = load_pair
        self._expected: deque[str] = deque()
        self._open = False
        self._order = list(order) if ahead else []
        self._position = {key: i for i, key in enumerate(self._order)}
        self._next = 0  # the first key of the order not yet handed to the pool
        self._loading: dict[str, Future] = {}
        self._ahead = ahead
        self._workers = workers
        self._pool: ThreadPoolExecutor | None = None

    def open(self) -> ReplayStereoCamera:
        self._open = True
        if self._order and self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=self._workers, thread_name_prefix="replay-load")
            self._load_ahead()
        return self

    def close(self) -> None:
        self._open = False
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self._loading.clear()

    def _load_ahead(self) -> None:
        while self._pool is not None and len(self._loading) < self._ahead and self._next < len(self._order):
            key = self._order[self._next]
            self._next += 1
            self._loading[key] = self._pool.submit(self._load, key)

    def _take(self, key: str) -> tuple[np.ndarray, np.ndarray, dict]:
        """The pair ``key``: loaded ahead if it was, else now; pairs before it in the order are not needed."""
        position = self._position.get(key)
        if position is not None:
            for skipped in [k for k in self._loading if self._position[k] < position]:
                self._loading.pop(skipped).cancel()
            # Loading ahead goes on after ``key`` (a key already handed to the pool lies before _next anyway).
            self._next = max(self._next, position + 1)
        future = self._loading.pop(key, None)
        self._load_ahead()
        return future.result() if future is not None else self._load(key)

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
        left, right, meta = self._take(key)
        frames = []
        for side, image in (("left", left), ("right", right)):
            described = meta.get(side) or {}
            frames.append(Frame(
                image=image, timestamp_s=float(described.get("timestamp_s", 0.0)),
                sequence=int(described.get("sequence", 0)), settings=CameraSettings(),
                source=f"replay:{side}:{key}", timestamp_source="replay",
            ))
        return StereoFrame(left=frames[0], right=frames[1], dt_s=float(meta.get("dt_s", 0.0)))
