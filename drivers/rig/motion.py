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


#: The simulated rig's homing cycle: seek at this rate (units/min), then locate and pull off in a fixed time.
REFERENCE_HOMING_SEEK_RATE_PER_MIN = 3000.0
REFERENCE_HOMING_SETTLE_S = 0.5


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
