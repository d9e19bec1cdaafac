"""Faults the emulator can be told to inject (a lost ``ok``, a garbled line, a delay, an alarm, a reset or a
vanished port mid-move, a failed homing), and :func:`parse_fault`, their command-line spelling (:data:`FAULT_HELP`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class LostOk:
    """Drop the ``ok`` of the next line containing ``match`` (any line if None), ``count`` times."""

    match: str | None = None
    count: int = 1


@dataclass
class GarbledLine:
    """Corrupt (one byte replaced by 0xFF) the next ``count`` outgoing lines of a kind: ok, status, any."""

    what: str = "ok"
    count: int = 1


@dataclass
class Delay:
    """Hold back the next ``count`` outgoing lines of a kind (ok, status, any) by ``seconds`` of real time."""

    seconds: float = 0.5
    count: int = 1
    what: str = "any"


@dataclass
class AlarmMidMove:
    """Raise ``ALARM:code`` once the next motion block is ``fraction`` done (1 = hard limit, 2 = soft limit)."""

    code: int = 1
    fraction: float = 0.5


@dataclass
class ResetMidMove:
    """The controller reboots by itself (brown-out, watchdog) once the next block is ``fraction`` done."""

    fraction: float = 0.5


@dataclass
class VanishMidMove:
    """The port disappears (USB unplugged) once the next block is ``fraction`` done."""

    fraction: float = 0.5


@dataclass
class HomingFail:
    """The next ``$H`` fails with ``ALARM:code``: 9 = switch not found within 1.5 x ``$13x``, 8 = pull-off
    did not clear it. ``alarm_line=False`` leaves the ALARM line out (only the late ``ok`` and the reboot)."""

    code: int = 9
    alarm_line: bool = True


Fault = LostOk | GarbledLine | Delay | AlarmMidMove | ResetMidMove | VanishMidMove | HomingFail

FAULT_HELP = (
    "lost-ok[:MATCH] | garble[:ok|status|any] | delay:SECONDS[:COUNT] | alarm[:CODE[:FRACTION]] | "
    "reset[:FRACTION] | vanish[:FRACTION] | homing-fail[:8|9[:silent]]"
)


def _fraction(text: str) -> float:
    """Where in a move a fault strikes: a finite number in [0, 1]."""
    value = float(text)
    if not 0.0 <= value <= 1.0:  # also refuses NaN
        raise ValueError(f"FRACTION must be in [0, 1], not {text!r}")
    return value


def parse_fault(spec: str) -> Fault:
    """A fault from its command-line spelling (see ``FAULT_HELP``). Raises ValueError with the reason."""
    name, _, rest = spec.strip().partition(":")
    args = [a for a in rest.split(":")] if rest else []
    try:
        if name == "delay" and args and not 0.0 <= float(args[0]) <= 3600.0:  # NaN too; an hour is no delay
            raise ValueError(f"SECONDS must be in [0, 3600], not {args[0]!r}")
        if name == "delay" and len(args) > 1 and not int(args[1]) >= 1:
            raise ValueError(f"COUNT must be at least 1, not {args[1]!r}")
        if name in ("alarm", "reset", "vanish") and len(args) > (1 if name == "alarm" else 0):
            _fraction(args[1 if name == "alarm" else 0])
        if name == "lost-ok":
            return LostOk(match=rest or None)
        if name == "garble":
            what = args[0] if args else "ok"
            if what not in ("ok", "status", "any"):
                raise ValueError(f"garble wants ok, status or any, not {what!r}")
            return GarbledLine(what=what)
        if name == "delay":
            if not args:
                raise ValueError("delay wants SECONDS")
            return Delay(seconds=float(args[0]), count=int(args[1]) if len(args) > 1 else 1)
        if name == "alarm":
            return AlarmMidMove(code=int(args[0]) if args else 1, fraction=float(args[1]) if len(args) > 1 else 0.5)
        if name == "reset":
            return ResetMidMove(fraction=float(args[0]) if args else 0.5)
        if name == "vanish":
            return VanishMidMove(fraction=float(args[0]) if args else 0.5)
        if name == "homing-fail":
            code = int(args[0]) if args else 9
            if code not in (8, 9):
                raise ValueError(f"homing-fail wants alarm 8 or 9, not {code}")
            if len(args) > 1 and args[1] != "silent":
                raise ValueError(f"homing-fail's second field can only be 'silent', not {args[1]!r}")
            return HomingFail(code=code, alarm_line=len(args) < 2)
    except (IndexError, ValueError) as error:
        raise ValueError(f"bad fault {spec!r}: {error}") from None
    raise ValueError(f"unknown fault {spec!r}; expected {FAULT_HELP}")
