"""A GRBL 1.1h controller served on a pseudo-terminal, so the real driver opens a real tty.

    with GrblEmulator(time_scale=20.0) as emulator:       # 20x faster than real time
        controller = GrblController(emulator.tty_path)    # pyserial opens /dev/pts/N
        ...
        emulator.machine_position()    # what Grbl's step counters say (MPos), thread-safe
        emulator.physical_position()   # where the axes really are

The firmware is the specification: gnea/grbl 1.1h with its default config.h (3 axes, HOMING_INIT_LOCK,
two startup lines, 128-byte serial buffer, 16-block planner). Comments name the file and function each
behaviour mirrors. What it does:

- Serial (serial.c, protocol.c ``protocol_main_loop``): a 128-byte receive buffer (serial.c's ring has
  ``RX_BUFFER_SIZE+1`` slots, so it holds all 128; bytes arriving when it is full are dropped and counted);
  spaces and comments dropped, at most 79 characters kept (``error:11`` beyond); lines answered
  ``ok``/``error:N`` in order once planned; real-time bytes ``?`` ``!`` ``~`` 0x18 and 0x85 acted on at
  once, without ``ok``.
- Settings (settings.c, report.c): ``$$`` lists defaults.h DEFAULTS_GENERIC overridden by the
  constructor's arguments, ``$x=value`` stores with the firmware's checks. Honoured: ``$10`` status
  mask, ``$13`` report inches, ``$20`` soft limits, ``$21`` hard limits, ``$22`` homing, ``$23`` homing
  direction mask, ``$24`` locate feed, ``$25`` seek rate, ``$26`` debounce, ``$27`` pull-off, ``$100``..
  steps/unit, ``$110``.. max rates, ``$120``.. accelerations, ``$130``.. max travel. ``$I`` answers
  ``[VER:1.1h.20190830:]`` ``[OPT:V,15,128]``; ``$N`` lists the two startup lines, ``$Nn=line`` stores one
  in Idle (executing it, as system.c does; ``error:8`` in Alarm).
- Positions are step counts (``sys_position``): a target is rounded to whole steps (planner.c
  ``plan_buffer_line``, ``lround``), MPos = steps / ``$10x``. Power-up and a reboot zero them wherever
  the axes stand (main.c); a soft reset keeps them. :meth:`physical_position` is where the axes really
  are, in the machine frame a successful homing establishes.
- Homing (motion_control.c ``mc_homing_cycle``, limits.c ``limits_go_home``): cycles of config.h (Z, then X
  and Y; :func:`drivers.rig.motion.homing_cycles`), each a seek to the switches at ``$25`` (each axis stops
  dead on its own), a pull-off of ``$27`` at ``$25``, a locate at ``$24`` and a last pull-off, each move
  followed by the ``$26`` debounce: its time is the firmware's (:func:`drivers.rig.motion.homing_time_s`).
  The switch is at the positive end of each axis (at the negative
  end with its ``$23`` bit set); after pull-off the axis is set to ``-$27`` (``-$13x + $27``): machine
  space is ``[-$13x, 0]``. A HOMING_FORCE_SET_ORIGIN build (``force_set_origin``, ``Z`` in ``[OPT:]``)
  sets 0 instead, and ``[0, $13x]`` on the axes whose ``$23`` bit is set; its switches are then one
  pull-off beyond 0 (at ``-$27`` or ``+$27``), as the physical frame is the homed machine frame on either
  build. No status is reported while homing: a ``?`` sent meanwhile is answered once the cycle is over
  (``<Home|MPos:...>``, motion_control.c ``mc_homing_cycle``), or never if it fails. With homing
  enabled the controller boots in Alarm (``[MSG:'$H'|'$X' to unlock]``). After a successful ``$H`` the
  startup lines run (echoed ``>line:ok``) before the ``ok`` of the ``$H``.
- Homing failure (:class:`HomingFail`, in the first cycle; or a switch beyond the search):
  ``ALARM:8``/``ALARM:9``, then - Grbl has reset itself - the late
  ``ok`` of the ``$H`` line and the banner with ``[MSG:'$H'|'$X' to unlock]`` (system.c ``$H`` still
  returns STATUS_OK, main.c re-initialises). The ALARM line can be left out (``alarm_line=False``),
  as was seen on the real firmware.
- Soft limits (motion_control.c ``mc_line``, limits.c ``limits_soft_check``): a g-code target outside
  machine space with ``$20=1`` raises ``ALARM:2`` (after a controlled stop if the axes are moving) and
  ``[MSG:Reset to continue]``; then nothing is answered - not even ``?`` - until 0x18 (protocol.c
  ``protocol_exec_rt_system``, critical-event loop). After the reset the offending line is answered
  ``ok`` (its ``gc_execute_line`` still returns STATUS_OK), then the banner. A jog beyond travel is
  ``error:15``. Check mode (``$C``) checks soft limits too. A reset received before
  ``[MSG:Reset to continue]`` (during report_alarm_message's pause) is lost: protocol.c clears it.
- Hard limits (``$21=1``, limits.c ``ISR(LIMIT_INT_vect)``): a homing switch that closes or opens during
  motion (not homing, not in Alarm) stops the axes dead there with ``ALARM:1``, critical as above; a boot or
  reset with a switch closed is Alarm with ``[MSG:Check Limits]`` (protocol.c, CHECK_LIMITS_AT_INIT).
- Feed hold (protocol.c): ``!`` decelerates (``Hold:1``), then ``Hold:0``; ``~`` resumes only a
  completed hold (a ``~`` during ``Hold:1`` is ignored). ``!`` during a jog cancels it.
- Soft reset (motion_control.c ``mc_reset``, main.c): ``ALARM:3`` if the axes were moving (including
  ``Hold:1``), ``ALARM:6`` during homing; a line still being executed (waiting for planner space or a
  ``G4``) is answered ``ok``; then the banner; Alarm stays Alarm, anything else comes back Idle and
  runs the startup lines. Leaving check mode (``$C`` again) resets the same way after
  ``[MSG:Disabled]`` and ``ok``.
- Every ``ALARM:N`` line is followed by a 0.5 s pause (report.c ``report_alarm_message``), in
  simulated time.
- grblHAL (``firmware="grblhal"``, from grblHAL/core): its ``$I`` lines and ``[OPT:VNML+W,100,1024,3,0]``,
  ``$22`` as a bitfield (``$22=1``: no homing lock, it boots Idle), soft limits on homed axes only within
  its work envelope (machine_limits.c), a 100 ms alarm pause, ``|H:1`` on the report after homing, no late
  ``ok`` after a failed homing, ``$481`` auto-reports; a 100-block planner and a 1024-byte buffer.
- A dialect without some ``$`` queries (``unsupported_queries``): answered ``error:3``.
- ``G20``/``G21``, ``G90``/``G91``, ``G53``, ``G0``/``G1`` (F in units/min), ``G4 P<s>`` (its ``ok``
  comes once the planner is empty, so it marks the end of motion), ``$X``, ``$J=``, ``$G``, ``$#``.
- Arduino auto-reset (``reboot_on_open``): opening the port reboots the board; the bootloader swallows
  what is sent for ``boot_delay_s`` (1.1 s on the real board), then Grbl boots (MPos 0, Alarm with
  homing enabled). The pty runs in packet mode (TIOCPKT), and an open is seen as the input flush that
  pyserial makes when it opens a port (a program that flushes its input later would reboot it too).
- Time is a :class:`~drivers.sim.clock.BenchClock` (shared with the simulated bench): it runs, paced by the
  wall clock times ``time_scale``, only while a block moves, a homing, a dwell or a boot is pending, and stops at
  the exact end of each (``t_start + duration``); a move commanded while idle starts at the frozen time. Every
  motion that ends is reported to ``on_motion`` (:class:`MotionEvent`). Output pacing (the pause after an alarm,
  scaled by ``time_scale``; :class:`Delay`) is on the wall clock: it spaces bytes on the line and moves nothing.
- Injectable faults (see :class:`LostOk`, :class:`GarbledLine`, :class:`Delay`, :class:`AlarmMidMove`,
  :class:`ResetMidMove`, :class:`VanishMidMove`, :class:`HomingFail` and :meth:`GrblEmulator.vanish`).

Simplifications (the driver does not depend on them): blocks do not blend at junctions (each runs
from rest to rest) and a feed hold decelerates within the current block; a switch trips exactly at its
position (no hysteresis); a motor never stalls at the end of its travel (only on a switch that never
answers, HomingFail 9) and there are no switches at the far ends; a startup line's ``G4`` does not wait;
arcs, probing, spindle, coolant, ``G10``/``G92`` offsets, sleep and ``$RST`` are not modelled (their g-codes
are refused with ``error:20``, ``$SLP`` and ``$RST=`` with ``error:3``).
Units are machine units (mm; a rotary axis in whatever unit its settings are given in).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import math
import os
import random
import re
import select
import struct
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable, Mapping

from drivers.rig.motion import (
    HOMING_LOCATE_SCALAR,
    HOMING_SEARCH_SCALAR,
    REFERENCE_HOMING,
    HomingMove,
    HomingSettings,
    homing_cycles,
    homing_move,
    path_limits,
)
from drivers.sim.clock import BenchClock
from drivers.sim.grbl.faults import (
    AlarmMidMove,
    Delay,
    Fault,
    GarbledLine,
    HomingFail,
    LostOk,
    ResetMidMove,
    VanishMidMove,
)
from drivers.sim.grbl.firmware import (
    _FLOAT_SETTINGS,
    _RPM_SETTINGS,
    ALARM_REPORT_DELAY_S,
    AUTO_RESET_BOOT_S,
    AXIS_LETTERS,
    CHECK_LIMITS_MESSAGE,
    CLIENT_POLL_S,
    DEFAULT_AXES,
    DEFAULT_SETTINGS,
    GRBL_BANNER,
    GRBL_VERSION,
    GRBLHAL_ALARM_REPORT_DELAY_S,
    GRBLHAL_BANNER,
    GRBLHAL_DRIVER,
    GRBLHAL_DRIVER_VERSION,
    GRBLHAL_PLANNER_BLOCKS,
    GRBLHAL_VERSION,
    HELP_MESSAGE,
    LINE_BUFFER_SIZE,
    MM_PER_INCH,
    N_STARTUP_LINES,
    PLANNER_BLOCKS,
    RESET_MESSAGE,
    RX_BUFFER_SIZE,
    UNLOCK_MESSAGE,
    AxisSpec,
    _fmt_setting,
)
from drivers.sim.grbl.planner import MotionEvent, PlannedMotion, _approach_of, _Block, _HomingPhase, _lround, _Stop


class GrblEmulator:
    """A GRBL 1.1h controller on a pty, served by one thread. See the module docstring.

    Args:
        axes: axis letters, in GRBL order (``"XYZ"``, or ``"XYZABC"`` for a grblHAL-like 6-axis board).
        axis_specs: per-axis settings (defaults :data:`DEFAULT_AXES`: X 350 mm, Y and Z 90 deg of travel).
        time_scale: simulated seconds per real second (1 = real time; 20 = twenty times faster).
        homing_enabled: ``$22``; with it Grbl 1.1h boots into Alarm and must be homed or unlocked.
        homing_init_lock: boot into Alarm with homing enabled; None: the firmware's default (Grbl 1.1h:
            config.h HOMING_INIT_LOCK, yes; grblHAL's simulator: ``$22=1``, bit 2 "homing on startup required"
            clear, so it boots Idle).
        soft_limits: ``$20``; needs homing enabled, as on GRBL.
        hard_limits: ``$21``: a homing switch that closes or opens during motion halts with ALARM:1.
        homing_seek_rate_per_min: ``$25``, the speed of the homing search and of the pull-offs.
        homing_feed_rate_per_min: ``$24``, the speed of the locate move.
        homing_debounce_ms: ``$26``, the pause after each homing move.
        homing_pulloff: ``$27``: where homing leaves an axis, from its switch.
        status_mask: ``$10``: bit 0 set reports MPos (else WPos), bit 1 adds ``Bf:``.
        report_inches: ``$13``: status reports in inches.
        force_set_origin: a build with HOMING_FORCE_SET_ORIGIN (homing sets 0; ``Z`` in ``[OPT:]``).
        startup_lines: ``$N0``, ``$N1`` (e.g. ``("G20",)``), run after every reset into Idle and every homing.
        firmware: ``"grbl"`` or ``"grblhal"`` (banner; grblHAL's 1024-byte receive buffer).
        rx_buffer_size: the serial receive buffer in bytes.
        shuffle_fields: report status fields in a random order (seeded), as a robustness test.
        faults: faults armed from the start; more with :meth:`inject`.
        start_position: where the axes physically stand at power-up (machine frame of a homed controller;
            default 0, so that MPos and the physical position agree until something moves them apart).
        reboot_on_open: reboot whenever a client opens the port (an Arduino's DTR auto-reset).
        boot_delay_s: simulated seconds from the open to the banner of such a reboot.
        clock: the bench clock motion, homing, dwells and boots run on (:mod:`drivers.sim.clock`; default: one of
            its own at ``time_scale``). Given, its ``time_scale`` is the emulator's.
        on_motion: called with a :class:`MotionEvent` for every motion that ends (from the serving thread or
            whichever thread brought the model up to date, with the emulator's lock held: it must not wait for a
            lock that is held while the emulator is called).
        report_interval_ms: grblHAL's ``$481``: with it, a status report every so many ms unasked (its
            grbllib.c ``auto_realtime_report``); 0: only when asked.
        unsupported_queries: ``$`` commands answered ``error:3`` (e.g. ``("$N",)``): a dialect that lacks them,
            answered as system.c answers any ``$`` command it does not know.
    """

    def __init__(
        self, *, axes: str = "XYZ", axis_specs: Mapping[str, AxisSpec] | None = None, time_scale: float = 1.0,
        homing_enabled: bool = True, homing_init_lock: bool | None = None, soft_limits: bool = True,
        hard_limits: bool = False, homing_seek_rate_per_min: float = REFERENCE_HOMING.seek_rate_per_min,
        homing_feed_rate_per_min: float = REFERENCE_HOMING.feed_rate_per_min,
        homing_debounce_ms: float = REFERENCE_HOMING.debounce_ms, homing_pulloff: float = REFERENCE_HOMING.pulloff,
        status_mask: int = 1, report_inches: bool = False, force_set_origin: bool = False,
        startup_lines: Iterable[str] = (), firmware: str = "grbl", rx_buffer_size: int | None = None,
        shuffle_fields: bool = False, seed: int = 0, faults: Iterable[Fault] = (),
        start_position: Mapping[str, float] | None = None, reboot_on_open: bool = False,
        boot_delay_s: float = AUTO_RESET_BOOT_S, report_interval_ms: int = 0, unsupported_queries: Iterable[str] = (),
        clock: BenchClock | None = None, on_motion: Callable[[MotionEvent], None] | None = None,
    ):
        if not axes or axes != "".join(a for a in AXIS_LETTERS if a in axes) or len(set(axes)) != len(axes):
            raise ValueError(f"axes must be letters of {AXIS_LETTERS} in that order, not {axes!r}")
        if time_scale <= 0:
            raise ValueError("time_scale must be > 0")
        if firmware not in ("grbl", "grblhal"):
            raise ValueError("firmware must be 'grbl' or 'grblhal'")
        lines = [_clean_line(line) for line in startup_lines]
        if len(lines) > N_STARTUP_LINES:
            raise ValueError(f"GRBL keeps {N_STARTUP_LINES} startup lines, not {len(lines)}")
        self.axes = axes
        specs = dict(DEFAULT_AXES)
        specs.update(axis_specs or {})
        self.specs = {a: specs[a] for a in axes}
        # Simulated time is the bench clock's: it runs only while something timed is pending (drivers/sim/clock.py).
        self.clock = clock if clock is not None else BenchClock(time_scale)
        self.time_scale = self.clock.time_scale
        self.on_motion = on_motion
        self._motions_reported = 0  # MotionEvents given to on_motion (PlannedMotion.reported)
        self.force_set_origin = force_set_origin
        self.firmware = firmware
        grblhal = firmware == "grblhal"
        self.homing_init_lock = (not grblhal) if homing_init_lock is None else bool(homing_init_lock)
        self.planner_blocks = GRBLHAL_PLANNER_BLOCKS if grblhal else PLANNER_BLOCKS
        self._alarm_delay_s = GRBLHAL_ALARM_REPORT_DELAY_S if grblhal else ALARM_REPORT_DELAY_S
        self.rx_buffer_size = rx_buffer_size or (1024 if firmware == "grblhal" else RX_BUFFER_SIZE)
        # serial.c: Grbl's ring buffer has RX_BUFFER_SIZE+1 slots (RX_RING_BUFFER), one always free, so it holds
        # all RX_BUFFER_SIZE bytes (and Bf: reports RX_BUFFER_SIZE free when empty). grblHAL's drivers' rings have
        # RX_BUFFER_SIZE slots, full when BUFNEXT(head) == tail, and report RX_BUFFER_SIZE - 1 - count free (its
        # serial.c, e.g. the RP2040 driver's): they hold RX_BUFFER_SIZE - 1.
        self._rx_capacity = self.rx_buffer_size - (1 if firmware == "grblhal" else 0)
        self.shuffle_fields = shuffle_fields
        self.unsupported_queries = frozenset(_clean_line(q) for q in unsupported_queries)
        self.reboot_on_open = reboot_on_open
        self.boot_delay_s = boot_delay_s
        self.startup_lines = lines + [""] * (N_STARTUP_LINES - len(lines))
        self.settings: dict[int, float] = dict(DEFAULT_SETTINGS)
        homing_flags = int(homing_enabled)
        if grblhal and homing_enabled:
            # grblHAL's $22 is a bitfield (settings.c): bit 0 enable, bit 2 homing required at startup, bit 3 set
            # machine origin to 0.
            homing_flags |= (4 if self.homing_init_lock else 0) | (8 if force_set_origin else 0)
        self.settings.update({10: status_mask, 13: int(report_inches), 22: homing_flags,
                              20: int(soft_limits and homing_enabled), 21: int(hard_limits),
                              24: homing_feed_rate_per_min, 25: homing_seek_rate_per_min, 26: homing_debounce_ms,
                              27: homing_pulloff})
        if grblhal:
            self.settings[481] = int(report_interval_ms)  # $481: auto-report interval, ms
        self.settings[23] = sum(1 << i for i, a in enumerate(axes) if self.specs[a].home_negative)
        for i, axis in enumerate(axes):
            spec = self.specs[axis]
            self.settings.update({100 + i: spec.steps_per_unit, 110 + i: spec.max_rate_per_min,
                                  120 + i: spec.acceleration, 130 + i: spec.max_travel})
        self._rng = random.Random(seed)
        self._faults: list[Fault] = list(faults)
        self._start_position = {a: float((start_position or {}).get(a, 0.0)) for a in axes}

        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._stop = threading.Event()
        self.tty_path: str | None = None
        self.vanished = False
        self._vanish_requested = False
        self._client = False  # a program has the port open
        self._booting_until: float | None = None  # sim time an auto-reset boot ends

        self._power_up()
        # Statistics for tests and benchmarks.
        self.max_rx_fill = 0
        self.rx_overflow_bytes = 0
        self.lines_received: deque[str] = deque(maxlen=1000)
        self.status_reports_sent = 0
        self.resets = 0
        self.client_opens = 0

    # ------------------------------------------------------------------ settings

    @property
    def homing_enabled(self) -> bool:
        return bool(int(self.settings[22]) & 1)  # grblHAL's $22 is a bitfield; bit 0 enables homing

    @property
    def hard_limits(self) -> bool:
        return bool(int(self.settings[21]) & 1)

    def _homing_settings(self) -> HomingSettings:
        """``$24`` ``$25`` ``$26`` ``$27`` as set now, and config.h N_HOMING_LOCATE_CYCLE (1)."""
        return HomingSettings(seek_rate_per_min=float(self.settings[25]), feed_rate_per_min=float(self.settings[24]),
                              debounce_ms=float(self.settings[26]), pulloff=float(self.settings[27]))

    @property
    def soft_limits(self) -> bool:
        return bool(self.settings[20])

    @property
    def status_mask(self) -> int:
        return int(self.settings[10])

    @property
    def report_inches(self) -> bool:
        return bool(self.settings[13])

    def _axis_setting(self, base: int, axis: str) -> float:
        return float(self.settings[base + self.axes.index(axis)])

    def _steps_per_unit(self, axis: str) -> float:
        return self._axis_setting(100, axis)

    def _max_travel(self, axis: str) -> float:
        return self._axis_setting(130, axis)

    def _home_negative(self, axis: str) -> bool:
        return bool((int(self.settings[23]) >> self.axes.index(axis)) & 1)

    def _on_grid(self, pos: Mapping[str, float]) -> dict[str, float]:
        """Whole steps (planner.c: targets are lround(target * $10x) steps; stepper.c counts whole steps)."""
        return {a: _lround(v * self._steps_per_unit(a)) / self._steps_per_unit(a) for a, v in pos.items()}

    def _machine_space(self, axis: str) -> tuple[float, float]:
        """system.c system_check_travel_limits: [-$13x, 0], or [0, $13x] on a HOMING_FORCE_SET_ORIGIN build
        for an axis homing toward - . grblHAL (machine_limits.c limits_set_work_envelope): one pull-off off
        each end with hard limits on, [-$13x + $27, -$27] ([-$13x + $27, 0] or [0, $13x - $27] with set-origin)."""
        travel = self._max_travel(axis)
        if self.firmware == "grblhal":
            pulloff = float(self.settings[27]) if self.hard_limits else 0.0
            if self.force_set_origin:
                return (0.0, travel - pulloff) if self._home_negative(axis) else (-travel + pulloff, 0.0)
            return -travel + pulloff, -pulloff
        if self.force_set_origin and self._home_negative(axis):
            return 0.0, travel
        return -travel, 0.0

    def _switch_engaged(self, axis: str, physical: float) -> bool:
        """limits.c limits_get_state for one axis: its homing switch is closed at or beyond the switch."""
        switch = self._switch_physical(axis)
        return physical <= switch + 1e-9 if self._home_negative(axis) else physical >= switch - 1e-9

    # The physical frame is the machine frame a successful homing sets up on this build (see
    # physical_position), so where homing leaves an axis and where its switch is follow the build: a
    # HOMING_FORCE_SET_ORIGIN build calls the pulled-off position 0, with the switch one pull-off beyond it.

    def _home_physical(self, axis: str) -> float:
        """limits.c limits_go_home: where homing leaves the axis, ``-$27`` (``-$13x + $27`` homing toward -),
        or 0 on a HOMING_FORCE_SET_ORIGIN build."""
        if self.force_set_origin:
            return 0.0
        pulloff = float(self.settings[27])
        return -self._max_travel(axis) + pulloff if self._home_negative(axis) else -pulloff

    def _switch_physical(self, axis: str) -> float:
        """The homing switch: one pull-off (``$27``) from where homing leaves the axis, on the side it homes to."""
        pulloff = float(self.settings[27])
        return self._home_physical(axis) + (-pulloff if self._home_negative(axis) else pulloff)

    def _home_machine(self, axis: str) -> float:
        """limits.c limits_go_home: the machine position a homed axis is set to (whole steps)."""
        spu = self._steps_per_unit(axis)
        return _lround(self._home_physical(axis) * spu) / spu

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> GrblEmulator:
        """Open the pty and start serving. Returns self; ``tty_path`` is then the device to open."""
        if self._thread is not None:
            return self
        master, slave = os.openpty()
        # Raw at once: with the default line discipline our output would be echoed back to us as input.
        # The setting outlives this descriptor, which is closed: the pty then reports a hang-up while
        # nobody has the port open. Packet mode reports the flush of every pyserial open (reboot_on_open).
        tty.setraw(slave)
        fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
        os.set_blocking(master, False)
        self.tty_path = os.ttyname(slave)
        os.close(slave)
        self._master = master
        self._wake_r, self._wake_w = os.pipe()
        self._stop.clear()
        with self._lock:
            self._power_up()
            self._client = False
            self._banner()  # booted before anyone connects, like a real board: nobody hears it
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
            for name in ("_master", "_wake_r", "_wake_w"):
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
        if self._master is not None:
            with contextlib.suppress(OSError):
                os.close(self._master)
            self._master = None

    # ------------------------------------------------------------------ public state (thread-safe)

    def inject(self, fault: Fault) -> None:
        """Arm a fault; it fires at its trigger and is then used up."""
        with self._lock:
            self._faults.append(fault)

    def machine_position(self) -> dict[str, float]:
        """What the step counters say now (MPos, machine units, whole steps), between reports too."""
        with self._lock:
            return self._on_grid(self._current_position(self._sim_now()))

    def physical_position(self) -> dict[str, float]:
        """Where the axes really are now, in the machine frame a successful homing sets up.

        Equal to :meth:`machine_position` once homed; different after a power-up or reboot (the counters
        restart at 0 wherever the axes stand) or a failed homing.
        """
        with self._lock:
            now = self._sim_now()
            if self._homing_block is not None and self._homing_block.t_start is not None:
                return self._homing_block.position_at(now - self._homing_block.t_start)
            machine = self._on_grid(self._current_position(now))
            return {a: machine[a] + self._offset[a] for a in self.axes}

    def planned_motion(self) -> PlannedMotion | None:
        """Where the axes will stand once the moves queued now have run (whole steps, as
        :meth:`physical_position` will then say), the motions still to be reported on the way there, and how
        many have been reported, all read at one instant (:class:`PlannedMotion`); None while homing or
        stopping (not known ahead)."""
        with self._lock:
            if self._homing_block is not None or any(isinstance(b, _Stop) for b in self._planner):
                return None
            machine = self._on_grid(self._planner[-1].end) if self._planner else self._on_grid(
                self._current_position(self._sim_now()))
            pending = []
            for block in self._planner:
                start, end = self._physical(self._on_grid(block.start)), self._physical(self._on_grid(block.end))
                if _approach_of(start, end):  # as _report_motion: a block that moves nothing is not reported
                    pending.append((start, end))
            return PlannedMotion(end=self._physical(machine), pending=tuple(pending),
                                 reported=self._motions_reported)

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
    def halted(self) -> bool:
        """In the critical-event loop after ALARM:1/2: nothing but a soft reset is heard."""
        with self._lock:
            return self._halted

    @property
    def homed(self) -> bool:
        with self._lock:
            return self._homed

    def sim_time(self) -> float:
        """Simulated seconds: the bench clock's (frozen while nothing timed is pending)."""
        with self._lock:
            return self._sim_now()

    # ------------------------------------------------------------------ machine model

    def _power_up(self) -> None:
        """main.c from the top: step counters zeroed wherever the axes stand; Alarm if homing is enabled."""
        self._position = {a: 0.0 for a in self.axes}
        self._offset = dict(self._start_position)  # physical = machine + offset
        self._wco = dict.fromkeys(self.axes, 0.0)
        self._homed = False
        # config.h HOMING_INIT_LOCK; grblHAL: $22 bit 2 (machine_limits.c limits_homing_required)
        self._state = "Alarm" if self.homing_enabled and self.homing_init_lock else "Idle"
        self._hold_complete = False
        # Output survives a soft reset (GRBL flushes its receive buffer, not its transmit buffer).
        self._out: deque[tuple[float, bytes]] = deque()
        self._last_release = 0.0
        self._reset_common()

    def _reset_common(self) -> None:
        """What main.c clears at every re-initialisation (the step counters are not among it)."""
        self._halted = False  # critical alarm: only reset is served
        self._halted_line: str | None = None  # the line that gets its late 'ok' once reset
        self._alarm_code: int | None = None
        self._planner: deque[_Block | _Stop] = deque()
        self._rx = bytearray()
        self._current: tuple[str, dict] | None = None  # a line waiting for the planner, a dwell or a stop
        self._dwell_end: float | None = None
        self._homing_block: _HomingPhase | None = None  # the homing move under way
        self._homing_phases: deque[_HomingPhase] = deque()  # the moves of the cycle still to come
        self._homing_fail: HomingFail | None = None
        # When (time.monotonic, like the output it follows) a reset ends a critical halt (report_alarm_message).
        self._reset_heard_from = 0.0
        self._auto_report_at = self._next_auto_report()
        self._report_homed = False  # grblHAL: the next status report carries H: (system_add_rt_report)
        # A '?' during homing, answered when the cycle ends; main.c clears it (sys_rt_exec_state) on a reset,
        # and a failed cycle resets before serving it (protocol_exec_rt_system returns at EXEC_RESET).
        self._status_after_homing = False
        self._modal = {"motion": 0, "distance": 90, "units": 21, "feed": 0.0}  # gcode.c gc_init
        self._wco_counter = 0
        self._ovr_counter = 0
        self._reply_prefix = ""

    def _next_auto_report(self) -> float | None:
        """grblHAL grbllib.c ``auto_realtime_report``: a report every ``$481`` ms when it is set. On the wall clock
        (``time.monotonic``, paced like the output): a report is traffic, not motion, and must come while the
        bench clock stands still too."""
        interval = float(self.settings.get(481, 0)) if self.firmware == "grblhal" else 0.0
        return time.monotonic() + self._real_delay(interval / 1000.0) if interval > 0 else None

    def _sim_now(self) -> float:
        return self.clock.now()

    def _schedule(self) -> None:
        """Let the bench clock run to the next timed event (a block's end, a fault, a dwell, a boot), or freeze it."""
        nxt = self._next_event_sim(self._sim_now())
        if nxt is None:
            self.clock.freeze()
        else:
            self.clock.run_until(nxt)

    def _report_motion(self, kind: str, start: Mapping[str, float], end: Mapping[str, float], start_s: float,
                       end_s: float, approach: Mapping[str, int] | None = None) -> None:
        """Tell the listener that a motion ended (machine positions are turned physical by the caller)."""
        approach = _approach_of(start, end) if approach is None else dict(approach)
        if self.on_motion is not None and approach:
            self._motions_reported += 1
            self.on_motion(MotionEvent(kind=kind, start=dict(start), end=dict(end), start_s=start_s, end_s=end_s,
                                       approach=approach))

    def _physical(self, machine: Mapping[str, float]) -> dict[str, float]:
        return {a: machine[a] + self._offset[a] for a in self.axes}

    def _real_delay(self, sim_seconds: float) -> float:
        return max(0.0, sim_seconds / self.time_scale)

    def _current_position(self, now: float) -> dict[str, float]:
        """Machine position (continuous; :meth:`_on_grid` makes it steps)."""
        if self._homing_block is not None and self._homing_block.t_start is not None:
            physical = self._homing_block.position_at(now - self._homing_block.t_start)
            return {a: physical[a] - self._offset[a] for a in self.axes}
        block = self._planner[0] if self._planner else None
        if block is not None and block.t_start is not None:
            return block.position_at(now - block.t_start)
        return dict(self._position)

    def _state_text(self) -> str:
        if self._state == "Hold":
            return f"Hold:{0 if self._hold_complete else 1}"
        return self._state

    def _moving(self) -> bool:
        """In motion as mc_reset sees it: cycle, jog, homing, or a hold still decelerating."""
        return (self._homing_block is not None or self._state in ("Run", "Jog", "Home")
                or (self._state == "Hold" and not self._hold_complete))

    def _advance(self, now: float) -> None:
        """Bring motion, homing and dwells up to ``now``, fire mid-move faults; then run or freeze the clock."""
        self._advance_model(now)
        self._schedule()

    def _advance_model(self, now: float) -> None:
        if self._booting_until is not None:
            return
        if self._homing_block is not None:
            block = self._homing_block
            while now >= block.t_start + block.duration:  # type: ignore[operator]
                if not self._homing_phases:
                    self._finish_homing()
                    break
                # limits.c: the next move of the cycle starts once the last one and its debounce are over.
                following = self._homing_phases.popleft()
                following.t_start = block.t_start + block.duration  # type: ignore[operator]
                self._homing_block = block = following
            return
        while self._planner:
            block = self._planner[0]
            if block.t_start is None:
                # protocol.c auto-cycle start: queued blocks run unless a hold keeps them.
                if self._state in ("Run", "Jog", "Idle"):
                    block.t_start = now
                    if self._state == "Idle":
                        self._state = "Jog" if block.kind == "jog" else "Run"
                else:
                    break
            if self._check_mid_move_faults(block, now) or self._check_hard_limits(block, now):
                break
            end = block.t_start + block.duration
            if now < end:
                break
            start = self._physical(self._on_grid(block.start))
            self._position = self._on_grid(block.end)
            self._planner.popleft()
            self._report_motion("stop" if isinstance(block, _Stop) else "move", start, self._physical(self._position),
                                block.t_start, end)
            if isinstance(block, _Stop):
                self._stop_complete(block)
                if self._halted:
                    return
                continue
            if self._planner and self._state in ("Run", "Jog"):
                nxt = self._planner[0]
                nxt.t_start = end
                self._state = "Jog" if nxt.kind == "jog" else "Run"
        if not self._planner and self._state in ("Run", "Jog"):
            self._state = "Idle"
        if self._current is not None:
            self._try_current(now)

    def _check_mid_move_faults(self, block: _Block | _Stop, now: float) -> bool:
        """Fire a fault due during ``block``; True if one fired (the block is then gone)."""
        if block.t_start is None or block.duration <= 0 or isinstance(block, _Stop):
            return False
        for fault in list(self._faults):
            if not isinstance(fault, (AlarmMidMove, ResetMidMove, VanishMidMove)):
                continue
            # Compared as _next_event_sim computes it (the time the clock stops at): a ratio could round below.
            at = block.t_start + fault.fraction * block.duration
            if now >= at:
                self._faults.remove(fault)
                self._stop_motion_at(at)
                if isinstance(fault, AlarmMidMove):
                    if fault.code in (1, 2):
                        # A line waiting for planner space is still inside mc_line: answered once reset.
                        self._halted_line = self._current[0] if self._current else None
                        self._current = None
                    self._raise_alarm(fault.code)
                elif isinstance(fault, ResetMidMove):
                    self._reboot()
                else:
                    self._vanish()
                return True
        return False

    def _check_hard_limits(self, block: _Block | _Stop, now: float) -> bool:
        """limits.c ``ISR(LIMIT_INT_vect)``: with ``$21=1`` a limit pin that changes during motion (a switch
        closing, or opening as an axis leaves it) calls mc_reset and raises ALARM:1, the axes stopping dead
        where they are. True if it fired (the block is then gone)."""
        at = self._hard_limit_time(block)
        if at is None or at > now:
            return False
        self._stop_motion_at(at)
        self._halted_line = self._current[0] if self._current else None  # a line inside mc_line: answered at reset
        self._current = None
        self._raise_alarm(1)
        return True

    def _hard_limit_time(self, block: _Block | _Stop) -> float | None:
        """The sim time at which ``block`` changes a switch's state, if hard limits are armed and it does."""
        if not self.hard_limits or self._state == "Alarm" or block.t_start is None or block.length <= 0:
            return None
        first = None
        for axis in self.axes:
            offset = self._offset[axis]
            begin, finish = block.start[axis] + offset, block.end[axis] + offset
            if self._switch_engaged(axis, begin) == self._switch_engaged(axis, finish):
                continue  # moves straight: it crosses its switch once at most
            switch = self._switch_physical(axis)
            fraction = (switch - begin) / (finish - begin)
            tau = block.time_at(min(max(fraction, 0.0), 1.0) * block.length)
            first = tau if first is None else min(first, tau)
        return None if first is None else block.t_start + first

    def _next_event_sim(self, now: float) -> float | None:
        times = []
        if self._homing_block is not None:
            times.append(self._homing_block.t_start + self._homing_block.duration)  # type: ignore[operator]
        elif self._planner and self._planner[0].t_start is not None:
            block = self._planner[0]
            times.append(block.t_start + block.duration)
            for fault in self._faults:  # those _check_mid_move_faults fires (the clock stops at each)
                if isinstance(fault, (AlarmMidMove, ResetMidMove, VanishMidMove)) and block.duration > 0 \
                        and not isinstance(block, _Stop):
                    times.append(block.t_start + fault.fraction * block.duration)
            tripped = self._hard_limit_time(block)
            if tripped is not None:
                times.append(tripped)
        if self._dwell_end is not None:
            times.append(self._dwell_end)
        if self._booting_until is not None:
            times.append(self._booting_until)
        return min(times) if times else None

    def _stop_motion_at(self, when: float) -> None:
        """Freeze the axes where they are at sim time ``when`` and drop all queued motion."""
        homing = self._homing_block if self._homing_block is not None and self._homing_block.t_start is not None \
            else None
        running = self._planner[0] if self._planner and self._planner[0].t_start is not None else None
        if homing is not None:
            self._position = self._on_grid(self._homing_counters(when))
            self._report_motion("abort", homing.start, self._physical(self._position), homing.t_start, when)
        else:
            self._position = self._on_grid(self._current_position(when))
            if running is not None:
                self._report_motion("abort", self._physical(self._on_grid(running.start)),
                                    self._physical(self._position), running.t_start, when)
        self._planner.clear()
        self._homing_block = None
        self._homing_phases.clear()
        self._homing_fail = None
        self._dwell_end = None
        self._current = None

    # -- feed hold, cycle start, controlled stops (protocol.c protocol_exec_rt_system)

    def _begin_stop(self, now: float, reason: str, line: str = "") -> None:
        """Decelerate the running block to a stop along its path (st_update_plan_block_parameters)."""
        block = self._planner[0] if self._planner and self._planner[0].t_start is not None else None
        if isinstance(block, _Stop):
            return
        if block is None:
            stop = _Stop(start=dict(self._position), direction=dict.fromkeys(self.axes, 0.0), v0=0.0, accel=1.0,
                         reason=reason, line=line)
            stop.t_start = now
            self._planner.appendleft(stop)
            return
        tau = now - block.t_start  # type: ignore[operator]
        here = block.position_at(tau)
        length = block.length or 1.0
        direction = {a: (block.end[a] - block.start[a]) / length for a in self.axes}
        stop = _Stop(start=here, direction=direction, v0=block.speed_at(tau), accel=block.accel, reason=reason,
                     interrupted=block, line=line)
        stop.t_start = now
        self._planner[0] = stop

    def _stop_complete(self, stop: _Stop) -> None:
        """EXEC_CYCLE_STOP after a stop: hold complete, jog cancelled, or the soft-limit alarm."""
        if stop.reason == "hold":
            rest = stop.interrupted
            if rest is not None:
                block = self._make_block(self._position, rest.end, rest.speed * 60.0, kind=rest.kind, line=rest.line)
                if block.length > 0:
                    self._planner.appendleft(block)
            self._hold_complete = True  # Hold:0, ready to resume
        elif stop.reason == "cancel":
            self._planner.clear()  # jog cancel: plan_reset, back to Idle
            self._state = "Idle"
        else:  # soft limit (limits.c limits_soft_check): stopped under control, now the critical alarm
            self._planner.clear()
            self._current = None
            self._halted_line = stop.line
            self._raise_alarm(2)

    def _feed_hold(self) -> None:
        if self._state in ("Alarm", "Check", "Home", "Hold") or self._halted:
            return
        now = self._sim_now()
        if self._state == "Idle":
            self._state, self._hold_complete = "Hold", True  # not moving: the hold is complete at once
        elif self._state == "Jog":
            self._begin_stop(now, "cancel")  # a hold cancels a jog (state stays Jog until stopped)
        else:
            self._begin_stop(now, "hold")
            self._state, self._hold_complete = "Hold", False

    def _cycle_start(self) -> None:
        # Cycle start only when IDLE or when a hold is complete and ready to resume: '~' during Hold:1 is lost.
        if self._state != "Hold" or not self._hold_complete:
            return
        self._hold_complete = False
        if self._planner:
            self._state = "Jog" if self._planner[0].kind == "jog" else "Run"
            self._planner[0].t_start = self._sim_now()
        else:
            self._state = "Idle"

    def _jog_cancel(self) -> None:
        if self._state == "Jog":
            self._begin_stop(self._sim_now(), "cancel")

    # -- alarms, resets, boots

    def _raise_alarm(self, code: int) -> None:
        self._state = "Alarm"
        self._alarm_code = code
        self._emit(f"ALARM:{code}", "alarm")
        self._alarm_pause()
        if code in (1, 2):
            # Hard and soft limits are critical in GRBL 1.1: protocol.c blocks everything but a reset -
            # no line, no status report - until 0x18 (what arrives meanwhile is flushed by the reset).
            self._halted = True
            self._rx.clear()
            self._emit(RESET_MESSAGE, "msg")
            # protocol.c protocol_exec_rt_system: the message comes after report_alarm_message's pause, then
            # system_clear_exec_state_flag(EXEC_RESET): a reset received before it is lost.
            # On the wall clock, as the pause itself: the bench clock stands still once the axes have stopped.
            self._reset_heard_from = self._last_release

    def _alarm_pause(self) -> None:
        """report.c report_alarm_message: delay_ms(500) after the ALARM line (grblHAL: 100 ms); nothing else goes
        out meanwhile."""
        self._last_release = max(self._last_release, time.monotonic()) + self._real_delay(self._alarm_delay_s)

    def _soft_reset(self) -> None:
        """0x18: motion_control.c mc_reset, then main.c re-initialises (step counters kept)."""
        self.resets += 1
        now = self._sim_now()
        moving = self._moving()
        homing = self._homing_block is not None
        late = self._halted_line or (self._current[0] if self._current else None)
        self._stop_motion_at(now)
        was_alarm = self._state == "Alarm"
        if moving:
            self._state = "Alarm"
            self._emit(f"ALARM:{6 if homing else 3}", "alarm")
            self._alarm_pause()
        if late is not None:
            # The line was inside gc_execute_line (waiting for the planner, a dwell, or in the soft-limit
            # loop); it still returns STATUS_OK once the abort unwinds it.
            self._reply(late, "ok", "ok")
        if homing:
            self._homed = False
        self._reset_common()
        self._state = "Alarm" if (moving or was_alarm) else "Idle"
        self._hold_complete = False
        self._banner()

    def _reboot(self) -> None:
        """Power cycle, watchdog or DTR auto-reset: main() from the top. The axes stay where they are, the
        step counters restart at 0 there (physical = machine + offset), the controller forgets it was homed."""
        self.resets += 1
        physical = {a: self._position[a] + self._offset[a] for a in self.axes}
        self._planner.clear()
        self._homing_block = None
        self._position = {a: 0.0 for a in self.axes}
        self._offset = physical
        self._homed = False
        self._state = "Alarm" if self.homing_enabled and self.homing_init_lock else "Idle"
        self._hold_complete = False
        self._reset_common()
        self._banner()

    def _banner(self) -> None:
        """report.c report_init_message, then protocol_main_loop's first words: the unlock message in
        Alarm, or the startup lines otherwise."""
        self._emit("", "banner")
        self._emit(GRBLHAL_BANNER if self.firmware == "grblhal" else GRBL_BANNER, "banner")
        if self.firmware == "grbl" and self.hard_limits and self._switches_engaged():
            # protocol.c protocol_main_loop, CHECK_LIMITS_AT_INIT (on in the default config.h; grblHAL's
            # DEFAULT_CHECK_LIMITS_AT_INIT is off): a closed switch at init is Alarm, said before the unlock line.
            self._state = "Alarm"
            self._emit(CHECK_LIMITS_MESSAGE, "msg")
        if self._state == "Alarm":
            self._emit(UNLOCK_MESSAGE, "msg")
        else:
            self._state = "Idle"
            self._run_startup_lines()

    def _switches_engaged(self) -> str:
        """The axes whose homing switch is closed now (limits.c limits_get_state)."""
        machine = self._current_position(self._sim_now())
        return "".join(a for a in self.axes if self._switch_engaged(a, machine[a] + self._offset[a]))

    def _run_startup_lines(self) -> None:
        """system.c system_execute_startup: each stored line through the g-code parser, echoed ``>line:result``."""
        now = self._sim_now()
        for stored in self.startup_lines:
            if stored:
                result = self._gcode(stored, stored, now, startup=True)
                self._emit(f">{stored}:{result}", "startup")

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
                    self._tick()
                    timeout = 0.1
                    nxt = self._next_event_sim(self._sim_now())
                    if nxt is not None:
                        timeout = min(timeout, self.clock.real_seconds_until(nxt))
                    if self._out:
                        timeout = min(timeout, max(0.0, self._out[0][0] - time.monotonic()))
                    if self._auto_report_at is not None:
                        timeout = min(timeout, max(0.0, self._auto_report_at - time.monotonic()))
                    master, wake, client = self._master, self._wake_r, self._client
                if master is None or wake is None:
                    return
                if not client:
                    # Nobody has the port open: the master reports a hang-up (select would not block on it),
                    # so look for an open every few ms instead.
                    readable, _, _ = select.select([wake], [], [], min(timeout, CLIENT_POLL_S))
                    if wake in readable:
                        with contextlib.suppress(OSError):
                            os.read(wake, 64)
                    if _client_present(master):
                        with self._lock:
                            self._client = True
                    continue
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
                        except OSError as error:
                            if error.errno == errno.EIO:  # the last client closed the port
                                self._client = False
                                continue
                            return
                        if data[:1] == b"\x00":  # packet mode: a data packet
                            self._receive(data[1:])
                        elif data and data[0] & termios.TIOCPKT_FLUSHREAD:
                            self._port_opened()  # pyserial flushes its input as it opens the port
                        self._flush_output()
        except Exception:
            # A bug in the model must not leave a tty that accepts bytes and never answers.
            with self._lock:
                self._vanish()
            raise

    def _tick(self) -> None:
        if self._booting_until is not None and self._sim_now() >= self._booting_until:
            self._booting_until = None
            self._reboot()
        now = self._sim_now()
        self._advance(now)
        if self._auto_report_at is not None and time.monotonic() >= self._auto_report_at:
            # Served by protocol_exec_rt_system: not while homing (unless $10 bit 12), halted or booting.
            if self._homing_block is None and not self._halted and self._booting_until is None:
                self._emit(self._status_report(), "status")
            self._auto_report_at = self._next_auto_report()
        self._process_lines(now)
        self._schedule()
        self._flush_output()

    def _port_opened(self) -> None:
        self.client_opens += 1
        if self.reboot_on_open:
            # DTR auto-reset: the board restarts as the port opens; its bootloader owns the UART (what is
            # sent now is lost) until Grbl boots and prints its banner.
            self._stop_motion_at(self._sim_now())
            self._out.clear()
            self._rx.clear()
            self._booting_until = self._sim_now() + self.boot_delay_s
            self._schedule()

    def _receive(self, data: bytes) -> None:
        if self._booting_until is not None:
            return
        now = self._sim_now()
        self._advance(now)
        for byte in data:
            if self._halted:
                if byte == 0x18 and time.monotonic() >= self._reset_heard_from:
                    self._soft_reset()
                # The critical-event loop hears only a reset, and only once it has said so: '?', '!', '~', lines
                # and a reset sent during report_alarm_message's pause go unanswered.
                continue
            if byte == 0x18:
                self._soft_reset()
            elif byte == ord("?"):
                self._advance(self._sim_now())
                if self._homing_block is not None:
                    # limits.c limits_go_home never runs protocol_execute_realtime: the request waits for the
                    # one motion_control.c mc_homing_cycle runs once the cycle is over (see _finish_homing).
                    self._status_after_homing = True
                elif not self._halted:
                    self._emit(self._status_report(), "status")
            elif byte == ord("!"):
                self._feed_hold()
            elif byte == ord("~"):
                self._cycle_start()
            elif byte == 0x85:
                self._jog_cancel()
            elif byte >= 0x80:
                pass  # overrides: accepted, not modelled
            elif len(self._rx) >= self._rx_capacity:
                self.rx_overflow_bytes += 1
            else:
                self._rx.append(byte)
                self.max_rx_fill = max(self.max_rx_fill, len(self._rx))
        self._process_lines(self._sim_now())
        self._schedule()

    def _process_lines(self, now: float) -> None:
        while not self._halted and self._booting_until is None:
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
        """protocol.c protocol_main_loop: one complete line."""
        self.lines_received.append(line)
        text = _clean_line(line)
        if len(text) > LINE_BUFFER_SIZE - 1:  # GRBL counts what it keeps: no spaces, no comments
            self._reply(line, "error:11", "error")
            return
        if not text:
            result: str | None = "ok"
        elif text.startswith("$"):
            result = self._system_command(line, text, now)
        elif self._state in ("Alarm", "Jog"):
            result = "error:9"  # g-code is locked out in Alarm and while jogging
        else:
            result = self._gcode(line, text, now)
        if result is not None:
            self._reply(line, result, "ok" if result == "ok" else "error")

    def _settings_lines(self) -> list[str]:
        """report.c report_grbl_settings: $0..$32, then per axis $100.., $110.., $120.., $130.."""
        rows = []
        for number in sorted(n for n in self.settings if n < 100):
            rows.append(f"${number}={_fmt_setting(number, self.settings[number])}")
        for base in (100, 110, 120, 130):
            for i in range(len(self.axes)):
                rows.append(f"${base + i}={self.settings[base + i]:.3f}")
        rows += [f"${number}={int(self.settings[number])}" for number in sorted(self.settings) if number > 133]
        return rows

    def _build_info_lines(self) -> list[str]:
        """report.c report_build_info. Grbl 1.1h's default build: ``V`` (VARIABLE_SPINDLE), ``Z`` with
        HOMING_FORCE_SET_ORIGIN. grblHAL (its report.c, for the Simulator driver: a variable spindle, mist coolant
        and a safety door, ``$22`` without "homing on startup required", WCO sync off): option letters in the
        order the source writes them, the planner and receive buffers, the axes and tools; then the extended
        lines. (The stored grblHAL simulator printed a ninth line this model has no source for.)"""
        if self.firmware != "grblhal":
            options = "V" + ("Z" if self.force_set_origin else "")
            return [f"[VER:{GRBL_VERSION}:]", f"[OPT:{options},{self.planner_blocks},{self.rx_buffer_size}]"]
        letters = "VNM" + ("Z" if self.force_set_origin else "") + ("" if self.homing_init_lock else "L") + "+W"
        newopt = "ENUMS,RT+," + ("HOME," if self.homing_enabled else "") + "TC,SED"
        return [
            f"[VER:{GRBLHAL_VERSION}:]",
            f"[OPT:{letters},{self.planner_blocks},{self.rx_buffer_size},{len(self.axes)},0]",
            f"[AXS:{len(self.axes)}:{self.axes}]",
            f"[NEWOPT:{newopt}]",
            "[FIRMWARE:grblHAL]",
            "[NVS STORAGE:*EEPROM]",
            f"[DRIVER:{GRBLHAL_DRIVER}]",
            f"[DRIVER VERSION:{GRBLHAL_DRIVER_VERSION}]",
        ]

    def _system_command(self, line: str, text: str, now: float) -> str | None:
        """system.c system_execute_line."""
        if text in self.unsupported_queries:
            return "error:3"
        if text == "$":
            self._emit(HELP_MESSAGE, "feedback")
            return "ok"
        command = text[1]
        if command == "J":
            if self._state not in ("Idle", "Jog"):
                return "error:8"
            if not text.startswith("$J="):
                return "error:3"
            return self._jog(line, text[3:], now)
        if command in "$GCX":
            if len(text) != 2:
                return "error:3"
            if command == "$":
                if self._state in ("Run", "Hold"):
                    return "error:8"  # takes too long to print during a cycle
                for row in self._settings_lines():
                    self._emit(row, "setting")
            elif command == "G":
                m = self._modal
                self._emit(f"[GC:G{m['motion']} G54 G17 G{m['units']} G{m['distance']} G94 M5 M9 T0 "
                           f"F{_fmt_number(m['feed'])} S0]", "feedback")
            elif command == "C":
                if self._state == "Check":
                    # Leaving check mode resets Grbl (mc_reset), after [MSG:Disabled] and this line's 'ok'.
                    self._emit("[MSG:Disabled]", "msg")
                    self._reply(line, "ok", "ok")
                    self._reset_common()
                    self._state = "Idle"
                    self._banner()
                    return None
                if self._state != "Idle":
                    return "error:8"
                self._state = "Check"
                self._emit("[MSG:Enabled]", "msg")
            elif command == "X" and self._state == "Alarm":
                self._emit("[MSG:Caution: Unlocked]", "msg")
                self._state = "Idle"  # no startup lines: stored moves must not run after an unlock
                self._alarm_code = None
            return "ok"
        # Everything else needs Idle or Alarm (EEPROM access, homing).
        if self._state not in ("Idle", "Alarm"):
            return "error:8"
        if command == "#":
            if len(text) != 2:
                return "error:3"
            zero = ",".join("0.000" for _ in self.axes)
            for name in ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"):
                self._emit(f"[{name}:{zero}]", "feedback")
            self._emit("[TLO:0.000]", "feedback")
            self._emit(f"[PRB:{zero}:0]", "feedback")
            return "ok"
        if command == "H":
            if not self.homing_enabled:
                return "error:5"
            if text != "$H":
                return "error:3"  # HOMING_SINGLE_AXIS_COMMANDS is off in the default build
            self._start_homing(line, now)
            return None
        if command == "I":
            if text != "$I":
                return "error:3"
            for row in self._build_info_lines():
                self._emit(row, "feedback")
            return "ok"
        if command == "N":
            if text == "$N":
                for n, stored in enumerate(self.startup_lines):
                    self._emit(f"$N{n}={stored}", "setting")
                return "ok"
            m = re.fullmatch(r"\$N(\d+)=(.*)", text)
            if m is None:
                return "error:3"
            if self._state != "Idle":
                return "error:8"  # stored only when idle: prevents motion during an alarm
            number, stored = int(m.group(1)), m.group(2)
            if number >= N_STARTUP_LINES:
                return "error:3"
            if stored:
                result = self._gcode(stored, stored, now, startup=True)  # executed to check it
                if result != "ok":
                    return result
            self.startup_lines[number] = stored
            return "ok"
        if m := re.fullmatch(r"\$(\d+)=([-+]?\d*\.?\d+)", text):
            return self._write_setting(int(m.group(1)), float(m.group(2)))
        return "error:3"

    def _write_setting(self, number: int, value: float) -> str:
        """settings.c settings_store_global_setting."""
        if value < 0.0:
            return "error:4"
        if number == 481 and self.firmware == "grblhal":
            self.settings[number] = int(value)  # the auto-report interval, ms
            self._auto_report_at = self._next_auto_report()
            return "ok"
        if number >= 100:
            base, index = 100 + (number - 100) // 10 * 10, (number - 100) % 10
            if base > 130 or index >= len(self.axes):
                return "error:3"
            self.settings[number] = value
            return "ok"
        integer = int(value)
        if number not in DEFAULT_SETTINGS:
            return "error:3"
        if number == 0 and integer < 3:
            return "error:6"
        if number == 20 and integer and not self.homing_enabled:
            return "error:10"
        if number == 22 and not integer & 1:
            self.settings[20] = 0  # disabling homing disables soft limits
        self.settings[number] = value if number in _FLOAT_SETTINGS | _RPM_SETTINGS else integer
        return "ok"

    def _start_homing(self, line: str, now: float) -> None:
        """motion_control.c mc_homing_cycle: limits.c limits_go_home for each cycle of config.h (HOMING_CYCLE_0 = Z,
        then X and Y; :func:`drivers.rig.motion.homing_cycles`). Each cycle: seek the switches at ``$25``, pull off
        ``$27``, locate at ``$24`` (N_HOMING_LOCATE_CYCLE = 1), pull off again; every move followed by the ``$26``
        debounce. All moves are planned here (each starts where the last ends) and run as blocks."""
        fail = next((f for f in self._faults if isinstance(f, HomingFail)), None)
        if fail is not None:
            self._faults.remove(fail)
        homing = self._homing_settings()
        debounce = homing.debounce_ms / 1000.0
        here = {a: self._position[a] + self._offset[a] for a in self.axes}
        phases: list[_HomingPhase] = []
        self._homing_fail = None
        for index, cycle in enumerate(homing_cycles(self.axes)):
            rate = min(self._axis_setting(110, a) for a in cycle)
            accel = min(self._axis_setting(120, a) for a in cycle)
            toward = {a: -1.0 if self._home_negative(a) else 1.0 for a in cycle}
            search = HOMING_SEARCH_SCALAR * max(self._max_travel(a) for a in cycle)
            seek = homing_move(search, homing.seek_rate_per_min, max_rate_per_min=rate, acceleration=accel)
            pull = homing_move(homing.pulloff, homing.seek_rate_per_min, max_rate_per_min=rate, acceleration=accel)
            locate = homing_move(HOMING_LOCATE_SCALAR * homing.pulloff, homing.feed_rate_per_min,
                                 max_rate_per_min=rate, acceleration=accel)

            def add(move: HomingMove, mode: str, step: dict[str, float], *, run_full: bool = False,
                    dwell: float = debounce, cycle: str = cycle) -> None:
                phase = _HomingPhase(start=dict(here), step=step, move=move, mode=mode, cycle=cycle,
                                     run_full=run_full, line=line, dwell_after=dwell)
                phases.append(phase)
                here.update(phase.end)

            to_switch = {a: max(0.0, (self._switch_physical(a) - here[a]) * toward[a]) for a in cycle}
            failing = fail if index == 0 else None
            if failing is None and any(d > search for d in to_switch.values()):
                failing = HomingFail(code=9)  # limits.c: the switch is beyond the search distance
            if failing is not None and failing.code == 9:
                # The switch never answers: the seek runs its whole search (the axis stalls at the switch, where the
                # travel ends), then ALARM:9 without a debounce (the exit routine raises it at once).
                add(seek, "seek", {a: toward[a] * to_switch[a] for a in cycle}, run_full=True, dwell=0.0)
                self._homing_fail = failing
                break
            add(seek, "seek", {a: toward[a] * to_switch[a] for a in cycle})
            if failing is not None:  # 8: the pull-off leaves the switch closed: ALARM:8 at the end of the move
                add(pull, "pulloff", {a: -toward[a] * homing.pulloff for a in cycle}, run_full=True, dwell=0.0)
                self._homing_fail = failing
                break
            add(pull, "pulloff", {a: -toward[a] * homing.pulloff for a in cycle}, run_full=True)
            for _ in range(homing.locate_cycles):
                back = {a: max(0.0, (self._switch_physical(a) - here[a]) * toward[a]) for a in cycle}
                add(locate, "locate", {a: toward[a] * back[a] for a in cycle})
                add(pull, "pulloff", {a: -toward[a] * homing.pulloff for a in cycle}, run_full=True)
        first = phases[0]
        first.t_start = now
        self._homing_block = first
        self._homing_phases = deque(phases[1:])
        self._state = "Home"
        self._current = (line, {})

    def _homing_counters(self, when: float) -> dict[str, float]:
        """The step counters during homing at sim time ``when`` (for an abort), making the offsets agree: axes of
        finished cycles stand homed (limits.c sets them at the end of their cycle), those of the current cycle
        count from 0 at the start of its current move, the others are untouched."""
        block = self._homing_block
        physical = block.position_at(when - block.t_start)  # type: ignore[union-attr, operator]
        counters = dict(self._position)
        done = self._homed_cycles(block)  # type: ignore[arg-type]
        for a in self.axes:
            if a in done:
                counters[a] = self._home_machine(a)
            elif a in block.cycle:  # type: ignore[union-attr]
                counters[a] = physical[a] - block.start[a]  # type: ignore[union-attr]
            self._offset[a] = physical[a] - counters[a]
        return counters

    def _homed_cycles(self, block: _HomingPhase) -> str:
        """The axes whose cycle ended before the one ``block`` belongs to."""
        cycles = homing_cycles(self.axes)
        return "".join(cycles[: cycles.index(block.cycle)])

    def _finish_homing(self) -> None:
        block = self._homing_block
        fail = self._homing_fail
        self._homing_block = None
        self._homing_fail = None
        # The axes last moved in the pull-off, away from the switch (a failed cycle: toward it, stuck there).
        seek = {a: -1 if self._home_negative(a) else 1 for a in self.axes}
        start = {a: self._switch_physical(a) for a in self.axes} if fail is None else dict(block.start)
        self._report_motion("home", start, dict(block.end), block.t_start, block.t_start + block.duration,
                            approach={a: -seek[a] if fail is None and float(self.settings[27]) > 0 else seek[a]
                                      for a in self.axes})
        if fail is None:
            self._position = {a: self._home_machine(a) for a in self.axes}
            self._offset = {a: block.end[a] - self._position[a] for a in self.axes}  # type: ignore[union-attr]
            self._homed = True
            self._report_homed = True
            if self._status_after_homing:
                # motion_control.c mc_homing_cycle: its protocol_execute_realtime serves a '?' that came during
                # the cycle, once, still in Home (system.c sets Idle after it returns), at the homed position.
                self._status_after_homing = False
                self._emit(self._status_report(), "status")
            self._state = "Idle"
            self._alarm_code = None
            self._run_startup_lines()  # system.c: after a successful $H, before its 'ok'
            self._finish_current("ok")
            return
        # limits.c: each move restarts the counters of its cycle's axes at 0 and counts its steps (a stalled axis
        # too); a failure leaves whatever was counted; the axes of cycles not run are untouched.
        counted = dict(self._position)
        done = self._homed_cycles(block)  # type: ignore[arg-type]
        for a in self.axes:
            if a in done:
                counted[a] = self._home_machine(a)
            elif a in block.cycle:  # type: ignore[union-attr]
                if fail.code == 9:  # the seek's steps, all issued (toward the switch)
                    counted[a] = block.move.search * (-1.0 if self._home_negative(a) else 1.0)  # type: ignore
                else:  # the pull-off's
                    counted[a] = block.step[a]  # type: ignore[union-attr]
        self._position = self._on_grid(counted)
        self._offset = {a: block.end[a] - self._position[a] for a in self.axes}  # type: ignore[union-attr]
        self._homed = False
        self._state = "Alarm"
        if fail.alarm_line:
            self._emit(f"ALARM:{fail.code}", "alarm")
            self._alarm_pause()
        if self.firmware == "grbl":
            # mc_reset has aborted Grbl, yet system.c's $H returns STATUS_OK: the late 'ok', then main.c
            # re-initialises (banner, [MSG:'$H'|'$X' to unlock]). grblHAL answers nothing for the line.
            self._finish_current("ok")
        self._current = None
        self._reset_common()
        self._banner()

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
            if len(self._planner) >= self.planner_blocks:
                return
            self._planner.append(words["block"])
            self._current = None
            self._reply(line, "ok", "ok")

    def _gcode(self, line: str, text: str, now: float, *, startup: bool = False) -> str | None:
        """gcode.c gc_execute_line for the words this rig uses. ``startup``: a startup line (answers at once)."""
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
        inches = self._modal["units"] == 20
        scale = MM_PER_INCH if inches else 1.0  # gcode.c: G20 words are converted to mm
        if "F" in values:
            if values["F"] < 0:
                return "error:4"
            self._modal["feed"] = values["F"] * scale
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
            if self._state == "Check" or startup:
                return "ok"  # mc_dwell does nothing in check mode
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
            # motion_control.c mc_line -> limits.c limits_soft_check: beyond machine space with $20=1 is a
            # critical alarm, not an error. Moving: a controlled stop first (feed hold), then the alarm.
            if self._state == "Run":
                self._begin_stop(now, "soft_limit", line=line)
                self._state, self._hold_complete = "Hold", False
                self._current = (line, {"stopping": True})
                return None
            self._stop_motion_at(now)
            self._halted_line = line
            self._raise_alarm(2)
            return None
        if self._state == "Check":
            return "ok"  # check mode: the planner is blocked, soft limits still apply
        feed = None if self._modal["motion"] == 0 else self._modal["feed"]
        block = self._make_block(base, self._on_grid(target), feed, kind=f"G{self._modal['motion']}", line=line)
        if block.length <= 0:
            return "ok"
        if len(self._planner) < self.planner_blocks:
            self._planner.append(block)
            return "ok"
        self._current = (line, {"block": block})  # mc_line waits for planner space before answering
        return None

    def _jog(self, line: str, body: str, now: float) -> str | None:
        """jog.c jog_execute: soft limits refuse the jog with error:15 instead of an alarm."""
        words = re.findall(r"([A-Z])([-+]?\d*\.?\d*)", body)
        if "".join(a + b for a, b in words) != body:
            return "error:16"
        values: dict[str, float] = {}
        relative = False
        machine = False
        inches = self._modal["units"] == 20
        for letter, value in words:
            if letter == "G":
                if value in ("91",):
                    relative = True
                elif value in ("53",):
                    machine = True
                elif value == "20":
                    inches = True
                elif value == "21":
                    inches = False
                elif value != "90":
                    return "error:16"
                continue
            if letter != "F" and letter not in self.axes:
                return "error:16"
            values[letter] = float(value)
        if "F" not in values:
            return "error:22"
        scale = MM_PER_INCH if inches else 1.0
        base = self._planned_end()
        target = dict(base)
        for axis in self.axes:
            if axis in values:
                if relative:
                    target[axis] = base[axis] + values[axis] * scale
                else:
                    target[axis] = values[axis] * scale + (0.0 if machine else self._wco[axis])
        if self.soft_limits and self._outside_travel(target):
            return "error:15"
        block = self._make_block(base, self._on_grid(target), values["F"] * scale, kind="jog", line=line)
        if block.length <= 0:
            return "ok"
        if len(self._planner) < self.planner_blocks:
            self._planner.append(block)
            return "ok"
        self._current = (line, {"block": block})
        return None

    def _planned_end(self) -> dict[str, float]:
        if self._planner:
            return dict(self._planner[-1].end)
        return dict(self._position)

    def _outside_travel(self, target: Mapping[str, float]) -> bool:
        """system.c system_check_travel_limits (exact comparisons, as the firmware makes them). grblHAL's
        check_travel_limits (machine_limits.c) checks the homed axes only: none before a homing cycle."""
        if self.firmware == "grblhal" and not self._homed:
            return False
        for axis, value in target.items():
            low, high = self._machine_space(axis)
            if value > high or value < low:
                return True
        return False

    def _make_block(self, start: Mapping[str, float], end: Mapping[str, float], feed_per_min: float | None,
                    *, kind: str, line: str) -> _Block:
        deltas = {a: end[a] - start[a] for a in self.axes}
        length = math.sqrt(sum(d * d for d in deltas.values()))
        if length <= 1e-12:
            return _Block(start=dict(start), end=dict(end), length=0.0, speed=1.0, accel=1.0, kind=kind, line=line)
        # Each axis' limits ($11x, $12x as set now) bound the speed and acceleration along the path, as GRBL's
        # planner does; the same model as the plan's estimate (drivers.rig.motion).
        limits = path_limits(deltas, max_rate_per_min={a: self._axis_setting(110, a) for a in deltas},
                             acceleration={a: self._axis_setting(120, a) for a in deltas}, feed_per_min=feed_per_min)
        return _Block(start=dict(start), end=dict(end), length=limits.length, speed=limits.speed, accel=limits.accel,
                      kind=kind, line=line)

    # ------------------------------------------------------------------ status report

    def _status_report(self) -> str:
        """report.c report_realtime_status."""
        now = self._sim_now()
        pos = self._on_grid(self._current_position(now))
        self.status_reports_sent += 1
        inches = self.report_inches
        coord = (lambda v: f"{v / MM_PER_INCH:.4f}") if inches else (lambda v: f"{v:.3f}")
        fields: list[str] = []
        if self.status_mask & 1:
            fields.append("MPos:" + ",".join(coord(pos[a]) for a in self.axes))
        else:
            fields.append("WPos:" + ",".join(coord(pos[a] - self._wco[a]) for a in self.axes))
        if self.status_mask & 2:
            fields.append(f"Bf:{self.planner_blocks - len(self._planner)},{self._rx_capacity - len(self._rx)}")
        speed = 0.0
        if self._planner and self._planner[0].t_start is not None and self._state in ("Run", "Jog", "Hold"):
            block = self._planner[0]
            speed = block.speed_at(now - block.t_start) * 60.0
        fields.append(f"FS:{speed / MM_PER_INCH:.1f},0" if inches else f"FS:{speed:.0f},0")
        busy = self._state in ("Run", "Jog", "Hold", "Home")
        if self._wco_counter > 0:
            self._wco_counter -= 1
        else:
            self._wco_counter = (30 if busy else 10) - 1  # config.h REPORT_WCO_REFRESH_BUSY/IDLE_COUNT
            if self._ovr_counter == 0:
                self._ovr_counter = 1
            fields.append("WCO:" + ",".join(coord(self._wco[a]) for a in self.axes))
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        else:
            self._ovr_counter = (20 if busy else 10) - 1  # config.h REPORT_OVR_REFRESH_BUSY/IDLE_COUNT
            fields.append("Ov:100,100,100")
        if self.firmware == "grblhal" and self._report_homed:
            # report.c report_realtime_status: report.homed, flagged when a homing cycle ends, adds |H:1 (all the
            # cycles' axes homed) to the next report.
            self._report_homed = False
            fields.append(f"H:{1 if self._homed else 0}")
        if self.shuffle_fields:
            self._rng.shuffle(fields)
        return "<" + "|".join([self._state_text(), *fields]) + ">"


def _client_present(master: int) -> bool:
    """True once a program has the pty's slave open (the master stops reporting a hang-up)."""
    poller = select.poll()
    poller.register(master, select.POLLIN)
    return not any(event & select.POLLHUP for _, event in poller.poll(0))


def _clean_line(line: str) -> str:
    """protocol.c protocol_main_loop: drop whitespace, control characters and comments; upper-case."""
    text = re.sub(r"\([^)]*\)", "", line).split(";", 1)[0]
    return "".join(ch for ch in text if ch > " ").upper()


def _fmt_number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:.3f}"
