"""The emulator's motion, as data timed by :mod:`drivers.rig.motion`: a planned block (its trapezoid, whole-step
target), a feed hold's stop within it, a homing phase, and the :class:`MotionEvent` every motion that ends reports.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from drivers.rig.motion import (
    HomingMove,
    Trapezoid,
    distance_at_time,
    time_at_distance,
    trapezoid,
)


@dataclass
class _Block:
    start: dict[str, float]
    end: dict[str, float]
    length: float
    speed: float  # units/s along the path
    accel: float  # units/s² along the path
    kind: str = "G1"  # G0, G1, jog, home
    t_start: float | None = None  # sim time the block began; None while queued or held
    line: str = ""
    dwell_after: float = 0.0  # sim seconds the block lasts after the axes stop (homing's settle)
    duration: float = field(init=False)
    motion_duration: float = field(init=False)
    _t_acc: float = field(init=False)
    _t_cruise: float = field(init=False)
    _v_peak: float = field(init=False)

    def __post_init__(self) -> None:
        if self.length <= 0.0:
            self._t_acc = self._t_cruise = self._v_peak = 0.0
            self.motion_duration = 0.0
            self.duration = self.dwell_after
            return
        profile = trapezoid(self.length, self.speed, self.accel)  # the plan's estimate uses the same model
        self._t_acc, self._t_cruise, self._v_peak = profile.t_acc_s, profile.t_cruise_s, profile.v_peak
        self.motion_duration = profile.duration_s
        self.duration = self.motion_duration + self.dwell_after

    def distance_at(self, tau: float) -> float:
        """Path distance covered ``tau`` sim-seconds into the block."""
        if tau <= 0.0:
            return 0.0
        if tau >= self.motion_duration:
            return self.length
        if tau < self._t_acc:
            return 0.5 * self.accel * tau * tau
        d_acc = 0.5 * self.accel * self._t_acc * self._t_acc
        if tau < self._t_acc + self._t_cruise:
            return d_acc + self._v_peak * (tau - self._t_acc)
        left = self.motion_duration - tau
        return min(self.length, max(0.0, self.length - 0.5 * self.accel * left * left))

    def time_at(self, distance: float) -> float:
        """Sim-seconds into the block at which it has covered ``distance`` along its path."""
        profile = Trapezoid(t_acc_s=self._t_acc, t_cruise_s=self._t_cruise, v_peak=self._v_peak)
        return time_at_distance(profile, self.length, self.accel, distance)

    def speed_at(self, tau: float) -> float:
        if tau <= 0.0 or tau >= self.motion_duration:
            return 0.0
        if tau < self._t_acc:
            return self.accel * tau
        if tau < self._t_acc + self._t_cruise:
            return self._v_peak
        return self.accel * (self.motion_duration - tau)

    def position_at(self, tau: float) -> dict[str, float]:
        if self.length <= 0.0:
            return dict(self.end)
        f = self.distance_at(tau) / self.length
        return {a: self.start[a] + (self.end[a] - self.start[a]) * f for a in self.start}


@dataclass
class _Stop:
    """A controlled stop from speed ``v0`` at constant deceleration: a feed hold, a jog cancel, or the
    stop before a soft-limit alarm (protocol.c: the hold decelerates along the path; ``Hold:1`` until
    the axes stand still). ``interrupted`` is the block it cut short; its rest is planned again on resume."""

    start: dict[str, float]
    direction: dict[str, float]  # unit vector along the path, per axis
    v0: float  # units/s
    accel: float  # units/s²
    reason: str  # "hold", "cancel" (jog) or "soft_limit"
    interrupted: _Block | None = None
    line: str = ""
    kind: str = "stop"
    t_start: float | None = None
    dwell_after: float = 0.0
    length: float = field(init=False)
    duration: float = field(init=False)
    motion_duration: float = field(init=False)
    end: dict[str, float] = field(init=False)

    def __post_init__(self) -> None:
        moving = self.v0 > 0.0 and self.accel > 0.0
        self.motion_duration = self.v0 / self.accel if moving else 0.0
        self.duration = self.motion_duration
        self.length = 0.5 * self.v0 * self.motion_duration
        self.end = {a: self.start[a] + self.direction[a] * self.length for a in self.start}

    def distance_at(self, tau: float) -> float:
        t = min(max(tau, 0.0), self.motion_duration)
        return self.v0 * t - 0.5 * self.accel * t * t

    def time_at(self, distance: float) -> float:
        d = min(max(distance, 0.0), self.length)
        return (self.v0 - math.sqrt(max(0.0, self.v0 * self.v0 - 2.0 * self.accel * d))) / self.accel

    def speed_at(self, tau: float) -> float:
        if tau <= 0.0 or tau >= self.motion_duration:
            return 0.0 if tau >= self.motion_duration else self.v0
        return self.v0 - self.accel * tau

    def position_at(self, tau: float) -> dict[str, float]:
        d = self.distance_at(tau)
        return {a: self.start[a] + self.direction[a] * d for a in self.start}


@dataclass(frozen=True)
class MotionEvent:
    """One finished motion, as the emulator reports it to its listener (``GrblEmulator(on_motion=...)``).

    ``kind``: ``"move"`` (a G0/G1/jog block run to its end), ``"stop"`` (a feed hold or jog cancel that ended
    a block short), ``"abort"`` (motion cut off by an alarm, a reset or a reboot) or ``"home"`` (a homing
    cycle). ``start``/``end``: where the axes stood (physical frame, see :meth:`GrblEmulator.physical_position`)
    when it began and ended; ``start_s``/``end_s``: bench-clock times (``end_s`` is the motion model's end,
    ``t_start + duration``, not when it was noticed). ``approach``: per axis that moved, the direction it
    arrived in (+1 toward larger machine values, -1 toward smaller); after homing every axis, the direction of
    its pull-off (away from its switch).
    """

    kind: str
    start: dict[str, float]
    end: dict[str, float]
    start_s: float
    end_s: float
    approach: dict[str, int]


@dataclass(frozen=True)
class PlannedMotion:
    """What the emulator's planner holds at one instant (:meth:`GrblEmulator.planned_motion`), read atomically.

    ``end``: where the axes will stand once the queued moves have run (physical frame, whole steps);
    ``pending``: the motions still to be reported, in order, each as ``(start, end)`` physical positions
    (the running one from where it began), only those that move an axis; ``reported``: how many
    :class:`MotionEvent` the listener has been given so far. A listener that counts the events it got
    knows, by comparing with ``reported``, whether one arrived after this reading was taken.
    """

    end: dict[str, float]
    pending: tuple[tuple[dict[str, float], dict[str, float]], ...]
    reported: int


def _approach_of(start: Mapping[str, float], end: Mapping[str, float]) -> dict[str, int]:
    """Per axis that moved from ``start`` to ``end``, the sign of its motion."""
    return {a: 1 if end[a] > start[a] else -1 for a in start if abs(end[a] - start[a]) > 1e-12}


@dataclass
class _HomingPhase:
    """One move of a homing cycle (limits.c ``limits_go_home``), in the physical frame: the cycle's axes start
    together on one planner block of ``move.search`` per axis; each covers its own ``step`` (signed) and stops
    dead there (its switch, met on a seek or locate), or the block runs to its end (a pull-off; a seek whose
    switch never answers, ``run_full``). Then the ``$26`` debounce (``dwell_after``)."""

    start: dict[str, float]  # every axis, physical
    step: dict[str, float]  # per cycle axis: the signed distance it covers
    move: HomingMove
    mode: str  # "seek", "pulloff" or "locate"
    cycle: str  # the axes of this cycle
    run_full: bool = False
    line: str = ""
    kind: str = "home"
    t_start: float | None = None
    dwell_after: float = 0.0
    duration: float = field(init=False)
    motion_duration: float = field(init=False)
    end: dict[str, float] = field(init=False)

    def __post_init__(self) -> None:
        full = self.move.profile.duration_s if self.move.search > 0 else 0.0
        stops = [self.move.time_to(abs(d)) for d in self.step.values()]
        self.motion_duration = full if self.run_full else max(stops, default=0.0)
        self.duration = self.motion_duration + self.dwell_after
        self.end = {a: self.start[a] + self.step.get(a, 0.0) for a in self.start}

    def position_at(self, tau: float) -> dict[str, float]:
        if self.move.search <= 0:
            return dict(self.end)
        covered = distance_at_time(self.move.profile, self.move.search, self.move.accel, tau)
        return {a: self.start[a] + math.copysign(min(abs(self.step[a]), covered), self.step[a])
                if a in self.step else self.start[a] for a in self.start}

    def speed_at(self, tau: float) -> float:
        return 0.0  # not reported: Grbl sends no status while homing


def _lround(value: float) -> int:
    """C's lround: to the nearest integer, halves away from zero (planner.c rounds targets to steps so)."""
    return int(math.copysign(math.floor(abs(value) + 0.5), value))
