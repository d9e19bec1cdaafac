"""GRBL 1.1 controller driver: typed commands in machine units over any :class:`Transport`.

Layers: :mod:`drivers.rig.transport` moves bytes, :mod:`drivers.rig.codec` turns them into messages,
and :class:`GrblController` (here) keeps the protocol's state; what it reports is data in
:mod:`drivers.rig.grbl_reports` (:class:`GrblReading`, :class:`ControllerInfo`), its failures are
:mod:`drivers.rig.grbl_errors`' (all re-exported here):

- a reader thread splits incoming bytes into lines and dispatches them: ``ok``/``error:N`` answer the
  oldest outstanding line (GRBL answers in order), ``<...>`` answers the oldest ``?``, ``ALARM:N`` and
  banners fail whatever is outstanding;
- lines are streamed by character counting: the bytes of lines not yet answered never exceed GRBL's
  receive buffer, less one byte (``rx_buffer_size - 1``: Grbl 1.1's ring holds all of it, serial.c
  ``RX_RING_BUFFER``, but a ring of exactly that size, as grblHAL's, keeps one slot free), so nothing is dropped;
- real-time bytes (``?`` ``!`` ``~`` 0x18) bypass the buffer and get no ``ok``;
- every wait has a deadline. ``ok`` only means *queued*; the end of motion is known from ``G4 P0``
  (its ``ok`` comes once the planner is empty), and while waiting for it the driver polls ``?`` so that
  a lost ``ok`` is detected (controller Idle, buffers empty, answer still missing) and recovered from.

What Grbl 1.1h does that the driver must know (its source is the specification):

- Opening an Arduino's port resets it (DTR auto-reset): the banner comes ~1.1 s later and the step
  counters restart at 0 wherever the axes stand. :meth:`GrblController.open` listens before it acts:
  a controller that answers ``?`` at once was running; every banner that comes before the first status
  report, however late, is a boot (``info.boot_detected``). After a boot - at open, late, or mid-run - the
  position is unknown and motion is refused (:class:`GrblPositionUnknown`), whatever ``$22`` says, until
  the rig is homed or :meth:`GrblController.trust_position` states that it is right.
- ``$I``, ``$$``, ``$N`` and ``$#`` are read at connect (:attr:`GrblController.info`): ``$13=1`` (inches) is
  refused, a startup line that switches units or moves is warned about, the receive buffer size in
  ``[OPT:]`` replaces a different configured one; a query answered ``error:N`` (a dialect without it) is
  recorded in ``info.unsupported`` and the connect goes on.
- A failed homing cycle (``ALARM:8``/``9``) resets Grbl: the ``$H`` line still gets a late ``ok`` and a
  banner follows (limits.c ``limits_go_home`` calls ``mc_reset``; system.c ``system_execute_line`` still
  returns STATUS_OK for ``$H``; main.c re-initialises). The driver keeps the ``$H`` outstanding for that ``ok`` and
  treats the banner as part of the failure; when the ALARM line is missing, the Alarm state after the
  ``ok`` tells.
- After ``ALARM:1``/``ALARM:2`` Grbl answers nothing, not even ``?``, until a soft reset (protocol.c
  ``protocol_exec_rt_system``, its critical-event loop): the driver says so instead of timing out. A
  reset received before its ``[MSG:Reset to continue]`` is discarded: :meth:`GrblController.soft_reset`
  waits for that message and resends once.
- grblHAL (``info.dialect``): ``$21``/``$22`` are bitfields, its work envelope keeps a pull-off off each end
  with hard limits on, and it checks soft limits on homed axes only (:func:`codec.soft_limit_space`).
- ``~`` during ``Hold:1`` (still decelerating) is ignored (protocol.c ``protocol_exec_rt_system`` starts a
  cycle only from Idle or a hold with SUSPEND_HOLD_COMPLETE, and clears the request either way):
  :meth:`GrblController.resume` waits for ``Hold:0``.
- Every ``ALARM:N`` line is followed by 0.5 s in which Grbl sends nothing (report.c ``report_alarm_message``,
  ``delay_ms(500)``), and ``?`` requests made meanwhile collapse into one report (a flag, serial.c):
  :meth:`GrblController.status` resends and takes any report newer than its request.
- Leaving check mode (``$C``) resets Grbl: expected, not an unexpected reset.

Positions in readings are only ever what the controller reported (MPos, or WPos + the last WCO).
Units are machine units (mm for G21; whatever a rotary axis is configured in).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO

import serial

from drivers.rig import codec
from drivers.rig.grbl_errors import (
    GrblAlarm,
    GrblCommandError,
    GrblConnectionError,
    GrblConnectionLost,
    GrblError,
    GrblLocked,
    GrblMoveError,
    GrblPositionUnknown,
    GrblResetError,
    GrblSettingsError,
    GrblTimeout,
)
from drivers.rig.grbl_reports import ControllerInfo, GrblReading
from drivers.rig.status import Outcome
from drivers.rig.transport import SerialTransport, SpyTransport, Transport, TransportError

log = logging.getLogger(__name__)


#: After ALARM:1/2 Grbl 1.1h pauses 500 ms (report.c ``report_alarm_message``), then says
#: ``[MSG:Reset to continue]`` and drops any reset received meanwhile: a reset waits for that message, at most
#: this long after the ALARM line (the pause, with room for a loaded host).
CRITICAL_RESET_WAIT_S = 1.5
#: A soft reset not answered by a banner within this long (or half its timeout) is sent once more (a reset the
#: firmware dropped, or a bootloader swallowed).
RESET_RESEND_AFTER_S = 1.0


class _Pending:
    """One line sent and not yet answered."""

    __slots__ = ("line", "size", "event", "reply", "error", "assumed", "feedback", "sent_at")

    def __init__(self, line: str, size: int):
        self.line = line
        self.size = size
        self.event = threading.Event()
        self.reply: codec.Response | None = None
        self.error: GrblError | None = None
        self.assumed = False  # answered by recovery after a lost reply, not by the controller
        self.feedback: list[str] = []
        self.sent_at = time.monotonic()

    def finish(self, reply: codec.Response | None = None, error: GrblError | None = None) -> None:
        self.reply, self.error = reply, error
        self.event.set()


class MoveStatus(Outcome):
    """The result of :meth:`GrblController.move_to`, in the manner of ophyd's MoveStatus.

    The move is already queued on the controller; :meth:`wait` blocks until motion has ended (bounded by
    ``timeout``), checks that the controller stopped at the target and returns the final reading.
    """

    def __init__(self, controller: GrblController, target: dict[str, float], pending: _Pending,
                 timeout_s: float, tolerance: Mapping[str, float], *, sequence: int = 0,
                 start: Mapping[str, float] | None = None):
        self.controller = controller
        self.target = target
        self.timeout_s = timeout_s
        self.tolerance = dict(tolerance)
        self.sequence = sequence
        self.start = dict(start) if start else None
        self._pending = pending
        super().__init__()
        self._wait_lock = threading.Lock()  # one waiter talks to the controller; others wait on it
        self.started_at = time.monotonic()

    @property
    def line(self) -> str:
        return self._pending.line

    def wait(self, timeout: float | None = None) -> GrblReading:
        """Block until the controller has stopped at the target; return its final report.

        Args:
            timeout: seconds; default the move's own ``timeout_s``.
        Raises:
            GrblTimeout, GrblAlarm, GrblCommandError, GrblConnectionError, GrblResetError, GrblMoveError.
        """
        with self._wait_lock:
            if self._done.is_set():
                if self._exception is not None:
                    raise self._exception
                return self._reading  # type: ignore[return-value]
            try:
                reading = self.controller.wait_idle(self.timeout_s if timeout is None else timeout)
                self.controller._raise_for(self._pending)
                self._check_position(reading)
            except BaseException as error:
                self._finish(None, error)
                raise
            self._finish(reading, None)
            return reading

    def _check_position(self, reading: GrblReading) -> None:
        position = reading.machine_position
        if position is None:
            raise GrblMoveError("motion ended but the controller reported no machine position")
        off = []
        reasons = set()
        for axis, target in self.target.items():
            actual = position.get(axis)
            if actual is None or abs(actual - target) > self.tolerance.get(axis, 0.01):
                off.append(f"{axis}={actual} (target {target:g})")
                reasons.add(self._why_off(axis, target, actual))
        if off:
            raise GrblMoveError(f"motion ended at {', '.join(off)}: {'; '.join(sorted(reasons))} "
                                f"(state {reading.full_state})")

    def _why_off(self, axis: str, target: float, actual: float | None) -> str:
        """Tell apart what can leave an axis off its target: a later move, step rounding, overshoot, a stop."""
        later = self.controller._move_sequence > self.sequence
        if later:
            return ("a later move was queued before this one was waited for; the axes went on to its target "
                    f"({self.controller._last_move_line!r})")
        if actual is None:
            return f"the controller reported no {axis} position"
        spu = self.controller.info.steps_per_unit(axis)
        if spu:
            steps = target * spu
            nearest = math.copysign(math.floor(abs(steps) + 0.5), steps) / spu  # planner.c: lround
            if abs(actual - nearest) <= 0.0005 + 1e-9:  # reports carry 3 decimals
                number = codec.SETTING_STEPS_PER_UNIT + codec.AXIS_LETTERS.index(axis)
                return (f"step rounding: {axis} moves in whole steps of {1.0 / spu:g} (${number}={spu:g}) and "
                        f"{nearest:.3f} is the step nearest the target; the tolerance "
                        f"{self.tolerance.get(axis, 0.01):g} is finer than one step")
        start = None if self.start is None else self.start.get(axis)
        if start is not None and (actual - target) * (target - start) > 0:
            return "overshoot: past the target in the direction of travel"
        return "the controller stopped short of the target"


class GrblController:
    """A GRBL 1.1 (or grblHAL) motion controller. Constructing it does no I/O.

    Args:
        port: a device path or pyserial URL, an open ``serial.SerialBase``, or any :class:`Transport`.
        baudrate: bits per second when ``port`` is a path or URL.
        rx_buffer_size: the controller's serial receive buffer (bytes): 128 for GRBL 1.1 on an Uno. The
            size the controller reports in ``$I`` (``[OPT:V,15,128]``) replaces it, with a warning.
        connect_timeout_s: how long :meth:`open` waits for the controller to answer.
        reset_on_open: soft-reset on open (flushes half-received lines; the position is kept when idle)
            unless the controller has just booted. False: only look, e.g. at a rig that is holding or
            that another program drives.
        boot_wait_s: how long :meth:`open` listens for a boot (an Arduino prints its banner ~1.1 s after
            the port opens) before it decides the controller is not answering.
        pulse_dtr_on_open: pulse DTR first (resets an Arduino the way the IDE does); tolerated on a pty.
        read_settings: read ``$I``, ``$$`` and ``$N`` at connect (:attr:`info`).
        status_retry_s: resend ``?`` if no report came within this long (a report can be lost).
        poll_interval_s: how often to poll ``?`` while waiting for motion to end.
        ok_grace_s: how long the controller must look Idle, with nothing outstanding, before a missing
            ``ok`` is declared lost.
        spy_log: a path or text stream: log every byte each way (see :class:`SpyTransport`).
    """

    def __init__(
        self, port: str | serial.SerialBase | Transport, *, baudrate: int = 115200,
        rx_buffer_size: int = codec.RX_BUFFER_SIZE, connect_timeout_s: float = 5.0, reset_on_open: bool = True,
        boot_wait_s: float = 2.0, pulse_dtr_on_open: bool = False, read_settings: bool = True,
        status_retry_s: float = 0.25, poll_interval_s: float = 0.05, ok_grace_s: float = 0.5,
        spy_log: str | Path | IO[str] | None = None,
    ):
        if isinstance(port, (str, serial.SerialBase)):
            transport: Transport = SerialTransport(port, baudrate=baudrate)
        else:
            transport = port
        if spy_log is not None:
            transport = SpyTransport(transport, spy_log)
        self.transport = transport
        self.port_name = transport.name
        self.baudrate = baudrate
        self.configured_rx_buffer_size = rx_buffer_size
        self.rx_buffer_size = rx_buffer_size
        self.connect_timeout_s = connect_timeout_s
        self.reset_on_open = reset_on_open
        self.boot_wait_s = boot_wait_s
        self.pulse_dtr_on_open = pulse_dtr_on_open
        self.read_settings = read_settings
        self.status_retry_s = status_retry_s
        self.poll_interval_s = poll_interval_s
        self.ok_grace_s = ok_grace_s

        self._cond = threading.Condition()
        self._send_lock = threading.Lock()  # one line sender at a time, so pending order = wire order
        self._write_lock = threading.Lock()  # real-time bytes never land inside a line's bytes
        self._reader: threading.Thread | None = None
        self._stop = threading.Event()
        self._opened_before = False
        self._reset_state()

    def _reset_state(self) -> None:
        self._pending: deque[_Pending] = deque()
        self._rx_used = 0
        self._status_sent = 0
        self._status_received = 0
        self._last_reading: GrblReading | None = None
        self._last_wco: tuple[float, ...] | None = None
        self._axes: str | None = None
        self._connection_error: GrblConnectionError | None = None
        self._alarm: codec.AlarmPush | None = None  # the alarm the controller is in, if known
        self._locked = False  # Alarm state: motion refused until $H / $X
        self._needs_reset = False  # critical alarm ("Reset to continue"): lines are ignored until 0x18
        self._homing = False  # $H outstanding: no status reports
        self._in_home = False  # inside home(): a reboot is part of a homing failure, not unexpected
        self._homing_alarm: codec.AlarmPush | None = None
        self._check_mode = False
        self._expecting_banner = False
        self._banner_grace_until = 0.0
        self._banner: codec.Banner | None = None
        self._banner_count = 0
        self._unexpected_reset = False
        self._position_unknown: str | None = None  # why the position cannot be trusted until homed
        self._banners_before_status = 0  # banners before the first status report since open: boots
        self._status_seen = False
        self._homed_here = False  # homed through this connection since the last banner (grblHAL's soft limits)
        self._critical_alarm_at: float | None = None  # monotonic time of the last ALARM:1/2 line
        self._reset_to_continue = False  # [MSG:Reset to continue] seen since it: a reset is heard now
        self._move_sequence = 0
        self._last_move_line = ""
        self.info = ControllerInfo()
        self.rx_buffer_size = self.configured_rx_buffer_size
        self.messages: deque[str] = deque(maxlen=100)
        self.lost_replies = 0
        self._hold_requested = False  # set by feed_hold(): a wait for motion then ends at the hold
        self.garbled_lines = 0
        self.stray_replies = 0

    # ------------------------------------------------------------------ lifecycle

    @property
    def is_open(self) -> bool:
        return self._reader is not None and self._reader.is_alive()

    def open(self) -> GrblController:
        """Open the port, find out whether the controller just booted, (soft-reset and) read its state,
        build info, settings and startup lines. Returns self."""
        if self.is_open and self._connection_error is None:
            return self
        if self._opened_before:
            # After a lost connection its reader may still be running and the port object still "open" on a
            # dead descriptor: stop and close both, then start clean.
            self.close()
        self._reset_state()
        try:
            self.transport.open()
        except TransportError as error:
            raise GrblConnectionError(error.strerror or str(error)) from None
        self._opened_before = True
        self._stop.clear()
        self._reader = threading.Thread(target=self._read_loop, name=f"grbl-reader {self.port_name}", daemon=True)
        self._reader.start()
        try:
            self._connect()
            if self.read_settings:
                self._read_info()
        except BaseException:
            self.close()
            raise
        return self

    def _connect(self) -> None:
        deadline = time.monotonic() + self.connect_timeout_s
        with self._cond:
            # An Arduino may be booting (DTR auto-reset): a banner during the connect is not a fault.
            self._banner_grace_until = deadline
        if self.pulse_dtr_on_open and hasattr(self.transport, "pulse_dtr"):
            self.transport.pulse_dtr()  # type: ignore[attr-defined]
        outcome = self._listen_for_boot(min(self.boot_wait_s, self.connect_timeout_s))
        reset_sent = False
        if outcome != "boot" and self.reset_on_open:
            reset_sent = outcome is None
            self._connect_by_reset(deadline)
        reading = self._last_reading
        if outcome != "running" or self.reset_on_open or reading is None or reading.machine_position is None:
            remaining = max(0.05, deadline - time.monotonic())
            try:
                self.status(timeout=remaining)
            except GrblTimeout:
                raise GrblConnectionError(self._silence_message(self.connect_timeout_s)) from None
        with self._cond:
            # It answered, so any boot is over: a banner from now on is a real reset.
            self._banner_grace_until = 0.0
            booted = self._banners_before_status > 0
        if booted:
            # Every banner before the first status report is a boot, however late it came (a slow bootloader,
            # grblHAL's simulator ~3 s, a hub): the step counters restarted at 0 wherever the axes stand.
            self.info.boot_detected = True
            if reset_sent:
                why = (f"{self.port_name} did not answer until it was reset and then printed its banner: it was "
                       "booting (a slow boot) or halted, and its step counters may have restarted at 0")
            else:
                why = (f"{self.port_name} booted when the port was opened (an Arduino's auto-reset?): its step "
                       "counters restarted at 0 wherever the axes stand")
            with self._cond:
                self._position_unknown = f"{why}, so the rig's position is unknown"
            self._warn(f"{why}: the rig's position is unknown until it is homed (or the position is confirmed with "
                       "`unlock --trust-position`)")

    def _silence_message(self, waited_s: float) -> str:
        return (f"no answer to '?' from {self.port_name} within {waited_s:g} s: a GRBL halted by a hard or soft "
                "limit (ALARM:1/2) answers nothing until it is reset (soft reset, 0x18); otherwise check that a "
                f"GRBL controller is on this port, at {self.baudrate} baud")

    def _listen_for_boot(self, timeout: float) -> str | None:
        """Ask ``?`` until a report ("running") or a banner ("boot") comes; None after ``timeout`` s of silence.

        A running Grbl answers ``?`` within milliseconds. A board reset by the opening of its port is in
        its bootloader, which swallows the ``?``, and then prints the banner: so a banner before any
        report means a boot.
        """
        start = time.monotonic()
        # Any banner since the port opened counts (the reset_state before open() zeroed the count): a board
        # that boots fast may have printed it before this thread got here.
        banners = 0
        wanted, asked_at = self._ask_status()
        next_retry = asked_at + self.status_retry_s
        while True:
            with self._cond:
                self._usable_or_raise()
                if self._banner_count != banners:
                    return "boot"
                reading = self._last_reading
                if self._status_received >= wanted and reading is not None and reading.monotonic >= asked_at:
                    return "running"
                now = time.monotonic()
                if now >= start + timeout:
                    return None
                if now < next_retry:
                    self._cond.wait(min(next_retry, start + timeout) - now)
                    continue
                self._status_received = max(self._status_received, self._status_sent)
            wanted, asked_at = self._ask_status()
            next_retry = asked_at + self.status_retry_s

    def _connect_by_reset(self, deadline: float) -> None:
        # An Arduino's bootloader may swallow the first reset byte: soft_reset sends a second one, once the
        # first has gone unanswered.
        remaining = deadline - time.monotonic()
        try:
            self.soft_reset(timeout=max(0.05, remaining), query_status=False)
        except GrblTimeout:
            raise GrblConnectionError(
                f"no GRBL banner from {self.port_name} within {self.connect_timeout_s:g} s of a soft reset: "
                f"is a GRBL controller on this port, at {self.baudrate} baud?") from None

    def _read_info(self) -> None:
        """``$I``, ``$$``, ``$N``: what the controller is, how it is set up, what it runs at every reset."""
        info = self.info
        info.firmware = None if self._banner is None else self._banner.text
        reading = self._last_reading
        state = reading.full_state if reading is not None else "unknown"
        if reading is None or reading.state not in ("Idle", "Alarm"):
            self._warn(f"{self.port_name}: settings not read: the controller is {state} ($I, $$ and $N need Idle "
                       "or Alarm); the rig config is not checked against them")
            return
        timeout = max(1.0, self.connect_timeout_s)
        build = codec.parse_build_info(self._query("$I", timeout))
        info.build, info.build_user_info, info.options = build.version, build.user_info, build.options
        info.planner_blocks, info.rx_buffer_size = build.planner_blocks, build.rx_buffer_size
        info.axis_count, info.build_tags = build.axis_count, dict(build.tags)
        settings = self._query("$$", timeout)
        info.startup_lines = codec.parse_startup_lines(self._query("$N", timeout))
        info.parameters = [line for line in self._query("$#", timeout) if line.startswith("[")]
        if "$$" in info.unsupported:
            self._warn(f"{self.port_name}: the controller refused $$ ({info.unsupported['$$']}): its settings are "
                       "unknown; the rig config is not checked against them")
            return
        info.settings = codec.parse_settings(settings)
        info.settings_read = True
        if info.settings.get(codec.SETTING_REPORT_INCHES):
            raise GrblSettingsError(
                f"{self.port_name}: $13=1: the controller reports positions in inches; this driver works in mm: "
                "set $13=0 (send '$13=0' from any serial terminal)")
        if info.rx_buffer_size is not None and info.rx_buffer_size != self.configured_rx_buffer_size:
            self._warn(f"{self.port_name}: the controller's receive buffer is {info.rx_buffer_size} bytes "
                       f"([OPT:] of $I), not the configured {self.configured_rx_buffer_size}: using "
                       f"{info.rx_buffer_size}")
            with self._cond:
                self.rx_buffer_size = info.rx_buffer_size
        for number, line in sorted(info.startup_lines.items()):
            hazards = codec.startup_line_hazards(line)
            if hazards:
                self._warn(f"{self.port_name}: startup line $N{number}={line} runs after every reset and homing and "
                           f"{' and '.join(hazards)}; every move of this driver carries G21 G90, but clear it "
                           f"(send '$N{number}=') unless it is meant")

    def _query(self, command: str, timeout: float) -> list[str]:
        """An informational query at connect; one the controller refuses (``error:N``: another dialect) is
        recorded in ``info.unsupported`` and answers nothing."""
        try:
            return self.send(command, timeout=timeout)
        except GrblCommandError as error:
            self.info.unsupported[command] = f"error:{error.code}"
            log.info("%s answers %s with error:%d (%s): recorded as unsupported", self.port_name, command,
                     error.code, error.meaning)
            return []

    def _warn(self, message: str) -> None:
        self.info.warnings.append(message)
        log.warning("%s", message)

    def close(self) -> None:
        """Stop the reader thread and close the port. Sends nothing: closing never moves or stops the rig."""
        self._stop.set()
        self.transport.cancel_read()
        reader, self._reader = self._reader, None
        if reader is not None and reader is not threading.current_thread():
            reader.join(timeout=2.0)
        self.transport.close()
        with self._cond:
            error = GrblConnectionError(f"connection to {self.port_name} closed")
            self._fail_pending(error)
            if self._connection_error is None:
                self._connection_error = error
            self._cond.notify_all()

    def __enter__(self) -> GrblController:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ what we know

    @property
    def axes(self) -> str | None:
        """Axis letters the controller reports (``XYZ``; ``XYZABC`` on a 6-axis grblHAL), once known."""
        return self._axes

    @property
    def banner(self) -> codec.Banner | None:
        return self._banner

    @property
    def last_reading(self) -> GrblReading | None:
        return self._last_reading

    @property
    def alarm(self) -> codec.AlarmPush | None:
        return self._alarm

    @property
    def locked(self) -> bool:
        """True while the controller is in Alarm state (boot with homing enabled, or after an alarm)."""
        return self._locked or self._needs_reset

    @property
    def halted(self) -> bool:
        """True after ALARM:1/2 until a soft reset: the controller answers nothing, not even ``?``."""
        return self._needs_reset

    @property
    def position_unknown(self) -> str | None:
        """Why the reported position cannot be trusted (a boot at connect, a reset, a failed homing), or None."""
        return self._position_unknown

    # ------------------------------------------------------------------ reader thread

    def _read_loop(self) -> None:
        splitter = codec.LineSplitter()
        while not self._stop.is_set():
            try:
                data = self.transport.read()
            except TransportError as error:
                if not self._stop.is_set():
                    self._lose_connection(f"lost the connection to {self.port_name}: {error.strerror or error}")
                return
            except Exception as error:  # a transport bug must not leave waiters hanging
                if not self._stop.is_set():
                    self._lose_connection(f"reading {self.port_name} failed: {error!r}")
                return
            if not data:
                continue
            for line in splitter.feed(data):
                try:
                    self._dispatch(line)
                except Exception:
                    log.exception("could not handle line %r from %s", line, self.port_name)

    def _lose_connection(self, message: str) -> None:
        with self._cond:
            self._connection_error = GrblConnectionLost(message)
            self._fail_pending(self._connection_error)
            self._cond.notify_all()
        # Raised to every caller from now on; logged below warning level so that it is reported once.
        log.info("%s", message)

    def _fail_pending(self, error: GrblError) -> None:
        while self._pending:
            self._pending.popleft().finish(error=error)
        self._rx_used = 0

    def _pop_pending(self) -> _Pending | None:
        if not self._pending:
            self.stray_replies += 1
            return None
        pending = self._pending.popleft()
        self._rx_used -= pending.size
        return pending

    def _dispatch(self, line: str) -> None:
        message = codec.parse_response(line)
        now_wall, now_mono = time.time(), time.monotonic()
        with self._cond:
            if isinstance(message, codec.Ok):
                pending = self._pop_pending()
                if pending is None:
                    # E.g. the late 'ok' of the line that hit a soft limit, after the reset that ended the halt.
                    log.info("'ok' with no line outstanding on %s (a late answer after a reset or a recovery)",
                             self.port_name)
                else:
                    pending.finish(reply=message)
            elif isinstance(message, codec.ErrorReply):
                pending = self._pop_pending()
                if pending is None:
                    log.info("error:%d with no line outstanding on %s", message.code, self.port_name)
                else:
                    pending.finish(reply=message, error=GrblCommandError(message.code, pending.line))
            elif isinstance(message, codec.StatusReport):
                self._on_status(message, now_wall, now_mono)
            elif isinstance(message, codec.AlarmPush):
                self._on_alarm(message, now_mono)
            elif isinstance(message, codec.Banner):
                self._on_banner(message, now_mono)
            elif isinstance(message, codec.Message):
                self.messages.append(message.text)
                if message.text == codec.UNLOCK_MESSAGE:
                    self._locked = True
                elif message.text == codec.RESET_TO_CONTINUE_MESSAGE:
                    self._needs_reset = True
                    self._locked = True
                    self._reset_to_continue = True
                elif message.text == codec.CHECK_MODE_ENABLED_MESSAGE:
                    self._check_mode = True
                elif message.text == codec.CHECK_MODE_DISABLED_MESSAGE:
                    # system.c: leaving check mode resets Grbl; the banner that follows is expected.
                    self._check_mode = False
                    self._banner_grace_until = max(self._banner_grace_until, now_mono + self.connect_timeout_s)
                if self._pending:
                    self._pending[0].feedback.append(line)
            elif isinstance(message, codec.StartupEcho):
                self.info.startup_executed.append(line)
                if not message.ok:
                    log.warning("startup line %r failed on %s: %s", message.line, self.port_name, message.result)
                if self._pending:
                    self._pending[0].feedback.append(line)
            elif isinstance(message, (codec.Feedback, codec.Setting, codec.StartupLine)):
                if self._pending:
                    self._pending[0].feedback.append(line)
            else:
                self.garbled_lines += 1
                log.warning("unparsable line from %s: %r", self.port_name, line)
            self._cond.notify_all()

    def _on_alarm(self, message: codec.AlarmPush, now_mono: float) -> None:
        self._alarm = message
        self._locked = True
        if message.code in codec.CRITICAL_ALARMS:
            # [MSG:Reset to continue] follows, but a caller must not be able to act in between.
            self._needs_reset = True
            self._critical_alarm_at = now_mono
            self._reset_to_continue = False
        if self._homing and message.code in codec.HOMING_ALARMS:
            # limits.c: the failed cycle resets Grbl, but system.c still answers the $H line ('ok') before
            # main.c prints the banner again: keep the $H outstanding so that 'ok' is not taken for the
            # answer to the next line. home() reports the failure.
            self._homing_alarm = message
            self._banner_grace_until = max(self._banner_grace_until, now_mono + max(5.0, self.connect_timeout_s))
        else:
            # An alarm aborts the stream: GRBL discards what it had buffered, so no answers will come.
            self._fail_pending(GrblAlarm(message.code, f"while talking to {self.port_name}"))
        # Raised to the caller (or on the next command): logged below warning level, so it is reported once.
        log.info("ALARM:%d on %s: %s", message.code, self.port_name, message.meaning)

    def _on_status(self, report: codec.StatusReport, now_wall: float, now_mono: float) -> None:
        if report.wco is not None:
            self._last_wco = report.wco
        n = report.axis_count
        if n is not None and self._axes is None:
            self._axes = codec.AXIS_LETTERS[:n]
        letters = codec.AXIS_LETTERS
        mpos = codec.machine_position(report, self._last_wco)
        wpos = report.wpos
        if wpos is None and mpos is not None and self._last_wco is not None and len(self._last_wco) == len(mpos):
            wpos = tuple(m - o for m, o in zip(mpos, self._last_wco, strict=True))
        reading = GrblReading(
            state=report.state, substate=report.substate,
            machine_position=None if mpos is None else codec.split_axes(mpos, letters),
            work_position=None if wpos is None else codec.split_axes(wpos, letters),
            feed_per_min=report.feed, planner_blocks_free=report.planner_blocks_free,
            rx_bytes_free=report.rx_bytes_free, pins=report.pins, timestamp=now_wall, monotonic=now_mono,
            raw=report.raw,
        )
        self._last_reading = reading
        self._status_received += 1
        self._status_seen = True
        if report.state == "Alarm":
            self._locked = True
        elif report.state in ("Idle", "Run", "Jog", "Hold", "Check"):
            # The controller is out of Alarm (someone homed or unlocked it): believe the controller.
            self._locked = False
            self._needs_reset = False
        self._check_mode = report.state == "Check"

    def _on_banner(self, banner: codec.Banner, now_mono: float) -> None:
        self._banner = banner
        self._banner_count += 1
        if not self._status_seen:
            self._banners_before_status += 1
        self._homed_here = False
        self._critical_alarm_at = None
        self._reset_to_continue = False
        expected = (self._expecting_banner or now_mono < self._banner_grace_until or self._homing
                    or self._in_home)
        self._needs_reset = False
        self._check_mode = False
        self._status_received = self._status_sent  # a reset drops any '?' not yet answered
        if self._homing:
            # A reboot during $H is the homing failing (with or without its ALARM line): home() says so.
            self._homing = False
            self._fail_pending(GrblResetError(f"{self.port_name} reset during the homing cycle"))
        elif expected:
            self._fail_pending(GrblResetError(f"line discarded by a soft reset of {self.port_name}"))
        else:
            self._unexpected_reset = True
            self._locked = True
            self._position_unknown = f"{self.port_name} reset unexpectedly"
            self._fail_pending(GrblResetError(
                f"{self.port_name} reset unexpectedly (power, watchdog or a DTR pulse?): outstanding lines were "
                "discarded and the position may be lost; home the rig"))
            log.info("unexpected reset of %s: %s", self.port_name, banner.text)

    # ------------------------------------------------------------------ sending

    def _usable_or_raise(self) -> None:
        if self._connection_error is not None:
            error = self._connection_error
            raise type(error)(str(error))
        if not self.is_open:
            raise GrblConnectionError(f"controller on {self.port_name} is not open")

    def _write(self, data: bytes) -> None:
        try:
            with self._write_lock:
                self.transport.write(data)
        except TransportError as error:
            self._lose_connection(f"lost the connection to {self.port_name}: {error.strerror or error}")
            raise GrblConnectionLost(str(self._connection_error)) from None

    def _send_line(self, line: str, deadline: float) -> _Pending:
        """Queue one line under character counting; returns its pending answer. Waits for buffer room."""
        data = codec.encode_line(line)
        if len(data) > self.rx_buffer_size - 1:
            raise codec.EncodeError(f"line of {len(data)} bytes can never fit GRBL's receive buffer: {line!r}")
        with self._send_lock:
            with self._cond:
                while True:
                    self._usable_or_raise()
                    if self._rx_used + len(data) <= self.rx_buffer_size - 1:
                        break
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise GrblTimeout(
                            f"GRBL's receive buffer on {self.port_name} stayed full ({self._rx_used} bytes "
                            f"unanswered) while sending {line!r}")
                    self._cond.wait(min(remaining, 0.1))
                pending = _Pending(line.strip(), len(data))
                self._pending.append(pending)
                self._rx_used += len(data)
                # The connect sequence is over once we send work: any banner from now on is a real reset.
                if not self._homing:
                    self._banner_grace_until = min(self._banner_grace_until, time.monotonic())
            self._write(data)
        return pending

    def _raise_for(self, pending: _Pending) -> None:
        if pending.error is not None:
            raise pending.error

    def _await(self, pending: _Pending, deadline: float, *, timeout_s: float, watch_idle: bool) -> _Pending:
        """Wait for the answer to ``pending``; with ``watch_idle``, poll ``?`` to detect a lost answer."""
        idle_since: float | None = None
        while True:
            if pending.event.is_set():
                self._raise_for(pending)
                return pending
            if self._needs_reset:
                raise self._halted_error()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                state = self._last_reading.full_state if self._last_reading else "unknown"
                raise GrblTimeout(
                    f"no answer from {self.port_name} to {pending.line!r} within {timeout_s:g} s "
                    f"(last reported state {state})")
            if pending.event.wait(min(remaining, self.poll_interval_s if watch_idle else remaining)):
                continue
            if not watch_idle:
                continue
            try:
                reading = self.status(timeout=min(max(deadline - time.monotonic(), 0.001), 4 * self.status_retry_s))
            except GrblTimeout:
                idle_since = None
                continue
            if pending.event.is_set():
                continue
            if self._hold_requested and reading.state == "Hold" and reading.substate in (0, None):
                raise GrblMoveError(f"{self.port_name}: motion stopped by a feed hold at {reading.full_state}; "
                                    "resume or reset to go on")
            if reading.is_idle and (reading.rx_bytes_free is None or reading.rx_bytes_free >= self.rx_buffer_size - 1):
                now = time.monotonic()
                idle_since = idle_since or now
                if now - idle_since >= self.ok_grace_s:
                    self._recover_lost_reply(pending, deadline)
                    return pending
            else:
                idle_since = None

    def _recover_lost_reply(self, pending: _Pending, deadline: float) -> None:
        """The controller is Idle with empty buffers but an answer is missing: it was lost on the way.

        Every outstanding line has been executed (nothing is buffered), so they are all marked as
        answered-by-assumption; a fresh ``G4 P0`` then checks that the link answers again.
        """
        with self._cond:
            lost = list(self._pending)
            self.lost_replies += 1
            for item in lost:
                item.assumed = True
            self._pending.clear()
            self._rx_used = 0
            for item in lost:
                item.finish(reply=codec.Ok())
        log.warning("lost reply from %s: %d line(s) outstanding while Idle (%s); resynchronising",
                    self.port_name, len(lost), ", ".join(repr(p.line) for p in lost))
        probe_deadline = min(deadline, time.monotonic() + max(1.0, 4 * self.ok_grace_s))
        probe = self._send_line("G4 P0", probe_deadline)
        if not probe.event.wait(max(0.0, probe_deadline - time.monotonic())):
            raise GrblTimeout(f"{self.port_name} stopped answering lines (no 'ok' to a G4 P0 after a lost reply)")
        self._raise_for(probe)

    def send(self, line: str, *, timeout: float = 5.0) -> list[str]:
        """Send one line (g-code or ``$`` command), wait for its ``ok``; return the feedback lines before it.

        Raises GrblCommandError on ``error:N``. Not for motion you need to wait on: see :meth:`move_to`.
        ``$C`` that leaves check mode also waits for the reset it causes (see :meth:`set_check_mode`).
        """
        deadline = time.monotonic() + timeout
        if self._needs_reset:
            raise self._halted_error()
        leaving_check = "".join(line.split()).upper() == "$C" and self._check_mode
        with self._cond:
            banners = self._banner_count
        pending = self._send_line(line, deadline)
        self._await(pending, deadline, timeout_s=timeout, watch_idle=False)
        if leaving_check:
            self._wait_for_banner(banners, deadline, what="the reset that ends check mode")
        return list(pending.feedback)

    def set_check_mode(self, enabled: bool, *, timeout: float = 5.0) -> GrblReading:
        """``$C``: enter or leave check mode (g-code parsed, soft limits checked, nothing moves).

        Leaving it resets Grbl (system.c: ``mc_reset`` after ``[MSG:Disabled]``); the banner that follows is
        expected, and the position is kept. Returns the state afterwards.
        """
        reading = self.status(timeout=timeout)
        if (reading.state == "Check") != enabled:
            self.send("$C", timeout=timeout)
        return self.status(timeout=timeout)

    def _wait_for_banner(self, count: int, deadline: float, *, what: str) -> None:
        with self._cond:
            while self._banner_count == count:
                self._usable_or_raise()
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise GrblTimeout(f"no banner from {self.port_name} after {what}")
                self._cond.wait(remaining)

    def stream(self, lines: Iterable[str], *, timeout: float = 60.0) -> list[str]:
        """Stream lines with character counting (as fast as GRBL's buffer allows); wait for every answer.

        Returns the lines sent. Raises the first error (the lines after it were still sent, as GRBL
        streaming does; an alarm stops the stream).
        """
        deadline = time.monotonic() + timeout
        pendings = [self._send_line(line, deadline) for line in lines]
        for pending in pendings:
            self._await(pending, deadline, timeout_s=timeout, watch_idle=False)
        return [p.line for p in pendings]

    # ------------------------------------------------------------------ real-time commands

    def _ask_status(self) -> tuple[int, float]:
        with self._cond:
            self._status_sent += 1
            wanted = self._status_sent
        asked_at = time.monotonic()
        self._write(codec.RT_STATUS)
        return wanted, asked_at

    def status(self, *, timeout: float = 1.0) -> GrblReading:
        """Ask ``?`` and return the report that answers it (resending if a report is lost).

        A report answers a ``?`` if it is at least the n-th report for the n-th ``?`` and arrived after it
        was sent, so an answer delayed from an earlier query is never taken for a fresh one.
        Raises GrblAlarm at once while the controller is halted by ALARM:1/2 (it answers nothing then),
        GrblError during homing (GRBL does not answer ``?`` then), GrblTimeout if no report comes.
        """
        self._usable_or_raise()
        if self._needs_reset:
            raise self._halted_error()
        if self._homing:
            raise GrblError("no status while homing: GRBL does not answer '?' during a homing cycle")
        deadline = time.monotonic() + timeout
        wanted, asked_at = self._ask_status()
        next_retry = asked_at + self.status_retry_s
        while True:
            with self._cond:
                self._usable_or_raise()
                if self._needs_reset:
                    raise self._halted_error()
                if self._homing:
                    raise GrblError("no status while homing: GRBL does not answer '?' during a homing cycle")
                reading = self._last_reading
                now = time.monotonic()
                answered = self._status_received >= wanted and reading is not None and reading.monotonic >= asked_at
                if answered and reading.machine_position is not None:
                    return reading
                if now >= deadline:
                    if answered:
                        raise GrblTimeout(f"no usable status report from {self.port_name} within {timeout:g} s "
                                          "(only WPos and no WCO yet)")
                    raise GrblTimeout(self._silence_message(timeout))
                if not answered:
                    if now < next_retry:
                        self._cond.wait(min(deadline, next_retry) - now)
                        continue
                    # The answer was lost or garbled: count it as such and ask again.
                    self._status_received = max(self._status_received, self._status_sent)
                # else: WPos without a WCO yet; GRBL sends WCO within 10-30 reports, so keep asking.
            wanted, asked_at = self._ask_status()
            next_retry = asked_at + self.status_retry_s

    def feed_hold(self) -> None:
        """``!``: decelerate to a stop and hold (``Hold:1``, then ``Hold:0``); :meth:`resume` continues.

        A wait for motion in progress (``wait_idle``, ``MoveStatus.wait``) then ends with
        GrblMoveError once the controller reports the hold complete, instead of running into its timeout.
        """
        self._usable_or_raise()
        self._hold_requested = True
        self._write(codec.RT_FEED_HOLD)

    def resume(self, *, timeout: float = 10.0) -> GrblReading:
        """``~``: continue after a feed hold, once the hold is complete; return the first report out of it.

        protocol.c starts a cycle only from Idle or from a *completed* hold: a ``~`` while the axes still
        decelerate (``Hold:1``) is ignored. So this waits for ``Hold:0``, sends ``~`` and confirms that
        the controller has left Hold (``Run``, or ``Idle`` if nothing was left to do). Not holding:
        returns the current report and sends nothing.
        Raises GrblTimeout if the hold does not complete, or the controller stays in it, within ``timeout``.
        """
        deadline = time.monotonic() + timeout
        reading = self.status(timeout=timeout)
        while reading.state == "Hold" and reading.substate == 1:
            if time.monotonic() >= deadline:
                raise GrblTimeout(f"{self.port_name} still decelerating (Hold:1) after {timeout:g} s")
            time.sleep(self.poll_interval_s)
            reading = self.status(timeout=max(0.05, deadline - time.monotonic()))
        if reading.state != "Hold":
            self._hold_requested = False
            return reading
        self._hold_requested = False
        self._write(codec.RT_CYCLE_START)
        while True:
            reading = self.status(timeout=max(0.05, deadline - time.monotonic()))
            if reading.state != "Hold":
                return reading
            if time.monotonic() >= deadline:
                raise GrblTimeout(f"{self.port_name} still in {reading.full_state} {timeout:g} s after '~'")
            time.sleep(self.poll_interval_s)

    def soft_reset(self, *, timeout: float = 5.0, query_status: bool = True) -> GrblReading | None:
        """0x18: stop at once, discard everything buffered, wait for the banner; return the state after it.

        Reset while moving loses position (GRBL raises ALARM:3); reset while idle keeps it. The only
        thing a controller halted by ALARM:1/2 listens to, and only once it has said so: Grbl 1.1h prints
        the ALARM line, waits 500 ms (report.c ``report_alarm_message``), prints ``[MSG:Reset to continue]``
        and then clears any reset that came meanwhile (protocol.c ``protocol_exec_rt_system``). So right after
        such an alarm this waits for that message (at most :data:`CRITICAL_RESET_WAIT_S` after the ALARM line)
        before sending 0x18, and sends it once more if no banner answers within
        :data:`RESET_RESEND_AFTER_S`.
        """
        self._usable_or_raise()
        deadline = time.monotonic() + timeout
        with self._cond:
            count = self._banner_count
            self._expecting_banner = True
            alarm_at = self._critical_alarm_at if self._needs_reset else None
            if alarm_at is not None:
                ready_by = min(deadline, alarm_at + CRITICAL_RESET_WAIT_S)
                while not self._reset_to_continue and self._banner_count == count:
                    self._usable_or_raise()
                    remaining = ready_by - time.monotonic()
                    if remaining <= 0:
                        break  # the message was lost: the firmware's pause is over anyway
                    self._cond.wait(remaining)
        try:
            self._write(codec.RT_SOFT_RESET)
            first = min(deadline, time.monotonic() + min(RESET_RESEND_AFTER_S, timeout / 2.0))
            try:
                self._wait_for_banner(count, first, what=f"a soft reset (within {timeout:g} s)")
            except GrblTimeout:
                if time.monotonic() >= deadline:
                    raise
                # A reset the controller did not take (the 500 ms after an ALARM line, a bootloader): once more.
                log.info("no banner from %s %g s after a soft reset: sending it again", self.port_name,
                         RESET_RESEND_AFTER_S)
                self._write(codec.RT_SOFT_RESET)
                self._wait_for_banner(count, deadline, what=f"a soft reset, sent twice (within {timeout:g} s)")
        finally:
            with self._cond:
                self._expecting_banner = False
                # A second banner may follow closely (an Arduino booting after its DTR reset, the resent reset
                # heard too): not a fault.
                self._banner_grace_until = time.monotonic() + 0.25
        self._hold_requested = False
        return self.status(timeout=max(1.0, timeout)) if query_status else None

    # ------------------------------------------------------------------ motion

    def _halted_error(self) -> GrblAlarm | GrblLocked:
        alarm = self._alarm
        if alarm is not None:
            return GrblAlarm(alarm.code, f"{self.port_name} is halted by it and answers nothing, not even '?': "
                                         "reset required (soft reset), then home")
        return GrblLocked(f"{self.port_name} halted ([MSG:Reset to continue]) and answers nothing: reset required "
                          "(soft reset), then home")

    def _lock_error(self) -> GrblLocked:
        # The alarm first: after ALARM:1 and a reset the refusal must name the hard limit, not the banner.
        if self._alarm is not None and (self._locked or self._unexpected_reset):
            lost = self._alarm.code not in (2,)  # only a soft limit stops under control (its meaning says so)
            remedy = "home ($H)" if lost else "home ($H), or unlock ($X) if the position was kept"
            return GrblLocked(f"controller on {self.port_name} is in Alarm after ALARM:{self._alarm.code} "
                              f"({self._alarm.meaning}): {remedy} before moving")
        if self._position_unknown is not None:
            if self.info.settings_read and not self.info.homing_enabled:
                remedy = ("homing is disabled ($22=0): confirm the position is right once the axes stand where the "
                          "controller counts (`rig unlock --trust-position`), or enable homing")
            else:
                remedy = ("home the rig ($H) before moving, or confirm the position is right "
                          "(`rig unlock --trust-position`)")
            return GrblPositionUnknown(f"{self._position_unknown}: {remedy}")
        return GrblLocked(f"controller on {self.port_name} is in Alarm (homing required): "
                          "home ($H) or unlock ($X) before moving")

    def _can_move_or_raise(self) -> None:
        self._usable_or_raise()
        if self._homing:
            raise GrblError("homing in progress")
        if self._needs_reset:
            raise self._halted_error()
        # Whatever $22 says: after a boot the step counters count from wherever the axes stood.
        if self._locked or self._unexpected_reset or self._position_unknown is not None:
            raise self._lock_error()

    def trust_position(self) -> None:
        """The user states that the controller's position is right (the rig was not moved while it booted, or
        stands where its machine 0 is): moves are no longer refused for a boot. Sends nothing; a controller in
        Alarm still needs :meth:`unlock` (or use ``unlock(trust_position=True)``)."""
        with self._cond:
            why = self._position_unknown
            self._position_unknown = None
            self._unexpected_reset = False
        if why is not None:
            # The caller asked for it and says so to the user; logged below warning level.
            log.info("%s: position trusted as it is, without homing (%s)", self.port_name, why)

    def home(self, *, timeout: float = 120.0) -> GrblReading:
        """``$H``: run the homing cycle and wait for its ``ok`` (GRBL reports no status while homing).

        A homing failure (``ALARM:8``/``9``, or a reboot without an ALARM line) raises GrblAlarm or
        GrblError once the controller has rebooted from it. On timeout the cycle is stopped with a soft
        reset and GrblTimeout is raised.
        """
        self._usable_or_raise()
        if self._needs_reset:
            raise self._halted_error()
        deadline = time.monotonic() + timeout
        with self._cond:
            self._homing = self._in_home = True
            self._homing_alarm = None
            banners = self._banner_count
        try:
            return self._home(deadline, timeout, banners)
        finally:
            with self._cond:
                self._homing = self._in_home = False

    def _home(self, deadline: float, timeout: float, banners: int) -> GrblReading:
        try:
            pending = self._send_line("$H", deadline)
            try:
                self._await(pending, deadline, timeout_s=timeout, watch_idle=False)
            except GrblResetError:
                pass  # rebooted without answering: a failure, reported below
            except GrblTimeout:
                with self._cond:
                    self._homing = False
                reading = self._status_or_none(timeout=max(0.5, 4 * self.status_retry_s))
                if reading is not None and reading.is_idle:
                    # Homing ended but its 'ok' never came: the controller's own report says it is done.
                    with self._cond:
                        if self._pending and self._pending[0] is pending:
                            self._pending.popleft()
                            self._rx_used -= pending.size
                        self.lost_replies += 1
                    pending.assumed = True
                    pending.finish(reply=codec.Ok())
                    log.warning("no 'ok' for $H from %s, but it reports Idle: homing done", self.port_name)
                else:
                    self._stop_after_timeout()
                    raise GrblTimeout(
                        f"homing on {self.port_name} did not finish within {timeout:g} s; sent a soft reset to "
                        "stop it: check the limit switches and homing settings") from None
            alarm = self._homing_alarm
            if alarm is not None:
                # The reboot follows the late 'ok': wait for it, so that nothing sent next is lost in it.
                self._wait_for_banner(banners, min(deadline, time.monotonic() + max(5.0, self.connect_timeout_s)),
                                      what=f"ALARM:{alarm.code} during homing")
                self._homing_failed(f"homing failed with ALARM:{alarm.code}")
                raise GrblAlarm(alarm.code, f"homing failed on {self.port_name}; Grbl reset itself: check the "
                                            "limit switches, $23 (homing direction) and $13x (travel)")
        finally:
            with self._cond:
                self._homing = False
        reading = self.status(timeout=max(1.0, deadline - time.monotonic()))
        with self._cond:
            rebooted = self._banner_count != banners
        if rebooted or reading.state == "Alarm":
            # Seen on the real firmware: the ALARM line of a failed homing can be missing; only the reboot
            # (banner, [MSG:'$H'|'$X' to unlock]) and Alarm state tell.
            self._homing_failed("homing failed (the controller rebooted without an ALARM line)")
            raise GrblError(f"homing failed on {self.port_name}: the controller rebooted and is in "
                            f"{reading.full_state} (no ALARM line was received): check the limit switches, $23 "
                            "(homing direction) and $13x (travel)")
        with self._cond:
            self._locked = False
            self._alarm = None
            self._unexpected_reset = False
            self._position_unknown = None
            self._homed_here = True
        return reading

    def _homing_failed(self, why: str) -> None:
        with self._cond:
            self._locked = True
            self._position_unknown = f"{self.port_name}: {why}; its position is unknown"

    def _status_or_none(self, *, timeout: float) -> GrblReading | None:
        try:
            return self.status(timeout=timeout)
        except GrblError:
            return None

    def _stop_after_timeout(self) -> None:
        try:
            self.soft_reset(timeout=2.0, query_status=False)
        except GrblError as error:
            log.error("soft reset after a timeout failed on %s: %s", self.port_name, error)

    def unlock(self, *, timeout: float = 5.0, trust_position: bool = False) -> GrblReading:
        """``$X``: leave Alarm without homing. The controller's position is then used as it is: only when it is
        right. After a boot the driver still refuses moves (the step counters restarted at 0 wherever the axes
        stood) unless ``trust_position`` says that position is right (see :meth:`trust_position`)."""
        self.send("$X", timeout=timeout)
        with self._cond:
            self._locked = False
            self._alarm = None
        if trust_position:
            self.trust_position()
        return self.status(timeout=timeout)

    @property
    def homed(self) -> bool:
        """Homed through this connection since the controller last printed its banner."""
        return self._homed_here

    def move_to(
        self, target: Mapping[str, float], *, feed_per_min: float | None = None, timeout_s: float = 120.0,
        tolerance: float | Mapping[str, float] = 0.01,
    ) -> MoveStatus:
        """Queue an absolute move in machine coordinates (axis letter -> machine units); return its status.

        Returns once GRBL has accepted the line (its ``ok``: planned, usually not yet moving far); the
        returned :class:`MoveStatus` waits for the end of motion. Refused before sending anything if the
        controller is in Alarm, its position is unknown, or an axis is not on it; GrblCommandError if
        GRBL answers ``error:N``. The line carries ``G21 G90 G53``: millimetres, absolute, machine
        coordinates, whatever modal state the controller is in.

        Args:
            feed_per_min: vector feed (units/min); None for a rapid (G0) at GRBL's per-axis max rates.
            timeout_s: default bound for the returned status' :meth:`MoveStatus.wait`.
            tolerance: how far (machine units) the stopped position may be from the target, per axis.
        """
        self._can_move_or_raise()
        target = {axis: float(value) for axis, value in target.items()}
        if self._axes is not None:
            missing = [a for a in target if a not in self._axes]
            if missing:
                raise GrblError(f"axis {', '.join(missing)} not on the controller at {self.port_name} "
                                f"(it reports {', '.join(self._axes)})")
        for axis, value in target.items():
            if not math.isfinite(value):
                raise GrblError(f"target {axis}={value} is not a number")
        line = codec.encode_move(target, feed_per_min=feed_per_min)
        start = self._last_reading.machine_position if self._last_reading is not None else None
        deadline = time.monotonic() + timeout_s
        pending = self._send_line(line, deadline)
        with self._cond:
            self._move_sequence += 1
            sequence = self._move_sequence
            self._last_move_line = line
        # Wait for 'ok' (accepted and planned, not done) so that a refusal (error:N) surfaces here.
        self._await(pending, deadline, timeout_s=timeout_s, watch_idle=True)
        tol = {a: float(tolerance) for a in target} if isinstance(tolerance, (int, float)) else dict(tolerance)
        return MoveStatus(self, target, pending, timeout_s, tol, sequence=sequence, start=start)

    def wait_idle(self, timeout: float = 60.0) -> GrblReading:
        """Block until every queued motion has ended (``G4 P0``, with ``?`` polling); return the final report.

        Raises GrblTimeout (e.g. held with ``!`` and never resumed), GrblAlarm, GrblResetError,
        GrblConnectionError; never waits past ``timeout`` s by more than one status round trip.
        """
        self._usable_or_raise()
        if self._needs_reset:
            raise self._halted_error()
        if self._locked or self._unexpected_reset:
            raise self._lock_error()
        deadline = time.monotonic() + timeout
        sync = self._send_line("G4 P0", deadline)
        self._await(sync, deadline, timeout_s=timeout, watch_idle=True)
        remaining = deadline - time.monotonic()
        reading = self.status(timeout=max(remaining, 4 * self.status_retry_s))
        if not reading.is_idle:
            raise GrblError(f"motion queue empty but {self.port_name} reports {reading.full_state}")
        return reading


__all__ = [
    "ControllerInfo", "GrblAlarm", "GrblCommandError", "GrblConnectionError", "GrblConnectionLost", "GrblController",
    "GrblError", "GrblLocked", "GrblMoveError", "GrblPositionUnknown", "GrblReading", "GrblResetError",
    "GrblSettingsError", "GrblTimeout", "MoveStatus",
]
