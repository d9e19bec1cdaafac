"""The plan of a fixed-board kinematic design (issue 25): one placement, no presentations, every visit's board
in both views, the operator's actions and time, and what ``campaign plan`` prints for each design."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.plan import (
    CaptureCalibration,
    Move,
    PlaceBoard,
    PrepareExtrinsics,
    estimate_duration,
    expand_plan,
    plan_steps,
    plan_summary,
    plan_visits,
)
from stereo_bench.cli import main
from stereo_bench.geometry import calibration_view_fits

PAPER_EXP1 = {"distance_mm": [300, 400, 500, 600, 700], "baseline_mm": [50, 100, 150, 200, 250], "alpha_deg": [90]}
HARDWARE = {"rig": {"kind": "grbl", "port": "/dev/ttyUSB7"},
            "cameras": {"kind": "v4l2", "left": "usb-port:1-1", "right": "usb-port:1-2"}}


def _config(design: str, **extra):
    return campaign_from_dict({"name": "paper-exp1", "plan": PAPER_EXP1,
                               "extrinsics": {"mode": "kinematic", "design": design}, **extra})


def test_paper_exp1_fixed_board_places_the_board_once_and_presents_nothing():
    config = _config("fixed-board")
    configurations = expand_plan(config)
    visits = plan_visits(config, configurations)
    steps = plan_steps(config, configurations, visits)
    summary = plan_summary(config)
    assert summary["calibration_presentations"] == {"visits": 0, "configurations": 0, "placements": 1, "total": 0}
    assert summary["operator_actions"] == {"presentations": 0, "placements": 1, "target_moves": 5,
                                           "manual_settings": 0, "total": 6}
    # The placement comes once, right after the first move (both views live at the first visit).
    places = [i for i, s in enumerate(steps) if isinstance(s, PlaceBoard)]
    assert len(places) == 1 and isinstance(steps[places[0] - 1], Move) and places[0] == 1
    captures = [s for s in steps if isinstance(s, CaptureCalibration)]
    assert len(captures) == len(visits) == 32 and all(c.fixed_board and c.n_views == 3 for c in captures)
    # One board pose for every visit, and it fits both views at each (where it was asked to stand).
    T = visits[0].fixed_board_matrix()
    board = config.calibration_board.build()
    left, right = (config.cameras.optics.camera_model(side) for side in ("left", "right"))
    assert all(v.runnable and np.array_equal(v.fixed_board_matrix(), T) for v in visits)
    assert all(calibration_view_fits(board, T, rig=v.rig_pose(), left=left, right=right) for v in visits)
    # The design spans the campaign's slide and turns the heads (0-6 deg) though the campaign stays at toe-in 0.
    assert {v.baseline_mm for v in visits} == {50.0, 116.7, 183.3, 250.0}
    assert {v.toe_in_left_deg for v in visits} == {0.0, 2.0, 4.0, 6.0}


def test_the_presented_design_still_presents_108_times():
    summary = plan_summary(_config("presented"))
    assert summary["calibration_presentations"]["total"] == 108
    assert summary["operator_actions"]["total"] == 113 and summary["operator_actions"]["placements"] == 0


def test_a_hardware_run_of_paper_exp1_needs_under_three_minutes_of_operator_time():
    fixed, presented = (_config(design, **HARDWARE) for design in ("fixed-board", "presented"))
    operator = {}
    for name, config in (("fixed", fixed), ("presented", presented)):
        configurations = expand_plan(config)
        operator[name] = estimate_duration(config, configurations, plan_steps(config, configurations)).operator_s
    assert operator["fixed"] == pytest.approx(5 * 30.0 + 20.0)  # 5 target moves, one placement
    assert operator["fixed"] < 180.0
    assert operator["presented"] == pytest.approx(5 * 30.0 + 108 * 5.0)


def test_a_fixed_board_design_outside_kinematic_mode_is_one_clear_error(tmp_path, capsys):
    path = tmp_path / "c.toml"
    path.write_text('[plan]\nbaseline_mm = [100]\ndistance_mm = [500]\nalpha_deg = [90]\n'
                    '[extrinsics]\nmode = "per-config"\ndesign = "fixed-board"\n')
    code = main(["campaign", "plan", str(path)])
    err = capsys.readouterr().err
    assert code != 0 and len(err.strip().splitlines()) == 1
    assert "design = 'fixed-board'" in err and 'mode = "kinematic"' in err and "c.toml" in err


def test_a_design_none_of_whose_visits_can_run_is_refused_by_plan_and_run_before_anything_moves(tmp_path, capsys):
    """The default 11x8 board never fits both views of cameras toed in 32-38 deg: the model cannot be fitted, and
    every configuration would have failed on its extrinsics after the rig had been through the plan (the run
    homed, visited nothing and failed 'no design visit captured views', exit 1). Now the plan shows each visit's
    reason and exits 2 with one line; the run refuses the same way and leaves no session."""
    path = tmp_path / "steep.toml"
    path.write_text('[plan]\nbaseline_mm = [100]\ndistance_mm = [500]\nalpha_deg = [45, 55]\n'
                    '[extrinsics]\nmode = "kinematic"\ndesign = "fixed-board"\n')
    assert main(["campaign", "plan", str(path)]) == 2
    captured = capsys.readouterr()
    assert "B100_Z500_A55" in captured.out and "NOT RUN: calibration board" in captured.out
    (line,) = captured.err.strip().splitlines()
    assert "steep.toml: extrinsics: no visit of the kinematic design (fixed-board) can run (design-1_" in line
    assert "never fits both views" in line and 'kind = "charuco"' in line and "extrinsics.kinematic_file" in line
    assert main(["campaign", "plan", str(path), "--json"]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out)["design_problem"] in captured.err
    session = tmp_path / "session"
    assert main(["campaign", "run", str(path), "--out", str(session), "--yes", "--quiet"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "campaign config: extrinsics: no visit of the kinematic design" in line
    assert not session.exists()
    # rig calibrate-kinematics says the same of the design alone, in one line, before anything moves.
    assert main(["rig", "calibrate-kinematics", "--design", "fixed-board", "--toe-in-range", "32", "38",
                 "--baseline-range", "100", "100", "--out", str(session), "--yes"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "rig calibrate-kinematics: extrinsics: no visit of the kinematic design (fixed-board) can run" in line
    assert "cannot be fitted; use a calibration board" in line and not session.exists()
    # The plan of a preset that can run says nothing of the kind.
    assert plan_summary(_config("fixed-board"))["design_problem"] is None


@pytest.mark.parametrize(("design", "expected"), [
    ("fixed-board", ["calibration board presentations: 0: 0 at visits", "calibration board placements: 1",
                     "operator actions: 6 (0 board presentations, 1 board placements, 5 target moves)",
                     "fixed board: placed once, centred", "design-1_B50_L0_R0", "fixed board\n"]),
    ("presented", ["calibration board presentations: 108: 108 at visits", "calibration board placements: 0",
                   "operator actions: 113 (108 board presentations, 0 board placements, 5 target moves)"]),
])
def test_campaign_plan_prints_placements_and_presentations_in_each_design(tmp_path, capsys, design, expected):
    path = tmp_path / "exp1.toml"
    path.write_text('[plan]\ndistance_mm = [300, 400, 500, 600, 700]\nbaseline_mm = [50, 100, 150, 200, 250]\n'
                    f'alpha_deg = [90]\n[extrinsics]\nmode = "kinematic"\ndesign = "{design}"\n')
    assert main(["campaign", "plan", str(path)]) == 0
    out = capsys.readouterr().out
    for text in expected:
        assert text in out, text


#: grblHAL with the tilts on A and B (tests/test_sim_tilt.py's TILT_RIG), inline.
TILT_RIG = {"controller": {"rx_buffer_size": 1024},
            "quantities": {side: {"axis": axis, "offset": -21.0, "scale": -1.0, "min": -20, "max": 20}
                           for side, axis in (("tilt_left_deg", "A"), ("tilt_right_deg", "B"))}}
SMALL_PLAN = {"baseline_mm": [80, 200], "distance_mm": [500], "toe_in_deg": [0, 10]}


def _tilt_config(plan=None, **extrinsics):
    return campaign_from_dict({"name": "tilt", "rig": TILT_RIG, "plan": {**SMALL_PLAN, **(plan or {})},
                               "calibration_board": {"cols": 9, "rows": 6, "square_mm": 20},
                               "extrinsics": {"mode": "kinematic", "design": "fixed-board", **extrinsics}})


def test_the_design_steps_the_tilts_when_the_plan_has_several_and_holds_them_at_one():
    several = _tilt_config({"tilts_deg": [-2, 2]})
    configurations = expand_plan(several)
    # tilts innermost, serpentine: one step of one axis between neighbours
    assert [c.config_id for c in configurations][:4] == ["B80_Z500_A90_Tm2", "B80_Z500_A90_T2", "B80_Z500_A80_T2",
                                                         "B80_Z500_A80_Tm2"]
    visits = plan_visits(several, configurations)
    assert len(visits) == 32 and all(v.runnable for v in visits)
    assert {v.tilt_left_deg for v in visits} == {v.tilt_right_deg for v in visits} == {-5.0, 0.0, 5.0}
    assert visits[0].config_id == "design-1_B80_L0_R0_TLm5_TR5"
    assert visits[0].move_request()["tilt_left_deg"] == -5.0 and visits[0].rig_pose().tilt_right_deg == 5.0
    for one in (_tilt_config(), _tilt_config(plan={"tilts_deg": [-2, 2]}, design_tilt="include")):
        held = plan_visits(one, expand_plan(one))
        assert len(held) == 32
    (single,) = {v.tilts_in_design for v in plan_visits(_tilt_config(), expand_plan(_tilt_config()))}
    assert single == ()  # held: recorded as before (no per-camera tilts)
    assert "tilt_left_deg" not in plan_visits(_tilt_config(), expand_plan(_tilt_config()))[0].as_dict()
    included = _tilt_config(design_tilt="include")
    assert {v.tilt_left_deg for v in plan_visits(included, expand_plan(included))} == {-5.0, 0.0, 5.0}


def test_campaign_plan_says_whether_the_design_steps_the_tilts_and_prints_their_joints(tmp_path, capsys):
    summary = plan_summary(_tilt_config({"tilts_deg": [-2, 2]}))
    assert summary["design_tilt"].startswith("tilts stepped (tilt_left_deg, tilt_right_deg; the campaign tilts")
    names = [row["name"] for row in summary["identifiability"]]
    assert len(names) == 34 and "right_tilt_axis_y_mm" in names
    held = plan_summary(_tilt_config())
    assert held["design_tilt"].startswith("tilts held at 0 deg (one campaign tilt")
    assert len(held["identifiability"]) == 22
    assert "design_tilt" not in plan_summary(_config("fixed-board"))  # a rig without tilt axes: as before
    path = tmp_path / "tilt.toml"
    rig = "".join(f'[rig.quantities.{side}]\naxis = "{axis}"\noffset = -21.0\nscale = -1.0\nmin = -20\nmax = 20\n'
                  for side, axis in (("tilt_left_deg", "A"), ("tilt_right_deg", "B")))
    path.write_text('[plan]\nbaseline_mm = [80, 200]\ndistance_mm = [500]\ntoe_in_deg = [0, 10]\ntilts_deg = [-2, 2]\n'
                    '[calibration_board]\ncols = 9\nrows = 6\nsquare_mm = 20\n'
                    '[extrinsics]\nmode = "kinematic"\ndesign = "fixed-board"\n'
                    '[rig.controller]\nrx_buffer_size = 1024\n' + rig)
    assert main(["campaign", "plan", str(path)]) == 0
    out = capsys.readouterr().out
    assert "design tilts: tilts stepped" in out and "tilt -5/5 deg" in out
    assert "34 parameters identified" in out and "left_tilt_axis_z_mm" in out


@pytest.mark.parametrize(("extrinsics", "plan", "message"), [
    ({"design": "presented"}, {"tilts_deg": [0, 4]}, "the presented design's fit has no tilt joints"),
    ({"design_tilt": "hold"}, {"tilts_deg": [0, 4]}, "design_tilt = \"hold\" keeps one tilt"),
    ({}, {"tilts_deg": [0, 4], "tilt_deg": 3}, "give tilt_deg or tilts_deg, not both"),
])
def test_a_plan_of_several_tilts_that_a_model_cannot_predict_is_refused_with_one_line(extrinsics, plan, message):
    from stereo_bench.campaign.config import ConfigError

    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        _tilt_config(plan, **extrinsics)


# --------------------------------------------------------------------------------------------------
# A lens calibration of presented views before the board is placed, only for what the fixed board cannot identify


SAMPLE_CALIB = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session" / "calib" / "B100_Z450_A90" / "a1"


def _lens_visits(config):
    visits = plan_visits(config, expand_plan(config))
    return [v for v in visits if v.purpose == "intrinsics"], [v for v in visits if v.purpose == "kinematic"]


def test_the_plan_assumes_the_corner_noise_it_is_told_and_says_so(tmp_path, capsys):
    """[extrinsics] plan_corner_sigma_px: at the lab bench's 0.21 px (the real webcam sets: 0.13-0.6) the board alone
    no longer separates the left pan axis' depth from the focal lengths, so auto presents a lens calibration first;
    the printed plan names the figure. A calib_dir needs no presentation at any noise; a noise of 0 is refused."""
    from stereo_bench.campaign.config import ConfigError

    def extrinsics(**extra):
        return {"extrinsics": {"mode": "kinematic", "design": "fixed-board", **extra}}

    noisy = plan_summary(_config("fixed-board", **extrinsics(plan_corner_sigma_px=0.21)))
    assert noisy["lens_calibration"]["presentations"] == 12
    assert noisy["lens_calibration"]["gains"] == ["left_axis_z_mm"]
    assert noisy["operator_actions"]["total"] == 6 + 12
    quiet = plan_summary(_config("fixed-board"))
    assert quiet["lens_calibration"]["presentations"] == 0  # the default, 0.1 px
    with pytest.raises(ConfigError, match="extrinsics.plan_corner_sigma_px"):
        _config("fixed-board", **extrinsics(plan_corner_sigma_px=0))
    path = tmp_path / "exp1.toml"
    path.write_text('[plan]\ndistance_mm = [300, 400, 500, 600, 700]\nbaseline_mm = [50, 100, 150, 200, 250]\n'
                    'alpha_deg = [90]\n[extrinsics]\nmode = "kinematic"\ndesign = "fixed-board"\n'
                    'plan_corner_sigma_px = 0.21\n')
    assert main(["campaign", "plan", str(path)]) == 0
    out = capsys.readouterr().out
    assert "0.21 px corners ([extrinsics] plan_corner_sigma_px)" in out
    assert "calibration board presentations: 12" in out


def test_paper_exp1_on_a_fixed_board_needs_no_lens_calibration_unless_asked():
    """paper-exp1's design turns the heads 0-6 deg over four slide positions: the board alone identifies all 22 (at the
    plan's 0.1 px), so auto adds nothing; "present" adds capture.calibration_views presentations before the
    placement; calib_dir and "none" add none."""
    auto = plan_summary(_config("fixed-board"))
    assert auto["lens_calibration"] == {"presentations": 0, "visit": None, "gains": [], "held": [],
                                        "reason": "the fixed board alone identifies every parameter"}
    assert auto["calibration_presentations"]["total"] == 0
    assert all(row["identified"] for row in auto["identifiability"])
    assert auto["identifiability"][0]["intrinsics"] == "from the design's views alone"

    present = _config("fixed-board", extrinsics={"mode": "kinematic", "design": "fixed-board",
                                                 "fixed_board_lens": "present"})
    (lens,), design = _lens_visits(present)
    assert lens.config_id == "intrinsics-B50_Z300_A90" and lens.runnable and not lens.board_fixed
    assert [v.index for v in design] == list(range(1, 33))  # the design after it, as before
    summary = plan_summary(present)
    assert summary["calibration_presentations"] == {"visits": 12, "configurations": 0, "placements": 1, "total": 12}
    assert summary["operator_actions"]["total"] == 6 + 12
    assert summary["lens_calibration"]["presentations"] == 12
    assert summary["lens_calibration"]["reason"].startswith('a lens calibration: fixed_board_lens = "present"; sigmas')
    assert summary["identifiability"][0]["intrinsics"] == ("a lens calibration of 12 presented views as prior "
                                                           "(predicted)")
    # The prior sharpens the right camera's depth (T_z: the ratio of the focal lengths, docs/EXTRINSICS.md).
    sigma = {table: {r["name"]: r["sigma"] for r in s["identifiability"]} for table, s in (("alone", auto),
                                                                                           ("prior", summary))}
    assert sigma["prior"]["right_z_mm"] < 0.5 * sigma["alone"]["right_z_mm"]
    steps = plan_steps(present, expand_plan(present))
    kinds = [type(s).__name__ for s in steps[:8]]
    assert kinds == ["Move", "Settle", "Flush", "CaptureCalibration", "VisitDone", "PrepareExtrinsics", "Move",
                     "PlaceBoard"]
    assert steps[3].n_views == 12 and not steps[3].fixed_board
    assert steps[5].purpose == "intrinsics" and steps[5].config_id == "extrinsics-intrinsics"
    assert [s.purpose for s in steps if isinstance(s, PrepareExtrinsics)] == ["intrinsics", "kinematic"]

    for extrinsics, reason in (({"fixed_board_lens": "none"}, 'fixed_board_lens = "none"'),
                               ({"fixed_board_lens": "present", "calib_dir": str(SAMPLE_CALIB)}, "calib_dir's lens")):
        config = _config("fixed-board", extrinsics={"mode": "kinematic", "design": "fixed-board", **extrinsics})
        assert _lens_visits(config)[0] == []
        summary = plan_summary(config)
        assert summary["calibration_presentations"]["total"] == 0 and summary["operator_actions"]["total"] == 6
        assert reason in summary["lens_calibration"]["reason"]


def test_the_plan_presents_a_lens_calibration_for_what_only_a_lens_prior_identifies():
    """One slide position (B 150 only): the board alone cannot place the pan axes' depths (confounded with the focal
    lengths); a 12-view lens prior can, so auto presents 12 views; the slide's parameters are held by rule (one
    value), which no presentation helps: held nominal and said so."""
    config = campaign_from_dict({"name": "one-b", "plan": {"distance_mm": [300, 500, 700], "baseline_mm": [150],
                                                          "alpha_deg": [90]},
                                 "extrinsics": {"mode": "kinematic", "design": "fixed-board"}, **HARDWARE})
    summary = plan_summary(config)
    lens = summary["lens_calibration"]
    assert lens["presentations"] == 12 and lens["visit"] == "intrinsics-B150_Z300_A90"
    assert lens["gains"] == ["left_axis_z_mm", "right_axis_z_mm"]
    assert lens["reason"].startswith("a lens calibration: the fixed board alone does not separate left_axis_z_mm, "
                                     "right_axis_z_mm from the focal lengths")
    assert lens["held"] == ["slide_yaw_deg", "slide_pitch_deg", "slide_scale", "slide_backlash_mm"]
    rows = {r["name"]: r for r in summary["identifiability"]}
    assert rows["left_axis_z_mm"]["identified"] and rows["right_axis_z_mm"]["identified"]
    assert rows["slide_scale"]["note"] == "not identifiable: the design holds baseline_mm at one value"
    assert summary["calibration_presentations"]["total"] == 12
    # Operator time on a real bench: 3 target moves, 1 placement, 12 presentations (the assumed figures).
    configurations = expand_plan(config)
    operator = estimate_duration(config, configurations, plan_steps(config, configurations)).operator_s
    assert operator == pytest.approx(3 * 30.0 + 20.0 + 12 * 5.0)
    # Asked for none: the board alone, the axes' depths held nominal as before.
    none = plan_summary(campaign_from_dict({**config.model_dump(mode="json"),
                                            "extrinsics": {"mode": "kinematic", "design": "fixed-board",
                                                           "fixed_board_lens": "none"}}))
    assert none["calibration_presentations"]["total"] == 0
    assert {r["name"] for r in none["identifiability"] if not r["identified"]} >= {"left_axis_z_mm"}


def test_campaign_plan_says_how_many_presentations_and_why(tmp_path, capsys):
    path = tmp_path / "one-b.toml"
    path.write_text('[plan]\ndistance_mm = [300, 500, 700]\nbaseline_mm = [150]\nalpha_deg = [90]\n'
                    '[extrinsics]\nmode = "kinematic"\ndesign = "fixed-board"\n')
    assert main(["campaign", "plan", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["lens_calibration"]["presentations"] == data["calibration_presentations"]["total"] == 12
    assert main(["campaign", "plan", str(path)]) == 0
    out = capsys.readouterr().out
    assert "kinematic design: 8 of 8 visits to run over B 150-150 mm, toe-in 0-0 deg, after 1 intrinsics visit" in out
    assert "calibration board presentations: 12: 12 at visits" in out
    assert ("lens calibration: 12 presentations at intrinsics-B150_Z300_A90, before the board is placed (a lens "
            "calibration: the fixed board alone does not separate left_axis_z_mm, right_axis_z_mm from the focal "
            "lengths") in out
    assert "held nominal all the same: slide_yaw_deg" in out
    assert "intrinsics a lens calibration of 12 presented views as prior (predicted)" in out
    assert "fixed board: placed once" in out


def test_a_lens_calibration_that_fails_fails_the_fit_with_its_reason():
    """The run's side of the plan's stage: nothing captured at the intrinsics visit is one clear error, and the
    fixed-board fit after it fails with that reason (every configuration then fails with it) instead of fitting
    without the prior the plan counted on."""
    from stereo_bench.campaign.documents import KinematicModelData
    from stereo_bench.campaign.extrinsics.kinematic import KinematicSource

    config = _config("fixed-board", extrinsics={"mode": "kinematic", "design": "fixed-board",
                                                "fixed_board_lens": "present"})
    source = KinematicSource()
    lens = source.prepare([], config, None, purpose="intrinsics")
    assert lens.lens is None and lens.error == ("no lens calibration for the fixed-board fit: the calibration visit "
                                                "captured nothing")
    fit = source.prepare([], config, None, purpose="kinematic", earlier=lens)
    assert fit.kinematic_model is None and fit.error == f"kinematic fit (fixed board): {lens.error}"
    assert KinematicModelData(**fit.record).error == lens.error  # recorded as the kinematic_model event says


def test_the_plan_predicts_the_sigma_of_r_t_at_every_measured_configuration(tmp_path, capsys):
    """What the fixed board's R, T will be worth before any view (issue 25 item 3): the planned model's sigma at each
    of paper-exp1's 25 configurations, approached as the steps approach them. It scales with the plan's corner noise,
    a lens prior sharpens T (the right camera's depth is the ratio of the focal lengths, docs/EXTRINSICS.md), the
    presented design has none, and a parameter held nominal is named as not counted. The sigmas against the scatter
    of repeated fits: tests/test_kinematics_fixed_board.py."""
    config = _config("fixed-board")
    alone = plan_summary(config)["predicted_extrinsics"]
    runnable = [c.config_id for c in expand_plan(config) if c.runnable]
    assert [r["config_id"] for r in alone["configurations"]] == runnable and len(runnable) == 25
    assert alone["held"] == [] and alone["corner_sigma_px"] == 0.1
    assert alone["intrinsics"] == "from the design's views alone"
    # Measured: sigma |T| 0.148-0.169 mm, angle(R) 0.0214 deg (0.1 px corners, no lens prior).
    assert 0.1 < alone["rms_sigma_T_mm"] < 0.25 and 0.01 < alone["rms_sigma_R_deg"] < 0.04, alone
    assert alone["max_sigma_T_mm"] == max(r["sigma_T_mm"] for r in alone["configurations"])
    assert all(r["extrapolated"] == [] and r["structure"]["baseline_mm"] > 0 for r in alone["configurations"])

    def extrinsics(**extra):
        return {"extrinsics": {"mode": "kinematic", "design": "fixed-board", **extra}}

    doubled = plan_summary(_config("fixed-board", **extrinsics(plan_corner_sigma_px=0.2, fixed_board_lens="none")))
    # First order in the corner noise; the landings' priors (the rig's repeatability) do not scale with it.
    assert doubled["predicted_extrinsics"]["rms_sigma_T_mm"] == pytest.approx(2 * alone["rms_sigma_T_mm"], rel=0.05)
    present = plan_summary(_config("fixed-board", **extrinsics(fixed_board_lens="present")))["predicted_extrinsics"]
    assert present["rms_sigma_T_mm"] < 0.6 * alone["rms_sigma_T_mm"], present  # measured 0.069 against 0.158 mm
    assert present["intrinsics"] == "a lens calibration of 12 presented views as prior (predicted)"
    assert plan_summary(_config("presented"))["predicted_extrinsics"] is None

    one_b = campaign_from_dict({"name": "one-b", "plan": {"distance_mm": [300, 500], "baseline_mm": [150],
                                                         "alpha_deg": [90]}, **extrinsics(fixed_board_lens="none")})
    held = plan_summary(one_b)["predicted_extrinsics"]["held"]
    assert {"slide_scale", "left_axis_z_mm"} <= set(held), held

    path = tmp_path / "exp1.toml"
    path.write_text('[plan]\ndistance_mm = [300, 400, 500, 600, 700]\nbaseline_mm = [50, 100, 150, 200, 250]\n'
                    'alpha_deg = [90]\n[extrinsics]\nmode = "kinematic"\ndesign = "fixed-board"\n')
    assert main(["campaign", "plan", str(path)]) == 0
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if line.startswith("predicted R, T"))
    assert line.startswith("predicted R, T at the 25 measured configurations (the planned fit to first order, 0.1 px "
                           "corners, intrinsics from the design's views alone): sigma |T| 0.1"), line
    assert "sigma angle(R) 0.0214 deg at every configuration" in line and "not counted" not in out
    path.write_text('[plan]\ndistance_mm = [300, 500]\nbaseline_mm = [150]\nalpha_deg = [90]\n'
                    '[extrinsics]\nmode = "kinematic"\ndesign = "fixed-board"\nfixed_board_lens = "none"\n')
    assert main(["campaign", "plan", str(path)]) == 0
    assert "not counted: the build tolerance of the " in capsys.readouterr().out
