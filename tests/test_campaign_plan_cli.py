"""``stereo-bench campaign plan / schema / presets`` in-process: output, JSON, errors, and that nothing moves."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import serial

from stereo_bench.cli import main
from stereo_bench.cli.campaign import format_duration

MINIMAL = """\
[plan]
baseline_mm = [100, 150]
distance_mm = [400, 500]
alpha_deg = [90]
"""


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["campaign", *argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def no_serial(monkeypatch):
    """Fail the test if anything tries to open a serial port."""

    def refuse(*args, **kwargs):
        raise AssertionError("a serial port was opened")

    monkeypatch.setattr(serial, "Serial", refuse)
    monkeypatch.setattr(serial, "serial_for_url", refuse)


def test_plan_file_prints_the_table_steps_and_duration(tmp_path, capsys, no_serial):
    path = tmp_path / "plan.toml"
    path.write_text(MINIMAL)
    code, out, err = _run(capsys, "plan", str(path))
    assert code == 0, err
    assert f"({path}): 4 configurations: 4 to run (0 partial), 0 infeasible, 0 outside the soft limits" in out
    assert "config_id" in out and "B mm" in out and "in both" in out and "status" in out
    rows = [line.split() for line in out.splitlines() if "_Z" in line and line.split()[0].isdigit()]
    assert [r[1] for r in rows] == ["B100_Z400_A90", "B150_Z400_A90", "B150_Z500_A90", "B100_Z500_A90"]
    assert rows[0][2:] == ["100", "400", "90", "0", "54/54", "100%", "feasible"]
    assert "steps: 26" in out
    assert "predicted duration: 0:00:" in out and "assumed: " in out
    assert out.rstrip().endswith("dry run: nothing moved, no port opened")


def test_plan_preset_shows_infeasible_configurations_with_the_reason(capsys, no_serial):
    code, out, _ = _run(capsys, "plan", "--preset", "paper-exp2")
    assert code == 0
    assert "6 configurations: 1 to run (1 partial), 5 infeasible" in out
    assert "why: 0 of 54 target corners in both views (left 18, right 18; 6 needed): the cameras' views do not " \
           "overlap on the board at alpha = 45 deg" in out
    row_55 = next(line for line in out.splitlines() if line.split()[1:2] == ["B100_Z500_A55"])
    assert "30/54" in row_55 and row_55.endswith("partial")


def test_plan_json(capsys, no_serial):
    code, out, _ = _run(capsys, "plan", "--preset", "paper-exp2-toe-in", "--json")
    assert code == 0
    data = json.loads(out)
    assert {"configurations", "predicted_duration_s", "n_steps", "infeasible"} <= set(data)
    assert data["infeasible"] == 2 and data["n_steps"] == 27 and data["source"] == "preset paper-exp2-toe-in"
    assert "steps" not in data
    fractions = [round(c["fraction_in_both"] * 54) for c in data["configurations"]]
    assert fractions == [54, 54, 54, 30, 0, 0]
    assert [c["status"] for c in data["configurations"]] == ["feasible"] * 3 + ["partial"] + ["infeasible"] * 2
    assert data["predicted_duration_s"] == pytest.approx(data["duration"]["total_s"])
    code, out, _ = _run(capsys, "plan", "--preset", "paper-exp2-toe-in", "--json", "--steps")
    assert len(json.loads(out)["steps"]) == 27


def test_plan_lists_steps_on_request(capsys):
    code, out, _ = _run(capsys, "plan", "--preset", "paper-exp2-toe-in", "--steps")
    assert code == 0
    assert "move to B100_Z500_A85: B = 100 mm, toe-in 5/5 deg" in out
    assert "operator: move the target to Z = 500 mm" in out
    assert "capture 12 calibration views" in out and "capture 3 measurement frames" in out
    assert "checkpoint B100_Z500_A35 (skipped: 0 of 54 target corners" in out


def test_plan_on_a_real_controller_opens_no_port_and_reports_limits(tmp_path, capsys, no_serial):
    path = tmp_path / "bench.toml"
    path.write_text(MINIMAL + '[rig]\nkind = "grbl"\nport = "/dev/ttyUSB7"\n'
                    '[rig.quantities.baseline_mm]\naxis = "X"\nmin = 0\nmax = 120\n'
                    '[cameras]\nkind = "v4l2"\nleft = "usb-port:1-1"\nright = "usb-port:1-2"\n')
    code, out, err = _run(capsys, "plan", str(path))
    assert code == 0, err
    assert "2 to run (0 partial), 0 infeasible, 2 outside the soft limits" in out
    assert "limits: baseline_mm = 150 outside [0, 120]" in out
    assert "feasible, outside limits" in out
    assert "operator 0:03:00" in out  # 2 target prompts x 30 s + 2 x 12 calibration views x 5 s
    # The same rig with simulated cameras is bring-up: boards and target are in the simulated scene.
    path.write_text(path.read_text().split("[cameras]")[0])
    code, out, err = _run(capsys, "plan", str(path))
    assert code == 0, err
    assert "rig grbl, cameras simulated" in out and "operator 0:00:00" in out


@pytest.mark.parametrize("argv, message", [
    ([], "give a campaign file or --preset NAME"),
    (["x.toml", "--preset", "paper-exp1"], "give a campaign file or --preset NAME, not both"),
    (["--preset", "paper-exp9"],
     "unknown preset 'paper-exp9'; known: paper-exp1, paper-exp2, paper-exp2-toe-in, paper-exp2-measurable"),
])
def test_plan_argument_errors(capsys, argv, message):
    code, out, err = _run(capsys, "plan", *argv)
    assert code == 2 and out == ""
    assert err == f"stereo-bench campaign: error: {message}\n"


def test_bad_config_is_one_line_naming_file_and_field(tmp_path, capsys, no_serial):
    path = tmp_path / "typo.toml"
    path.write_text(MINIMAL + "[capture]\nsettle = 2\n")
    code, out, err = _run(capsys, "plan", str(path))
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert err.startswith(f"stereo-bench campaign: error: {path}: capture.settle: unknown key; known: settle_s")


def test_schema_is_json_schema(capsys):
    code, out, _ = _run(capsys, "schema")
    assert code == 0
    schema = json.loads(out)
    assert schema["$schema"].startswith("https://json-schema.org/") and "plan" in schema["required"]


def test_presets_listed(capsys):
    code, out, _ = _run(capsys, "presets")
    assert code == 0
    assert [line.split()[0] for line in out.splitlines()] == ["paper-exp1", "paper-exp2", "paper-exp2-toe-in",
                                                                "paper-exp2-measurable"]
    code, out, _ = _run(capsys, "presets", "--json")
    assert set(json.loads(out)) == {"paper-exp1", "paper-exp2", "paper-exp2-toe-in", "paper-exp2-measurable"}


def test_campaign_needs_an_action(capsys):
    assert main(["campaign"]) == 2  # main() returns argparse's status instead of exiting
    err = capsys.readouterr().err
    assert "stereo-bench campaign: error:" in err and err.count("\n") == 1


def test_format_duration():
    assert format_duration(0) == "0:00:00"
    assert format_duration(48.75) == "0:00:49"
    assert format_duration(3 * 3600 + 61.4) == "3:01:01"


def test_installed_entry_point_runs_the_plan():
    result = subprocess.run([sys.executable, "-m", "stereo_bench", "campaign", "plan", "--preset", "paper-exp1"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "25 configurations: 25 to run (1 partial)" in result.stdout
