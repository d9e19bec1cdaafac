"""GRBL 1.1 codec: pure parsing/encoding, and the driver against scripted request/reply pairs (no port at all).

The scripted tests follow pymeasure's ``expected_protocol``: each write must be the next scripted
request, and the test fails if any pair is left unused.
"""

from __future__ import annotations

import io
import json
import threading
import time

import pytest

from drivers.rig import RigError, codec
from drivers.rig.grbl import (
    GrblAlarm,
    GrblCommandError,
    GrblConnectionError,
    GrblController,
    GrblLocked,
    GrblResetError,
    GrblSettingsError,
    GrblTimeout,
)
from drivers.rig.transport import ScriptedTransport, SpyTransport, expected_protocol, script_from_spy_log

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
IDLE = b"<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n"


# ---------------------------------------------------------------------------------------------------- parsing


def test_status_report_with_fields_in_any_order():
    a = codec.parse_status("<Idle|MPos:1.000,2.500,-3.250|FS:500,0|WCO:0.000,1.000,0.000|Pn:XZ|Ov:100,90,100>")
    b = codec.parse_status("<Idle|Ov:100,90,100|Pn:XZ|WCO:0.000,1.000,0.000|FS:500,0|MPos:1.000,2.500,-3.250>")
    for report in (a, b):
        assert report.state == "Idle" and report.substate is None
        assert report.mpos == (1.0, 2.5, -3.25)
        assert report.wco == (0.0, 1.0, 0.0)
        assert report.feed == 500.0 and report.spindle == 0.0
        assert report.pins == "XZ"
        assert report.overrides == (100, 90, 100)


def test_status_report_substate_buffer_line_and_unknown_fields_kept():
    report = codec.parse_status("<Hold:1|WPos:10.000,0.000,0.000|Bf:15,128|Ln:42|F:300|H:1,7|A:SFM>")
    assert report.state == "Hold" and report.substate == 1 and report.full_state == "Hold:1"
    assert report.wpos == (10.0, 0.0, 0.0) and report.mpos is None
    assert (report.planner_blocks_free, report.rx_bytes_free) == (15, 128)
    assert report.line_number == 42 and report.feed == 300.0
    assert report.accessories == "SFM"
    assert report.homed is True and report.homed_mask == 7  # grblHAL's homed field (report.c)
    assert report.extra == {}


def test_six_axis_grblhal_report():
    report = codec.parse_status("<Run|MPos:1.000,2.000,3.000,4.000,5.000,6.000|FS:1200,0>")
    assert report.axis_count == 6
    assert codec.split_axes(report.mpos) == {"X": 1.0, "Y": 2.0, "Z": 3.0, "A": 4.0, "B": 5.0, "C": 6.0}


def test_machine_position_from_wpos_needs_a_wco():
    report = codec.parse_status("<Idle|WPos:10.000,5.000,0.000|FS:0,0>")
    assert codec.machine_position(report, None) is None  # unknown, not zero
    assert codec.machine_position(report, (1.0, 2.0, 3.0)) == (11.0, 7.0, 3.0)
    with_wco = codec.parse_status("<Idle|WPos:10.000,5.000,0.000|WCO:-1.000,0.000,0.000>")
    assert codec.machine_position(with_wco, (1.0, 2.0, 3.0)) == (9.0, 5.0, 0.0)


@pytest.mark.parametrize("line", [
    "<Idle|MPos:1.0,2\xff.0,3.0|FS:0,0>",  # a garbled byte
    "<Idle|MPos:1.000,2.000",  # cut short
    "<Idel|MPos:0,0,0>",  # unknown state
    "<Idle|MPos:1,2,3|WPos:1,2,3>",  # both positions
    "<Idle|MPos:1,2,3|WCO:0,0>",  # axis counts disagree
    "<Idle|MPos:1,2,3|MPos:1,2,3>",  # repeated field
    "<Idle|MPos:nan,2,3>",
    "<Idle|FS:1>",
])
def test_malformed_status_is_rejected_not_half_read(line):
    with pytest.raises(codec.ParseError):
        codec.parse_status(line)
    assert isinstance(codec.parse_response(line), codec.Unparsed)


def test_responses_are_classified():
    assert codec.parse_response("ok") == codec.Ok()
    err = codec.parse_response("error:22")
    assert err == codec.ErrorReply(22) and "feed rate" in err.meaning.lower()
    alarm = codec.parse_response("ALARM:1")
    assert alarm == codec.AlarmPush(1) and "Hard limit" in alarm.meaning
    assert codec.parse_response("[MSG:'$H'|'$X' to unlock]") == codec.Message(codec.UNLOCK_MESSAGE)
    assert codec.parse_response("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]") == codec.Feedback(
        "GC", "G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0")
    assert codec.parse_response("$110=3000.000") == codec.Setting(110, "3000.000")
    assert codec.parse_response("o\xffk") == codec.Unparsed("o\xffk")


def test_startup_lines_and_their_echo_are_parsed_not_garbled():
    # report.c: '$N' lists "$N0=G20"; after a reset Grbl echoes each startup line it ran, ">G20:ok".
    assert codec.parse_response("$N0=G20") == codec.StartupLine(0, "G20")
    assert codec.parse_response("$N1=") == codec.StartupLine(1, "")
    echo = codec.parse_response(">G20:ok")
    assert echo == codec.StartupEcho("G20", "ok") and echo.ok
    failed = codec.parse_response(">G0X5:error:9")
    assert failed == codec.StartupEcho("G0X5", "error:9") and not failed.ok
    assert codec.parse_startup_lines(["$N0=G20", "$N1=", "ok"]) == {0: "G20", 1: ""}


def test_build_info_and_settings_answers():
    info = codec.parse_build_info(["[VER:1.1h.20190830:my rig]", "[OPT:VZ,15,128]"])
    assert (info.version, info.user_info, info.options) == ("1.1h.20190830", "my rig", "VZ")
    assert (info.planner_blocks, info.rx_buffer_size) == (15, 128)
    settings = codec.parse_settings(["$0=10", "$11=0.010", "$130=200.000", "[MSG:x]"])
    assert settings == {0: 10.0, 11: 0.01, 130: 200.0}


def test_machine_space_follows_homing_direction_and_build():
    settings = {22: 1, 23: 0b010, 130: 200.0, 131: 90.0}
    # limits.c: homed to -$27 from the switch, machine space [-$13x, 0] whatever $23 says ...
    assert codec.soft_limit_space(settings, "V", "X") == (-200.0, 0.0)
    assert codec.soft_limit_space(settings, "V", "Y") == (-90.0, 0.0)
    # ... except on a HOMING_FORCE_SET_ORIGIN build ('Z'), for the axes homing toward - ($23 bit set).
    assert codec.soft_limit_space(settings, "VZ", "X") == (-200.0, 0.0)
    assert codec.soft_limit_space(settings, "VZ", "Y") == (0.0, 90.0)
    assert codec.soft_limit_space({**settings, 22: 0}, "V", "X") is None  # no homing: no fixed frame


def test_grblhal_build_info_tags_with_spaces_and_the_extended_opt():
    # report.c report_build_info: "[NVS STORAGE:...]" and "[DRIVER VERSION:...]" are feedback, not noise.
    lines = ["[VER:1.1f.20231210:]", "[OPT:VNML+W,100,1024,3,0]", "[AXS:3:XYZ]", "[NEWOPT:ENUMS,RT+,HOME,TC,SED]",
             "[FIRMWARE:grblHAL]", "[NVS STORAGE:*EEPROM]", "[DRIVER:Simulator]", "[DRIVER VERSION:260913]", "ok"]
    assert codec.parse_response("[NVS STORAGE:*EEPROM]") == codec.Feedback("NVS STORAGE", "*EEPROM")
    info = codec.parse_build_info(lines)
    assert (info.options, info.planner_blocks, info.rx_buffer_size, info.axis_count, info.tool_count) == (
        "VNML+W", 100, 1024, 3, 0)
    assert info.firmware == "grblHAL" and info.tags["DRIVER VERSION"] == "260913" and info.tags["AXS"] == "3:XYZ"
    assert not any(isinstance(codec.parse_response(line), codec.Unparsed) for line in lines)


def test_grblhal_status_fields():
    # report.c report_realtime_status: Alarm substate, FS with the measured rpm, A:, H:, TLR:, and flags without a
    # value (|AR) on a full report.
    report = codec.parse_status("<Alarm:11|MPos:0.000,0.000,0.000|FS:0,0,0|Pn:XZ|WCO:0.000,0.000,0.000|A:|H:0|"
                                "TLR:0|FW:grblHAL|AR>")
    assert (report.state, report.substate, report.feed, report.spindle) == ("Alarm", 11, 0.0, 0.0)
    assert report.accessories == "" and report.homed is False and report.homed_mask is None
    assert report.extra == {"TLR": "0", "FW": "grblHAL", "AR": ""}
    for bad in ("<Idle|MPos|FS:0,0>", "<Idle|MPos:0,0,0|FS:0,0,0,0>", "<Idle|MPos:0,0,0|x y:1>"):
        assert isinstance(codec.parse_response(bad), codec.Unparsed), bad


def test_grblhal_bitfields_and_work_envelope():
    # settings.c: $22 bit 0 enables homing (bit 2: homing required at startup, bit 3: set origin to 0); $21 bit 0
    # hard limits. machine_limits.c limits_set_work_envelope: one pull-off off each end with hard limits.
    settings = {21: 0, 22: 5, 23: 0b010, 27: 2.0, 130: 200.0, 131: 90.0}
    assert codec.homing_enabled(settings) and not codec.hard_limits_enabled(settings)
    assert codec.setting_bit(settings, 22, 2) and not codec.setting_bit(settings, 22, 3)
    assert codec.soft_limit_space(settings, "VNM", "X", firmware="GrblHAL") == (-200.0, 0.0)
    hard = {**settings, 21: 3}  # enable + strict mode
    assert codec.soft_limit_space(hard, "VNM", "X", firmware="GrblHAL") == (-198.0, -2.0)
    assert codec.soft_limit_space(hard, "VNMZ", "X", firmware="GrblHAL") == (-198.0, 0.0)
    assert codec.soft_limit_space(hard, "VNMZ", "Y", firmware="GrblHAL") == (0.0, 88.0)  # $23 axis
    assert codec.soft_limit_space(hard, "V", "X") == (-200.0, 0.0)  # Grbl 1.1h: hard limits change nothing
    assert codec.soft_limit_space({**hard, 22: 4}, "VNM", "X", firmware="GrblHAL") is None  # bit 0 clear


def test_switch_positions():
    # limits.c limits_go_home: the switch is one pull-off beyond where homing leaves the axis.
    settings = {22: 1, 23: 0b010, 27: 1.5, 130: 200.0, 131: 90.0}
    assert codec.switch_position(settings, "V", "X") == 0.0
    assert codec.switch_position(settings, "V", "Y") == -90.0  # homes toward -: its switch at -$131
    assert codec.switch_position(settings, "VZ", "X") == 1.5 and codec.switch_position(settings, "VZ", "Y") == -1.5
    assert codec.switch_position({**settings, 22: 0}, "V", "X") is None


def test_startup_line_hazards():
    assert codec.startup_line_hazards("G20") == ["G20 switches the controller to inches"]
    assert codec.startup_line_hazards("G21 G90 (safe)") == []
    assert codec.startup_line_hazards("G91.1") == []  # arc distance mode, not G91
    assert codec.startup_line_hazards("G0 X-10") == ["it moves the axes"]


def test_banners_grbl_and_grblhal():
    grbl = codec.parse_response("Grbl 1.1h ['$' for help]")
    assert grbl == codec.Banner("Grbl", "1.1h", "Grbl 1.1h ['$' for help]")
    hal = codec.parse_response("GrblHAL 1.1f ['$' or '$HELP' for help]")
    assert isinstance(hal, codec.Banner) and hal.firmware == "GrblHAL" and hal.version == "1.1f"


def test_every_grbl_error_and_alarm_has_a_meaning():
    for code in [*range(1, 18), *range(20, 39)]:
        assert codec.error_meaning(code) and "unknown" not in codec.error_meaning(code)
    for code in range(1, 10):
        assert "unknown" not in codec.alarm_meaning(code)
    assert codec.error_meaning(99) == "unknown GRBL error 99"


def test_line_splitter_handles_chunks_and_crlf():
    splitter = codec.LineSplitter()
    assert splitter.feed(b"o") == []
    assert splitter.feed(b"k\r\n<Idle|MPos:0.000,0.000,0.000>\r") == ["ok", "<Idle|MPos:0.000,0.000,0.000>"]
    assert splitter.feed(b"\nerror:9\r\n") == ["error:9"]


# ---------------------------------------------------------------------------------------------------- encoding


def test_encode_move_machine_coordinates_in_mm_and_absolute():
    # Units and distance mode are the controller's modal state: every motion line sets them itself.
    assert codec.encode_move({"Y": -5, "X": -100}) == "G21 G90 G53 G0 X-100.000 Y-5.000"
    assert codec.encode_move({"X": -0.0001, "Z": 1.23456}, feed_per_min=1500) == (
        "G21 G90 G53 G1 X0.000 Z1.235 F1500.0")
    with pytest.raises(codec.EncodeError):
        codec.encode_move({})
    with pytest.raises(codec.EncodeError):
        codec.encode_move({"Q": 1.0})
    with pytest.raises(codec.EncodeError):
        codec.encode_move({"X": float("nan")})
    with pytest.raises(codec.EncodeError):
        codec.encode_move({"X": 1.0}, feed_per_min=0.0)


def test_encode_line_refuses_realtime_characters_and_overlong_lines():
    assert codec.encode_line("  G4 P0 ") == b"G4 P0\n"
    for bad in ("G0 X1?", "G0 X1!", "G0\x18", "G0 X1~", "G0\nX1", "G0 X1 é"):
        with pytest.raises(codec.EncodeError):
            codec.encode_line(bad)
    with pytest.raises(codec.EncodeError):
        codec.encode_line("G1 " + "X1.000 " * 20)
    # Grbl keeps 79 characters once spaces are dropped: a 6-axis move with spaces still fits.
    six = codec.encode_move({"X": -350, "Y": -90, "Z": -90, "A": -90, "B": -90, "C": -2000}, feed_per_min=12000)
    assert len(six) > 79 and codec.encode_line(six)


def test_encode_error_is_a_rig_error():
    # One 'except RigError' in a caller (the CLI, the campaign runner) covers a line that cannot be sent.
    with pytest.raises(RigError):
        codec.encode_line("G0 X1?")


def test_vector_feed_keeps_every_axis_within_its_own_rate():
    # X moves 30, Y moves 40 (path 50): Y is the slower axis at 600/min -> F = 600 * 50 / 40 = 750.
    assert codec.vector_feed({"X": 30.0, "Y": 40.0}, {"X": 3000.0, "Y": 600.0}) == pytest.approx(750.0)
    assert codec.vector_feed({"X": 30.0, "Y": 0.0}, {"X": 3000.0, "Y": None}) == pytest.approx(3000.0)
    assert codec.vector_feed({"X": 30.0, "Y": 1.0}, {"X": 3000.0, "Y": None}) is None  # rapid
    assert codec.vector_feed({"X": 0.0}, {"X": 3000.0}) is None


# ---------------------------------------------------------------------------------------------------- scripted


def _controller(transport, **kwargs) -> GrblController:
    # Most scripts leave out the $I/$$/$N reads; test_connect_reads_build_settings_and_startup_lines has them.
    options = dict(reset_on_open=True, connect_timeout_s=2.0, status_retry_s=0.2, read_settings=False)
    options.update(kwargs)
    return GrblController(transport, **options)


ALARM_REPORT = b"<Alarm|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n"
SETTINGS = b"".join(f"${n}={v}\r\n".encode() for n, v in [
    (10, 1), (13, 0), (20, 1), (22, 1), (23, 0), (27, "1.000"), (100, "250.000"), (101, "250.000"),
    (102, "250.000"), (130, "350.000"), (131, "90.000"), (132, "90.000")])


#: report.c report_ngc_parameters of Grbl 1.1h, three axes, nothing set.
PARAMETERS = b"".join(b"[" + name + b":0.000,0.000,0.000]\r\n"
                      for name in (b"G54", b"G55", b"G56", b"G57", b"G58", b"G59", b"G28", b"G30", b"G92")
                      ) + b"[TLO:0.000]\r\n[PRB:0.000,0.000,0.000:0]\r\n"


def _settings_script(settings: bytes = SETTINGS, startup: bytes = b"$N0=\r\n$N1=\r\n", opt: bytes = b"V,15,128"):
    return [
        (b"$I\n", b"[VER:1.1h.20190830:]\r\n[OPT:" + opt + b"]\r\nok\r\n"),
        (b"$$\n", settings + b"ok\r\n"),
        (b"$N\n", startup + b"ok\r\n"),
        (b"$#\n", PARAMETERS + b"ok\r\n"),
    ]


def test_connect_resets_waits_for_banner_and_sees_boot_alarm():
    with expected_protocol([
        (b"?", ALARM_REPORT),  # running: answers at once, so it did not just boot
        (b"\x18", BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"),
        (b"?", ALARM_REPORT),
    ]) as transport:
        with _controller(transport) as grbl:
            assert grbl.banner.version == "1.1h"
            assert grbl.locked
            assert grbl.axes == "XYZ"
            with pytest.raises(GrblLocked, match="homing required"):
                grbl.move_to({"X": 10.0})  # refused: the script would fail on any write
            assert not grbl.info.boot_detected


def test_a_banner_before_any_report_is_a_boot_at_connect():
    # An Arduino's auto-reset: the bootloader swallows the first '?', Grbl then boots and prints its banner.
    with expected_protocol([
        (b"?", b""),
        (b"?", BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"),
        (b"?", ALARM_REPORT),  # no soft reset: it has just booted
    ]) as transport:
        with _controller(transport, status_retry_s=0.3) as grbl:  # one retry, even on a busy machine
            assert grbl.info.boot_detected and grbl.locked
            assert "position is unknown" in grbl.info.warnings[0]
            assert "booted when the port was opened" in grbl.position_unknown


class _RebootsOnDtr(ScriptedTransport):
    """A board that reboots when DTR is pulsed and prints its banner before the driver asks anything."""

    def pulse_dtr(self) -> bool:
        self.push(BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n")
        time.sleep(0.1)  # the reader thread has long dispatched it when the driver starts to listen
        return True


def test_a_banner_that_came_before_the_first_question_is_still_a_boot():
    # The race the full suite found: a fast boot's banner arrived before the driver looked for one.
    transport = _RebootsOnDtr([(b"?", ALARM_REPORT), (b"?", ALARM_REPORT)])
    with _controller(transport, pulse_dtr_on_open=True) as grbl:
        assert grbl.info.boot_detected and "booted when the port was opened" in grbl.position_unknown
    transport.check()


def test_connect_reads_build_settings_and_startup_lines():
    with expected_protocol([
        (b"?", ALARM_REPORT), (b"\x18", BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"), (b"?", ALARM_REPORT),
        *_settings_script(startup=b"$N0=G20\r\n$N1=\r\n", opt=b"V,15,256"),
    ]) as transport:
        with _controller(transport, read_settings=True) as grbl:
            info = grbl.info
            assert info.build == "1.1h.20190830" and info.options == "V" and info.planner_blocks == 15
            assert info.settings[130] == 350.0 and info.steps_per_unit("Y") == 250.0
            assert info.machine_space("X") == (-350.0, 0.0)
            assert info.startup_lines == {0: "G20", 1: ""}
            # One line per conflict: the buffer size the firmware reports wins; a G20 startup line is a trap.
            assert grbl.rx_buffer_size == 256
            assert any("receive buffer is 256 bytes" in w and "not the configured 128" in w for w in info.warnings)
            assert any("$N0=G20" in w and "inches" in w for w in info.warnings)
            data = json.loads(json.dumps(info.to_dict()))
            assert data["settings"]["$130"] == 350 and data["startup_lines"] == ["G20", ""]
            assert data["rx_buffer_size"] == 256 and data["boot_detected"] is False


def test_inches_reporting_is_refused_at_connect():
    inches = SETTINGS.replace(b"$13=0", b"$13=1")
    with expected_protocol([(b"?", ALARM_REPORT), *_settings_script(settings=inches)]) as transport:
        grbl = _controller(transport, read_settings=True, reset_on_open=False)
        with pytest.raises(GrblSettingsError, match=r"\$13=1: the controller reports positions in inches"):
            grbl.open()
        assert not grbl.is_open


def test_home_then_move_waits_with_g4_p0():
    with expected_protocol([
        (b"?", ALARM_REPORT),
        (b"\x18", BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"),
        (b"?", b"<Alarm|MPos:0.000,0.000,0.000|FS:0,0>\r\n"),
        (b"$H\n", b"ok\r\n"),
        (b"?", b"<Idle|MPos:-1.000,-1.000,-1.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n"),
        (b"G21 G90 G53 G0 X-120.000 Y-5.000 Z-5.000\n", b"ok\r\n"),
        (b"G4 P0\n", b"ok\r\n"),
        (b"?", b"<Idle|MPos:-120.000,-5.000,-5.000|FS:0,0>\r\n"),
    ]) as transport:
        with _controller(transport, poll_interval_s=10.0) as grbl:
            assert grbl.home(timeout=2.0).machine_position == {"X": -1.0, "Y": -1.0, "Z": -1.0}
            status = grbl.move_to({"X": -120.0, "Y": -5.0, "Z": -5.0})
            reading = status.wait(2.0)
            assert status.done and status.success
            assert reading.machine_position == {"X": -120.0, "Y": -5.0, "Z": -5.0}


def test_failed_homing_keeps_the_h_outstanding_for_its_late_ok():
    # limits.c/system.c: ALARM:9, then the late 'ok' of $H, then the reboot. The old driver took that 'ok'
    # as the answer to the next line ($X), which Grbl had discarded in its reset.
    with expected_protocol([
        (b"?", ALARM_REPORT), (b"\x18", BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"), (b"?", ALARM_REPORT),
        (b"$H\n", b"ALARM:9\r\nok\r\n" + BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"),
        (b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n"),
        (b"?", IDLE),
    ]) as transport:
        with _controller(transport) as grbl:
            with pytest.raises(GrblAlarm, match="ALARM:9.*homing failed"):
                grbl.home(timeout=2.0)
            assert grbl.locked and "homing failed" in grbl.position_unknown
            assert grbl.stray_replies == 0
            assert grbl.unlock().state == "Idle"  # its own 'ok', and no "reset unexpectedly"


def test_error_reply_carries_grbl_meaning():
    with expected_protocol([
        (None, b""),
        (b"?", IDLE),
        (b"G1 X10\n", b"error:22\r\n"),
    ]) as transport:
        with _controller(transport, reset_on_open=False) as grbl:
            with pytest.raises(GrblCommandError) as info:
                grbl.send("G1 X10", timeout=1.0)
            assert info.value.code == 22 and "Undefined feed rate" in str(info.value)


def test_alarm_push_fails_the_wait_with_its_meaning():
    with expected_protocol([
        (b"?", IDLE),
        (b"G21 G90 G53 G0 X-300.000\n", b"ok\r\n"),
        (b"G4 P0\n", b"ALARM:1\r\n[MSG:Reset to continue]\r\n"),
    ]) as transport:
        with _controller(transport, reset_on_open=False, poll_interval_s=10.0) as grbl:
            status = grbl.move_to({"X": -300.0})
            with pytest.raises(GrblAlarm) as info:
                status.wait(2.0)
            assert info.value.code == 1 and "Hard limit" in str(info.value)
            assert not status.success
            assert grbl.locked and grbl.halted
            # Halted, Grbl answers nothing, not even '?': say so at once (the script fails on any write).
            with pytest.raises(GrblAlarm, match="halted by it and answers nothing.*reset required"):
                grbl.status(timeout=5.0)


def test_unexpected_banner_fails_outstanding_lines():
    with expected_protocol([
        (b"?", IDLE),
        (b"G21 G90 G53 G0 X-10.000\n", b"ok\r\n"),
        (b"G4 P0\n", BANNER + b"[MSG:'$H'|'$X' to unlock]\r\n"),
    ]) as transport:
        with _controller(transport, reset_on_open=False, poll_interval_s=10.0) as grbl:
            with pytest.raises(GrblResetError, match="reset unexpectedly"):
                grbl.move_to({"X": -10.0}).wait(2.0)
            with pytest.raises(GrblLocked, match="reset unexpectedly"):
                grbl.move_to({"X": -10.0})


def test_lost_status_report_is_asked_again():
    with expected_protocol([
        (b"?", IDLE),
        (b"?", b""),  # lost on the way
        (b"?", b"<Idle|MPos:1.000,2.000,3.000|FS:0,0>\r\n"),
    ]) as transport:
        with _controller(transport, reset_on_open=False, status_retry_s=0.05) as grbl:
            assert grbl.status(timeout=1.0).machine_position == {"X": 1.0, "Y": 2.0, "Z": 3.0}


def test_wpos_reports_use_the_last_wco():
    with expected_protocol([
        (b"?", b"<Idle|WPos:0.000,0.000,0.000|FS:0,0>\r\n"),  # no WCO yet: position unknown, ask again
        (b"?", b"<Idle|WPos:0.000,0.000,0.000|FS:0,0|WCO:10.000,20.000,30.000>\r\n"),
        (b"?", b"<Idle|WPos:1.000,1.000,1.000|FS:0,0>\r\n"),
    ]) as transport:
        with _controller(transport, reset_on_open=False) as grbl:
            assert grbl.last_reading.machine_position == {"X": 10.0, "Y": 20.0, "Z": 30.0}
            reading = grbl.status(timeout=1.0)
            assert reading.machine_position == {"X": 11.0, "Y": 21.0, "Z": 31.0}
            assert reading.work_position == {"X": 1.0, "Y": 1.0, "Z": 1.0}


def test_a_silent_controller_is_named_as_possibly_halted():
    # After ALARM:1/2 a Grbl answers nothing until reset; a look without reset must say so, not only "baud rate".
    transport = ScriptedTransport([(b"?", b"")] * 100)
    grbl = _controller(transport, reset_on_open=False, connect_timeout_s=0.3, status_retry_s=0.05)
    with pytest.raises(GrblConnectionError, match=r"no answer to '\?'.*halted by a hard or soft limit.*reset"):
        grbl.open()
    assert not grbl.is_open


def test_no_banner_is_a_clear_connection_error():
    transport = ScriptedTransport([(b"?", b""), (b"\x18", b"garbage\r\n"), (b"\x18", b"")])
    grbl = _controller(transport, connect_timeout_s=0.4, boot_wait_s=0.1)
    with pytest.raises(GrblConnectionError, match="no GRBL banner"):
        grbl.open()
    transport.check()


class _HeldOks:
    """A transport that answers '?' at once but each line's 'ok' only when the test says so."""

    name = "held-oks"

    def __init__(self):
        self._cond = threading.Condition()
        self._rx = bytearray()
        self._open = False
        self.unanswered: list[int] = []
        self.max_outstanding = 0
        self.lines: list[bytes] = []

    @property
    def is_open(self):
        return self._open

    def open(self):
        self._open = True

    def close(self):
        self._open = False

    def write(self, data):
        with self._cond:
            if data == b"?":
                self._rx += IDLE
            else:
                self.lines.append(data)
                self.unanswered.append(len(data))
                self.max_outstanding = max(self.max_outstanding, sum(self.unanswered))
            self._cond.notify_all()

    def read(self):
        with self._cond:
            if not self._rx:
                self._cond.wait(0.01)
            data, self._rx = bytes(self._rx), bytearray()
            return data

    def cancel_read(self):
        with self._cond:
            self._cond.notify_all()

    def answer_one(self):
        with self._cond:
            self.unanswered.pop(0)
            self._rx += b"ok\r\n"
            self._cond.notify_all()


def test_character_counting_never_exceeds_the_receive_buffer():
    # 10 lines of 21 bytes: 6 fit in GRBL's 127 usable bytes, so the 7th must wait for the first 'ok'.
    lines = [f"G1 X{i:03d}.000 F100.000" for i in range(10)]
    assert all(len(codec.encode_line(line)) == 21 for line in lines)
    transport = _HeldOks()
    with _controller(transport, reset_on_open=False) as grbl:
        result: list = []
        streamer = threading.Thread(target=lambda: result.append(grbl.stream(lines, timeout=10.0)))
        streamer.start()
        seen_full = False
        answered = 0
        while answered < len(lines):
            expected = min(len(lines), answered + 6)
            deadline = time.monotonic() + 5.0
            while len(transport.lines) < expected and time.monotonic() < deadline:
                time.sleep(0.005)
            time.sleep(0.02)  # room for one line too many, if the driver were to send it
            assert len(transport.lines) == expected
            seen_full |= len(transport.unanswered) == 6
            transport.answer_one()
            answered += 1
        streamer.join(5.0)
        assert not streamer.is_alive() and result and len(result[0]) == 10
    assert seen_full
    assert transport.max_outstanding == 6 * 21 <= codec.RX_BUFFER_SIZE - 1
    assert transport.lines == [codec.encode_line(line) for line in lines]


def test_unused_pair_fails_the_protocol_check():
    with pytest.raises(AssertionError, match="unused"):
        with expected_protocol([(b"?", IDLE), (b"$X\n", b"ok\r\n")]) as transport:
            with _controller(transport, reset_on_open=False):
                pass


def test_unexpected_write_fails_the_protocol_check():
    with pytest.raises(AssertionError, match="expected"):
        with expected_protocol([(b"?", IDLE), (b"$X\n", b"ok\r\n")]) as transport:
            with _controller(transport, reset_on_open=False) as grbl:
                with pytest.raises(GrblTimeout):
                    grbl.send("$H", timeout=0.2)


def test_spy_log_records_every_byte_and_replays_as_a_script(tmp_path):
    log_path = tmp_path / "session.jsonl"
    pairs = [(b"?", IDLE), (b"$I\n", b"[VER:1.1h.20190825:]\r\n[OPT:V,15,128]\r\nok\r\n")]
    grbl = _controller(SpyTransport(ScriptedTransport(pairs), log_path), reset_on_open=False)
    with grbl:
        assert grbl.send("$I", timeout=1.0) == ["[VER:1.1h.20190825:]", "[OPT:V,15,128]"]
    records = [json.loads(line) for line in log_path.read_text().splitlines()]
    assert records[0]["event"] == "open" and records[-1]["event"] == "close"
    times = [r["t"] for r in records]
    assert times == sorted(times)
    tx = "".join(r["data"] for r in records if r.get("dir") == "tx")
    assert tx == "?$I\n"
    # The recording becomes a script that drives the driver the same way again.
    replay = script_from_spy_log(log_path)
    assert [p[0] for p in replay] == [b"?", b"$I\n"]
    with expected_protocol(replay) as transport:
        with _controller(transport, reset_on_open=False) as again:
            assert again.send("$I", timeout=1.0)[0] == "[VER:1.1h.20190825:]"


def test_spy_log_to_a_stream():
    stream = io.StringIO()
    with _controller(SpyTransport(ScriptedTransport([(b"?", IDLE)]), stream), reset_on_open=False):
        pass
    assert '"dir": "tx", "data": "?"' in stream.getvalue()


def test_constructing_does_no_io():
    transport = ScriptedTransport([])
    GrblController(transport)
    assert transport.written == [] and not transport.is_open
    GrblController("/dev/this-port-does-not-exist")  # opening is open()'s job
