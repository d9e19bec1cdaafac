"""The real GRBL driver, through pyserial, against the GRBL emulator on a real pty.

Every fault ends in a recovered move or a clear error, within a bounded time; a reported position is
always one the controller reported (checked against the emulator's own state).
"""

from __future__ import annotations

import threading
import time

import pytest
import serial

from drivers.rig.grbl import (
    GrblAlarm,
    GrblCommandError,
    GrblConnectionError,
    GrblController,
    GrblLocked,
    GrblMoveError,
    GrblResetError,
    GrblTimeout,
)
from drivers.sim.grbl_emulator import (
    AlarmMidMove,
    AxisSpec,
    Delay,
    GarbledLine,
    GrblEmulator,
    LostOk,
    ResetMidMove,
    VanishMidMove,
    parse_fault,
)

FAST = 50.0  # emulator time scale: a 100 mm move takes 2.25 s simulated, 45 ms real


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


# ---------------------------------------------------------------------------------------------- basics


def test_boot_in_alarm_refuses_motion_until_homed(emulator, grbl):
    assert grbl.banner is not None and grbl.banner.text == "Grbl 1.1h ['$' for help]"
    assert grbl.locked and grbl.last_reading.state == "Alarm"
    assert "'$H'|'$X' to unlock" in grbl.messages
    received = len(emulator.lines_received)
    with pytest.raises(GrblLocked, match=r"home \(\$H\) or unlock"):
        grbl.move_to({"X": 10.0})
    assert len(emulator.lines_received) == received  # refused before any byte was sent
    reading = grbl.home(timeout=5.0)
    assert reading.state == "Idle" and not grbl.locked
    assert reading.machine_position == {"X": 0.0, "Y": 0.0, "Z": 0.0}
    assert emulator.homed


def test_move_waits_until_stopped_and_reports_the_controllers_position(emulator, homed):
    status = homed.move_to({"X": 100.0, "Y": 10.0, "Z": 5.0})
    assert not status.done
    time.sleep(0.01)  # accepted means planned: give it a few simulated mm
    during = homed.status(timeout=1.0)
    assert during.state == "Run"
    assert 0.0 < during.machine_position["X"] < 100.0
    reading = status.wait(5.0)
    assert status.done and status.success and status.reading is reading
    assert reading.state == "Idle"
    assert reading.machine_position == {"X": 100.0, "Y": 10.0, "Z": 5.0}
    assert _close_to(reading.machine_position, emulator.machine_position())
    assert abs(reading.timestamp - time.time()) < 5.0
    assert status.wait(0.01) is reading  # waiting again is free


def test_move_takes_the_simulated_time(emulator, homed):
    # X: 3000 mm/min, 200 mm/s^2 -> 100 mm in 2.25 s simulated; at x50, 45 ms of real time.
    t0 = time.monotonic()
    homed.move_to({"X": 100.0}).wait(5.0)
    elapsed = time.monotonic() - t0
    assert 0.045 <= elapsed < 1.0


def test_feed_move_and_callbacks(homed):
    finished = []
    status = homed.move_to({"Y": 30.0}, feed_per_min=900.0)
    status.add_callback(finished.append)
    status.wait(5.0)
    assert finished == [status]
    late = []
    status.add_callback(late.append)
    assert late == [status]


def test_feed_hold_then_resume(emulator, homed):
    status = homed.move_to({"X": 300.0}, feed_per_min=600.0)  # 30 s simulated: still moving when held
    time.sleep(0.05)
    homed.feed_hold()
    time.sleep(0.05)
    held = homed.status(timeout=1.0)
    assert held.full_state == "Hold:0"
    started = time.monotonic()
    with pytest.raises(GrblMoveError, match="feed hold"):  # not a wait into the timeout
        status.wait(5.0)
    assert time.monotonic() - started < 2.0
    assert emulator.state == "Hold:0"
    homed.resume()
    reading = homed.wait_idle(timeout=5.0)
    assert reading.machine_position["X"] == 300.0


def test_commands_feedback_and_errors(homed):
    assert homed.send("$I")[0].startswith("[VER:1.1h")
    settings = homed.send("$$")
    assert "$22=1" in settings and "$130=350" in settings
    with pytest.raises(GrblCommandError) as info:
        homed.send("G1 X10")  # no feed rate yet
    assert info.value.code == 22
    with pytest.raises(GrblCommandError) as info:
        homed.send("$J=G53 X500 F1000")  # jog past the travel: refused, no alarm
    assert info.value.code == 15 and "Travel exceeded" in str(info.value)
    assert homed.status().state == "Idle"


def test_locked_controller_answers_gcode_with_error_9(grbl):
    with pytest.raises(GrblCommandError) as info:
        grbl.send("G4 P0")
    assert info.value.code == 9 and "locked out" in str(info.value)
    grbl.unlock()
    assert not grbl.locked
    grbl.move_to({"Z": 2.0}).wait(5.0)


def test_axis_not_on_the_controller_is_refused_before_sending(emulator, homed):
    received = len(emulator.lines_received)
    with pytest.raises(Exception, match="axis A not on the controller"):
        homed.move_to({"A": 1.0})
    assert len(emulator.lines_received) == received


def test_soft_limit_in_the_controller_is_an_alarm_and_recovers(emulator, homed):
    # GrblRig refuses this before sending; the bare controller lets GRBL's own soft limits catch it.
    with pytest.raises(GrblAlarm) as info:
        homed.move_to({"X": 400.0}).wait(5.0)
    assert info.value.code == 2 and "Soft limit" in str(info.value)
    with pytest.raises(GrblAlarm, match="soft-reset"):
        homed.move_to({"X": 10.0})
    reading = homed.soft_reset()
    assert reading.state == "Alarm"  # position kept, but GRBL wants an unlock or homing
    homed.unlock()
    assert homed.move_to({"X": 10.0}).wait(5.0).machine_position["X"] == 10.0


def test_soft_reset_while_moving_raises_alarm_3(emulator, homed):
    homed.move_to({"X": 300.0}, feed_per_min=600.0)
    time.sleep(0.05)
    reading = homed.soft_reset()
    assert reading.state == "Alarm"
    assert homed.alarm is not None and homed.alarm.code == 3
    assert 0.0 < reading.machine_position["X"] < 300.0
    assert _close_to(reading.machine_position, emulator.machine_position())


def test_streaming_many_lines_never_overflows_the_receive_buffer(emulator, homed):
    lines = [f"G1 X{1 + i * 0.5:.3f} F3000" for i in range(60)]
    homed.stream(lines, timeout=20.0)
    reading = homed.wait_idle(timeout=20.0)
    assert reading.machine_position["X"] == pytest.approx(30.5)
    assert emulator.rx_overflow_bytes == 0
    assert 0 < emulator.max_rx_fill <= 127


def test_the_emulator_drops_bytes_past_its_buffer_like_grbl(emulator):
    # Without character counting: 60 lines at once while GRBL is busy overflow its 127 bytes.
    port = serial.Serial(emulator.tty_path, timeout=0.2)
    try:
        port.write(b"$X\nG4 P5\n" + b"G1 X1 F100\n" * 60)
        time.sleep(0.2)
        assert emulator.rx_overflow_bytes > 0
        assert emulator.max_rx_fill == 127
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


# ---------------------------------------------------------------------------------------------- variants


def test_status_fields_in_random_order_and_wpos_reports():
    with GrblEmulator(time_scale=FAST, shuffle_fields=True, status_mask=0 | 2, seed=3) as emu:
        with _controller(emu) as grbl:
            grbl.home(timeout=5.0)
            reading = grbl.move_to({"X": 12.5}).wait(5.0)
            assert reading.machine_position == {"X": 12.5, "Y": 0.0, "Z": 0.0}
            assert reading.work_position == {"X": 12.5, "Y": 0.0, "Z": 0.0}
            assert reading.rx_bytes_free == 128 and reading.planner_blocks_free == 15


def test_grblhal_six_axes():
    with GrblEmulator(time_scale=FAST, axes="XYZABC", firmware="grblhal") as emu:
        with _controller(emu, rx_buffer_size=1024) as grbl:
            assert grbl.banner.firmware == "GrblHAL" and grbl.axes == "XYZABC"
            grbl.home(timeout=5.0)
            reading = grbl.move_to({"X": 50.0, "A": -3.0, "B": 2.0, "C": 400.0}).wait(10.0)
            assert reading.machine_position == {"X": 50.0, "Y": 0.0, "Z": 0.0, "A": -3.0, "B": 2.0, "C": 400.0}


def test_step_quantisation_within_tolerance():
    specs = {"X": AxisSpec(travel=(0.0, 350.0), steps_per_unit=80.0)}
    with GrblEmulator(time_scale=FAST, axis_specs=specs) as emu:
        with _controller(emu) as grbl:
            grbl.home(timeout=5.0)
            reading = grbl.move_to({"X": 10.004}, tolerance=0.01).wait(5.0)
            assert reading.machine_position["X"] == 10.0  # 800 steps: what the controller reports


def test_homing_disabled_boots_idle_and_refuses_home():
    with GrblEmulator(time_scale=FAST, homing_enabled=False) as emu:
        with _controller(emu) as grbl:
            assert not grbl.locked
            with pytest.raises(GrblCommandError) as info:
                grbl.home(timeout=2.0)
            assert info.value.code == 5


def test_homing_timeout_stops_the_cycle_with_a_reset():
    with GrblEmulator(time_scale=1.0, homing_settle_s=60.0) as emu:
        with _controller(emu) as grbl:
            t0 = time.monotonic()
            with pytest.raises(GrblTimeout, match="homing .* did not finish"):
                grbl.home(timeout=0.3)
            assert time.monotonic() - t0 < 3.0
            assert emu.state == "Alarm" and not emu.homed
            assert grbl.alarm is not None and grbl.alarm.code == 6
            assert grbl.status().state == "Alarm"


def test_no_status_while_homing(emulator, grbl):
    emulator_slow = GrblEmulator(time_scale=1.0, homing_settle_s=0.5)
    with emulator_slow as emu, _controller(emu) as controller:
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


# ---------------------------------------------------------------------------------------------- faults


def test_lost_ok_of_the_move_is_recovered(emulator, homed):
    emulator.inject(LostOk(match="G53"))
    reading = homed.move_to({"X": 80.0}).wait(5.0)
    assert reading.machine_position["X"] == 80.0
    assert homed.lost_replies == 1
    # The link is in step again: the next move needs no recovery.
    homed.move_to({"X": 20.0}).wait(5.0)
    assert homed.lost_replies == 1


def test_lost_ok_of_the_dwell_is_recovered(emulator, homed):
    emulator.inject(LostOk(match="G4"))
    reading = homed.move_to({"Y": 45.0}).wait(5.0)
    assert reading.machine_position["Y"] == 45.0 and homed.lost_replies == 1


def test_lost_ok_of_homing_is_recovered(emulator, grbl):
    emulator.inject(LostOk(match="$H"))
    reading = grbl.home(timeout=1.0)
    assert reading.state == "Idle" and grbl.lost_replies == 1
    assert grbl.move_to({"X": 5.0}).wait(5.0).machine_position["X"] == 5.0


def test_garbled_ok_is_recovered(emulator, homed):
    emulator.inject(GarbledLine(what="ok"))
    reading = homed.move_to({"Z": 30.0}).wait(5.0)
    assert reading.machine_position["Z"] == 30.0
    assert homed.garbled_lines == 1 and homed.lost_replies == 1


def test_garbled_status_is_never_reported(emulator, homed):
    homed.move_to({"X": 42.0}).wait(5.0)
    emulator.inject(GarbledLine(what="status", count=3))
    reading = homed.status(timeout=3.0)
    assert reading.machine_position == {"X": 42.0, "Y": 0.0, "Z": 0.0}
    assert homed.garbled_lines == 3


def test_delayed_replies_are_waited_for(emulator, homed):
    emulator.inject(Delay(seconds=0.3, count=2, what="ok"))
    t0 = time.monotonic()
    reading = homed.move_to({"X": 10.0}).wait(5.0)
    assert reading.machine_position["X"] == 10.0
    assert time.monotonic() - t0 >= 0.3
    assert homed.lost_replies == 0


def test_a_delay_past_the_timeout_is_a_clear_timeout_not_a_hang(emulator, homed):
    emulator.inject(Delay(seconds=3.0, what="any"))
    t0 = time.monotonic()
    with pytest.raises(GrblTimeout, match="no answer"):
        homed.move_to({"X": 10.0}, timeout_s=0.5)
    assert time.monotonic() - t0 < 2.0


def test_alarm_mid_move_is_an_error_then_recovers_by_reset_and_homing(emulator, homed):
    emulator.inject(AlarmMidMove(code=1, fraction=0.5))
    with pytest.raises(GrblAlarm) as info:
        homed.move_to({"X": 200.0}).wait(5.0)
    assert info.value.code == 1 and "Hard limit" in str(info.value)
    stopped = homed.status()
    assert stopped.state == "Alarm"
    assert 0.0 < stopped.machine_position["X"] < 200.0  # where it really stopped, as reported
    assert _close_to(stopped.machine_position, emulator.machine_position())
    with pytest.raises(GrblAlarm, match="soft-reset it, then home"):
        homed.move_to({"X": 10.0})
    homed.soft_reset()
    homed.home(timeout=5.0)
    assert homed.move_to({"X": 10.0}).wait(5.0).machine_position["X"] == 10.0


def test_spontaneous_reset_mid_move_is_an_error_and_needs_homing(emulator, homed):
    emulator.inject(ResetMidMove(fraction=0.3))
    with pytest.raises(GrblResetError, match="reset unexpectedly"):
        homed.move_to({"X": 150.0}).wait(5.0)
    with pytest.raises(GrblLocked, match="reset unexpectedly"):
        homed.move_to({"X": 10.0})
    homed.home(timeout=5.0)
    assert homed.move_to({"X": 10.0}).wait(5.0).machine_position["X"] == 10.0


def test_port_vanishing_mid_move_is_a_connection_error(emulator, homed):
    emulator.inject(VanishMidMove(fraction=0.5))
    t0 = time.monotonic()
    with pytest.raises(GrblConnectionError, match="lost the connection"):
        homed.move_to({"X": 100.0}).wait(5.0)
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


def test_parse_fault_spellings():
    assert parse_fault("lost-ok") == LostOk()
    assert parse_fault("lost-ok:G4") == LostOk(match="G4")
    assert parse_fault("garble:status") == GarbledLine(what="status")
    assert parse_fault("delay:0.5:3") == Delay(seconds=0.5, count=3)
    assert parse_fault("alarm:1:0.25") == AlarmMidMove(code=1, fraction=0.25)
    assert parse_fault("reset") == ResetMidMove()
    assert parse_fault("vanish:0.9") == VanishMidMove(fraction=0.9)
    for bad in ("explode", "delay", "garble:foo", "alarm:x"):
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
        homed.move_to({"X": 200.0}).wait(5.0)
    finally:
        stop.set()
        thread.join(2.0)
    assert samples == sorted(samples)  # monotonic along the move
    assert any(0.0 < x < 200.0 for x in samples) and samples[-1] <= 200.0
    assert emulator.machine_position()["X"] == 200.0


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
