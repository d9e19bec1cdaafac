"""The emulated firmware as built and configured: its build constants (buffers, planner, banners, messages, report
delays, for Grbl 1.1h and grblHAL), the ``$$`` table's defaults (defaults.h) and how report.c prints them, and
the axes (:class:`AxisSpec`: steps, rates, accelerations, travel, homing).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

from drivers.rig.motion import (
    REFERENCE_AXIS_MOTION,
)

AXIS_LETTERS = "XYZABC"
RX_BUFFER_SIZE = 128
PLANNER_BLOCKS = 15  # GRBL 1.1 on an Uno: 16-block ring buffer, one kept free ([OPT:...,15,...])
GRBLHAL_PLANNER_BLOCKS = 100  # grblHAL's simulator: [OPT:VNML+W,100,1024,3,0]
LINE_BUFFER_SIZE = 80
N_STARTUP_LINES = 2  # config.h N_STARTUP_LINE
MM_PER_INCH = 25.4

GRBL_VERSION = "1.1h.20190830"  # grbl.h GRBL_VERSION "." GRBL_VERSION_BUILD
GRBLHAL_VERSION = "1.1f.20231210"
GRBL_BANNER = "Grbl 1.1h ['$' for help]"
GRBLHAL_BANNER = "GrblHAL 1.1f ['$' or '$HELP' for help]"
UNLOCK_MESSAGE = "[MSG:'$H'|'$X' to unlock]"
RESET_MESSAGE = "[MSG:Reset to continue]"
HELP_MESSAGE = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"

ALARM_REPORT_DELAY_S = 0.5  # report.c report_alarm_message: delay_ms(500) after every ALARM line
GRBLHAL_ALARM_REPORT_DELAY_S = 0.1  # grblHAL report.c report_alarm_message: hal.delay_ms(100)
CHECK_LIMITS_MESSAGE = "[MSG:Check Limits]"  # report.c MESSAGE_CHECK_LIMITS
GRBLHAL_DRIVER = "Simulator"  # grblHAL/Simulator driver.c: hal.info
GRBLHAL_DRIVER_VERSION = "260913"  # grblHAL/Simulator driver.c: hal.driver_version (the stored version)
AUTO_RESET_BOOT_S = 1.1  # seen on the real board: the banner ~1.1 s after the port was opened
CLIENT_POLL_S = 0.02  # how often to look for a client while nobody has the port open

#: defaults.h DEFAULTS_GENERIC (the non-axis settings; axis settings come from each AxisSpec).
DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0, 20: 0, 21: 0, 22: 0,
    23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000.0, 31: 0.0, 32: 0,
}
#: Settings report.c prints as floats (3 decimals; the spindle rpm ones with none); the rest are integers.
_FLOAT_SETTINGS = frozenset({11, 12, 24, 25, 27})
_RPM_SETTINGS = frozenset({30, 31})


# --------------------------------------------------------------------------------------------------
# The axes


@dataclass(frozen=True)
class AxisSpec:
    """One simulated axis, as its firmware settings describe it (machine units, mm for a linear axis).

    ``max_travel`` is ``$13x`` (and the real length of the axis: the emulator assumes it was set right),
    ``max_rate_per_min`` ``$11x`` (units/min), ``acceleration`` ``$12x`` (units/s²), ``steps_per_unit``
    ``$10x``; ``home_negative`` is this axis' bit of ``$23`` (its homing switch at the negative end).
    """

    max_travel: float = 350.0
    max_rate_per_min: float = 3000.0
    acceleration: float = 200.0
    steps_per_unit: float = 250.0
    home_negative: bool = False


# Rates and accelerations are the reference rig's (drivers.rig.motion), which the plan's estimate assumes too.
DEFAULT_AXES: dict[str, AxisSpec] = {
    axis: AxisSpec(max_travel=travel, max_rate_per_min=REFERENCE_AXIS_MOTION[axis].max_rate_per_min,
                   acceleration=REFERENCE_AXIS_MOTION[axis].acceleration)
    for axis, travel in {"X": 350.0, "Y": 90.0, "Z": 90.0, "A": 90.0, "B": 90.0, "C": 2000.0}.items()
}


def axis_specs_for_travel(travel: Mapping[str, tuple[float, float]], base: Mapping[str, AxisSpec] | None = None,
                          *, margin: float = 0.0) -> tuple[dict[str, AxisSpec], bool]:
    """Axis settings whose machine space covers ``travel`` (axis -> (low, high), machine units).

    Returns the specs and whether they need a HOMING_FORCE_SET_ORIGIN build. A range at or below 0 is
    what a stock Grbl gives once homed: ``$13x = -low + margin``, homing toward +. A range at or above 0
    exists only on a HOMING_FORCE_SET_ORIGIN build, homing toward - (``$23`` bit set), ``$13x = high +
    margin``. A range across 0 fits no Grbl build: it gets ``$13x = high - low`` on the stock space, and its
    positive targets meet the soft limits as they would on the real controller. ``margin`` (the pull-off,
    ``$27``) keeps the far end as far from the end of travel as a config that keeps one pull-off off the
    switch (the default mapping) is from the switch.
    """
    base = DEFAULT_AXES if base is None else base
    specs: dict[str, AxisSpec] = {}
    force_origin = False
    for axis, (low, high) in travel.items():
        spec = base.get(axis, AxisSpec())
        if high <= 0.0:
            specs[axis] = replace(spec, max_travel=max(-low + margin, 1e-3), home_negative=False)
        elif low >= 0.0:
            specs[axis] = replace(spec, max_travel=max(high + margin, 1e-3), home_negative=True)
            force_origin = True
        else:
            specs[axis] = replace(spec, max_travel=high - low, home_negative=False)
    return specs, force_origin


def _fmt_setting(number: int, value: float) -> str:
    """report.c: integer settings bare, float settings with 3 decimals, the rpm ones with none."""
    if number in _RPM_SETTINGS:
        return f"{value:.0f}"
    if number in _FLOAT_SETTINGS:
        return f"{value:.3f}"
    return str(int(value))
