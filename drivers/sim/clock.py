"""The simulated bench's clock: virtual seconds that pass only with what the bench does.

    clock = BenchClock(time_scale=50.0)
    emulator = GrblEmulator(clock=clock)        # motion, homing, dwells and boots run on it
    bench = BenchSimulator(clock=clock, ...)     # exposures advance it; ringing is read on it
    clock.advance(0.1)                           # the runner's settle: 0.1 s pass at once

Everything the simulated bench records that depends on time (how far a head still rings when a frame
is taken, where an axis stands mid-move, the bench time stamped on frames) is a function of this
clock, and the clock is a function of the plan only:

- While the emulator has timed activity pending (a block moving, a homing cycle, a dwell, a boot), the
  clock *runs*, paced by the wall clock (``time_scale`` virtual seconds per real second), but never
  past the end of that activity (:meth:`run_until`): however late the emulator's thread notices that
  a block has finished, the time it reads is the block's exact end (``t_start + duration`` of the
  motion model), and the next block starts there.
- Otherwise it is *frozen*: a move commanded while idle starts at the frozen time, whenever its line
  arrives in real time. Time then passes only by explicit :meth:`advance` calls: the campaign's
  settle waits, each frame's exposure and readout. A preview advances nothing.

So ``time_scale`` only paces the simulation against the wall clock: it changes no recorded number,
and neither does a loaded machine, a slow render or a late driver.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable


class BenchClock:
    """Virtual seconds (from 0 at construction), frozen unless timed activity runs it (module docstring).

    ``time_scale``: virtual seconds per real second while running (> 0; ``inf`` jumps at once to the end of
    the pending activity). ``wall``: the real clock (monotonic seconds; injectable for tests).
    Thread-safe.
    """

    def __init__(self, time_scale: float = 1.0, *, wall: Callable[[], float] = time.monotonic):
        if not time_scale > 0:  # NaN too
            raise ValueError(f"time_scale must be > 0, not {time_scale!r}")
        self.time_scale = float(time_scale)
        self._wall = wall
        self._lock = threading.Lock()
        self._t_s = 0.0  # virtual time at the anchor (while frozen: the time)
        self._anchor_wall: float | None = None  # wall time the clock started running; None: frozen
        self._until_s = 0.0  # while running: it stops here (the end of the pending activity)

    def _now_locked(self) -> float:
        if self._anchor_wall is None:
            return self._t_s
        if self.time_scale == math.inf:
            return self._until_s
        return min(self._t_s + (self._wall() - self._anchor_wall) * self.time_scale, self._until_s)

    def now(self) -> float:
        """Virtual seconds now."""
        with self._lock:
            return self._now_locked()

    @property
    def running(self) -> bool:
        """Whether timed activity is pending (the clock moves with the wall clock, up to its end)."""
        with self._lock:
            return self._anchor_wall is not None

    def run_until(self, until_s: float) -> None:
        """Run (paced by the wall clock) until virtual time ``until_s`` at most: the end of the activity pending.

        Called again with a later or earlier end as the activity changes (a block queued behind the running
        one, a feed hold). An end at or before now freezes the clock where it is.
        """
        with self._lock:
            now = self._now_locked()
            if not until_s > now:
                self._t_s, self._anchor_wall = now, None
                return
            self._t_s, self._anchor_wall, self._until_s = now, self._wall(), float(until_s)

    def freeze(self) -> float:
        """Nothing timed is pending: stop where the clock is (the end of the last activity, exactly). Returns it."""
        with self._lock:
            self._t_s, self._anchor_wall = self._now_locked(), None
            return self._t_s

    def advance(self, seconds: float) -> float:
        """``seconds`` of virtual time pass at once (a settle, an exposure); returns the time after.

        While timed activity runs this hurries it (never past its end: the emulator then ends it there); in
        a campaign it is called only while the rig is idle, when the clock is frozen.
        """
        if not seconds >= 0:  # NaN too
            raise ValueError(f"seconds must be >= 0, not {seconds!r}")
        with self._lock:
            self._t_s += seconds
            return self._now_locked()

    def real_seconds_until(self, t_s: float) -> float:
        """Real seconds until the clock reads ``t_s`` (0 if it has; inf if it will not without an advance)."""
        with self._lock:
            now = self._now_locked()
            if t_s <= now:
                return 0.0
            if self._anchor_wall is None or t_s > self._until_s:
                return math.inf
            return (t_s - now) / self.time_scale
