"""``stereo-bench rig`` in-process against a running emulator, and ``sim-controller`` as a real subprocess."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from drivers.sim.grbl_emulator import AlarmMidMove, GrblEmulator
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
    assert data["state"] == "Alarm" and data["locked"] is True
    assert data["alpha_left_deg"] == 90.0 and data["machine_position"] == {"X": 0.0, "Y": 0.0, "Z": 0.0}
    assert emulator.resets == 0  # looking does not reset the controller


def test_home_move_status(emulator, capsys):
    port = emulator.tty_path
    code, out, err = _run(capsys, "rig", "--port", port, "home")
    assert code == 0, err
    assert "homed" in out and "Idle" in out

    code, out, err = _run(capsys, "rig", "--port", port, "move", "--baseline", "120", "--alpha", "85")
    assert code == 0, err
    assert "moving: X120.000 Y5.000 Z5.000" in out
    assert "stopped. Idle: B = 120.000 mm, toe-in L = 5.000 deg (alpha 85.000 deg)" in out
    assert emulator.machine_position() == {"X": 120.0, "Y": 5.0, "Z": 5.0}  # returned only once stopped there

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
        "stereo-bench rig: error: move refused, outside soft limits: baseline_mm = 400 outside [0, 350]")
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
    assert sent.startswith("\x18") and "$H\n" in sent
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


def test_sim_controller_subprocess_and_status_json(tmp_path):
    link = tmp_path / "grbl"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    sim = subprocess.Popen(
        [sys.executable, "-m", "stereo_bench", "sim-controller", "--link", str(link), "--time-scale", "50"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        deadline = time.monotonic() + 20.0
        while not link.is_symlink() and time.monotonic() < deadline and sim.poll() is None:
            time.sleep(0.05)
        assert link.is_symlink(), sim.stderr.read() if sim.poll() is not None else "no link"
        status = subprocess.run(
            [sys.executable, "-m", "stereo_bench", "rig", "--port", str(link), "status", "--json"],
            capture_output=True, text=True, timeout=30, env=env,
        )
        assert status.returncode == 0, status.stderr
        data = json.loads(status.stdout)
        assert data["state"] == "Alarm" and data["baseline_mm"] == 0.0 and data["alpha_right_deg"] == 90.0
    finally:
        sim.send_signal(signal.SIGINT)
        try:
            out, err = sim.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            out, err = sim.communicate()
    assert sim.returncode == 0, err
    assert "serving on /dev/pts/" in out and "GRBL emulator stopped" in out
    assert not link.exists() and not link.is_symlink()
