"""The emulator's grblHAL mode against grblHAL's own source, and the driver against it over a real pty.

What grblHAL does differently from Grbl 1.1h (grblHAL/core report.c, machine_limits.c, settings.c, grbllib.c;
the Simulator driver's driver.c): ``$I`` has tagged lines whose tags may hold spaces and an extended ``[OPT:]``;
``$22`` is a bitfield and ``$22=1`` (no "homing on startup required") boots Idle; soft limits apply to homed axes
only, within an envelope one pull-off off each end when hard limits are on; the ALARM pause is 100 ms; a failed
homing is not followed by a late ``ok``; ``$481`` makes it report its status unasked.
"""

from __future__ import annotations

import time

import pytest
import serial

from drivers.rig import GrblRig
from drivers.rig.config import MachineSpaceError, rig_config_from_dict
from drivers.rig.grbl import GrblAlarm, GrblController, GrblPositionUnknown
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.faults import HomingFail

FAST = 50.0


def _controller(emu: GrblEmulator, **kwargs) -> GrblController:
    options = dict(connect_timeout_s=3.0, ok_grace_s=0.2, poll_interval_s=0.02, rx_buffer_size=1024)
    options.update(kwargs)
    return GrblController(emu.tty_path, **options)


def _lines(emu: GrblEmulator, data: bytes, until: bytes, wait_s: float = 2.0) -> list[str]:
    port = serial.Serial(emu.tty_path, 115200, timeout=0.02)
    try:
        port.write(data)
        received, deadline = b"", time.monotonic() + wait_s
        while until not in received and time.monotonic() < deadline:
            received += port.read(512)
        time.sleep(0.05)
        received += port.read(512)
        return [line for line in received.decode("latin-1").split("\r\n") if line]
    finally:
        port.close()


def test_build_info_transcript():
    # report.c report_build_info for the Simulator driver: V (variable spindle), N, M (mist), L ($22 bit 2 clear),
    # + (safety door), W (WCO sync off); 100 planner blocks, 1024 bytes, 3 axes, 0 tools; then the extended lines.
    with GrblEmulator(time_scale=FAST, firmware="grblhal") as emu:
        lines = _lines(emu, b"$I\n", until=b"ok\r\n")
    assert lines == ["[VER:1.1f.20231210:]", "[OPT:VNML+W,100,1024,3,0]", "[AXS:3:XYZ]",
                     "[NEWOPT:ENUMS,RT+,HOME,TC,SED]", "[FIRMWARE:grblHAL]", "[NVS STORAGE:*EEPROM]",
                     "[DRIVER:Simulator]", "[DRIVER VERSION:260913]", "ok"]


def test_the_driver_reads_grblhals_build_info_without_unparsable_lines():
    # The old codec took a tag holding a space for noise: "unparsable line" on every connect.
    with GrblEmulator(time_scale=FAST, firmware="grblhal") as emu, _controller(emu) as grbl:
        info = grbl.info
        assert grbl.garbled_lines == 0
        assert info.dialect == "GrblHAL" and info.options == "VNML+W" and info.axis_count == 3
        assert (info.planner_blocks, info.rx_buffer_size) == (100, 1024)
        assert info.build_tags["NVS STORAGE"] == "*EEPROM" and info.build_tags["DRIVER VERSION"] == "260913"
        assert info.settings[22] == 1 and info.homing_enabled and not info.boots_locked


def test_it_boots_idle_with_homing_enabled_and_the_driver_still_refuses_to_move():
    # $22=1 without bit 2: no homing lock at startup (machine_limits.c limits_homing_required). The controller
    # would move; the driver refuses, the position being unknown after the boot.
    with GrblEmulator(time_scale=FAST, firmware="grblhal", reboot_on_open=True) as emu, _controller(emu) as grbl:
        assert grbl.info.boot_detected and grbl.status().state == "Idle" and not grbl.locked
        with pytest.raises(GrblPositionUnknown):
            grbl.move_to({"X": -10.0})
        assert grbl.home(timeout=5.0).machine_position == {"X": -1.0, "Y": -1.0, "Z": -1.0}
        assert grbl.last_reading.raw.endswith("|H:1>")  # the first report after the cycle: all homed


def test_soft_limits_apply_to_homed_axes_only_so_the_driver_refuses_with_the_right_reason():
    # machine_limits.c check_travel_limits: only homed axes are checked. After $X (no homing) a target past the
    # switch runs; the driver's own machine-space check is then the only safety, and says why.
    with GrblEmulator(time_scale=FAST, firmware="grblhal") as emu:
        lines = _lines(emu, b"G53 G0 X5\nG4 P0\n?", until=b">\r\n")
        assert "ALARM:2" not in lines and emu.machine_position()["X"] == 5.0  # ran past the switch
    config = rig_config_from_dict({"quantities": {"baseline_mm": {"axis": "X", "offset": -350, "min": 0, "max": 360}}})
    with GrblEmulator(time_scale=FAST, firmware="grblhal") as emu:
        with GrblRig(emu.tty_path, config, connect_timeout_s=3.0, rx_buffer_size=1024) as rig:
            rig.trust_position()
            sent = list(emu.lines_received)
            with pytest.raises(MachineSpaceError, match="X=5 is outside the controller's work envelope X -350..0 "
                                                        r"\(\$130=350; grblHAL checks soft limits only on homed axes"):
                rig.move_to(baseline_mm=355.0).wait()
            assert list(emu.lines_received) == sent  # refused before a byte was sent
            rig.home()
            with pytest.raises(MachineSpaceError, match="soft limits would halt it with ALARM:2"):
                rig.move_to(baseline_mm=355.0).wait()


def test_after_homing_the_envelope_keeps_a_pull_off_off_the_switches_with_hard_limits():
    # machine_limits.c limits_set_work_envelope: hard limits on, [-$13x + $27, -$27] = [-349, -1] on X.
    with GrblEmulator(time_scale=FAST, firmware="grblhal", hard_limits=True) as emu, _controller(emu) as grbl:
        assert grbl.info.machine_space("X") == (-349.0, -1.0)
        grbl.home(timeout=5.0)
        grbl.move_to({"X": -1.0}).wait(5.0)
        with pytest.raises(GrblAlarm, match="ALARM:2"):
            grbl.move_to({"X": -0.5}).wait(5.0)
        assert grbl.soft_reset(timeout=3.0).state == "Alarm"


def test_a_failed_homing_gets_no_late_ok():
    with GrblEmulator(time_scale=FAST, firmware="grblhal", faults=[HomingFail(code=9)]) as emu:
        lines = _lines(emu, b"$H\n", until=b"unlock]\r\n", wait_s=5.0)
    assert lines == ["ALARM:9", "GrblHAL 1.1f ['$' or '$HELP' for help]", "[MSG:'$H'|'$X' to unlock]"]  # no ok
    with GrblEmulator(time_scale=FAST, firmware="grblhal", faults=[HomingFail(code=9)]) as emu:
        with _controller(emu) as grbl:
            with pytest.raises(GrblAlarm, match="ALARM:9"):
                grbl.home(timeout=5.0)
            assert grbl.stray_replies == 0


def test_status_reports_sent_unasked_every_20_ms_do_not_confuse_the_driver():
    # grbllib.c auto_realtime_report: with $481 = 20 a report every 20 ms, asked or not.
    with GrblEmulator(time_scale=1.0, firmware="grblhal", report_interval_ms=20) as emu:
        time.sleep(0.2)
        assert emu.status_reports_sent >= 5  # nobody asked
        with _controller(emu) as grbl:
            grbl.unlock(trust_position=True)
            assert grbl.move_to({"X": -2.0}).wait(5.0).machine_position["X"] == -2.0
            assert grbl.lost_replies == 0 and grbl.garbled_lines == 0
