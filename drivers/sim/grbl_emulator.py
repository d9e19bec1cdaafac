"""A stateful GRBL 1.1 controller served on a pseudo-terminal, so the real driver opens a real tty.

    with GrblEmulator(time_scale=20.0) as emulator:       # 20x faster than real time
        controller = GrblController(emulator.tty_path)    # pyserial opens /dev/pts/N
        ...
        emulator.machine_position()                        # {"X": ..., "Y": ..., "Z": ...}, thread-safe

What it models, as GRBL 1.1 does it:

- the 128-byte serial receive buffer (bytes arriving when it holds 127 are dropped and counted), a
  15-block planner, lines answered ``ok``/``error:N`` in order once planned;
- real-time bytes ``?`` ``!`` ``~`` 0x18 (and 0x85 jog cancel) acted on at once, without ``ok``;
- timed motion: each block a trapezoidal velocity profile from rest to rest (per-axis max rate and
  acceleration), on a clock running ``time_scale`` times faster than real time;
- ``G4 P<s>`` waits for the planner to empty, so its ``ok`` marks the end of motion;
- homing (``$H``: no status reports while homing), boot into Alarm with ``[MSG:'$H'|'$X' to unlock]``
  when homing is enabled, ``$X``;
- soft limits: a jog beyond travel is ``error:15``; a g-code move beyond travel raises ``ALARM:2`` and
  halts (``[MSG:Reset to continue]``) until a soft reset; a reset during motion raises ``ALARM:3``;
- injectable faults (see :class:`LostOk`, :class:`GarbledLine`, :class:`Delay`, :class:`AlarmMidMove`,
  :class:`ResetMidMove`, :class:`VanishMidMove` and :meth:`GrblEmulator.vanish`).

Simplifications (the driver does not depend on them): a feed hold stops at once instead of
decelerating; blocks do not blend at junctions; at power-up the reported position is the simulated
physical position (a real GRBL starts at 0 wherever the axes are); ``$C`` check mode, arcs, probing,
spindle and coolant are not modelled (their g-codes are accepted where harmless, refused otherwise).
Units are machine units (mm; a rotary axis in whatever unit its travel is given in).
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import random
import re
import select
import threading
import time
import tty
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from drivers.rig.motion import REFERENCE_AXIS_MOTION, path_limits, trapezoid

AXIS_LETTERS = "XYZABC"
RX_BUFFER_SIZE = 128
PLANNER_BLOCKS = 15  # GRBL 1.1 on an Uno: 16-block ring buffer, one kept free
LINE_BUFFER_SIZE = 80

GRBL_BANNER = "Grbl 1.1h ['$' for help]"
GRBLHAL_BANNER = "GrblHAL 1.1f ['$' or '$HELP' for help]"
UNLOCK_MESSAGE = "[MSG:'$H'|'$X' to unlock]"


# --------------------------------------------------------------------------------------------------
# Configuration and faults


@dataclass(frozen=True)
class AxisSpec:
    """One simulated axis. Positions in machine units; rate in units/min (GRBL $11x), accel in units/s² ($12x).

    ``home_position`` is where ``$H`` leaves the axis; None = 0 if inside the travel, else the nearer end.
    """

    travel: tuple[float, float] = (0.0, 350.0)
    max_rate_per_min: float = 3000.0
    acceleration: float = 200.0
    home_position: float | None = None
    steps_per_unit: float | None = None  # quantise reported positions to whole steps, like real firmware

    @property
    def home(self) -> float:
        if self.home_position is not None:
            return self.home_position
        low, high = self.travel
        return min(max(0.0, low), high)


# Rates and accelerations are the reference rig's (drivers.rig.motion), which the plan's estimate assumes too.
DEFAULT_AXES: dict[str, AxisSpec] = {
    axis: AxisSpec(travel=travel, max_rate_per_min=REFERENCE_AXIS_MOTION[axis].max_rate_per_min,
                   acceleration=REFERENCE_AXIS_MOTION[axis].acceleration)
    for axis, travel in {"X": (0.0, 350.0), "Y": (0.0, 90.0), "Z": (0.0, 90.0), "A": (-45.0, 45.0),
                         "B": (-45.0, 45.0), "C": (0.0, 2000.0)}.items()
}


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


Fault = LostOk | GarbledLine | Delay | AlarmMidMove | ResetMidMove | VanishMidMove

FAULT_HELP = (
    "lost-ok[:MATCH] | garble[:ok|status|any] | delay:SECONDS[:COUNT] | alarm[:CODE[:FRACTION]] | "
    "reset[:FRACTION] | vanish[:FRACTION]"
)


def parse_fault(spec: str) -> Fault:
    """A fault from its command-line spelling (see ``FAULT_HELP``). Raises ValueError with the reason."""
    name, _, rest = spec.strip().partition(":")
    args = [a for a in rest.split(":")] if rest else []
    try:
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
    except (IndexError, ValueError) as error:
        raise ValueError(f"bad fault {spec!r}: {error}") from None
    raise ValueError(f"unknown fault {spec!r}; expected {FAULT_HELP}")


# --------------------------------------------------------------------------------------------------
# Motion


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


# --------------------------------------------------------------------------------------------------
# The emulator


class GrblEmulator:
    """A GRBL 1.1 controller on a pty, served by one thread. See the module docstring.

    Args:
        axes: axis letters, in GRBL order (``"XYZ"``, or ``"XYZABC"`` for a grblHAL-like 6-axis board).
        axis_specs: per-axis travel/rates (defaults: X 0-350 mm, Y and Z 0-90 deg, A B -45..45, C 0-2000).
        time_scale: simulated seconds per real second (1 = real time; 20 = twenty times faster).
        homing_enabled: ``$22``; with it the controller boots into Alarm and must be homed or unlocked.
        soft_limits: ``$20``; needs homing enabled, as on GRBL.
        homing_seek_rate_per_min: speed of the homing cycle (units/min); plus ``homing_settle_s``.
        status_mask: ``$10``: bit 0 set reports MPos (else WPos), bit 1 adds ``Bf:``.
        firmware: ``"grbl"`` or ``"grblhal"`` (banner; grblHAL's 1024-byte receive buffer).
        rx_buffer_size: the serial receive buffer in bytes.
        shuffle_fields: report status fields in a random order (seeded), as a robustness test.
        faults: faults armed from the start; more with :meth:`inject`.
    """

    def __init__(
        self, *, axes: str = "XYZ", axis_specs: Mapping[str, AxisSpec] | None = None, time_scale: float = 1.0,
        homing_enabled: bool = True, soft_limits: bool = True, homing_seek_rate_per_min: float = 3000.0,
        homing_settle_s: float = 0.5, status_mask: int = 1, firmware: str = "grbl",
        rx_buffer_size: int | None = None, shuffle_fields: bool = False, seed: int = 0,
        faults: Iterable[Fault] = (), start_position: Mapping[str, float] | None = None,
    ):
        if not axes or axes != "".join(a for a in AXIS_LETTERS if a in axes) or len(set(axes)) != len(axes):
            raise ValueError(f"axes must be letters of {AXIS_LETTERS} in that order, not {axes!r}")
        if time_scale <= 0:
            raise ValueError("time_scale must be > 0")
        if firmware not in ("grbl", "grblhal"):
            raise ValueError("firmware must be 'grbl' or 'grblhal'")
        self.axes = axes
        specs = dict(DEFAULT_AXES)
        specs.update(axis_specs or {})
        self.specs = {a: specs[a] for a in axes}
        self.time_scale = float(time_scale)
        self.homing_enabled = homing_enabled
        self.soft_limits = soft_limits and homing_enabled
        self.homing_seek_rate_per_min = homing_seek_rate_per_min
        self.homing_settle_s = homing_settle_s
        self.status_mask = status_mask
        self.firmware = firmware
        self.rx_buffer_size = rx_buffer_size or (1024 if firmware == "grblhal" else RX_BUFFER_SIZE)
        self.shuffle_fields = shuffle_fields
        self._rng = random.Random(seed)
        self._faults: list[Fault] = list(faults)
        self._start_position = {a: float((start_position or {}).get(a, self.specs[a].home)) for a in axes}

        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._stop = threading.Event()
        self.tty_path: str | None = None
        self.vanished = False
        self._vanish_requested = False

        self._t0_real = time.monotonic()
        self._power_up()
        # Statistics for tests and benchmarks.
        self.max_rx_fill = 0
        self.rx_overflow_bytes = 0
        self.lines_received: deque[str] = deque(maxlen=1000)
        self.status_reports_sent = 0
        self.resets = 0

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> GrblEmulator:
        """Open the pty and start serving. Returns self; ``tty_path`` is then the device to open."""
        if self._thread is not None:
            return self
        master, slave = os.openpty()
        # Raw at once: with the default line discipline the banner written before anyone opens the
        # slave would be echoed back to us as if it were input.
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.tty_path = os.ttyname(slave)
        self._wake_r, self._wake_w = os.pipe()
        self._stop.clear()
        with self._lock:
            self._t0_real = time.monotonic()
            self._power_up()
            self._banner()
            # Booted before anyone connects, like a real board: the banner waits in the tty's queue.
            self._flush_output()
        self._thread = threading.Thread(target=self._serve, name=f"grbl-emulator {self.tty_path}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty; the serving thread has ended when this returns."""
        self._stop.set()
        if self._wake_w is not None:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
            if thread.is_alive():
                raise RuntimeError("GRBL emulator thread did not stop")
        self._close_fds()

    def __enter__(self) -> GrblEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        """Serving: started, not stopped, and the port has not vanished."""
        return not self.vanished and self._thread is not None and self._thread.is_alive()

    def _close_fds(self) -> None:
        with self._lock:
            for name in ("_master", "_slave", "_wake_r", "_wake_w"):
                fd = getattr(self, name)
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
                    setattr(self, name, None)

    def vanish(self, timeout: float = 5.0) -> None:
        """The port disappears now, as when a USB cable is pulled: the tty is closed and its path goes away.

        Returns once it has (the serving thread closes it, so no other thread races it for the fds).
        """
        thread = self._thread
        if thread is None or not thread.is_alive():
            with self._lock:
                self._vanish()
            return
        with self._lock:
            self._vanish_requested = True
            if self._wake_w is not None:
                with contextlib.suppress(OSError):
                    os.write(self._wake_w, b"x")
        if thread is not threading.current_thread():
            thread.join(timeout)

    def _vanish(self) -> None:
        self.vanished = True
        self._stop.set()
        for name in ("_master", "_slave"):
            fd = getattr(self, name)
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
                setattr(self, name, None)

    # ------------------------------------------------------------------ public state (thread-safe)

    def inject(self, fault: Fault) -> None:
        """Arm a fault; it fires at its trigger and is then used up."""
        with self._lock:
            self._faults.append(fault)

    def machine_position(self) -> dict[str, float]:
        """Where the axes are now (machine units), between status reports too. Thread-safe."""
        with self._lock:
            return self._current_position(self._sim_now())

    @property
    def state(self) -> str:
        """Machine state as a status report would name it (``Idle``, ``Run``, ``Hold:0``, ``Alarm``, ``Home``...)."""
        with self._lock:
            self._advance(self._sim_now())
            text = self._state_text()
            if self._out and self._wake_w is not None:
                with contextlib.suppress(OSError):
                    os.write(self._wake_w, b"x")  # let the serving thread send what advancing produced
            return text

    @property
    def homed(self) -> bool:
        with self._lock:
            return self._homed

    def sim_time(self) -> float:
        """Simulated seconds since start."""
        with self._lock:
            return self._sim_now()

    # ------------------------------------------------------------------ machine model

    def _power_up(self) -> None:
        self._position = dict(self._start_position)
        self._wco = dict.fromkeys(self.axes, 0.0)
        self._homed = False
        self._state = "Alarm" if self.homing_enabled else "Idle"
        self._hold_complete = False
        # Output survives a soft reset (GRBL flushes its receive buffer, not its transmit buffer).
        self._out: deque[tuple[float, bytes]] = deque()
        self._last_release = 0.0
        self._reset_common()

    def _reset_common(self) -> None:
        self._halted = False  # critical alarm: only reset and status are served
        self._alarm_code: int | None = None
        self._planner: deque[_Block] = deque()
        self._rx = bytearray()
        self._current: tuple[str, dict] | None = None  # a line waiting for the planner or a dwell
        self._dwell_end: float | None = None
        self._homing_block: _Block | None = None
        self._modal = {"motion": 0, "distance": 90, "units": 21, "feed": 0.0}
        self._wco_counter = 0
        self._ovr_counter = 0

    def _sim_now(self) -> float:
        return (time.monotonic() - self._t0_real) * self.time_scale

    def _real_delay(self, sim_seconds: float) -> float:
        return max(0.0, sim_seconds / self.time_scale)

    def _current_position(self, now: float) -> dict[str, float]:
        block = self._homing_block or (self._planner[0] if self._planner else None)
        if block is not None and block.t_start is not None:
            pos = block.position_at(now - block.t_start)
        else:
            pos = dict(self._position)
        return pos

    def _quantise(self, pos: Mapping[str, float]) -> dict[str, float]:
        out = {}
        for axis, value in pos.items():
            steps = self.specs[axis].steps_per_unit
            out[axis] = round(value * steps) / steps if steps else value
        return out

    def _state_text(self) -> str:
        if self._state == "Hold":
            return f"Hold:{0 if self._hold_complete else 1}"
        return self._state

    def _advance(self, now: float) -> None:
        """Bring motion, homing and dwells up to sim time ``now``; fire mid-move faults."""
        if self._homing_block is not None:
            block = self._homing_block
            if now >= block.t_start + block.duration:  # type: ignore[operator]
                self._position = {a: self.specs[a].home for a in self.axes}
                self._homing_block = None
                self._homed = True
                self._state = "Idle"
                self._alarm_code = None
                self._finish_current("ok")
            return
        while self._planner:
            block = self._planner[0]
            if block.t_start is None:
                if self._state in ("Run", "Jog", "Idle"):
                    block.t_start = now
                    if self._state == "Idle":
                        self._state = "Jog" if block.kind == "jog" else "Run"
                else:
                    break
            if self._check_mid_move_faults(block, now):
                break
            if now >= block.t_start + block.duration:
                self._position = dict(block.end)
                self._planner.popleft()
                if self._planner:
                    nxt = self._planner[0]
                    nxt.t_start = block.t_start + block.duration
                    if self._state in ("Run", "Jog"):
                        self._state = "Jog" if nxt.kind == "jog" else "Run"
                continue
            break
        if not self._planner and self._state in ("Run", "Jog"):
            self._state = "Idle"
        if self._current is not None:
            self._try_current(now)

    def _check_mid_move_faults(self, block: _Block, now: float) -> bool:
        """Fire a fault due during ``block``; True if one fired (the block is then gone)."""
        if block.t_start is None or block.duration <= 0:
            return False
        done = (now - block.t_start) / block.duration
        for fault in list(self._faults):
            if isinstance(fault, (AlarmMidMove, ResetMidMove, VanishMidMove)) and done >= fault.fraction:
                self._faults.remove(fault)
                at = block.t_start + fault.fraction * block.duration
                if isinstance(fault, AlarmMidMove):
                    self._stop_motion_at(at)
                    self._raise_alarm(fault.code)
                elif isinstance(fault, ResetMidMove):
                    self._stop_motion_at(at)
                    self._reboot()
                else:
                    self._stop_motion_at(at)
                    self._vanish()
                return True
        return False

    def _next_event_sim(self, now: float) -> float | None:
        times = []
        if self._homing_block is not None:
            times.append(self._homing_block.t_start + self._homing_block.duration)  # type: ignore[operator]
        elif self._planner and self._planner[0].t_start is not None:
            block = self._planner[0]
            times.append(block.t_start + block.duration)
            for fault in self._faults:
                if isinstance(fault, (AlarmMidMove, ResetMidMove, VanishMidMove)):
                    times.append(block.t_start + fault.fraction * block.duration)
        if self._dwell_end is not None:
            times.append(self._dwell_end)
        return min(times) if times else None

    def _stop_motion_at(self, when: float) -> None:
        """Freeze the axes where they are at sim time ``when`` and drop all queued motion."""
        self._position = self._current_position(when)
        self._planner.clear()
        self._homing_block = None
        self._dwell_end = None
        self._current = None

    def _raise_alarm(self, code: int) -> None:
        self._state = "Alarm"
        self._alarm_code = code
        self._rx.clear()
        self._emit(f"ALARM:{code}", "alarm")
        if code in (1, 2):
            # Hard and soft limits are critical in GRBL 1.1: nothing but reset and status until a reset.
            self._halted = True
            self._emit("[MSG:Reset to continue]", "msg")

    def _reboot(self) -> None:
        """Power-cycle-like reset: the controller forgets it was homed and boots as at power-up."""
        self.resets += 1
        pos = dict(self._position)
        self._homed = False
        self._state = "Alarm" if self.homing_enabled else "Idle"
        self._hold_complete = False
        self._reset_common()
        self._position = pos
        self._banner()

    def _soft_reset(self) -> None:
        self.resets += 1
        now = self._sim_now()
        # A completed hold (Hold:0) is not motion: GRBL keeps the position without an alarm.
        moving = self._homing_block is not None or self._state in ("Run", "Jog", "Home")
        homing = self._homing_block is not None
        self._stop_motion_at(now)
        was_alarm = self._state == "Alarm"
        self._reset_common()
        if moving:
            self._state = "Alarm"
            self._emit(f"ALARM:{6 if homing else 3}", "alarm")
        elif was_alarm:
            self._state = "Alarm"
        else:
            self._state = "Idle"
        self._hold_complete = False
        self._banner()

    def _banner(self) -> None:
        self._emit("", "banner")
        self._emit(GRBLHAL_BANNER if self.firmware == "grblhal" else GRBL_BANNER, "banner")
        if self._state == "Alarm":
            self._emit(UNLOCK_MESSAGE, "msg")

    # ------------------------------------------------------------------ output and faults

    def _emit(self, text: str, kind: str) -> None:
        data = text.encode("latin-1") + b"\r\n"
        release = time.monotonic()
        for fault in list(self._faults):
            if isinstance(fault, LostOk) and kind == "ok" and (fault.match is None or fault.match in self._ok_for):
                fault.count -= 1
                if fault.count <= 0:
                    self._faults.remove(fault)
                return
            if isinstance(fault, GarbledLine) and kind != "banner" and fault.what in (kind, "any") and len(text) >= 2:
                fault.count -= 1
                if fault.count <= 0:
                    self._faults.remove(fault)
                mid = len(text) // 2
                data = text[:mid].encode("latin-1") + b"\xff" + text[mid + 1:].encode("latin-1") + b"\r\n"
                if len(text) == 2:
                    data = text[0].encode("latin-1") + b"\xff" + text[1].encode("latin-1") + b"\r\n"
                break
        for fault in list(self._faults):
            if isinstance(fault, Delay) and fault.what in (kind, "any") and kind != "banner":
                fault.count -= 1
                if fault.count <= 0:
                    self._faults.remove(fault)
                release += fault.seconds
                break
        # A serial line keeps order: nothing overtakes a delayed line.
        release = max(release, self._last_release)
        self._last_release = release
        self._out.append((release, data))

    _ok_for = ""  # the line an 'ok' answers, for LostOk(match=...)

    def _flush_output(self) -> None:
        now = time.monotonic()
        while self._out and self._out[0][0] <= now and self._master is not None:
            _, data = self._out[0]
            try:
                os.write(self._master, data)
            except BlockingIOError:
                # Nobody is reading the port and the pty buffer is full: a UART would lose it too.
                pass
            except OSError as error:
                if error.errno != errno.EIO:
                    raise
            self._out.popleft()

    # ------------------------------------------------------------------ input

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                with self._lock:
                    if self._vanish_requested:
                        self._vanish()
                        return
                    now = self._sim_now()
                    self._advance(now)
                    self._process_lines(now)
                    self._flush_output()
                    timeout = 0.1
                    nxt = self._next_event_sim(self._sim_now())
                    if nxt is not None:
                        timeout = min(timeout, self._real_delay(nxt - self._sim_now()))
                    if self._out:
                        timeout = min(timeout, max(0.0, self._out[0][0] - time.monotonic()))
                    master, wake = self._master, self._wake_r
                if master is None or wake is None:
                    return
                try:
                    readable, _, _ = select.select([master, wake], [], [], timeout)
                except (OSError, ValueError):
                    return
                if wake in readable:
                    with contextlib.suppress(OSError):
                        os.read(wake, 64)
                if master in readable:
                    with self._lock:
                        if self._master != master:  # vanished meanwhile: the number may belong to another file now
                            return
                        try:
                            data = os.read(master, 4096)
                        except BlockingIOError:
                            continue
                        except OSError:
                            return
                        self._receive(data)
                        self._flush_output()
        except Exception:
            # A bug in the model must not leave a tty that accepts bytes and never answers.
            with self._lock:
                self._vanish()
            raise

    def _receive(self, data: bytes) -> None:
        now = self._sim_now()
        self._advance(now)
        for byte in data:
            if byte == 0x18:
                self._soft_reset()
            elif byte == ord("?"):
                self._advance(self._sim_now())
                if self._homing_block is None:  # GRBL 1.1 does not report while homing
                    self._emit(self._status_report(), "status")
            elif byte == ord("!"):
                self._feed_hold()
            elif byte == ord("~"):
                self._cycle_start()
            elif byte == 0x85:
                self._jog_cancel()
            elif byte >= 0x80:
                pass  # overrides: accepted, not modelled
            elif self._halted:
                pass  # critical alarm: input is ignored until reset
            elif len(self._rx) >= self.rx_buffer_size - 1:
                self.rx_overflow_bytes += 1
            else:
                self._rx.append(byte)
                self.max_rx_fill = max(self.max_rx_fill, len(self._rx))
        self._process_lines(self._sim_now())

    def _feed_hold(self) -> None:
        if self._state in ("Alarm", "Hold", "Home") or self._halted:
            return
        now = self._sim_now()
        if self._planner and self._planner[0].t_start is not None:
            block = self._planner[0]
            here = block.position_at(now - block.t_start)
            rest = self._make_block(here, block.end, block.speed * 60.0, kind=block.kind, line=block.line)
            self._position = here
            self._planner[0] = rest
        if self._state == "Jog":
            # A hold during a jog cancels it, as GRBL does.
            self._planner.clear()
            self._state = "Idle"
            return
        self._state = "Hold"
        self._hold_complete = True

    def _cycle_start(self) -> None:
        if self._state != "Hold":
            return
        self._hold_complete = False
        self._state = "Run" if self._planner else "Idle"
        if self._planner:
            self._planner[0].t_start = self._sim_now()

    def _jog_cancel(self) -> None:
        if self._state != "Jog":
            return
        self._stop_motion_at(self._sim_now())
        self._state = "Idle"

    def _process_lines(self, now: float) -> None:
        while not self._halted:
            if self._current is not None:
                self._try_current(now)
                if self._current is not None:
                    return
            if self._homing_block is not None:
                return
            newline = self._rx.find(b"\n")
            carriage = self._rx.find(b"\r")
            ends = [i for i in (newline, carriage) if i >= 0]
            if not ends:
                return
            end = min(ends)
            raw = bytes(self._rx[:end])
            del self._rx[: end + 1]
            self._execute_line(raw.decode("latin-1"), now)

    def _reply(self, line: str, text: str, kind: str) -> None:
        self._ok_for = line
        self._emit(text, kind)
        self._ok_for = ""

    def _finish_current(self, result: str) -> None:
        if self._current is None:
            return
        line, _ = self._current
        self._current = None
        self._reply(line, result, "ok" if result == "ok" else "error")

    # ------------------------------------------------------------------ lines

    def _execute_line(self, line: str, now: float) -> None:
        self.lines_received.append(line)
        text = re.sub(r"\([^)]*\)", "", line).split(";", 1)[0]
        text = "".join(text.split()).upper()
        if len(text) > LINE_BUFFER_SIZE - 1:  # GRBL counts what it keeps: no spaces, no comments
            self._reply(line, "error:11", "error")
            return
        if not text:
            self._reply(line, "ok", "ok")
            return
        if text.startswith("$"):
            result = self._system_command(line, text, now)
        else:
            result = self._gcode(line, text, now)
        if result is not None:
            self._reply(line, result, "ok" if result == "ok" else "error")

    def _settings(self) -> list[tuple[int, float]]:
        rows = [(0, 10), (1, 25), (2, 0), (3, 0), (4, 0), (5, 0), (6, 0), (10, self.status_mask), (11, 0.010),
                (12, 0.002), (13, 0), (20, int(self.soft_limits)), (21, 0), (22, int(self.homing_enabled)), (23, 0),
                (24, 25.0), (25, self.homing_seek_rate_per_min), (26, 250), (27, 1.0), (30, 1000), (31, 0), (32, 0)]
        for i, axis in enumerate(self.axes):
            spec = self.specs[axis]
            rows += [(100 + i, spec.steps_per_unit or 250.0), (110 + i, spec.max_rate_per_min),
                     (120 + i, spec.acceleration), (130 + i, spec.travel[1] - spec.travel[0])]
        return sorted(rows)

    def _system_command(self, line: str, text: str, now: float) -> str | None:
        if text == "$H":
            if not self.homing_enabled:
                return "error:5"
            if self._state not in ("Idle", "Alarm") or self._planner:
                return "error:8"
            self._start_homing(line, now)
            return None
        if text == "$X":
            if self._state == "Alarm":
                self._state = "Idle"
                self._alarm_code = None
                self._emit("[MSG:Caution: Unlocked]", "msg")
            return "ok"
        if text == "$$":
            for number, value in self._settings():
                self._emit(f"${number}={_fmt_setting(value)}", "setting")
            return "ok"
        if text == "$I":
            version = "1.1f.20231210" if self.firmware == "grblhal" else "1.1h.20190825"
            self._emit(f"[VER:{version}:]", "feedback")
            self._emit(f"[OPT:V,{PLANNER_BLOCKS},{self.rx_buffer_size}]", "feedback")
            return "ok"
        if text == "$G":
            m = self._modal
            self._emit(f"[GC:G{m['motion']} G54 G17 G{m['units']} G{m['distance']} G94 M5 M9 T0 "
                       f"F{_fmt_setting(m['feed'])} S0]", "feedback")
            return "ok"
        if text == "$#":
            for name in ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"):
                self._emit(f"[{name}:{','.join('0.000' for _ in self.axes)}]", "feedback")
            self._emit("[TLO:0.000]", "feedback")
            return "ok"
        if text.startswith("$J="):
            return self._jog(line, text[3:], now)
        if m := re.fullmatch(r"\$(\d+)=([-+]?\d*\.?\d+)", text):
            return self._write_setting(int(m.group(1)), float(m.group(2)))
        return "error:3"

    def _write_setting(self, number: int, value: float) -> str:
        if self._state not in ("Idle", "Alarm"):
            return "error:8"
        if number == 10:
            self.status_mask = int(value)
        elif number == 20:
            if value and not self.homing_enabled:
                return "error:10"
            self.soft_limits = bool(value)
        elif number == 22:
            self.homing_enabled = bool(value)
            if not self.homing_enabled:
                self.soft_limits = False
        elif number not in dict(self._settings()):
            return "error:3"
        return "ok"

    def _start_homing(self, line: str, now: float) -> None:
        home = {a: self.specs[a].home for a in self.axes}
        here = dict(self._position)
        rate = self.homing_seek_rate_per_min / 60.0
        far = max(abs(home[a] - here[a]) for a in self.axes)
        # Seek at the homing rate (no ramps), then the locate/pull-off phases as a fixed settle time.
        block = _Block(start=here, end=home, length=far, speed=rate, accel=1e12, kind="home", line=line,
                       dwell_after=self.homing_settle_s)
        block.t_start = now
        self._homing_block = block
        self._state = "Home"
        self._current = (line, {})

    def _try_current(self, now: float) -> None:
        """Retry a line that waits: a G4 for the planner to empty and then its dwell; motion for a free block."""
        if self._current is None or self._homing_block is not None:
            return
        line, words = self._current
        if words.get("dwell") is not None:
            if self._dwell_end is None:
                if self._planner:
                    return
                self._dwell_end = now + words["dwell"]
            if now >= self._dwell_end:
                self._dwell_end = None
                self._finish_current("ok")
            return
        if words.get("block") is not None:
            if len(self._planner) >= PLANNER_BLOCKS:
                return
            self._planner.append(words["block"])
            self._current = None
            self._reply(line, "ok", "ok")

    def _gcode(self, line: str, text: str, now: float) -> str | None:
        if self._state == "Alarm":
            return "error:9"
        words = re.findall(r"([A-Z])([^A-Z]*)", text)
        if "".join(letter + value for letter, value in words) != text:
            return "error:1"
        g_codes: list[float] = []
        m_codes: list[float] = []
        values: dict[str, float] = {}
        for letter, value in words:
            if not re.fullmatch(r"[-+]?(\d+\.?\d*|\.\d+)", value):
                return "error:2"
            number = float(value)
            if letter == "G":
                g_codes.append(number)
            elif letter == "M":
                m_codes.append(number)
            elif letter in "FPN" or letter in self.axes:
                if letter in values:
                    return "error:25"
                values[letter] = number
            else:
                return "error:20"
        motion = [g for g in g_codes if g in (0, 1, 2, 3, 38.2, 80)]
        distance = [g for g in g_codes if g in (90, 91)]
        units = [g for g in g_codes if g in (20, 21)]
        supported = {0, 1, 4, 17, 20, 21, 53, 54, 90, 91, 94, 80}
        for g in g_codes:
            if g not in supported:
                return "error:20"
        if len(motion) > 1 or len(distance) > 1 or len(units) > 1 or g_codes.count(4) + g_codes.count(53) > 1:
            return "error:21"
        for m in m_codes:
            if m not in (0, 2, 5, 9, 30):
                return "error:20"
        if units:
            self._modal["units"] = int(units[0])
        if distance:
            self._modal["distance"] = int(distance[0])
        if "F" in values:
            if values["F"] < 0:
                return "error:4"
            self._modal["feed"] = values["F"] * (25.4 if self._modal["units"] == 20 else 1.0)
        if motion:
            self._modal["motion"] = int(motion[0])
        axis_words = {a: v for a, v in values.items() if a in self.axes}
        if 4 in g_codes:
            if axis_words:
                return "error:31"
            if "P" not in values:
                return "error:28"
            if values["P"] < 0:
                return "error:4"
            self._current = (line, {"dwell": values["P"]})
            self._try_current(now)
            return None
        if "P" in values:
            return "error:36"
        if not axis_words:
            if 53 in g_codes:
                return "error:26"
            return "ok"
        if self._modal["motion"] == 80:
            return "error:31"
        if 53 in g_codes and self._modal["motion"] not in (0, 1):
            return "error:30"
        scale = 25.4 if self._modal["units"] == 20 else 1.0
        base = self._planned_end()
        target = dict(base)
        for axis, value in axis_words.items():
            value *= scale
            if 53 in g_codes:
                target[axis] = value
            elif self._modal["distance"] == 91:
                target[axis] = base[axis] + value
            else:
                target[axis] = value + self._wco[axis]
        if self._modal["motion"] == 1 and self._modal["feed"] <= 0:
            return "error:22"
        if self.soft_limits and self._outside_travel(target):
            # GRBL 1.1: motion beyond travel with soft limits on is a critical alarm, not an error.
            self._stop_motion_at(now)
            self._raise_alarm(2)
            return None
        feed = None if self._modal["motion"] == 0 else self._modal["feed"]
        block = self._make_block(base, target, feed, kind=f"G{self._modal['motion']}", line=line)
        if block.length <= 0:
            return "ok"
        self._current = (line, {"block": block})
        self._try_current(now)
        return None

    def _jog(self, line: str, body: str, now: float) -> str | None:
        if self._state not in ("Idle", "Jog"):
            return "error:8"
        words = re.findall(r"([A-Z])([-+]?\d*\.?\d*)", body)
        if "".join(a + b for a, b in words) != body:
            return "error:16"
        values: dict[str, float] = {}
        relative = False
        machine = False
        for letter, value in words:
            if letter == "G":
                if value in ("91",):
                    relative = True
                elif value in ("53",):
                    machine = True
                elif value not in ("90", "21", "20"):
                    return "error:16"
                continue
            if letter != "F" and letter not in self.axes:
                return "error:16"
            values[letter] = float(value)
        if "F" not in values:
            return "error:22"
        base = self._planned_end()
        target = dict(base)
        for axis in self.axes:
            if axis in values:
                if relative:
                    target[axis] = base[axis] + values[axis]
                else:
                    target[axis] = values[axis] + (0.0 if machine else self._wco[axis])
        if self.soft_limits and self._outside_travel(target):
            return "error:15"
        block = self._make_block(base, target, values["F"], kind="jog", line=line)
        if block.length <= 0:
            return "ok"
        self._current = (line, {"block": block})
        self._try_current(now)
        return None

    def _planned_end(self) -> dict[str, float]:
        if self._planner:
            return dict(self._planner[-1].end)
        return dict(self._position)

    def _outside_travel(self, target: Mapping[str, float]) -> bool:
        for axis, value in target.items():
            low, high = self.specs[axis].travel
            if not low - 1e-9 <= value <= high + 1e-9:
                return True
        return False

    def _make_block(self, start: Mapping[str, float], end: Mapping[str, float], feed_per_min: float | None,
                    *, kind: str, line: str) -> _Block:
        deltas = {a: end[a] - start[a] for a in self.axes}
        length = math.sqrt(sum(d * d for d in deltas.values()))
        if length <= 1e-12:
            return _Block(start=dict(start), end=dict(end), length=0.0, speed=1.0, accel=1.0, kind=kind, line=line)
        limits = path_limits(deltas, max_rate_per_min={a: self.specs[a].max_rate_per_min for a in self.axes},
                             acceleration={a: self.specs[a].acceleration for a in self.axes}, feed_per_min=feed_per_min)
        return _Block(start=dict(start), end=dict(end), length=limits.length, speed=limits.speed, accel=limits.accel,
                      kind=kind, line=line)

    # ------------------------------------------------------------------ status report

    def _status_report(self) -> str:
        now = self._sim_now()
        pos = self._quantise(self._current_position(now))
        self.status_reports_sent += 1
        fields: list[str] = []
        if self.status_mask & 1:
            fields.append("MPos:" + ",".join(f"{pos[a]:.3f}" for a in self.axes))
        else:
            fields.append("WPos:" + ",".join(f"{pos[a] - self._wco[a]:.3f}" for a in self.axes))
        if self.status_mask & 2:
            fields.append(f"Bf:{PLANNER_BLOCKS - len(self._planner)},{self.rx_buffer_size - len(self._rx)}")
        speed = 0.0
        if self._planner and self._planner[0].t_start is not None and self._state in ("Run", "Jog"):
            block = self._planner[0]
            speed = block.speed_at(now - block.t_start) * 60.0
        fields.append(f"FS:{speed:.0f},0")
        if self._wco_counter > 0:
            self._wco_counter -= 1
        else:
            busy = self._state in ("Run", "Jog", "Hold", "Home")
            self._wco_counter = (30 if busy else 10) - 1
            if self._ovr_counter == 0:
                self._ovr_counter = 1
            fields.append("WCO:" + ",".join(f"{self._wco[a]:.3f}" for a in self.axes))
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        else:
            self._ovr_counter = 19
            fields.append("Ov:100,100,100")
        if self.shuffle_fields:
            self._rng.shuffle(fields)
        return "<" + "|".join([self._state_text(), *fields]) + ">"


def _fmt_setting(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:.3f}"
