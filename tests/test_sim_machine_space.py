"""The simulated rig stands where the rig config maps the controller's position, in either machine space.

A rig config whose machine targets are positive gets an emulated HOMING_FORCE_SET_ORIGIN build (limits.c:
homing sets every axis to 0, machine space ``[0, $13x]`` on the axes homing toward -). The emulator's
physical frame is the machine frame a successful homing sets up, so the mechanics - and the cameras - stand
at ``to_physical(config, MPos)`` whichever space the config uses. Before the fix the frame was the stock
build's: the cameras stood ``$13x - $27`` away on a positive axis (B = -199 mm for B = 100 mm on [0, 300])
and one pull-off (1 deg) away on the others.
"""

from __future__ import annotations

import tomllib

import pytest

from drivers.rig.config import RigConfig, rig_config_from_dict
from drivers.rig.grbl import GrblAlarm, GrblController
from drivers.rig.rig import GrblRig
from drivers.sim.bench import BenchSimulator
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.faults import HomingFail
from drivers.sim.grbl.firmware import AxisSpec
from drivers.sim.mechanics import pair_state
from drivers.sim.profile import LAB
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main
from stereo_bench.geometry import invert_transform, stereo_structure
from tests.campaigns import SMALL, results_csv

FAST = 50.0

# Rig config files (TOML) over both machine spaces; what a file leaves out keeps the default mapping.
MAPPINGS = {
    "negative-default": "# the default mapping: stock Grbl, machine space [-$13x, 0]\n",
    "positive-min-20": '[quantities.baseline_mm]\naxis = "X"\nmin = 20\nmax = 300\n',
    "toe-in-sign-flipped": '[quantities.toe_in_left_deg]\naxis = "Y"\nscale = 1.0\nmin = 0\nmax = 90\n',
}
SCALED = ('[quantities.baseline_mm]\naxis = "X"\noffset = 10.0\nscale = 0.5\nmin = 20\nmax = 300\n'
          '[quantities.toe_in_right_deg]\naxis = "Z"\noffset = -90.0\nscale = -1.0\nmin = 0\nmax = 90\n')


def _config(text: str) -> RigConfig:
    return rig_config_from_dict(tomllib.loads(text))


def _controller(emu: GrblEmulator) -> GrblController:
    return GrblController(emu.tty_path, connect_timeout_s=3.0, ok_grace_s=0.2, poll_interval_s=0.02)


def test_a_force_set_origin_build_has_its_switches_one_pull_off_beyond_machine_zero():
    """limits.c with HOMING_FORCE_SET_ORIGIN: every homed axis is set to 0 where the pull-off left it, so the
    physical frame (the homed machine frame) has the switch at -$27 (homing toward -) or +$27 (toward +).
    A switch that never answers stalls its axis there (ALARM:9, in the first cycle: Z, config.h HOMING_CYCLE_0);
    with hard limits on, a move onto a switch trips it (ALARM:1)."""
    specs = {"X": AxisSpec(max_travel=300.0, home_negative=True)}
    with GrblEmulator(time_scale=FAST, axis_specs=specs, force_set_origin=True, homing_pulloff=2.0, hard_limits=True,
                      soft_limits=False, faults=[HomingFail(code=9)]) as emu, _controller(emu) as grbl:
        with pytest.raises(GrblAlarm, match="ALARM:9"):
            grbl.home(timeout=5.0)
        assert emu.physical_position() == {"X": 0.0, "Y": 0.0, "Z": 2.0}  # Z stalled on its switch, +$27
        grbl.soft_reset()  # [MSG:Check Limits]: Z stands on its switch (CHECK_LIMITS_AT_INIT)
        assert "Check Limits" in grbl.messages
        assert grbl.home(timeout=5.0).machine_position == {"X": 0.0, "Y": 0.0, "Z": 0.0}
        assert emu.physical_position() == {"X": 0.0, "Y": 0.0, "Z": 0.0}
        grbl.move_to({"X": 120.0, "Y": -5.0}).wait(5.0)
        assert emu.physical_position() == emu.machine_position() == {"X": 120.0, "Y": -5.0, "Z": 0.0}
        grbl.move_to({"X": -1.9}).wait(5.0)  # one pull-off below 0 is X's switch: short of it, nothing trips
        # (soft limits are off: on, [0, $130] would refuse these targets with ALARM:2 first)
        with pytest.raises(GrblAlarm, match="ALARM:1"):
            grbl.move_to({"X": -2.0}).wait(5.0)
        assert emu.halted and emu.physical_position()["X"] == -2.0


@pytest.mark.parametrize("text", [*MAPPINGS.values(), SCALED], ids=[*MAPPINGS, "positive-scaled-offset"])
def test_the_lab_bench_stands_where_the_config_maps_the_controllers_position(text):
    """At rest at the commanded pose, the lab bench's pair is the lab build's at that pose (pair_state with no
    history) up to the backlash of the approach (0.04 mm on the slide, 0.03 deg on a head whose optical centre
    is 22 mm off its axis): well under 0.1 mm and 0.04 deg. The lab build's own offsets (~7.5 mm shorter than
    B at 5/4 deg toe-in) are the same in every machine space."""
    config = _config(text)
    commanded = {"baseline_mm": 100.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 4.0,
                 "tilt_left_deg": 0.0, "tilt_right_deg": 0.0}
    with BenchSimulator(rig_config=config, time_scale=FAST, profile=LAB, seed=3) as bench:
        with GrblRig(bench.tty_path, config) as rig:
            rig.home()
            reading = rig.move_to(
                **{q: commanded[q] for q in ("baseline_mm", "toe_in_left_deg", "toe_in_right_deg")}).wait()
        assert reading.baseline_mm == pytest.approx(100.0, abs=1e-9)
        assert bench.reported_values() == pytest.approx(commanded, abs=1e-9)
        truth = bench.truth_without_landing()["structure"]
    nominal = pair_state(LAB, commanded)
    expected = stereo_structure(*_R_T(nominal.T_bench_left, nominal.T_bench_right))
    assert truth["baseline_mm"] == pytest.approx(expected["baseline_mm"], abs=0.1)
    assert truth["alpha_left_deg"] == pytest.approx(expected["alpha_left_deg"], abs=0.04)
    assert truth["alpha_right_deg"] == pytest.approx(expected["alpha_right_deg"], abs=0.04)


def _R_T(T_bench_left, T_bench_right):
    T_right_left = invert_transform(T_bench_right) @ T_bench_left
    return T_right_left[:3, :3], T_right_left[:3, 3]


@pytest.mark.slow  # a small campaign per mapping (~4 s each)
@pytest.mark.parametrize("text", MAPPINGS.values(), ids=MAPPINGS.keys())
def test_a_campaign_measures_with_a_rig_config_in_either_machine_space(text, tmp_path):
    """The ideal bench: every calibration view's and measurement frame's truth is the commanded B and alpha."""
    plan = SMALL
    edits = {"[rig]\n": '[rig]\nconfig_file = "rig.toml"\n', "frames_per_config = 2": "frames_per_config = 1",
             "baseline_mm = [100, 150]": "baseline_mm = [100]", "alpha_deg = [90, 35]": "alpha_deg = [85]"}
    for old, new in edits.items():
        assert old in plan
        plan = plan.replace(old, new)
    (tmp_path / "rig.toml").write_text(text)
    (tmp_path / "plan.toml").write_text(plan)
    out = tmp_path / "session"
    assert main(["campaign", "run", str(tmp_path / "plan.toml"), "--out", str(out), "--yes", "--quiet"]) == 0
    (row,) = results_csv(out)
    assert row["status"] == "measured" and abs(float(row["error_mm"])) <= 0.1
    reader = SessionReader(out)
    events = [*reader.events(kind="calibration_view"), *reader.events(kind="measurement_frame")]
    assert len(events) == 6 + 1
    for event in events:
        for side in ("left", "right"):
            structure = getattr(event.data, side).meta["truth"]["structure"]
            assert structure["baseline_mm"] == pytest.approx(100.0, abs=1e-6)
            assert structure["alpha_left_deg"] == pytest.approx(85.0, abs=1e-6)
            assert structure["alpha_right_deg"] == pytest.approx(85.0, abs=1e-6)


@pytest.mark.slow  # a one-configuration campaign (seconds)
def test_a_campaign_without_homing_trusts_the_position_and_records_it(tmp_path):
    """``[rig] homing = false`` says the position the controller reports is right (as ``rig unlock
    --trust-position``): the runner tells the driver so before the first move, and records it. The old runner
    recorded nothing, and against a controller that booted at connect its first move would have been refused."""
    plan = SMALL
    edits = {"[rig]\n": "[rig]\nhoming = false\n", "baseline_mm = [100, 150]": "baseline_mm = [100]",
             "alpha_deg = [90, 35]": "alpha_deg = [90]", "frames_per_config = 2": "frames_per_config = 1"}
    for old, new in edits.items():
        assert old in plan
        plan = plan.replace(old, new)
    (tmp_path / "plan.toml").write_text(plan)
    out = tmp_path / "session"
    assert main(["campaign", "run", str(tmp_path / "plan.toml"), "--out", str(out), "--yes", "--quiet"]) == 0
    reader = SessionReader(out)
    assert not list(reader.events(kind="home"))
    (trusted,) = reader.events(kind="rig_position_trusted")
    assert "homing = false" in trusted.data.reason
    # The simulated rig powered up at machine 0: B = 350 mm, each head one pull-off (1 deg) beyond parallel.
    assert trusted.data.rig.baseline_mm == 350.0 and trusted.data.rig.alpha_left_deg == 91.0
    (row,) = results_csv(out)
    assert row["status"] == "measured"
