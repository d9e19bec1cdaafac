"""The real GRBL driver, through pyserial, against the GRBL emulator on a real pty.

Every fault ends in a recovered move or a clear error, within a bounded time; a reported position is
always one the controller reported (checked against the emulator's own state). The emulator follows
Grbl 1.1h: machine space [-$13x, 0] once homed, silence while halted, late 'ok' + reboot after a homing
failure, decelerating holds, whole steps.
"""

from __future__ import annotations

import os
import threading
import time

import pytest
import serial

from drivers.rig.grbl import (
    GrblAlarm,
    GrblCommandError,
    GrblConnectionError,
    GrblConnectionLost,
    GrblController,
    GrblError,
    GrblLocked,
    GrblMoveError,
    GrblPositionUnknown,
    GrblResetError,
    GrblSettingsError,
    GrblTimeout,
)
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.faults import (
    AlarmMidMove,
    Delay,
    GarbledLine,
    HomingFail,
    LostOk,
    ResetMidMove,
    VanishMidMove,
    parse_fault,
)
from drivers.sim.grbl.firmware import AxisSpec

FAST = 50.0  # emulator time scale: a 100 mm move takes 2.25 s simulated, 45 ms real
HOME = {"X": -1.0, "Y": -1.0, "Z": -1.0}  # limits.c: homed axes sit at -$27 (pull-off 1 mm)


def _close_to(a: dict[str, float], b: dict[str, float], tol: float = 1e-3) -> bool:
    return a.keys() == b.keys() and all(abs(a[k] - b[k]) <= tol for k in a)


@pytest.fixture
def emulator():
    emu = GrblEmulator(time_scale=FAST)
    emu.start()
    yield emu
    emu.stop()


def _controller(emu: GrblEmulator, **kwargs) -> GrblController:
    options = dict(connect_timeout_s=3.0, ok_grace_s=0.2, poll_interval_s=0.02)
    options.update(kwargs)
    return GrblController(emu.tty_path, **options)


@pytest.fixture
def grbl(emulator):
    controller = _controller(emulator)
    controller.open()
    yield controller
    controller.close()


@pytest.fixture
def homed(grbl):
    grbl.home(timeout=5.0)
    return grbl


def _raw(emu: GrblEmulator, data: bytes, wait_s: float = 0.15) -> bytes:
    """Talk to the emulator without the driver: write ``data``, return what comes back within ``wait_s``."""
    port = serial.Serial(emu.tty_path, 115200, timeout=0.02)
    try:
        port.write(data)
        deadline = time.monotonic() + wait_s
        received = b""
        while time.monotonic() < deadline:
            received += port.read(256)
        return received
    finally:
        port.close()


# ---------------------------------------------------------------------------------------------- basics


def test_boot_in_alarm_refuses_motion_until_homed(emulator, grbl):
    assert grbl.banner is not None and grbl.banner.text == "Grbl 1.1h ['$' for help]"
    assert grbl.locked and grbl.last_reading.state == "Alarm"
    assert "'$H'|'$X' to unlock" in grbl.messages
    received = len(emulator.lines_received)
    with pytest.raises(GrblLocked, match=r"home \(\$H\) or unlock"):
        grbl.move_to({"X": -10.0})
    assert len(emulator.lines_received) == received  # refused before any byte was sent
    reading = grbl.home(timeout=5.0)
    assert reading.state == "Idle" and not grbl.locked
    assert reading.machine_position == HOME
    assert emulator.homed and emulator.physical_position() == HOME


def test_connect_reads_the_controllers_settings(emulator, grbl):
    info = grbl.info
    assert info.build == "1.1h.20190830" and info.options == "V" and info.rx_buffer_size == 128
    assert info.settings[22] == 1 and info.settings[20] == 1 and info.settings[130] == 350.0
    assert info.startup_lines == {0: "", 1: ""} and info.warnings == [] and not info.boot_detected
    assert list(emulator.lines_received)[:3] == ["$I", "$$", "$N"]


def test_move_waits_until_stopped_and_reports_the_controllers_position(emulator, homed):
    status = homed.move_to({"X": -100.0, "Y": -10.0, "Z": -5.0})
    assert not status.done
    time.sleep(0.01)  # accepted means planned: give it a few simulated mm
    during = homed.status(timeout=1.0)
    assert during.state == "Run"
    assert -100.0 < during.machine_position["X"] < -1.0
    reading = status.wait(5.0)
    assert status.done and status.success and status.reading is reading
    assert reading.state == "Idle"
    assert reading.machine_position == {"X": -100.0, "Y": -10.0, "Z": -5.0}
    assert _close_to(reading.machine_position, emulator.machine_position())
    assert abs(reading.timestamp - time.time()) < 5.0
    assert status.wait(0.01) is reading  # waiting again is free
    # Units and distance mode are never assumed: the line itself says mm and absolute.
    assert emulator.lines_received[-2] == "G21 G90 G53 G0 X-100.000 Y-10.000 Z-5.000"


def test_move_takes_the_simulated_time(emulator, homed):
    # X: 3000 mm/min, 200 mm/s^2 -> 100 mm in 2.25 s simulated; at x50, 45 ms of real time.
    t0 = time.monotonic()
    homed.move_to({"X": -101.0}).wait(5.0)
    elapsed = time.monotonic() - t0
    assert 0.045 <= elapsed < 1.0


def test_feed_move_and_callbacks(homed):
    finished = []
    status = homed.move_to({"Y": -30.0}, feed_per_min=900.0)
    status.add_callback(finished.append)
    status.wait(5.0)
    assert finished == [status]
    late = []
    status.add_callback(late.append)
    assert late == [status]


def test_commands_feedback_and_errors(homed):
    assert homed.send("$I")[0].startswith("[VER:1.1h")
    settings = homed.send("$$")
    assert "$22=1" in settings and "$130=350.000" in settings and "$27=1.000" in settings
    with pytest.raises(GrblCommandError) as info:
        homed.send("G1 X-10")  # no feed rate yet
    assert info.value.code == 22
    with pytest.raises(GrblCommandError) as info:
        homed.send("$J=G53 X-500 F1000")  # jog past the travel: refused, no alarm
    assert info.value.code == 15 and "Travel exceeded" in str(info.value)
    assert homed.status().state == "Idle"


def test_locked_controller_answers_gcode_with_error_9(grbl):
    with pytest.raises(GrblCommandError) as info:
        grbl.send("G4 P0")
    assert info.value.code == 9 and "locked out" in str(info.value)
    grbl.unlock()
    assert not grbl.locked
    grbl.move_to({"Z": -2.0}).wait(5.0)


def test_axis_not_on_the_controller_is_refused_before_sending(emulator, homed):
    received = len(emulator.lines_received)
    with pytest.raises(Exception, match="axis A not on the controller"):
        homed.move_to({"A": -1.0})
    assert len(emulator.lines_received) == received


# ---------------------------------------------------------------------------------------------- machine space


def test_positive_targets_hit_grbls_soft_limit_and_silence_until_reset(emulator, homed):
    # Homed with $23=0, machine space is [-$130, 0]: X = +10 is outside (system_check_travel_limits).
    with pytest.raises(GrblAlarm) as info:
        homed.move_to({"X": 10.0}).wait(5.0)
    assert info.value.code == 2 and "Soft limit" in str(info.value)
    assert emulator.halted
    # Grbl answers nothing now, not even '?': the driver says so at once instead of timing out.
    t0 = time.monotonic()
    with pytest.raises(GrblAlarm, match="halted by it and answers nothing.*reset required"):
        homed.status(timeout=5.0)
    assert time.monotonic() - t0 < 0.5
    with pytest.raises(GrblAlarm, match="reset required"):
        homed.move_to({"X": -10.0})
    reading = homed.soft_reset()
    assert reading.state == "Alarm"  # position kept, but GRBL wants an unlock or homing
    assert reading.machine_position == HOME
    assert homed.stray_replies == 1  # the late 'ok' of the refused line, after the reset (gcode.c)
    homed.unlock()
    assert homed.move_to({"X": -10.0}).wait(5.0).machine_position["X"] == -10.0


def test_the_emulator_is_silent_while_halted():
    with GrblEmulator(time_scale=FAST, homing_enabled=False) as emu:
        assert b"<Idle" in _raw(emu, b"?")
        with GrblEmulator(time_scale=FAST) as halted:
            reply = _raw(halted, b"$X\nG53 G0 X5\n", wait_s=0.3)
            assert b"ALARM:2" in reply and b"[MSG:Reset to continue]" in reply
            assert _raw(halted, b"?$I\n", wait_s=0.2) == b""  # nothing, not even a status report
            after = _raw(halted, b"\x18", wait_s=0.3)
            assert after.startswith(b"ok\r\n") and b"Grbl 1.1h" in after  # the late 'ok', then the banner


def test_connecting_to_a_halted_controller_without_reset_names_the_halt():
    with GrblEmulator(time_scale=FAST) as emu:
        _raw(emu, b"$X\nG53 G0 X5\n", wait_s=0.3)
        assert emu.halted
        grbl = _controller(emu, reset_on_open=False, connect_timeout_s=0.6, boot_wait_s=0.3)
        with pytest.raises(GrblConnectionError, match="halted by a hard or soft limit.*until it is reset"):
            grbl.open()
        with _controller(emu, boot_wait_s=0.3) as resetting:  # a soft reset at connect ends the halt
            assert resetting.status().state == "Alarm" and not emu.halted


def test_soft_reset_while_moving_raises_alarm_3(emulator, homed):
    homed.move_to({"X": -300.0}, feed_per_min=600.0)
    time.sleep(0.05)
    reading = homed.soft_reset()
    assert reading.state == "Alarm"
    assert homed.alarm is not None and homed.alarm.code == 3
    assert -300.0 < reading.machine_position["X"] < -1.0
    assert _close_to(reading.machine_position, emulator.machine_position())


# ---------------------------------------------------------------------------------------------- units, steps


def test_g20_startup_line_is_warned_about_and_every_move_is_still_in_mm():
    # $N0=G20: Grbl runs it at every reset and homing (echo '>G20:ok'); a move without G21 would go in inches.
    with GrblEmulator(time_scale=FAST, startup_lines=("G20",)) as emu:
        with _controller(emu) as grbl:
            assert any("$N0=G20" in w and "inches" in w for w in grbl.info.warnings)
            grbl.home(timeout=5.0)  # runs the startup line
            assert grbl.info.startup_executed == [">G20:ok"] and grbl.garbled_lines == 0
            # What the old line (no G21) does on this controller: 2 inches, not 2 mm.
            grbl.send("G53 G0 X-2")
            assert grbl.wait_idle(5.0).machine_position["X"] == -50.8
            assert grbl.move_to({"X": -2.0}).wait(5.0).machine_position["X"] == -2.0


def test_inches_reporting_is_refused():
    with GrblEmulator(time_scale=FAST, report_inches=True) as emu:
        grbl = _controller(emu)
        with pytest.raises(GrblSettingsError, match=r"\$13=1.*inches"):
            grbl.open()
        assert not grbl.is_open


def test_inches_reports_of_the_emulator(emulator):
    with GrblEmulator(time_scale=FAST, report_inches=True, homing_enabled=False,
                      start_position={"X": -25.4}) as emu:
        assert b"MPos:0.0000,0.0000,0.0000" in _raw(emu, b"?")


def test_positions_are_whole_steps_and_step_rounding_is_named():
    specs = {"X": AxisSpec(max_travel=350.0, steps_per_unit=80.0)}
    with GrblEmulator(time_scale=FAST, axis_specs=specs) as emu, _controller(emu) as grbl:
        grbl.home(timeout=5.0)
        reading = grbl.move_to({"X": -10.004}, tolerance=0.0125).wait(5.0)
        assert reading.machine_position["X"] == -10.0  # 800 steps: what the controller reports
        assert emu.physical_position()["X"] == -10.0
        with pytest.raises(GrblMoveError, match=r"step rounding.*whole steps of 0.0125 \(\$100=80\)"):
            grbl.move_to({"X": -20.004}, tolerance=0.001).wait(5.0)


def test_a_later_queued_move_is_named(homed):
    first = homed.move_to({"X": -50.0})
    homed.move_to({"X": -80.0})
    with pytest.raises(GrblMoveError, match="a later move was queued"):
        first.wait(5.0)


def test_overshoot_and_short_stop_are_told_apart(homed):
    homed.move_to({"X": -20.0}).wait(5.0)
    status = homed.move_to({"X": -40.0})
    reading = status.wait(5.0)
    fake = type(reading)(**{**reading.__dict__, "machine_position": {"X": -40.5, "Y": -1.0, "Z": -1.0}})
    with pytest.raises(GrblMoveError, match="overshoot: past the target"):
        status._check_position(fake)
    fake = type(reading)(**{**reading.__dict__, "machine_position": {"X": -30.0, "Y": -1.0, "Z": -1.0}})
    with pytest.raises(GrblMoveError, match="stopped short of the target"):
        status._check_position(fake)


# ---------------------------------------------------------------------------------------------- hold / resume


def test_feed_hold_decelerates_and_resume_waits_for_the_hold_to_complete():
    # 50 mm/s, 20 mm/s^2: 2.5 s (0.5 s real at x5) to stop from full speed, so that "still decelerating" is
    # seen however loaded the machine is (a 12.5 ms deceleration was missed under load).
    slow = {"X": AxisSpec(max_travel=350.0, max_rate_per_min=3000.0, acceleration=20.0)}
    with GrblEmulator(time_scale=5.0, axis_specs=slow) as emu, _controller(emu) as grbl:
        grbl.unlock()
        status = grbl.move_to({"X": -340.0})
        deadline = time.monotonic() + 5.0
        while emu.machine_position()["X"] > -70.0 and time.monotonic() < deadline:  # cruising
            time.sleep(0.01)
        grbl.feed_hold()
        assert grbl.status(timeout=1.0).full_state == "Hold:1"  # still decelerating
        started = time.monotonic()
        with pytest.raises(GrblMoveError, match="feed hold"):  # not a wait into the timeout
            status.wait(5.0)
        assert time.monotonic() - started < 2.0
        assert emu.state == "Hold:0"
        reading = grbl.resume(timeout=5.0)
        assert reading.state == "Run"  # it left the hold
        assert grbl.wait_idle(timeout=30.0).machine_position["X"] == -340.0


def test_resume_during_hold_1_waits_instead_of_being_ignored():
    # 50 mm/s, 20 mm/s^2: 62.5 mm ramps, 2.5 s (0.5 s real at x5) to stop from full speed.
    slow = {"X": AxisSpec(max_travel=350.0, max_rate_per_min=3000.0, acceleration=20.0)}
    with GrblEmulator(time_scale=5.0, axis_specs=slow) as emu, _controller(emu) as grbl:
        grbl.unlock()
        grbl.move_to({"X": -340.0})
        deadline = time.monotonic() + 5.0
        while emu.machine_position()["X"] > -70.0 and time.monotonic() < deadline:  # cruising
            time.sleep(0.01)
        grbl.feed_hold()
        assert grbl.status().full_state == "Hold:1"
        assert b"Hold:1" in _raw_while_connected(grbl, b"~")  # Grbl ignores '~' while decelerating
        reading = grbl.resume(timeout=5.0)
        assert reading.state == "Run"
        assert grbl.wait_idle(timeout=20.0).machine_position["X"] == -340.0


def _raw_while_connected(grbl: GrblController, data: bytes) -> bytes:
    grbl._write(data)
    time.sleep(0.05)
    return grbl.status().raw.encode()


# ---------------------------------------------------------------------------------------------- homing failures


@pytest.mark.parametrize("code", [8, 9])
def test_failed_homing_then_unlock_is_answered_by_its_own_ok(code):
    with GrblEmulator(time_scale=FAST, faults=[HomingFail(code=code)]) as emu, _controller(emu) as grbl:
        with pytest.raises(GrblAlarm, match=f"ALARM:{code}.*homing failed") as info:
            grbl.home(timeout=5.0)
        assert info.value.code == code
        assert grbl.stray_replies == 0 and grbl.locked and emu.resets == 1
        with pytest.raises(GrblLocked, match=f"ALARM:{code} \\(Homing fail"):
            grbl.move_to({"X": -5.0})
        reading = grbl.unlock()  # the old driver returned on the stale 'ok' of $H here ...
        assert reading.state == "Idle"
        # ... the failed search left the step counters at whatever they counted: out of Alarm, the position is
        # still unknown until the user says it is right.
        with pytest.raises(GrblPositionUnknown, match="homing failed.*its position is unknown"):
            grbl.move_to({"X": -5.0})
        grbl.trust_position()
        assert grbl.move_to({"X": -5.0, "Y": -5.0, "Z": -5.0}).wait(5.0).state == "Idle"


def test_failed_homing_without_its_alarm_line_is_still_a_homing_failure():
    with GrblEmulator(time_scale=FAST, faults=[HomingFail(code=9, alarm_line=False)]) as emu:
        with _controller(emu) as grbl:
            with pytest.raises(GrblError, match="homing failed.*no ALARM line") as info:
                grbl.home(timeout=5.0)
            assert "power, watchdog" not in str(info.value)
            assert grbl.home(timeout=5.0).machine_position == HOME  # the switches work again


# ---------------------------------------------------------------------------------------------- auto-reset


def test_auto_reset_on_open_is_detected_and_the_position_is_unknown():
    with GrblEmulator(time_scale=FAST, reboot_on_open=True) as emu:
        with _controller(emu) as grbl:
            grbl.home(timeout=5.0)
            grbl.move_to({"X": -30.0}).wait(5.0)
        assert emu.physical_position()["X"] == -30.0
        with _controller(emu) as again:  # opening the port reboots the board: MPos 0 at X = -30
            assert again.info.boot_detected and emu.resets == 2
            assert again.last_reading.machine_position["X"] == 0.0 and emu.physical_position()["X"] == -30.0
            assert any("booted when the port was opened" in w for w in again.info.warnings)
            with pytest.raises(GrblLocked, match="booted when the port was opened.*home the rig"):
                again.move_to({"X": -20.0})
            again.home(timeout=5.0)
            assert again.move_to({"X": -20.0}).wait(5.0).machine_position["X"] == -20.0
            assert emu.physical_position()["X"] == -20.0


def test_no_reboot_without_auto_reset(emulator):
    with _controller(emulator) as first:
        first.home(timeout=5.0)
    with _controller(emulator) as second:
        assert not second.info.boot_detected and second.last_reading.machine_position == HOME


# ---------------------------------------------------------------------------------------------- check mode


def test_leaving_check_mode_resets_grbl_and_that_is_expected(emulator, homed):
    assert homed.set_check_mode(True).state == "Check"
    homed.send("G21 G90 G53 G0 X-200")  # parsed, not moved
    assert emulator.machine_position() == HOME
    reading = homed.set_check_mode(False)
    assert reading.state == "Idle" and reading.machine_position == HOME
    assert emulator.resets == 1 and not homed.locked and homed.position_unknown is None
    assert homed.move_to({"X": -20.0}).wait(5.0).machine_position["X"] == -20.0


# ---------------------------------------------------------------------------------------------- variants


def test_status_fields_in_random_order_and_wpos_reports():
    with GrblEmulator(time_scale=FAST, shuffle_fields=True, status_mask=0 | 2, seed=3) as emu:
        with _controller(emu) as grbl:
            grbl.home(timeout=5.0)
            reading = grbl.move_to({"X": -12.5}).wait(5.0)
            assert reading.machine_position == {"X": -12.5, "Y": -1.0, "Z": -1.0}
            assert reading.work_position == {"X": -12.5, "Y": -1.0, "Z": -1.0}
            assert reading.rx_bytes_free == 128 and reading.planner_blocks_free == 15


def test_grblhal_six_axes():
    with GrblEmulator(time_scale=FAST, axes="XYZABC", firmware="grblhal") as emu:
        with _controller(emu, rx_buffer_size=1024) as grbl:
            assert grbl.banner.firmware == "GrblHAL" and grbl.axes == "XYZABC"
            grbl.home(timeout=5.0)
            reading = grbl.move_to({"X": -50.0, "A": -3.0, "B": -2.0, "C": -400.0}).wait(10.0)
            assert reading.machine_position == {"X": -50.0, "Y": -1.0, "Z": -1.0, "A": -3.0, "B": -2.0,
                                                "C": -400.0}


def test_grblhal_reports_the_receive_bytes_its_ring_can_still_take():
    # grblHAL's ring of RX_BUFFER_SIZE slots is full one byte early and its Bf says so (RX_BUFFER_SIZE - 1 - count);
    # Grbl 1.1's ring has one slot more and reports all 128 (test_status_fields_in_random_order_and_wpos_reports).
    with GrblEmulator(time_scale=FAST, firmware="grblhal", status_mask=1 | 2) as emu:
        with _controller(emu, rx_buffer_size=1024) as grbl:
            grbl.home(timeout=5.0)
            reading = grbl.move_to({"X": -12.5}).wait(5.0)
            assert reading.rx_bytes_free == 1023 and reading.planner_blocks_free == 100  # [OPT:VNML+W,100,1024,...]


def test_a_buffer_size_other_than_configured_is_warned_and_the_controllers_used():
    with GrblEmulator(time_scale=FAST, rx_buffer_size=64) as emu, _controller(emu) as grbl:
        assert grbl.rx_buffer_size == 64
        assert any("receive buffer is 64 bytes" in w for w in grbl.info.warnings)
        grbl.unlock()
        grbl.stream([f"G21 G90 G53 G1 X-{1 + i * 0.5:.3f} F3000" for i in range(20)], timeout=20.0)
        assert emu.rx_overflow_bytes == 0 and emu.max_rx_fill <= 63


def test_force_set_origin_build_counts_positive():
    specs = {"X": AxisSpec(max_travel=350.0, home_negative=True)}
    with GrblEmulator(time_scale=FAST, axis_specs=specs, force_set_origin=True) as emu, _controller(emu) as grbl:
        assert grbl.info.options == "VZ" and grbl.info.machine_space("X") == (0.0, 350.0)
        assert grbl.home(timeout=5.0).machine_position["X"] == 0.0
        assert grbl.move_to({"X": 120.0}).wait(5.0).machine_position["X"] == 120.0


def test_homing_disabled_boots_idle_and_refuses_home():
    with GrblEmulator(time_scale=FAST, homing_enabled=False) as emu:
        with _controller(emu) as grbl:
            assert not grbl.locked
            with pytest.raises(GrblCommandError) as info:
                grbl.home(timeout=2.0)
            assert info.value.code == 5


def test_homing_timeout_stops_the_cycle_with_a_reset():
    with GrblEmulator(time_scale=1.0, homing_debounce_ms=60_000) as emu:
        with _controller(emu) as grbl:
            t0 = time.monotonic()
            with pytest.raises(GrblTimeout, match="homing .* did not finish"):
                grbl.home(timeout=0.3)
            assert time.monotonic() - t0 < 3.0
            assert emu.state == "Alarm" and not emu.homed
            assert grbl.alarm is not None and grbl.alarm.code == 6
            assert grbl.status().state == "Alarm"


def test_no_status_while_homing():
    with GrblEmulator(time_scale=5.0) as emu, _controller(emu) as controller:
        errors = []
        homing = threading.Thread(target=lambda: controller.home(timeout=5.0))
        homing.start()
        time.sleep(0.1)
        try:
            controller.status()
        except Exception as error:  # noqa: BLE001 - the point is which error
            errors.append(error)
        homing.join(5.0)
        assert errors and "no status while homing" in str(errors[0])
        assert controller.status().state == "Idle"


def _raw_homing(emu: GrblEmulator, until: bytes) -> list[str]:
    """Send ``$H`` and, while it runs, two ``?``; return the lines received up to and including ``until``."""
    port = serial.Serial(emu.tty_path, 115200, timeout=0.02)
    try:
        port.write(b"$H\n")
        time.sleep(0.05)  # well inside the cycle: its first debounce alone lasts 0.2 s real
        port.write(b"??")
        received, deadline = b"", time.monotonic() + 5.0
        while until not in received and time.monotonic() < deadline:
            received += port.read(256)
        time.sleep(0.1)
        received += port.read(256)
        return received.decode().split("\r\n")
    finally:
        port.close()


def test_a_status_asked_during_homing_is_answered_once_when_the_cycle_ends():
    # motion_control.c mc_homing_cycle: limits_go_home serves no real-time request; the protocol_execute_realtime
    # after it answers the '?' (one report for any number of them), still in Home, at the homed position.
    with GrblEmulator(time_scale=5.0, homing_debounce_ms=1000) as emu:
        lines = _raw_homing(emu, until=b"ok\r\n")
    reports = [line for line in lines if line.startswith("<")]
    assert len(reports) == 1 and reports[0].startswith("<Home|MPos:-1.000,-1.000,-1.000|")
    assert lines.index(reports[0]) < lines.index("ok")


def test_a_status_asked_during_a_failed_homing_is_never_answered():
    # limits.c: the failed cycle's mc_reset reaches protocol_exec_rt_system's EXEC_RESET first; main.c clears the rest.
    with GrblEmulator(time_scale=5.0, homing_debounce_ms=1000, faults=[HomingFail(code=8)]) as emu:
        lines = _raw_homing(emu, until=b"to unlock]\r\n")
    assert "ALARM:8" in lines and "ok" in lines and "[MSG:'$H'|'$X' to unlock]" in lines
    assert not [line for line in lines if line.startswith("<")]


def test_the_emulator_drops_bytes_past_its_buffer_like_grbl(emulator):
    # Without character counting: 60 lines at once while GRBL is busy overflow its 128 bytes (serial.c: the
    # ring has RX_BUFFER_SIZE+1 slots, so all 128 hold data before the receive interrupt drops a byte).
    port = serial.Serial(emulator.tty_path, timeout=0.2)
    try:
        port.write(b"$X\nG4 P5\n" + b"G1 X-1 F100\n" * 60)
        time.sleep(0.2)
        assert emulator.rx_overflow_bytes > 0
        assert emulator.max_rx_fill == 128
    finally:
        port.close()


def test_dtr_pulse_is_tolerated_on_a_pty(emulator):
    # pyserial's dtr setter raises OSError ENOTTY on a pty; an Arduino-style reset must not fail on it.
    with _controller(emulator, pulse_dtr_on_open=True) as grbl:
        assert grbl.transport.pulse_dtr(low_s=0.0) is False
        assert grbl.status().state == "Alarm"


def test_an_open_serial_object_can_be_passed_in(emulator):
    port = serial.Serial(emulator.tty_path, 115200, timeout=0.5)
    with GrblController(port, reset_on_open=False) as grbl:
        assert grbl.status().machine_position == {"X": 0.0, "Y": 0.0, "Z": 0.0}


# ---------------------------------------------------------------------------------------------- faults


def test_lost_ok_of_the_move_is_recovered(emulator, homed):
    emulator.inject(LostOk(match="G53"))
    reading = homed.move_to({"X": -80.0}).wait(5.0)
    assert reading.machine_position["X"] == -80.0
    assert homed.lost_replies == 1
    # The link is in step again: the next move needs no recovery.
    homed.move_to({"X": -20.0}).wait(5.0)
    assert homed.lost_replies == 1


def test_lost_ok_of_the_dwell_is_recovered(emulator, homed):
    emulator.inject(LostOk(match="G4"))
    reading = homed.move_to({"Y": -45.0}).wait(5.0)
    assert reading.machine_position["Y"] == -45.0 and homed.lost_replies == 1


def test_lost_ok_of_homing_is_recovered(emulator, grbl):
    emulator.inject(LostOk(match="$H"))
    reading = grbl.home(timeout=1.0)
    assert reading.state == "Idle" and grbl.lost_replies == 1
    assert grbl.move_to({"X": -5.0}).wait(5.0).machine_position["X"] == -5.0


def test_garbled_ok_is_recovered(emulator, homed):
    emulator.inject(GarbledLine(what="ok"))
    reading = homed.move_to({"Z": -30.0}).wait(5.0)
    assert reading.machine_position["Z"] == -30.0
    assert homed.garbled_lines == 1 and homed.lost_replies == 1


def test_garbled_status_is_never_reported(emulator, homed):
    homed.move_to({"X": -42.0}).wait(5.0)
    emulator.inject(GarbledLine(what="status", count=3))
    reading = homed.status(timeout=3.0)
    assert reading.machine_position == {"X": -42.0, "Y": -1.0, "Z": -1.0}
    assert homed.garbled_lines == 3


def test_delayed_replies_are_waited_for(emulator, homed):
    emulator.inject(Delay(seconds=0.3, count=2, what="ok"))
    t0 = time.monotonic()
    reading = homed.move_to({"X": -10.0}).wait(5.0)
    assert reading.machine_position["X"] == -10.0
    assert time.monotonic() - t0 >= 0.3
    assert homed.lost_replies == 0


def test_a_delay_past_the_timeout_is_a_clear_timeout_not_a_hang(emulator, homed):
    emulator.inject(Delay(seconds=3.0, what="any"))
    t0 = time.monotonic()
    with pytest.raises(GrblTimeout, match="no answer"):
        homed.move_to({"X": -10.0}, timeout_s=0.5)
    assert time.monotonic() - t0 < 2.0


def test_alarm_mid_move_is_an_error_then_recovers_by_reset_and_homing(emulator, homed):
    emulator.inject(AlarmMidMove(code=1, fraction=0.5))
    with pytest.raises(GrblAlarm) as info:
        homed.move_to({"X": -200.0}).wait(5.0)
    assert info.value.code == 1 and "Hard limit" in str(info.value)
    with pytest.raises(GrblAlarm, match="reset required"):  # halted: no status to read
        homed.status()
    with pytest.raises(GrblAlarm, match="reset required"):
        homed.move_to({"X": -10.0})
    stopped = homed.soft_reset()
    assert stopped.state == "Alarm"
    assert -200.0 < stopped.machine_position["X"] < -1.0  # where it really stopped, as reported
    assert _close_to(stopped.machine_position, emulator.machine_position())
    homed.home(timeout=5.0)
    assert homed.move_to({"X": -10.0}).wait(5.0).machine_position["X"] == -10.0


def test_spontaneous_reset_mid_move_is_an_error_and_needs_homing(emulator, homed):
    emulator.inject(ResetMidMove(fraction=0.3))
    with pytest.raises(GrblResetError, match="reset unexpectedly"):
        homed.move_to({"X": -150.0}).wait(5.0)
    with pytest.raises(GrblLocked, match="reset unexpectedly"):
        homed.move_to({"X": -10.0})
    assert homed.status().machine_position == {"X": 0.0, "Y": 0.0, "Z": 0.0}  # a reboot zeroes the counters
    homed.home(timeout=5.0)
    assert homed.move_to({"X": -10.0}).wait(5.0).machine_position["X"] == -10.0


def test_port_vanishing_mid_move_is_a_connection_error(emulator, homed):
    emulator.inject(VanishMidMove(fraction=0.5))
    t0 = time.monotonic()
    with pytest.raises(GrblConnectionLost, match="lost the connection"):
        homed.move_to({"X": -100.0}).wait(5.0)
    assert time.monotonic() - t0 < 3.0
    with pytest.raises(GrblConnectionError):
        homed.status()
    homed.close()
    assert emulator.vanished and not emulator.running
    # (Not re-opening the path: the kernel may already have given that pts number to another program.)


def test_port_vanishing_while_idle(emulator, homed):
    emulator.vanish()
    with pytest.raises(GrblConnectionError):
        for _ in range(50):
            homed.status(timeout=0.5)
            time.sleep(0.01)


def test_open_again_after_a_lost_connection_works_at_once(tmp_path):
    # The same device path comes back (USB replugged): open() on the same object must not fail on the old fd.
    link = tmp_path / "grbl"
    first = GrblEmulator(time_scale=FAST).start()
    os.symlink(first.tty_path, link)
    grbl = GrblController(str(link), connect_timeout_s=3.0)
    try:
        grbl.open()
        first.vanish()
        with pytest.raises(GrblConnectionLost):
            for _ in range(50):
                grbl.status(timeout=0.5)
                time.sleep(0.01)
        with GrblEmulator(time_scale=FAST) as second:
            link.unlink()
            os.symlink(second.tty_path, link)
            grbl.open()
            assert grbl.status().state == "Alarm"
    finally:
        grbl.close()
        first.stop()


def test_parse_fault_spellings():
    assert parse_fault("lost-ok") == LostOk()
    assert parse_fault("lost-ok:G4") == LostOk(match="G4")
    assert parse_fault("garble:status") == GarbledLine(what="status")
    assert parse_fault("delay:0.5:3") == Delay(seconds=0.5, count=3)
    assert parse_fault("alarm:1:0.25") == AlarmMidMove(code=1, fraction=0.25)
    assert parse_fault("reset") == ResetMidMove()
    assert parse_fault("vanish:0.9") == VanishMidMove(fraction=0.9)
    assert parse_fault("homing-fail") == HomingFail(code=9)
    assert parse_fault("homing-fail:8:silent") == HomingFail(code=8, alarm_line=False)
    for bad in ("explode", "delay", "garble:foo", "alarm:x", "homing-fail:3", "homing-fail:9:loud"):
        with pytest.raises(ValueError):
            parse_fault(bad)


# ---------------------------------------------------------------------------------------------- threads


def test_machine_position_is_readable_from_other_threads_during_motion(emulator, homed):
    samples: list[float] = []
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            samples.append(emulator.machine_position()["X"])
            time.sleep(0.001)

    thread = threading.Thread(target=sample)
    thread.start()
    try:
        homed.move_to({"X": -201.0}).wait(5.0)
    finally:
        stop.set()
        thread.join(2.0)
    assert samples == sorted(samples, reverse=True)  # monotonic along the move
    assert any(-201.0 < x < -1.0 for x in samples) and samples[-1] >= -201.0
    assert emulator.machine_position()["X"] == -201.0


def test_closing_leaves_no_threads_running():
    before = {t.name for t in threading.enumerate()}
    emu = GrblEmulator(time_scale=FAST).start()
    grbl = _controller(emu).open()
    names = {t.name for t in threading.enumerate()} - before
    assert any(n.startswith("grbl-emulator") for n in names) and any(n.startswith("grbl-reader") for n in names)
    grbl.close()
    emu.stop()
    time.sleep(0.05)
    left = {t.name for t in threading.enumerate()} - before
    assert not [n for n in left if n.startswith("grbl")]


# ---------------------------------------------------------------------------------------------- position trust


def test_a_boot_makes_the_position_unknown_even_with_homing_disabled():
    # An Uno with $22=0 reboots on open: MPos restarts at 0 wherever the carriage stands. The old driver refused
    # moves after a boot only when $22 was set, and so drove a rig from a position it could not know.
    with GrblEmulator(time_scale=FAST, homing_enabled=False, reboot_on_open=True,
                      start_position={"X": -50.0}) as emu, _controller(emu) as grbl:
        assert grbl.info.boot_detected and not grbl.locked and grbl.status().state == "Idle"
        with pytest.raises(GrblPositionUnknown, match="booted when the port was opened.*--trust-position"):
            grbl.move_to({"X": -100.0})
        assert emu.physical_position()["X"] == -50.0 and list(emu.lines_received)[-1] == "$#"  # nothing sent
        grbl.unlock(trust_position=True)  # the user states the counters are right (here: 50 mm off)
        grbl.move_to({"X": -100.0}).wait(5.0)
        assert emu.physical_position()["X"] == -150.0


def test_a_banner_3_s_late_is_a_boot():
    # grblHAL's simulator boots in ~3 s, so do slow bootloaders: later than the driver's 2 s boot window. The old
    # driver took that banner for the answer to its own soft reset and trusted the restarted counters. Real time:
    # the driver's own 2 s window is what is tested (3.5 s).
    with GrblEmulator(time_scale=1.0, homing_enabled=False, reboot_on_open=True, boot_delay_s=3.0) as emu:
        with GrblController(emu.tty_path, connect_timeout_s=6.0) as grbl:
            # The soft reset sent at 2 s went into the bootloader; its resend a second later may land just after the
            # boot (a second banner, still before any status report).
            assert grbl.info.boot_detected and emu.resets in (1, 2)
            with pytest.raises(GrblPositionUnknown, match="did not answer until it was reset"):
                grbl.move_to({"X": -10.0})


def test_a_late_banner_while_only_looking_is_a_boot_too():
    # reset_on_open=False (`rig status`, `resume`): the driver keeps asking '?' and the banner comes first.
    with GrblEmulator(time_scale=10.0, reboot_on_open=True, boot_delay_s=3.0) as emu:
        with _controller(emu, reset_on_open=False, boot_wait_s=0.1, connect_timeout_s=3.0) as grbl:
            assert grbl.info.boot_detected and emu.resets == 1
            assert grbl.position_unknown is not None and "booted when the port was opened" in grbl.position_unknown


def test_a_soft_reset_0_2_s_after_alarm_2_recovers():
    # report.c report_alarm_message waits 500 ms after ALARM:2, then protocol.c clears any reset received meanwhile:
    # the old driver's at-once reset was lost and it timed out. Real time, so that 0.2 s is inside the pause.
    with GrblEmulator(time_scale=1.0) as emu, _controller(emu) as grbl:
        grbl.unlock()
        with pytest.raises(GrblAlarm, match="ALARM:2"):
            grbl.move_to({"X": 5.0}).wait(5.0)  # past the switch: Grbl halts (the controller class does not check)
        time.sleep(0.2)
        t0 = time.monotonic()
        reading = grbl.soft_reset(timeout=3.0)
        assert reading.state == "Alarm" and emu.resets == 2 and not emu.halted  # the connect's reset, then this
        assert time.monotonic() - t0 < 1.0  # waited for [MSG:Reset to continue], ~0.3 s on


def test_the_emulator_drops_a_reset_inside_the_alarm_pause():
    with GrblEmulator(time_scale=1.0) as emu:
        port = serial.Serial(emu.tty_path, 115200, timeout=0.02)
        try:
            port.write(b"$X\nG53 G0 X5\n")
            received, deadline = b"", time.monotonic() + 2.0
            while b"ALARM:2" not in received and time.monotonic() < deadline:
                received += port.read(256)
            time.sleep(0.2)
            port.write(b"\x18")  # inside report_alarm_message's 500 ms: lost, as on the firmware
            time.sleep(0.6)
            received += port.read(512)
            assert b"[MSG:Reset to continue]" in received and b"Grbl 1.1h" not in received and emu.halted
            port.write(b"\x18")  # after the message: heard
            time.sleep(0.2)
            assert b"Grbl 1.1h" in port.read(512) and not emu.halted
        finally:
            port.close()


def test_after_alarm_1_and_a_reset_the_refusal_names_the_alarm(emulator, homed):
    emulator.inject(AlarmMidMove(code=1, fraction=0.5))
    with pytest.raises(GrblAlarm, match="ALARM:1"):
        homed.move_to({"X": -200.0}).wait(5.0)
    homed.soft_reset(timeout=3.0)  # at once: the driver waits out the firmware's pause itself
    with pytest.raises(GrblLocked, match=r"in Alarm after ALARM:1 \(Hard limit") as info:
        homed.move_to({"X": -10.0})
    assert "boot" not in str(info.value) and "reset unexpectedly" not in str(info.value)


def test_queries_a_controller_refuses_are_recorded_as_unsupported():
    # A dialect without $N (or $#) answers error:3: the old driver failed the connect, and so `rig home`.
    with GrblEmulator(time_scale=FAST, unsupported_queries=("$N", "$#")) as emu, _controller(emu) as grbl:
        assert grbl.info.unsupported == {"$N": "error:3", "$#": "error:3"}
        assert grbl.info.settings_read and grbl.info.startup_lines == {}
        assert grbl.home(timeout=5.0).machine_position == HOME


def test_the_emulator_stores_a_startup_line_when_idle_as_grbl_does():
    # system.c: "$Nx=line" is stored in Idle only ("Prevents motion during ALARM", error:8 in Alarm), after the
    # line is executed to check it.
    with GrblEmulator(time_scale=FAST) as emu, _controller(emu) as grbl:
        with pytest.raises(GrblCommandError) as info:
            grbl.send("$N0=G20")
        assert info.value.code == 8
        grbl.unlock()
        assert grbl.send("$N0=G20") == [] and emu.startup_lines[0] == "G20"


# ---------------------------------------------------------------------------------------------- hard limits


def test_hard_limits_halt_at_the_switch_and_check_limits_after_the_reset():
    # limits.c ISR(LIMIT_INT_vect): a switch that changes during motion is ALARM:1 at once; protocol.c
    # CHECK_LIMITS_AT_INIT: a reset with a switch closed is Alarm with [MSG:Check Limits].
    with GrblEmulator(time_scale=FAST, hard_limits=True) as emu, _controller(emu) as grbl:
        grbl.home(timeout=5.0)
        grbl.move_to({"X": -0.5}).wait(5.0)  # short of the switch at X = 0
        with pytest.raises(GrblAlarm, match="ALARM:1"):
            grbl.move_to({"X": 0.0}).wait(5.0)  # a target on the switch: soft limits accept it, the switch trips
        assert emu.halted and emu.physical_position()["X"] == 0.0
        assert grbl.soft_reset(timeout=3.0).state == "Alarm"
        assert "Check Limits" in grbl.messages
        grbl.unlock(trust_position=True)
        with pytest.raises(GrblAlarm, match="ALARM:1"):  # leaving the switch changes the pin too (no force check)
            grbl.move_to({"X": -5.0}).wait(5.0)
        grbl.soft_reset(timeout=3.0)
        assert grbl.home(timeout=5.0).machine_position == HOME  # homing disables hard limits for its cycle
