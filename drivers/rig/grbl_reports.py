"""What a GRBL controller reports, as data: a status report (:class:`GrblReading`) and what it said about itself
at connect (:class:`ControllerInfo`: build, options, the ``$$`` settings, startup lines, and the dialect, Grbl 1.1 or
grblHAL, that decides how the settings read). Parsing the lines is :mod:`drivers.rig.codec`'s; this holds the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drivers.rig import codec


@dataclass(frozen=True)
class GrblReading:
    """One status report, timestamped when it arrived. Positions in machine units, keyed by axis letter.

    ``machine_position`` is None only when the report gave WPos and no WCO has been seen yet.
    """

    state: str
    substate: int | None
    machine_position: dict[str, float] | None
    work_position: dict[str, float] | None
    feed_per_min: float | None
    planner_blocks_free: int | None
    rx_bytes_free: int | None
    pins: str | None
    timestamp: float  # time.time(), s
    monotonic: float  # time.monotonic(), s
    raw: str

    @property
    def full_state(self) -> str:
        return self.state if self.substate is None else f"{self.state}:{self.substate}"

    @property
    def is_idle(self) -> bool:
        return self.state == "Idle"

    def to_dict(self) -> dict:
        return {
            "state": self.full_state, "machine_position": self.machine_position, "work_position": self.work_position,
            "feed_per_min": self.feed_per_min, "pins": self.pins, "timestamp": self.timestamp, "raw": self.raw,
        }

    @staticmethod
    def describe() -> dict:
        return {
            "machine_position": {"units": "machine units (mm for G21)", "source": "GRBL status report MPos/WPos+WCO"},
            "timestamp": {"units": "s since the epoch", "source": "host clock when the report arrived"},
        }


@dataclass
class ControllerInfo:
    """What the controller said about itself at connect (``$I``, ``$$``, ``$N``, ``$#``, the banner), for the record.

    ``settings`` maps setting numbers to values (``{100: 250.0, ...}``); ``startup_lines`` maps ``$N``
    numbers to the stored lines; ``startup_executed`` lists the ``>line:result`` echoes seen; ``parameters``
    are the ``$#`` lines (work offsets, G28/G30, TLO, probe); ``build_tags`` grblHAL's further ``$I`` lines by
    tag; ``unsupported`` the queries the controller refused (``{"$N": "error:3"}``: a dialect without them);
    ``warnings`` are the one-line warnings issued at connect.
    """

    firmware: str | None = None
    build: str | None = None
    build_user_info: str = ""
    options: str = ""
    planner_blocks: int | None = None
    rx_buffer_size: int | None = None
    axis_count: int | None = None
    build_tags: dict[str, str] = field(default_factory=dict)
    settings: dict[int, float] = field(default_factory=dict)
    startup_lines: dict[int, str] = field(default_factory=dict)
    startup_executed: list[str] = field(default_factory=list)
    parameters: list[str] = field(default_factory=list)
    unsupported: dict[str, str] = field(default_factory=dict)
    boot_detected: bool = False
    settings_read: bool = False
    warnings: list[str] = field(default_factory=list)

    @property
    def dialect(self) -> str:
        """``GrblHAL`` when its banner or ``[FIRMWARE:grblHAL]`` says so, else ``Grbl`` (1.1)."""
        banner = (self.firmware or "").lower()
        if banner.startswith("grblhal") or self.build_tags.get("FIRMWARE", "").lower() == "grblhal":
            return "GrblHAL"
        return "Grbl"

    @property
    def homing_enabled(self) -> bool:
        return codec.homing_enabled(self.settings)

    @property
    def hard_limits(self) -> bool:
        return codec.hard_limits_enabled(self.settings)

    @property
    def boots_locked(self) -> bool:
        """Whether a boot with homing enabled lands in Alarm: Grbl's HOMING_INIT_LOCK, grblHAL's ``$22`` bit 2
        ("homing on startup required"); ``L`` in ``[OPT:]`` says a build boots Idle (report.c)."""
        if self.dialect == "GrblHAL":
            return self.homing_enabled and codec.setting_bit(self.settings, codec.SETTING_HOMING, 2)
        return self.homing_enabled and "L" not in self.options

    def setting(self, number: int) -> float | None:
        return self.settings.get(number)

    def steps_per_unit(self, axis: str) -> float | None:
        return codec.axis_setting(self.settings, codec.SETTING_STEPS_PER_UNIT, axis)

    def machine_space(self, axis: str) -> tuple[float, float] | None:
        """The machine coordinates this axis can reach once homed (see :func:`codec.soft_limit_space`)."""
        return codec.soft_limit_space(self.settings, self.options, axis, firmware=self.dialect)

    def switch_position(self, axis: str) -> float | None:
        """Where this axis' homing switch trips, in machine coordinates (see :func:`codec.switch_position`)."""
        return codec.switch_position(self.settings, self.options, axis)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: settings keyed ``"$100"``, startup lines as a list in ``$N`` order."""
        return {
            "firmware": self.firmware, "dialect": self.dialect, "build": self.build,
            "build_user_info": self.build_user_info, "options": self.options, "planner_blocks": self.planner_blocks,
            "rx_buffer_size": self.rx_buffer_size, "axis_count": self.axis_count, "build_tags": dict(self.build_tags),
            "settings": {f"${n}": (int(v) if float(v).is_integer() else v) for n, v in sorted(self.settings.items())},
            "startup_lines": [self.startup_lines[n] for n in sorted(self.startup_lines)],
            "startup_executed": list(self.startup_executed), "parameters": list(self.parameters),
            "unsupported": dict(self.unsupported), "boot_detected": self.boot_detected,
            "settings_read": self.settings_read, "warnings": list(self.warnings),
        }
