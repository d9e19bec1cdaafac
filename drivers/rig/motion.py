"""GRBL's motion time model: one straight move from rest to rest, with a trapezoidal velocity profile.

Pure functions, no I/O, imported by both the campaign plan (predicted durations) and the GRBL
emulator (timed motion), so the prediction and the simulated rig cannot drift apart::

    limits = path_limits({"X": 50.0}, max_rate_per_min={"X": 3000.0}, acceleration={"X": 200.0})
    profile = trapezoid(limits.length, limits.speed, limits.accel)   # profile.duration_s == 1.25
    move_time_s({"X": 50.0}, max_rate_per_min=..., acceleration=...)  # the same, in one call

Units are machine units (mm, or a rotary axis' own unit): lengths in units, speeds in units/s,
accelerations in units/s², rates as GRBL writes them ($110-$115) in units/min.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class AxisMotion:
    """One axis' limits as GRBL's settings give them: max rate ($11x, units/min), acceleration ($12x, units/s²)."""

    max_rate_per_min: float
    acceleration: float


#: The reference rig's axes: the simulated rig runs with these, and the plan's duration estimate
#: assumes them (a real controller's $110-$125 are not known offline).
REFERENCE_AXIS_MOTION: dict[str, AxisMotion] = {
    "X": AxisMotion(max_rate_per_min=3000.0, acceleration=200.0),
    "Y": AxisMotion(max_rate_per_min=1800.0, acceleration=180.0),
    "Z": AxisMotion(max_rate_per_min=1800.0, acceleration=180.0),
    "A": AxisMotion(max_rate_per_min=1800.0, acceleration=180.0),
    "B": AxisMotion(max_rate_per_min=1800.0, acceleration=180.0),
    "C": AxisMotion(max_rate_per_min=6000.0, acceleration=300.0),
}


#: limits.c: the seek covers 1.5 x the cycle's longest travel ($13x), a locate 5 x the pull-off ($27).
HOMING_SEARCH_SCALAR = 1.5
HOMING_LOCATE_SCALAR = 5.0


@dataclass(frozen=True)
class HomingSettings:
    """The homing cycle's settings (units/min, ms, units): ``$25`` seek rate, ``$24`` locate feed rate, ``$26``
    debounce, ``$27`` pull-off, and N_HOMING_LOCATE_CYCLE (config.h; grblHAL's ``$43``)."""

    seek_rate_per_min: float
    feed_rate_per_min: float
    debounce_ms: float
    pulloff: float
    locate_cycles: int = 1


#: The simulated rig's homing settings; the plan's estimate assumes them for a real controller too (its $24-$27
#: are not known offline). Grbl's defaults.h has $25=500 and $24=25: a slower real rig homes slower.
REFERENCE_HOMING = HomingSettings(seek_rate_per_min=3000.0, feed_rate_per_min=200.0, debounce_ms=100.0,
                                  pulloff=1.0)


def homing_cycles(axes: str) -> list[str]:
    """The axes each homing cycle moves together, in order: config.h HOMING_CYCLE_0 = Z, HOMING_CYCLE_1 = X and
    Y (grblHAL's defaults, ``$44``/``$45``, are the same), then the other axes of a grblHAL board together (its
    ``$46``, which a rig driving A/B/C must set). Axes the controller lacks are left out."""
    cycles = ["Z", "XY", "ABC"]
    return [kept for kept in ("".join(a for a in cycle if a in axes) for cycle in cycles) if kept]


@dataclass(frozen=True)
class HomingMove:
    """One move of a homing cycle (limits.c ``limits_go_home``): every axis of the cycle starts together on one
    planner block of ``search`` units per axis at the cycle's rate (vector feed rate x sqrt(n), so that each axis
    moves at the rate, capped by ``$11x``, ramping at ``$12x``); an axis stops dead where it meets its switch
    (``stop`` units along its way, approach moves), or at the block's end (pull-offs). Units per axis."""

    search: float
    speed: float  # units/s, per axis
    accel: float  # units/s², per axis

    @property
    def profile(self) -> Trapezoid:
        return trapezoid(self.search, self.speed, self.accel)

    def time_to(self, distance: float) -> float:
        """When an axis has covered ``distance`` (<= ``search``) along this move, s."""
        return time_at_distance(self.profile, self.search, self.accel, distance)


def homing_move(search: float, rate_per_min: float, *, max_rate_per_min: float, acceleration: float) -> HomingMove:
    """The per-axis profile of a homing move (``max_rate_per_min`` and ``acceleration``: the lowest ``$11x``/``$12x``
    of the cycle's axes, as the planner applies each axis' limit to the block; every axis has the same |delta|, so
    the vector feed rate x sqrt(n) is ``rate_per_min`` per axis)."""
    return HomingMove(search=search, speed=min(rate_per_min, max_rate_per_min) / 60.0, accel=acceleration)


def distance_at_time(profile: Trapezoid, length: float, accel: float, tau: float) -> float:
    """Distance covered ``tau`` s into a move of ``length`` with ``profile`` (ramping at ``accel``)."""
    if tau <= 0.0:
        return 0.0
    if tau >= profile.duration_s:
        return length
    if tau < profile.t_acc_s:
        return 0.5 * accel * tau * tau
    d_acc = 0.5 * accel * profile.t_acc_s ** 2
    if tau < profile.t_acc_s + profile.t_cruise_s:
        return d_acc + profile.v_peak * (tau - profile.t_acc_s)
    left = profile.duration_s - tau
    return min(length, max(0.0, length - 0.5 * accel * left * left))


def time_at_distance(profile: Trapezoid, length: float, accel: float, distance: float) -> float:
    """When a move of ``length`` with ``profile`` (ramping at ``accel``) has covered ``distance``, s."""
    d = min(max(distance, 0.0), length)
    d_acc = 0.5 * accel * profile.t_acc_s ** 2
    if d <= d_acc:
        return math.sqrt(2.0 * d / accel)
    if d <= length - d_acc:
        return profile.t_acc_s + (d - d_acc) / profile.v_peak
    left = length - d
    return profile.duration_s - math.sqrt(2.0 * left / accel)


def homing_time_s(to_switch: Mapping[str, float], *, max_travel: Mapping[str, float], homing: HomingSettings,
                  max_rate_per_min: Mapping[str, float], acceleration: Mapping[str, float]) -> float:
    """Duration (s) of a successful homing cycle (``$H``), as Grbl 1.1h and grblHAL run it.

    ``to_switch``: axis letter -> distance (units) from where the axis stands to its homing switch;
    ``max_travel``: ``$13x`` per axis (the seek's search is 1.5 x the cycle's longest). Per cycle
    (:func:`homing_cycles`): seek to the switches at ``$25``, pull off ``$27`` at ``$25``, then
    ``locate_cycles`` x (locate at ``$24``, pull off), each move followed by the ``$26`` debounce.
    """
    total = 0.0
    debounce = homing.debounce_ms / 1000.0
    for cycle in homing_cycles("".join(to_switch)):
        rate = min(max_rate_per_min[a] for a in cycle)
        accel = min(acceleration[a] for a in cycle)
        search = HOMING_SEARCH_SCALAR * max(max_travel[a] for a in cycle)
        seek = homing_move(search, homing.seek_rate_per_min, max_rate_per_min=rate, acceleration=accel)
        pull = homing_move(homing.pulloff, homing.seek_rate_per_min, max_rate_per_min=rate,
                           acceleration=accel)
        locate = homing_move(HOMING_LOCATE_SCALAR * homing.pulloff, homing.feed_rate_per_min,
                             max_rate_per_min=rate, acceleration=accel)
        total += max(seek.time_to(to_switch[a]) for a in cycle) + debounce
        pulloff_s = pull.profile.duration_s if homing.pulloff > 0 else 0.0
        total += pulloff_s + debounce
        for _ in range(homing.locate_cycles):
            total += locate.time_to(homing.pulloff) + debounce + pulloff_s + debounce
    return total


@dataclass(frozen=True)
class PathLimits:
    """A straight move's path ``length`` (units) and the ``speed`` (units/s) and ``accel`` (units/s²) along it."""

    length: float
    speed: float
    accel: float


@dataclass(frozen=True)
class Trapezoid:
    """Velocity profile of a move from rest to rest: ramp up for ``t_acc_s``, cruise ``t_cruise_s``, ramp down.

    Triangular (``t_cruise_s`` = 0) when the move is too short to reach its speed; ``v_peak`` is the
    highest speed reached (units/s).
    """

    t_acc_s: float
    t_cruise_s: float
    v_peak: float

    @property
    def duration_s(self) -> float:
        return 2.0 * self.t_acc_s + self.t_cruise_s


def path_limits(deltas: Mapping[str, float], *, max_rate_per_min: Mapping[str, float],
                acceleration: Mapping[str, float], feed_per_min: float | None = None) -> PathLimits:
    """Length, speed and acceleration along a straight move of ``deltas`` (axis letter -> units).

    Each moving axis' max rate and acceleration bound the speed and acceleration along the path, as
    GRBL's planner does; ``feed_per_min`` (None = rapid) bounds the speed too.
    """
    moving = {axis: delta for axis, delta in deltas.items() if abs(delta) > 0}
    length = math.sqrt(sum(delta * delta for delta in moving.values()))
    speed = math.inf if feed_per_min is None else feed_per_min / 60.0
    accel = math.inf
    for axis, delta in moving.items():
        speed = min(speed, max_rate_per_min[axis] / 60.0 * length / abs(delta))
        accel = min(accel, acceleration[axis] * length / abs(delta))
    return PathLimits(length=length, speed=speed, accel=accel)


def trapezoid(length: float, speed: float, accel: float) -> Trapezoid:
    """The profile of a move of ``length`` at most ``speed``, ramping at ``accel`` (length > 0)."""
    t_acc = speed / accel
    d_acc = 0.5 * accel * t_acc * t_acc
    if 2.0 * d_acc >= length:  # the two ramps cover the whole move: it never cruises
        t_acc = math.sqrt(length / accel)
        return Trapezoid(t_acc_s=t_acc, t_cruise_s=0.0, v_peak=accel * t_acc)
    return Trapezoid(t_acc_s=t_acc, t_cruise_s=(length - 2.0 * d_acc) / speed, v_peak=accel * t_acc)


def move_time_s(deltas: Mapping[str, float], *, max_rate_per_min: Mapping[str, float],
                acceleration: Mapping[str, float], feed_per_min: float | None = None) -> float:
    """Duration (s) of one straight move of ``deltas`` from rest to rest; 0 for no motion."""
    limits = path_limits({a: d for a, d in deltas.items() if abs(d) > 1e-12}, max_rate_per_min=max_rate_per_min,
                         acceleration=acceleration, feed_per_min=feed_per_min)
    if limits.length == 0.0:
        return 0.0
    return trapezoid(limits.length, limits.speed, limits.accel).duration_s
