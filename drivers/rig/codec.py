"""GRBL 1.1 wire format: pure functions from bytes to typed messages and back. No I/O here.

Everything the driver sends or receives passes through this module, so it can be tested with no
port at all. Units: whatever the controller is configured for (machine units, mm for G21); the
codec never converts.

What GRBL 1.1 sends (one line each, terminated by ``\\r\\n``):

- ``ok`` / ``error:N``: the answer to one line of g-code or ``$`` command, in order.
- ``ALARM:N``: pushed when the controller enters Alarm (hard/soft limit, homing fail, reset in motion).
- ``<State|MPos:x,y,z|FS:f,s|...>``: the answer to the real-time ``?``; fields after the state may be
  missing or come in any order; grblHAL adds some (``H:``, ``SD:``, ...), which are kept as text.
- ``[MSG:...]``, ``[GC:...]``, ``[VER:...]``, ``[OPT:...]`` ...: feedback, never an answer by itself.
- ``Grbl 1.1h ['$' for help]`` / ``GrblHAL 1.1f ['$' or '$HELP' for help]``: the banner after a reset.
- ``$N=value``: a setting line (answer to ``$$``); ``$Nn=line``: a stored startup line (answer to ``$N``).
- ``>line:ok`` / ``>line:error:N``: a startup line executed after a reset or homing, and its result
  (report.c ``report_execute_startup_message``).

Which settings matter to a driver (settings.c, limits.c, system.c of Grbl 1.1h): ``$13`` reports in
inches; ``$20`` soft limits; ``$22`` homing; ``$23`` homing direction mask; ``$100``... steps per unit;
``$130``... max travel. :func:`soft_limit_space` turns them into the machine space Grbl accepts.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from drivers.rig.errors import RigError

#: Serial receive buffer of a GRBL 1.1 build on an ATmega328p. The ring buffer keeps one slot free
#: to tell full from empty, so at most ``RX_BUFFER_SIZE - 1`` bytes may be outstanding.
RX_BUFFER_SIZE = 128
#: grblHAL's usual receive buffer.
GRBLHAL_RX_BUFFER_SIZE = 1024
#: GRBL's line buffer: longer lines are answered with error:11 and not executed.
MAX_LINE_LENGTH = 80

RT_STATUS = b"?"
RT_FEED_HOLD = b"!"
RT_CYCLE_START = b"~"
RT_SOFT_RESET = b"\x18"
RT_JOG_CANCEL = b"\x85"
REALTIME_BYTES = frozenset(b"?!~\x18") | frozenset(range(0x80, 0x100))

AXIS_LETTERS = "XYZABC"

#: GRBL 1.1 error codes (``error:N``) and what they mean, from GRBL's own error_codes table.
GRBL_ERRORS: dict[int, str] = {
    1: "Expected command letter: a g-code word consists of a letter and a value; the letter was not found",
    2: "Bad number format: missing the expected g-code word value, or the numeric format is not valid",
    3: "Invalid statement: '$' system command was not recognized or supported",
    4: "Value < 0: negative value received for an expected positive value",
    5: "Setting disabled: homing cycle is not enabled via settings ($22)",
    6: "Value < 3 usec: minimum step pulse time must be greater than 3 usec",
    7: "EEPROM read fail: using defaults; affected EEPROM restored to default values",
    8: "Not idle: '$' command cannot be used unless GRBL is Idle",
    9: "G-code lock: g-code commands are locked out during Alarm or Jog state",
    10: "Homing not enabled: soft limits cannot be enabled without homing also enabled",
    11: "Line overflow: max characters per line exceeded; the line was not executed",
    12: "Step rate > 30 kHz: '$' setting value causes the step rate to exceed the maximum supported",
    13: "Check door: safety door detected as opened and door state initiated",
    14: "Line length exceeded: build info or startup line exceeded the EEPROM line length limit",
    15: "Travel exceeded: jog target exceeds machine travel; the jog was ignored",
    16: "Invalid jog command: jog has no '=' or contains prohibited g-code",
    17: "Setting disabled: laser mode requires PWM output",
    20: "Unsupported command: unsupported or invalid g-code command found in block",
    21: "Modal group violation: more than one g-code command from the same modal group in block",
    22: "Undefined feed rate: feed rate has not yet been set or is undefined",
    23: "G-code command in block requires an integer value",
    24: "Two g-code commands that both require the use of axis words were detected in the block",
    25: "A g-code word was repeated in the block",
    26: "A g-code command implicitly or explicitly requires axis words in the block, but none were detected",
    27: "N line number value is not within the valid range of 1 - 9,999,999",
    28: "A g-code command was sent, but is missing some required P or L value words in the line",
    29: "GRBL supports six work coordinate systems G54-G59; G59.1, G59.2 and G59.3 are not supported",
    30: "The G53 g-code command requires either a G0 seek or G1 feed motion mode to be active",
    31: "There are unused axis words in the block and G80 motion mode cancel is active",
    32: "A G2 or G3 arc was commanded but there are no XYZ axis words in the selected plane",
    33: "The motion command has an invalid target",
    34: "A G2 or G3 arc, traced with the radius definition, had a mathematical error",
    35: "A G2 or G3 arc, traced with the offset definition, is missing the IJK offset word in the plane",
    36: "There are unused, leftover g-code words that aren't used by any command in the block",
    37: "The G43.1 dynamic tool length offset command cannot apply an offset to an axis other than its configured axis",
    38: "Tool number greater than max supported value",
}

#: GRBL 1.1 alarm codes (``ALARM:N``); 10 and up are grblHAL's.
GRBL_ALARMS: dict[int, str] = {
    1: "Hard limit triggered. Machine position is likely lost due to sudden and immediate halt; re-homing is "
       "highly recommended",
    2: "Soft limit: g-code motion target exceeds machine travel. Machine position safely retained; alarm may be "
       "unlocked",
    3: "Reset while in motion. GRBL cannot guarantee position; lost steps are likely, re-homing is highly "
       "recommended",
    4: "Probe fail: the probe is not in the expected initial state before starting the probe cycle",
    5: "Probe fail: the probe did not contact the workpiece within the programmed travel",
    6: "Homing fail: reset during active homing cycle",
    7: "Homing fail: safety door was opened during active homing cycle",
    8: "Homing fail: cycle failed to clear limit switch when pulling off; try increasing pull-off or check wiring",
    9: "Homing fail: could not find limit switch within search distance",
    10: "E-stop asserted (grblHAL)",
    11: "Homing required: home the machine before moving (grblHAL)",
    12: "Limit switch engaged at startup (grblHAL)",
    13: "Probe protection triggered (grblHAL)",
    14: "Spindle at speed timeout (grblHAL)",
    15: "Homing fail: could not find the second limit switch of an auto-squared axis (grblHAL)",
}

#: Machine states as GRBL 1.1 names them in status reports.
STATES = ("Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep", "Tool")

#: Alarms after which GRBL 1.1 answers nothing, not even ``?``, until a soft reset (hard limit, soft limit;
#: grblHAL's e-stop): protocol.c ``protocol_exec_rt_system`` spins in an empty loop until EXEC_RESET (its comment
#: says status reports are served too; the loop does not serve them), and main.c clears the pending request.
CRITICAL_ALARMS = frozenset({1, 2, 10})

#: Alarms that end a homing cycle (limits.c ``limits_go_home``): Grbl resets after them, still answers the
#: ``$H`` line with a late ``ok`` and then prints its banner again.
HOMING_ALARMS = frozenset({6, 7, 8, 9})

UNLOCK_MESSAGE = "'$H'|'$X' to unlock"
RESET_TO_CONTINUE_MESSAGE = "Reset to continue"
CHECK_MODE_ENABLED_MESSAGE = "Enabled"
CHECK_MODE_DISABLED_MESSAGE = "Disabled"

#: Setting numbers (report.c ``report_grbl_settings``; axis settings are base + axis index).
SETTING_STATUS_MASK = 10
SETTING_REPORT_INCHES = 13
SETTING_SOFT_LIMITS = 20
SETTING_HARD_LIMITS = 21
SETTING_HOMING = 22
SETTING_HOMING_DIR_MASK = 23
SETTING_HOMING_PULLOFF = 27
SETTING_STEPS_PER_UNIT = 100
SETTING_MAX_RATE = 110
SETTING_ACCELERATION = 120
SETTING_MAX_TRAVEL = 130
#: ``[OPT:...]`` letter of a build with HOMING_FORCE_SET_ORIGIN (config.h): homing sets 0 instead of -pull-off.
OPTION_FORCE_SET_ORIGIN = "Z"


def error_meaning(code: int) -> str:
    return GRBL_ERRORS.get(code, f"unknown GRBL error {code}")


def alarm_meaning(code: int) -> str:
    return GRBL_ALARMS.get(code, f"unknown GRBL alarm {code}")


# --------------------------------------------------------------------------------------------------
# Messages from the controller


@dataclass(frozen=True)
class Ok:
    """``ok``: the oldest outstanding line was accepted (queued, not necessarily executed)."""


@dataclass(frozen=True)
class ErrorReply:
    """``error:N``: the oldest outstanding line was rejected."""

    code: int

    @property
    def meaning(self) -> str:
        return error_meaning(self.code)


@dataclass(frozen=True)
class AlarmPush:
    """``ALARM:N``: the controller entered Alarm state."""

    code: int

    @property
    def meaning(self) -> str:
        return alarm_meaning(self.code)


@dataclass(frozen=True)
class Message:
    """``[MSG:text]``."""

    text: str


@dataclass(frozen=True)
class Feedback:
    """Any other bracketed feedback: ``[GC:...]``, ``[VER:...]``, ``[OPT:...]``, ``[PRB:...]``, ``[echo:...]``."""

    kind: str
    text: str


@dataclass(frozen=True)
class Banner:
    """The welcome line printed after power-up or a soft reset."""

    firmware: str  # "Grbl" or "GrblHAL"
    version: str  # e.g. "1.1h"
    text: str


@dataclass(frozen=True)
class Setting:
    """``$N=value`` (answer to ``$$``)."""

    number: int
    value: str


@dataclass(frozen=True)
class StartupLine:
    """``$Nn=line``: startup line ``n`` as stored (answer to ``$N``; empty when unused)."""

    number: int
    line: str


@dataclass(frozen=True)
class StartupEcho:
    """``>line:ok`` or ``>line:error:N``: a startup line Grbl executed after a reset or a homing cycle."""

    line: str
    result: str  # "ok" or "error:N"

    @property
    def ok(self) -> bool:
        return self.result == "ok"


@dataclass(frozen=True)
class StatusReport:
    """A parsed ``<...>`` real-time status report. Positions are in machine units, per axis letter.

    ``mpos`` and ``wpos`` are mutually exclusive in GRBL 1.1 ($10 chooses); ``wco`` arrives only in some
    reports, so a driver keeps the last one it saw. Unknown fields are kept verbatim in ``extra``.
    """

    state: str
    substate: int | None = None
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    wco: tuple[float, ...] | None = None
    feed: float | None = None
    spindle: float | None = None
    planner_blocks_free: int | None = None
    rx_bytes_free: int | None = None
    line_number: int | None = None
    pins: str | None = None
    overrides: tuple[int, ...] | None = None
    accessories: str | None = None
    homed: bool | None = None  # grblHAL's H: field (None: not in this report)
    homed_mask: int | None = None
    extra: dict[str, str] = field(default_factory=dict)
    raw: str = ""

    @property
    def full_state(self) -> str:
        """State as printed, e.g. ``Hold:0``."""
        return self.state if self.substate is None else f"{self.state}:{self.substate}"

    @property
    def axis_count(self) -> int | None:
        pos = self.mpos if self.mpos is not None else self.wpos
        return None if pos is None else len(pos)


@dataclass(frozen=True)
class Unparsed:
    """A line that is none of the above: noise on the line, a garbled answer, or a firmware we don't know."""

    text: str


Response = (Ok | ErrorReply | AlarmPush | Message | Feedback | Banner | Setting | StartupLine | StartupEcho
            | StatusReport | Unparsed)


class ParseError(ValueError):
    """A line that looks like one kind of message but does not parse as it."""


_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)"
_FLOAT_RE = re.compile(rf"^{_FLOAT}$")
_BANNER_RE = re.compile(r"^(Grbl|GrblHAL|grblHAL)\s+v?(\d+\.\d+[a-zA-Z]?)\s+\[(.*)\]\s*$")
_ERROR_RE = re.compile(r"^error:(\d+)$")
_ALARM_RE = re.compile(r"^ALARM:(\d+)$")
_SETTING_RE = re.compile(r"^\$(\d+)=(.*)$")
_STARTUP_LINE_RE = re.compile(r"^\$N(\d+)=(.*)$")
_STARTUP_ECHO_RE = re.compile(r"^>(.*):(ok|error:\d+)$")
# grblHAL's $I tags may hold spaces ("[NVS STORAGE:*EEPROM]", "[DRIVER VERSION:260913]": its report.c
# report_build_info).
_FEEDBACK_RE = re.compile(r"^\[([A-Za-z][A-Za-z0-9]*(?: [A-Za-z0-9]+)*):(.*)\]$")
# A status field's name: letters (``MPos``), or grblHAL's ``$C`` (report.c report_realtime_status).
_FIELD_NAME_RE = re.compile(r"^\$?[A-Za-z][A-Za-z0-9]*$")


def _floats(text: str, *, name: str) -> tuple[float, ...]:
    parts = text.split(",")
    if not parts or not all(_FLOAT_RE.match(p) for p in parts):
        raise ParseError(f"{name}: not a list of numbers: {text!r}")
    values = tuple(float(p) for p in parts)
    if not all(math.isfinite(v) for v in values):
        raise ParseError(f"{name}: non-finite value in {text!r}")
    return values


def _ints(text: str, *, name: str) -> tuple[int, ...]:
    parts = text.split(",")
    if not all(re.fullmatch(r"-?\d+", p) for p in parts):
        raise ParseError(f"{name}: not a list of integers: {text!r}")
    return tuple(int(p) for p in parts)


#: Status fields that always carry a value (report.c of Grbl 1.1h and grblHAL).
_VALUED_FIELDS = frozenset({"MPos", "WPos", "WCO", "FS", "F", "Bf", "Ln", "Pn", "Ov", "A", "H"})


def parse_status(line: str) -> StatusReport:
    """Parse one ``<State|field:value|...>`` report. Raises :class:`ParseError` on anything malformed.

    Strict on purpose: a report is the only source of a position, so a garbled one must be rejected
    rather than half-read.
    """
    if not (line.startswith("<") and line.endswith(">")) or len(line) < 3:
        raise ParseError(f"not a status report: {line!r}")
    body = line[1:-1]
    fields = body.split("|")
    state_text = fields[0]
    state, _, sub = state_text.partition(":")
    if state not in STATES:
        raise ParseError(f"unknown machine state {state_text!r} in {line!r}")
    substate = None
    if sub:
        if not sub.isdigit():
            raise ParseError(f"bad sub-state {state_text!r} in {line!r}")
        substate = int(sub)
    values: dict[str, object] = {}
    extra: dict[str, str] = {}
    seen: set[str] = set()
    for item in fields[1:]:
        key, sep, value = item.partition(":")
        if not _FIELD_NAME_RE.match(key) or (not sep and key in _VALUED_FIELDS):
            # grblHAL sends a few flags without a value (``|AR``, report.c); a known field always has one.
            raise ParseError(f"field without a name in {line!r}: {item!r}")
        if key in seen:
            raise ParseError(f"field {key} repeated in {line!r}")
        seen.add(key)
        if key == "MPos":
            values["mpos"] = _floats(value, name=key)
        elif key == "WPos":
            values["wpos"] = _floats(value, name=key)
        elif key == "WCO":
            values["wco"] = _floats(value, name=key)
        elif key == "FS":
            fs = _floats(value, name=key)
            if len(fs) not in (2, 3):  # grblHAL adds the spindle's measured rpm (report.c report_realtime_status)
                raise ParseError(f"FS wants feed,speed in {line!r}")
            values["feed"], values["spindle"] = fs[:2]
        elif key == "F":
            (values["feed"],) = _floats(value, name=key)
        elif key == "Bf":
            bf = _ints(value, name=key)
            if len(bf) != 2:
                raise ParseError(f"Bf wants blocks,bytes in {line!r}")
            values["planner_blocks_free"], values["rx_bytes_free"] = bf
        elif key == "Ln":
            (values["line_number"],) = _ints(value, name=key)
        elif key == "Pn":
            values["pins"] = value
        elif key == "Ov":
            values["overrides"] = _ints(value, name=key)
        elif key == "A":
            values["accessories"] = value
        elif key == "H":
            # grblHAL: 1 when every axis of the homing cycles is homed, then (with single-axis homing) the mask.
            flags = _ints(value, name=key)
            values["homed"] = bool(flags[0])
            if len(flags) > 1:
                values["homed_mask"] = flags[1]
        else:
            extra[key] = value
    mpos, wpos, wco = values.get("mpos"), values.get("wpos"), values.get("wco")
    if mpos is not None and wpos is not None:
        raise ParseError(f"both MPos and WPos in {line!r}")
    lengths = {len(v) for v in (mpos, wpos, wco) if v is not None}
    if len(lengths) > 1:
        raise ParseError(f"position fields disagree on the number of axes in {line!r}")
    if lengths and not 1 <= lengths.pop() <= len(AXIS_LETTERS):
        raise ParseError(f"unsupported number of axes in {line!r}")
    return StatusReport(state=state, substate=substate, extra=extra, raw=line, **values)  # type: ignore[arg-type]


def parse_response(line: str) -> Response:
    """Classify one line from the controller (without its line terminator). Never raises.

    A line that looks like a status report but doesn't parse is returned as :class:`Unparsed`.
    """
    text = line.strip()
    if text == "ok":
        return Ok()
    if text.startswith("<"):
        try:
            return parse_status(text)
        except ParseError:
            return Unparsed(text)
    if m := _ERROR_RE.match(text):
        return ErrorReply(int(m.group(1)))
    if m := _ALARM_RE.match(text):
        return AlarmPush(int(m.group(1)))
    if m := _FEEDBACK_RE.match(text):
        kind, body = m.group(1), m.group(2)
        if kind == "MSG":
            return Message(body)
        return Feedback(kind, body)
    if m := _BANNER_RE.match(text):
        firmware = "GrblHAL" if m.group(1).lower() == "grblhal" else "Grbl"
        return Banner(firmware=firmware, version=m.group(2), text=text)
    if m := _SETTING_RE.match(text):
        return Setting(int(m.group(1)), m.group(2))
    if m := _STARTUP_LINE_RE.match(text):
        return StartupLine(int(m.group(1)), m.group(2))
    if m := _STARTUP_ECHO_RE.match(text):
        return StartupEcho(m.group(1), m.group(2))
    return Unparsed(text)


class LineSplitter:
    """Reassembles lines from arbitrary chunks of bytes. GRBL ends lines with ``\\r\\n``; either alone works.

    Bytes that are not printable ASCII are kept (as latin-1) so that a garbled line is seen as garbled
    instead of silently repaired.
    """

    def __init__(self, max_line: int = 1024):
        self._buffer = bytearray()
        self._max_line = max_line

    def feed(self, data: bytes) -> list[str]:
        lines: list[str] = []
        for byte in data:
            if byte in (0x0A, 0x0D):
                if self._buffer:
                    lines.append(self._buffer.decode("latin-1"))
                    self._buffer.clear()
            else:
                self._buffer.append(byte)
                if len(self._buffer) > self._max_line:
                    # Noise with no terminator: hand it up as one unparsable line rather than growing forever.
                    lines.append(self._buffer.decode("latin-1"))
                    self._buffer.clear()
        return lines

    def clear(self) -> None:
        self._buffer.clear()


def machine_position(report: StatusReport, last_wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
    """Machine position from a report: MPos as given, or WPos + WCO (this report's WCO, else ``last_wco``).

    Returns None when the report carries WPos and no WCO is known yet: the position is then unknown,
    not zero.
    """
    if report.mpos is not None:
        return report.mpos
    if report.wpos is None:
        return None
    wco = report.wco if report.wco is not None else last_wco
    if wco is None or len(wco) != len(report.wpos):
        return None
    return tuple(w + o for w, o in zip(report.wpos, wco, strict=True))


# --------------------------------------------------------------------------------------------------
# Lines to the controller


class EncodeError(RigError, ValueError):
    """A command that must not be sent as given."""


def format_number(value: float, decimals: int = 3) -> str:
    """A g-code number: fixed decimals, no exponent, no ``-0.000``."""
    if not math.isfinite(value):
        raise EncodeError(f"not a finite number: {value!r}")
    text = f"{value:.{decimals}f}"
    if float(text) == 0.0:
        text = f"{0.0:.{decimals}f}"
    return text


def encode_line(command: str) -> bytes:
    """One line of g-code or ``$`` command, terminated by ``\\n``.

    Refuses characters GRBL would take as real-time commands (they would be acted upon mid-line) and
    lines longer than GRBL's line buffer, which holds what is left after Grbl drops spaces
    (protocol.c ``protocol_main_loop``: characters <= ' ' are thrown away, at most 79 are kept).
    """
    text = command.strip()
    if not text:
        raise EncodeError("empty command")
    data = text.encode("ascii", errors="strict") if text.isascii() else None
    if data is None:
        raise EncodeError(f"non-ASCII command: {command!r}")
    bad = sorted({chr(b) for b in data if b in REALTIME_BYTES or b < 0x20})
    if bad:
        raise EncodeError(f"command {text!r} contains real-time or control characters {bad!r}")
    kept = sum(1 for b in data if b > 0x20)
    if kept > MAX_LINE_LENGTH - 1:
        raise EncodeError(f"command longer than GRBL's {MAX_LINE_LENGTH - 1}-character line: {text!r}")
    return data + b"\n"


def encode_move(
    targets: Mapping[str, float], *, feed_per_min: float | None = None, machine_coordinates: bool = True,
    decimals: int = 3,
) -> str:
    """An absolute straight move to ``targets`` (axis letter -> position, machine units).

    With ``feed_per_min`` a feed move ``G1 ... F`` (units/min, vector feed over all moving axes),
    otherwise a rapid ``G0`` at each axis' maximum rate. ``G53`` makes the targets machine coordinates
    whatever work offset is active; it applies to this line only. Every line also carries ``G21 G90``:
    units and distance mode are modal on the controller (a startup line or an earlier program may have
    left ``G20`` inches or ``G91`` relative), so they are set on the very line that moves.
    """
    if not targets:
        raise EncodeError("a move needs at least one axis")
    words = []
    for axis in AXIS_LETTERS:  # GRBL doesn't care about order; a fixed one makes lines comparable in logs
        if axis in targets:
            words.append(f"{axis}{format_number(float(targets[axis]), decimals)}")
    unknown = sorted(set(targets) - set(AXIS_LETTERS))
    if unknown:
        raise EncodeError(f"unknown axis letter(s) {unknown}: GRBL axes are {AXIS_LETTERS}")
    prefix = "G21 G90 G53 " if machine_coordinates else "G21 G90 "
    if feed_per_min is None:
        return prefix + "G0 " + " ".join(words)
    if not (math.isfinite(feed_per_min) and feed_per_min > 0):
        raise EncodeError(f"feed rate must be > 0 units/min, not {feed_per_min!r}")
    return prefix + "G1 " + " ".join(words) + f" F{format_number(feed_per_min, 1)}"


def vector_feed(deltas: Mapping[str, float], axis_feeds_per_min: Mapping[str, float | None]) -> float | None:
    """The vector feed (units/min) of a straight move so that no axis exceeds its own feed rate.

    GRBL's F is the speed along the path, so an axis moves at F * |d_axis| / |d|. Returns None if any
    moving axis has no feed rate of its own (the move is then a rapid, limited by GRBL's $11x settings),
    or if nothing moves.
    """
    moving = {a: d for a, d in deltas.items() if abs(d) > 0.0}
    if not moving:
        return None
    length = math.sqrt(sum(d * d for d in moving.values()))
    feeds = []
    for axis, delta in moving.items():
        f = axis_feeds_per_min.get(axis)
        if f is None:
            return None
        feeds.append(f * length / abs(delta))
    return min(feeds)


def split_axes(values: tuple[float, ...], letters: str = AXIS_LETTERS) -> dict[str, float]:
    """Name the values of a position field by axis letter, in GRBL's order X Y Z A B C."""
    return dict(zip(letters, values, strict=False))


# --------------------------------------------------------------------------------------------------
# What the controller says about itself ($I, $$, $N)


def parse_setting_value(text: str) -> float:
    """The value of a ``$n=value`` line as a number (Grbl prints integers bare, floats with 3 decimals)."""
    if not _FLOAT_RE.match(text):
        raise ParseError(f"setting value is not a number: {text!r}")
    return float(text)


@dataclass(frozen=True)
class BuildInfo:
    """``$I`` (report.c ``report_build_info``): ``[VER:1.1h.20190830:user text]`` and ``[OPT:V,15,128]``.

    ``options`` are the compile-time option letters (``Z`` = HOMING_FORCE_SET_ORIGIN, ``L`` = no homing
    lock at power-up, ...); ``planner_blocks`` and ``rx_buffer_size`` the planner and serial receive buffer
    sizes. grblHAL extends ``[OPT:]`` with the number of axes and of tools (``[OPT:VNML+W,100,1024,3,0]``) and
    adds tagged lines (``[AXS:3:XYZ]``, ``[NEWOPT:...]``, ``[FIRMWARE:grblHAL]``, ``[NVS STORAGE:*EEPROM]``,
    ``[DRIVER:Simulator]``, ``[DRIVER VERSION:...]``...), kept in ``tags`` by name.
    """

    version: str | None = None
    user_info: str = ""
    options: str = ""
    planner_blocks: int | None = None
    rx_buffer_size: int | None = None
    axis_count: int | None = None
    tool_count: int | None = None
    tags: dict[str, str] = field(default_factory=dict)

    @property
    def firmware(self) -> str | None:
        """``grblHAL`` when its ``[FIRMWARE:]`` line says so; None when no line names the firmware."""
        return self.tags.get("FIRMWARE")


def parse_build_info(lines: list[str]) -> BuildInfo:
    """The build information in the feedback lines of ``$I`` (other lines are ignored)."""
    version, user_info, options = None, "", ""
    numbers: list[int | None] = [None, None, None, None]  # planner blocks, rx buffer, axes, tools
    tags: dict[str, str] = {}
    for line in lines:
        message = parse_response(line)
        if not isinstance(message, Feedback):
            continue
        if message.kind == "VER":
            version, _, user_info = message.text.partition(":")
        elif message.kind == "OPT":
            parts = message.text.split(",")
            options = parts[0]
            for index, part in enumerate(parts[1:5]):
                numbers[index] = int(part) if part.strip().isdigit() else None
        else:
            tags[message.kind] = message.text
    blocks, rx, axes, tools = numbers
    return BuildInfo(version=version, user_info=user_info, options=options, planner_blocks=blocks,
                     rx_buffer_size=rx, axis_count=axes, tool_count=tools, tags=tags)


def parse_settings(lines: list[str]) -> dict[int, float]:
    """``$$`` answer lines -> setting number -> value. Lines that are not settings are ignored."""
    settings: dict[int, float] = {}
    for line in lines:
        message = parse_response(line)
        if isinstance(message, Setting):
            try:
                settings[message.number] = parse_setting_value(message.value)
            except ParseError:
                continue
    return settings


def parse_startup_lines(lines: list[str]) -> dict[int, str]:
    """``$N`` answer lines -> startup line number -> stored line (empty string when unused)."""
    return {m.number: m.line for m in map(parse_response, lines) if isinstance(m, StartupLine)}


_AXIS_WORD_RE = re.compile(r"[XYZABC][-+.\d]")


def startup_line_hazards(line: str) -> list[str]:
    """Why a stored startup line is a trap for a driver, if it is one (empty list if not).

    Grbl runs its startup lines after every reset that comes back Idle (protocol.c ``protocol_main_loop``;
    one that stays in Alarm prints the unlock message instead) and after every successful homing cycle
    (system.c ``system_execute_line``, ``$H``), so modal state they set is the state the next program meets.
    """
    text = "".join(line.split()).upper()
    text = re.sub(r"\([^)]*\)", "", text).split(";", 1)[0]
    hazards = []
    if re.search(r"G20(?!\d)", text):
        hazards.append("G20 switches the controller to inches")
    if re.search(r"G91(?!\.\d)", text):
        hazards.append("G91 switches the controller to relative distances")
    if _AXIS_WORD_RE.search(text) and not text.startswith("$"):
        hazards.append("it moves the axes")
    return hazards


def axis_setting(settings: Mapping[int, float], base: int, axis: str) -> float | None:
    """An axis setting (``base`` = 100 steps/unit, 110 max rate, 120 acceleration, 130 max travel)."""
    return settings.get(base + AXIS_LETTERS.index(axis))


def setting_bit(settings: Mapping[int, float], number: int, bit: int = 0) -> bool:
    """One bit of a setting. grblHAL prints ``$21`` (hard limits) and ``$22`` (homing) as bitfields whose bit 0
    enables the feature (settings.c: ``$22`` = enable, single-axis commands, homing required at startup, set
    origin to 0, ...); Grbl 1.1h prints them as 0/1, so bit 0 reads both."""
    return bool((int(settings.get(number, 0)) >> bit) & 1)


def homing_enabled(settings: Mapping[int, float]) -> bool:
    return setting_bit(settings, SETTING_HOMING)


def hard_limits_enabled(settings: Mapping[int, float]) -> bool:
    return setting_bit(settings, SETTING_HARD_LIMITS)


def soft_limit_space(settings: Mapping[int, float], options: str, axis: str, *,
                     firmware: str = "Grbl") -> tuple[float, float] | None:
    """The machine coordinates (low, high) the controller gives ``axis`` once homed; None without homing.

    Grbl 1.1h: limits.c ``limits_go_home`` sets the homed axis to ``-$27`` (or ``-$13x + $27`` when its ``$23``
    bit is set): machine space is ``[-$13x, 0]``, and system.c ``system_check_travel_limits`` rejects any
    target outside it when soft limits are on (``$20=1``: ALARM:2). Only a build with
    HOMING_FORCE_SET_ORIGIN (``Z`` in ``[OPT:]``) homes to 0 and counts positive, ``[0, $13x]``, on the
    axes whose ``$23`` bit is set.

    grblHAL (``firmware="GrblHAL"``): machine_limits.c ``limits_set_work_envelope`` keeps one pull-off off
    each end when hard limits are on (``$21`` bit 0), so that no target reaches a switch:
    ``[-$13x + $27, -$27]``; with set-origin (``Z``): ``[-$13x + $27, 0]``, or ``[0, $13x - $27]`` on a
    ``$23`` axis. Without hard limits the pull-off is 0.
    """
    if not homing_enabled(settings):
        return None
    travel = axis_setting(settings, SETTING_MAX_TRAVEL, axis)
    if travel is None:
        return None
    index = AXIS_LETTERS.index(axis)
    homes_negative = bool((int(settings.get(SETTING_HOMING_DIR_MASK, 0)) >> index) & 1)
    set_origin = OPTION_FORCE_SET_ORIGIN in options
    if firmware.lower() == "grblhal":
        pulloff = float(settings.get(SETTING_HOMING_PULLOFF, 0.0)) if hard_limits_enabled(settings) else 0.0
        if set_origin:
            return (0.0, travel - pulloff) if homes_negative else (-travel + pulloff, 0.0)
        return (-travel + pulloff, 0.0 - pulloff)  # 0.0 - 0.0 is 0.0, where -0.0 would print as "-0"
    return (0.0, travel) if set_origin and homes_negative else (-travel, 0.0)


def switch_position(settings: Mapping[int, float], options: str, axis: str) -> float | None:
    """Where ``axis``' homing switch trips, in machine coordinates of a homed controller; None without homing.

    Homing pulls off ``$27`` from the switch and sets ``-$27`` (``-$13x + $27`` for a ``$23`` axis): the switch
    is at 0 (at ``-$13x``). On a set-origin build (``Z``) homing sets 0 there, the switch one pull-off
    beyond (limits.c ``limits_go_home``; grblHAL's ``limits_set_machine_positions``).
    """
    if not homing_enabled(settings):
        return None
    travel = axis_setting(settings, SETTING_MAX_TRAVEL, axis)
    if travel is None:
        return None
    pulloff = float(settings.get(SETTING_HOMING_PULLOFF, 0.0))
    homes_negative = bool((int(settings.get(SETTING_HOMING_DIR_MASK, 0)) >> AXIS_LETTERS.index(axis)) & 1)
    if OPTION_FORCE_SET_ORIGIN in options:
        return -pulloff if homes_negative else pulloff
    return -travel if homes_negative else 0.0
