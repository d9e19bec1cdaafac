"""``stereo-bench rig`` in-process against a running emulator, and ``sim-controller`` as a real subprocess.

The default rig mapping is stock Grbl's machine space one pull-off inside it: X = B - 350 mm, Y/Z = -1 - toe-in.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from drivers.rig import GrblController, GrblRig
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.faults import AlarmMidMove
from stereo_bench.cli import main

FAST = 50.0


@pytest.fixture
def emulator():
    with GrblEmulator(time_scale=FAST) as emu:
        yield emu


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_status_json_before_homing(emulator, capsys):
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "status", "--json")
    assert code == 0, err
    data = json.loads(out)
    for key in ("state", "baseline_mm", "toe_in_left_deg", "toe_in_right_deg", "alpha_left_deg", "alpha_right_deg"):
        assert key in data
    assert data["state"] == "Alarm" and data["locked"] is True and data["halted"] is False
    assert data["alpha_left_deg"] == 91.0 and data["machine_position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0}
    # Machine 0 is the homing switch: B = 350 mm, and each pan head one pull-off (1 deg) beyond parallel.
    assert data["baseline_mm"] == 350.0
    assert data["controller"]["settings"]["$130"] == 350 and data["controller"]["boot_detected"] is False
    assert emulator.resets == 0  # looking does not reset the controller


def test_home_move_status(emulator, capsys):
    port = emulator.tty_path
    code, out, err = _run(capsys, "rig", "--port", port, "home")
    assert code == 0, err
    assert "homed" in out and "Idle" in out

    code, out, err = _run(capsys, "rig", "--port", port, "move", "--baseline", "120", "--alpha", "85")
    assert code == 0, err
    assert "moving: X-230.000 Y-6.000 Z-6.000" in out
    assert "stopped. Idle: B = 120.000 mm, toe-in L = 5.000 deg (alpha 85.000 deg)" in out
    assert emulator.machine_position() == {"X": -230.0, "Y": -6.0, "Z": -6.0}  # returned only once stopped there

    code, out, err = _run(capsys, "rig", "--port", port, "move", "--toe-in-left", "2", "--toe-in-right", "3")
    assert code == 0, err
    code, out, err = _run(capsys, "rig", "--port", port, "status", "--json")
    data = json.loads(out)
    assert (data["baseline_mm"], data["toe_in_left_deg"], data["toe_in_right_deg"]) == (120.0, 2.0, 3.0)
    assert (data["alpha_left_deg"], data["alpha_right_deg"]) == (88.0, 87.0)
    assert data["state"] == "Idle" and data["locked"] is False

    code, out, _ = _run(capsys, "rig", "--port", port, "status")
    assert code == 0 and out.startswith("Idle: B = 120.000 mm")


def test_manual_target_prompts_the_operator(emulator, capsys, monkeypatch):
    port = emulator.tty_path
    assert _run(capsys, "rig", "--port", port, "home")[0] == 0
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n"))
    code, out, err = _run(capsys, "rig", "--port", port, "move", "--baseline", "200", "--target", "400")
    assert code == 0, err
    assert "move the target to Z = 400 mm, then press Enter" in err
    assert "target Z = 400.000 mm" in out


def _one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_refused_move_is_one_line_and_sends_nothing(emulator, capsys):
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "move", "--baseline", "400")
    assert code == 2
    assert _one_line_error(err) == (
        "stereo-bench rig: error: move refused, outside soft limits: baseline_mm = 400 outside [1, 349]")
    assert list(emulator.lines_received) == []  # the port was not even opened


@pytest.mark.parametrize(("args", "message"), [
    (["--alpha", "85", "--toe-in-left", "3"], "not both"),
    ([], "nothing to move"),
    (["--tilt", "5"], "tilt_left_deg is fixed at 0"),
])
def test_bad_move_requests(emulator, capsys, args, message):
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "move", *args)
    assert code == 2 and message in _one_line_error(err)


def test_unreachable_port(tmp_path, capsys):
    code, _, err = _run(capsys, "rig", "--port", str(tmp_path / "no-such-tty"), "status")
    assert code == 2
    assert "cannot open serial port" in _one_line_error(err) and "No such file or directory" in err


def test_calibrate_kinematics_on_a_port_that_is_not_there_is_exit_2_as_campaign_run(tmp_path, capsys):
    # The one mapping (stereo_bench.cli.failure): a port that is not there is the user's to fix (2), not a fault
    # of the controller during work (1); `campaign run` on the same port says 2.
    code, _, err = _run(capsys, "rig", "--port", str(tmp_path / "no-such-tty"), "calibrate-kinematics",
                        "--out", str(tmp_path / "kin"))
    assert code == 2, err
    assert "cannot open serial port" in err and f"nothing was recorded: --out {tmp_path / 'kin'} is as it was" in err
    assert not (tmp_path / "kin").exists()  # refused before anything moved: --out as it was


def test_move_before_homing_is_a_clear_error(emulator, capsys):
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "move", "--baseline", "10")
    assert code == 1
    assert "in Alarm (homing required)" in _one_line_error(err)


def test_alarm_mid_move(emulator, capsys):
    assert _run(capsys, "rig", "--port", emulator.tty_path, "home")[0] == 0
    emulator.inject(AlarmMidMove(code=1, fraction=0.5))
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "move", "--baseline", "300")
    assert code == 1
    assert "ALARM:1: Hard limit triggered" in _one_line_error(err)
    assert "stopped." not in out


def test_spy_log_records_the_session(emulator, capsys, tmp_path):
    log = tmp_path / "spy.jsonl"
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "--spy-log", str(log), "home")
    assert code == 0, err
    records = [json.loads(line) for line in log.read_text().splitlines()]
    sent = "".join(r["data"] for r in records if r.get("dir") == "tx")
    received = "".join(r["data"] for r in records if r.get("dir") == "rx")
    assert sent.startswith("?\x18") and "$I\n$$\n$N\n" in sent and "$H\n" in sent
    assert "Grbl 1.1h ['$' for help]" in received and "ok\r\n" in received


def test_bad_rig_config_file(tmp_path, emulator, capsys):
    path = tmp_path / "rig.toml"
    path.write_text('[quantities.baseline_mm]\naxis = "X"\nmin = 0\nmax = "far"\n')
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "--rig-config", str(path), "status")
    assert code == 2
    assert f"{path}: quantities.baseline_mm.max" in _one_line_error(err)


def test_bad_fault_spec(tmp_path, capsys):
    code, _, err = _run(capsys, "sim-controller", "--link", str(tmp_path / "grbl"), "--fault", "explode")
    assert code == 2 and "unknown fault 'explode'" in _one_line_error(err)


ENV = dict(os.environ, PYTHONUNBUFFERED="1")


@contextlib.contextmanager
def _sim_controller(link, *options: str):
    """``stereo-bench sim-controller --link LINK`` as a real process; yields it once the link exists, stops it
    with SIGINT on exit (its output is then in ``process.outcome``)."""
    sim = subprocess.Popen(
        [sys.executable, "-m", "stereo_bench", "sim-controller", "--link", str(link), "--time-scale", "50",
         *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        deadline = time.monotonic() + 20.0
        while not link.is_symlink() and time.monotonic() < deadline and sim.poll() is None:
            time.sleep(0.05)
        assert link.is_symlink(), sim.stderr.read() if sim.poll() is not None else "no link"
        yield sim
    finally:
        sim.send_signal(signal.SIGINT)
        try:
            sim.outcome = sim.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.outcome = sim.communicate()


def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stereo_bench", *argv], capture_output=True, text=True,
                          timeout=30, env=ENV)


def test_sim_controller_subprocess_and_status_json(tmp_path):
    link = tmp_path / "grbl"
    with _sim_controller(link) as sim:
        status = _cli("rig", "--port", str(link), "status", "--json")
        assert status.returncode == 0, status.stderr
        data = json.loads(status.stdout)
        assert data["state"] == "Alarm" and data["baseline_mm"] == 350.0 and data["alpha_right_deg"] == 91.0
    out, err = sim.outcome
    assert sim.returncode == 0, err
    assert "serving on /dev/pts/" in out and "GRBL emulator stopped" in out
    assert not link.exists() and not link.is_symlink()


# ---------------------------------------------------------------------------------------------- one connection


def test_chained_actions_run_on_one_connection(emulator, capsys):
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "home", "move", "--baseline", "100",
                          "--alpha", "88", "status", "--json")
    assert code == 0, err
    assert emulator.client_opens == 1
    lines = out.splitlines()
    assert lines[1].startswith("homed. Idle: B = 349.000 mm") and "stopped. Idle: B = 100.000 mm" in out
    data = json.loads(lines[-1])
    assert (data["baseline_mm"], data["alpha_left_deg"], data["state"]) == (100.0, 88.0, "Idle")
    assert emulator.physical_position() == {"X": -250.0, "Y": -3.0, "Z": -3.0}


def test_auto_reset_between_calls_is_named_and_chaining_works(capsys):
    # An Arduino reboots whenever its port opens: two calls in a row each start at MPos 0, position unknown.
    with GrblEmulator(time_scale=FAST, reboot_on_open=True) as emu:
        port = emu.tty_path
        code, out, err = _run(capsys, "rig", "--port", port, "home")
        assert code == 0, err
        assert "warning:" in err and "booted when the port was opened" in err
        code, out, err = _run(capsys, "rig", "--port", port, "move", "--baseline", "30")
        assert code == 2 and "moving" not in out  # refused before a byte was sent: the user's to fix
        error = [line for line in err.splitlines() if "error:" in line]
        assert len(error) == 1 and "booted when the port was opened" in error[0]
        assert "chain actions in one call" in error[0] and "shell" in error[0]
        assert emu.physical_position()["X"] == -1.0  # nothing moved
        code, out, err = _run(capsys, "rig", "--port", port, "home", "move", "--baseline", "30")
        assert code == 0, err
        assert emu.physical_position()["X"] == -320.0 and "B = 30.000 mm" in out


def test_auto_reset_with_homing_disabled_refuses_the_second_call(capsys):
    # The Uno with $22=0: each call reboots the board and restarts the counters at 0. The old driver then
    # moved `--baseline 250` to machine -400, 50 mm past the end of a 350 mm slide, printing "B = 250.000 mm".
    with GrblEmulator(time_scale=FAST, homing_enabled=False, reboot_on_open=True) as emu:
        port = emu.tty_path
        code, out, err = _run(capsys, "rig", "--port", port, "unlock", "--trust-position", "move", "--baseline", "300")
        assert code == 0, err
        assert "the position is trusted as it is" in out and emu.physical_position()["X"] == -50.0
        code, out, err = _run(capsys, "rig", "--port", port, "move", "--baseline", "250")
        assert code == 2 and "moving" not in out and "stopped." not in out
        errors = [line for line in err.splitlines() if "error:" in line]  # the rest are the connect's warnings
        assert len(errors) == 1 and "position is unknown" in errors[0] and "--trust-position" in errors[0]
        assert "homing is disabled" in errors[0]  # so `home` is no remedy there
        assert emu.physical_position()["X"] == -50.0  # nothing moved


def test_resume_after_a_reboot_says_nothing_was_resumed(capsys):
    with GrblEmulator(time_scale=FAST, reboot_on_open=True) as emu:
        code, out, err = _run(capsys, "rig", "--port", emu.tty_path, "resume")
    assert code == 1 and "stopped." not in out and "resuming" not in out
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1 and "nothing to resume: opening" in errors[0] and "rebooted the controller" in errors[0]


def test_resume_with_nothing_held_says_so(emulator, capsys):
    with GrblController(emulator.tty_path) as grbl:
        grbl.unlock()
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "resume")
    assert code == 0 and out.startswith("nothing to resume: the controller is not holding (Idle)")


def test_shell_runs_commands_until_quit(emulator, capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO(
        "home\nmove --baseline 100 --toe-in 3\nmove --baseline 999\nfly\nstatus --json\nmove --help\nquit\n"
        "move --baseline 10\n"))
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "shell")
    assert code == 0, err
    assert "homed. Idle" in out and "stopped. Idle: B = 100.000 mm, toe-in L = 3.000 deg" in out
    errors = err.splitlines()
    assert errors == ["error: move refused, outside soft limits: baseline_mm = 999 outside [1, 349]",
                      "error: unknown action 'fly'; actions: home, unlock, move, status, resume, reset, shell"]
    # Piped input is not echoed: the prompts of the refused commands share the line of the next output.
    line = next(line for line in out.splitlines() if line.startswith("rig> rig> rig> {"))
    status = json.loads(line.removeprefix("rig> rig> rig> "))
    assert status["baseline_mm"] == 100.0
    assert "--toe-in-left DEG" in out  # move --help
    assert emulator.machine_position()["X"] == -250.0  # nothing ran after quit
    assert emulator.client_opens == 1


def test_shell_ends_at_end_of_input(emulator, capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO("status\n"))
    code, out, _ = _run(capsys, "rig", "--port", emulator.tty_path, "shell")
    assert code == 0 and out.count("Alarm: B = 350.000 mm") == 2


def test_resume_completes_a_held_move_from_another_call(emulator, capsys):
    with GrblController(emulator.tty_path) as grbl:
        grbl.home(timeout=5.0)
        grbl.move_to({"X": -301.0}, feed_per_min=600.0)
        time.sleep(0.05)
        grbl.feed_hold()
        while grbl.status().full_state != "Hold:0":
            time.sleep(0.01)
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "resume")
    assert code == 0, err
    assert "stopped. Idle: B = 49.000 mm" in out and emulator.machine_position()["X"] == -301.0


def test_reset_ends_a_halt_after_a_soft_limit_alarm(emulator, capsys, tmp_path):
    quick = tmp_path / "rig.toml"
    quick.write_text("[controller]\nconnect_timeout_s = 0.6\n")  # a halted Grbl never answers: don't wait 5 s
    with GrblController(emulator.tty_path) as grbl:
        grbl.unlock()
        with pytest.raises(Exception, match="ALARM:2"):
            grbl.move_to({"X": 5.0}).wait(5.0)  # past the homing switch: Grbl halts
    assert emulator.halted
    time.sleep(0.1)  # let the alarm's [MSG:Reset to continue] go out (0.5 s simulated) while nobody listens
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "--rig-config", str(quick), "status")
    assert code == 2, err
    assert "halted by a hard or soft limit" in _one_line_error(err)
    code, out, err = _run(capsys, "rig", "--port", emulator.tty_path, "reset", "status")
    assert code == 0, err
    assert "soft reset on connect. Alarm" in out and not emulator.halted


def test_interrupted_move_names_the_commands_to_resume_or_reset(emulator, capsys, monkeypatch):
    def interrupted(self, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(GrblRig, "move_to", interrupted)
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "move", "--baseline", "100")
    assert code == 130
    assert f"`stereo-bench rig --port {emulator.tty_path} resume` continues the move" in err
    assert "`... reset` abandons it" in err


def test_controller_warnings_are_printed_once(capsys):
    with GrblEmulator(time_scale=FAST, startup_lines=("G20",)) as emu:
        code, out, err = _run(capsys, "rig", "--port", emu.tty_path, "status")
    assert code == 0
    warnings = [line for line in err.splitlines() if line.strip()]
    assert len(warnings) == 1 and warnings[0].startswith("stereo-bench rig: warning: ")
    assert "$N0=G20" in warnings[0] and "inches" in warnings[0]


def test_action_help_and_bad_actions(emulator, capsys):
    code, out, _ = _run(capsys, "rig", "--port", emulator.tty_path, "move", "--help")
    assert code == 0 and "--baseline MM" in out
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path)
    assert code == 2 and "give an action" in _one_line_error(err)
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "home", "shell")
    assert code == 2 and "shell runs on its own" in _one_line_error(err)
    code, _, err = _run(capsys, "rig", "--port", emulator.tty_path, "move", "--speed", "3")
    assert code == 2 and "unrecognized arguments: --speed 3" in _one_line_error(err)
    assert emulator.client_opens == 0  # none of these opened the port


def test_lost_connection_exits_1_and_says_so_once(tmp_path):
    # A real process, so that logging is configured as for a user (no test log capture).
    link = tmp_path / "grbl"
    with _sim_controller(link, "--fault", "vanish:0.5"):
        result = _cli("rig", "--port", str(link), "home", "move", "--baseline", "100")
    assert result.returncode == 1, result.stderr
    assert "homed." in result.stdout
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "lost the connection" in lines[0], result.stderr
