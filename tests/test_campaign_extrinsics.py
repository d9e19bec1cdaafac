"""Campaigns with kinematic and nominal extrinsics on the rendered lab bench (half resolution, few views).

One kinematic campaign (the design's 9 visits, one fit, two configurations between the design's levels)
is shared by the tests that read it; the per-config and nominal campaigns reuse its model or are small.
What is checked: the recording (visits, the model and its TOML, truth, controller, structure documents,
the result columns), the measurement against the bench's truth within the uncertainty it states, replay to
the last digit (the model fitted again from the recorded views too), resume without visiting the design
again, a model file read from inside the session, and the board presentations each mode needs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest

from stereo_bench.campaign.config import campaign_from_dict, load_preset
from stereo_bench.campaign.execute import CampaignPlan, RunControl, replay_session, run_campaign
from stereo_bench.campaign.operator import SimulatedOperator
from stereo_bench.campaign.plan import PREPARE_ID, plan_summary
from stereo_bench.campaign.recorded import RecordedStart
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main
from stereo_bench.kinematics import load_model, model_from_toml
from tests.campaigns import SMALL, results_csv, small_config

pytestmark = pytest.mark.slow

#: The campaign tests' small half-resolution campaign, on the lab bench, over B x toe-in.
LAB_SMALL = {"name": "lab-small", "seed": 3, "sim": {"profile": "lab"},
             "calibration_board": {"cols": 11, "rows": 8, "square_mm": 25},
             "capture": {"calibration_views": 4, "settle_s": 0.3},  # the lab heads stop ringing 0.24 s after a move
             "plan": {"baseline_mm": [80, 200], "distance_mm": [500], "toe_in_deg": [0, 10], "alpha_deg": None}}


def lab_config(**sections):
    merged = {name: {**values, **sections.get(name, {})} if isinstance(values, dict) else values
              for name, values in LAB_SMALL.items()}
    return small_config(**{**sections, **merged})


def _two_configurations(config):
    """B 110 / toe-in 3 and B 170 / toe-in 7: between the design's levels (B 80/140/200, toe-in 0/5/10)."""
    plan = CampaignPlan.of(config)
    chosen = [c for c in plan.configurations if (c.baseline_mm, c.toe_in_deg) in {(80.0, 0.0), (200.0, 10.0)}]
    inner = [dataclasses.replace(chosen[0], baseline_mm=110.0, toe_in_deg=3.0, alpha_deg=87.0,
                                 config_id="B110_Z500_A87", index=0),
             dataclasses.replace(chosen[1], baseline_mm=170.0, toe_in_deg=7.0, alpha_deg=83.0,
                                 config_id="B170_Z500_A83", index=1)]
    return CampaignPlan.of(config, inner, plan.visits)


@pytest.fixture(scope="module")
def kinematic_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("kinematic") / "session"
    config = lab_config(extrinsics={"mode": "kinematic"})
    summary = run_campaign(config, out, yes=True, plan=_two_configurations(config))
    assert summary.exit_status == "success", summary.reason
    return out


def _events(session, kind):
    return SessionReader(session).events(kind=kind, attempt=None)


def test_the_design_is_visited_fitted_once_and_the_model_recorded(kinematic_session):
    reader = SessionReader(kinematic_session)
    design = RecordedStart.of(reader.start()).visits
    assert len(design) == 9 and {v.purpose for v in design} == {"kinematic"}
    assert {(v.baseline_mm, v.toe_in_left_deg) for v in design} >= {(80.0, 0.0), (200.0, 10.0)}
    views = _events(kinematic_session, "calibration_view")
    assert len(views) == 9 * 4 and {e.config_id for e in views} == {v.config_id for v in design}
    # The measured configurations get no calibration views: the model predicts their R, T.
    assert not [e for e in views if not e.config_id.startswith("design-")]
    (model_event,) = _events(kinematic_session, "kinematic_model")
    assert model_event.config_id is None and model_event.data.source == "design"
    assert model_event.data.n_views == 36 and model_event.data.visits_used == [v.config_id
                                                                                       for v in design]
    model = model_from_toml(reader.read_bytes(model_event.files["kinematic_model.toml"]).decode())
    assert model.fit.n_views == 36 and model.intrinsics_covariance_matrix().shape == (16, 16)
    # Every move records where the rig arrived from: the design approaches each axis from both sides.
    moves = [e for e in _events(kinematic_session, "move") if e.config_id.startswith("design-")]
    assert {e.data.approach["baseline_mm"] for e in moves} == {1, -1}


def test_kinematic_results_carry_mode_structure_truth_and_uncertainty(kinematic_session):
    rows = {row["config_id"]: row for row in results_csv(kinematic_session)}
    assert set(rows) == {"B110_Z500_A87", "B170_Z500_A83"}
    structures = {e.config_id: e.data for e in _events(kinematic_session, "structure")}
    truths = {e.config_id: e.data for e in _events(kinematic_session, "truth")}
    for config_id, row in rows.items():
        assert row["status"] == "measured" and row["extrinsics_mode"] == "kinematic"
        structure, truth = structures[config_id], truths[config_id]
        assert structure.used == "kinematic" and set(structure.sources) == {"kinematic", "nominal"}
        kinematic = structure.sources["kinematic"]
        # The columns are the used source's structure and the truth recorded at the measurement.
        assert float(row["baseline_used_mm"]) == pytest.approx(kinematic.structure["baseline_mm"], abs=1e-9)
        assert float(row["baseline_true_mm"]) == pytest.approx(truth.structure["baseline_mm"], abs=1e-9)
        assert float(row["square_true_mm"]) == pytest.approx(27.0 * 1.0008, abs=1e-9)
        # The prediction at a configuration the model was not fitted at, against the truth: within 4 of the
        # sigmas it states (parameters, landing repeatability, backlash).
        for key in ("baseline_mm", "alpha_left_deg", "alpha_right_deg"):
            error = kinematic.structure[key] - truth.structure[key]
            assert abs(error) <= 4 * kinematic.structure_sigma[key], (config_id, key, error)
        # The pan axes stand behind the optical centres: the true optical baseline is not the commanded B,
        # and the nominal geometry, which assumes it is, measures the square tenths of a mm off.
        assert abs(float(row["baseline_true_mm"]) - float(row["baseline_mm"])) > 1.0
        assert abs(structure.sources["nominal"].error_true_mm) > 0.3
        u = float(row["u_combined_mm"])
        assert float(row["U_expanded_mm"]) == pytest.approx(2 * u)
        assert float(row["sigma_mm"]) < u  # sigma_mm stays the random noise component
        assert abs(kinematic.error_true_mm) <= 4 * u
        budget = json.loads(row["uncertainty"]) if isinstance(row["uncertainty"], str) else row["uncertainty"]
        assert budget["combined"] == pytest.approx(u) and budget["noise_random_mm"] == pytest.approx(
            float(row["sigma_mm"]))


def test_the_controller_as_read_at_connect_is_recorded(kinematic_session):
    (controller,) = _events(kinematic_session, "controller")
    assert controller.config_id is None
    assert controller.data.info["build"].startswith("1.1") and "$100" in controller.data.info["settings"]


@pytest.mark.replay
def test_replay_refits_the_design_and_reproduces_every_number(kinematic_session, tmp_path):
    summary = replay_session(kinematic_session, tmp_path / "replayed")
    assert summary.differences == [] and summary.identical == summary.compared == 2
    again = SessionReader(tmp_path / "replayed")
    (model_event,) = again.events(kind="kinematic_model", attempt=None)
    original = _events(kinematic_session, "kinematic_model")[0]
    assert again.read_bytes(model_event.files["kinematic_model.toml"]) == \
        SessionReader(kinematic_session).read_bytes(original.files["kinematic_model.toml"])
    assert [e.data.structure for e in again.events(kind="truth")] == \
        [e.data.structure for e in _events(kinematic_session, "truth")]


@pytest.mark.replay
def test_replay_says_when_the_recorded_model_is_not_the_one_the_views_give(kinematic_session, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(kinematic_session, copy)
    (model_event,) = _events(copy, "kinematic_model")
    path = copy / model_event.files["kinematic_model.toml"]
    text = path.read_text()
    path.write_text(text.replace("reference_baseline_mm = ", "reference_baseline_mm = 1", 1))
    summary = replay_session(copy)
    assert any("kinematic model" in d and "differs" in d for d in summary.differences)


def test_a_resume_after_the_fit_does_not_visit_the_design_again(tmp_path):
    config = lab_config(extrinsics={"mode": "kinematic"}, capture={"calibration_views": 3})
    plan = _two_configurations(config)
    control = RunControl()

    class StopAtTheTarget(SimulatedOperator):
        """Asked to place the target (the first measured configuration: the design's visits ask nothing): stop."""

        def offer(self, ticket) -> None:
            if ticket.prompt.kind == "target":
                control.request_stop("test: stop after the design")
            super().offer(ticket)

    first = run_campaign(config, tmp_path / "s", plan=plan, control=control, operators=[StopAtTheTarget()])
    assert first.exit_status == "interrupted" and not first.rows
    assert SessionReader(tmp_path / "s").events(kind="kinematic_model", attempt=1)  # what was complete is kept
    second = run_campaign(config, tmp_path / "s", yes=True, resume=True)
    assert second.exit_status == "success" and {r["status"] for r in second.rows} == {"measured"}
    reader = SessionReader(tmp_path / "s")
    assert not reader.events(kind="calibration_view", attempt=2)
    assert not [e for e in reader.events(kind="move", attempt=2) if e.config_id.startswith("design-")]
    assert len(reader.events(kind="kinematic_model", attempt=None)) == 1
    assert {row.extrinsics_mode for row in reader.results()} == {"kinematic"}
    assert replay_session(tmp_path / "s").differences == []


def test_per_config_with_a_model_file_compares_all_sources_and_replays_from_inside(kinematic_session, tmp_path):
    (model_event,) = _events(kinematic_session, "kinematic_model")
    model_file = tmp_path / "model.toml"
    model_file.write_bytes(SessionReader(kinematic_session).read_bytes(model_event.files["kinematic_model.toml"]))
    config = lab_config(extrinsics={"mode": "per-config", "kinematic_file": str(model_file)},
                        capture={"calibration_views": 6},
                        plan={"baseline_mm": [110], "distance_mm": [500], "toe_in_deg": [3]})
    summary = run_campaign(config, tmp_path / "s", yes=True)
    assert summary.exit_status == "success"
    (row,) = results_csv(tmp_path / "s")
    assert row["extrinsics_mode"] == "per-config"
    assert float(row["baseline_used_mm"]) == pytest.approx(float(row["baseline_estimated_mm"]))
    (structure,) = _events(tmp_path / "s", "structure")
    sources = structure.data.sources
    assert set(sources) == {"calibrated", "kinematic", "nominal"}
    assert sources["calibrated"].uncertainty["structure"] == 0.0  # the rig did not move since its views
    # Same detections, three extrinsics: calibrated and kinematic agree to a few hundredths of a mm, nominal not.
    assert abs(sources["calibrated"].square_mean_mm - sources["kinematic"].square_mean_mm) < 0.05
    assert abs(sources["nominal"].error_true_mm) > 0.3
    model_file.unlink()  # a replay reads the session's copy, never the file the config named
    assert replay_session(tmp_path / "s").differences == []


def test_nominal_extrinsics_use_the_commanded_geometry_and_one_calibration(tmp_path):
    config = lab_config(extrinsics={"mode": "nominal"}, capture={"calibration_views": 5})
    plan = CampaignPlan.of(config)
    assert [v.purpose for v in plan.visits] == ["intrinsics"]
    summary = run_campaign(config, tmp_path / "s", yes=True, plan=plan)
    assert summary.exit_status == "success"
    reader = SessionReader(tmp_path / "s")
    assert {e.config_id for e in reader.events(kind="calibration_view")} == {plan.visits[0].config_id}
    rows = results_csv(tmp_path / "s")
    assert len(rows) == 4 and {r["extrinsics_mode"] for r in rows} == {"nominal"}
    for row in rows:
        # R, T of the ideal geometry at the commanded B and alpha, to the last digit.
        assert float(row["baseline_used_mm"]) == pytest.approx(float(row["baseline_mm"]), abs=1e-9)
        assert float(row["alpha_left_used_deg"]) == pytest.approx(float(row["alpha_deg"]), abs=1e-9)
        budget = json.loads(row["uncertainty"]) if isinstance(row["uncertainty"], str) else row["uncertainty"]
        assert budget["dominant"] == "structure"  # the rig's stated tolerances
        # Paper-like: tenths of a mm or more, and covered by its stated uncertainty's order of magnitude.
        error = float(row["square_mean_mm"]) - float(row["square_true_mm"])
        assert 0.1 < abs(error) < 3 * float(row["U_expanded_mm"])
    assert replay_session(tmp_path / "s").differences == []


def test_board_presentations_per_mode_and_adding_configurations_adds_none_to_kinematic():
    exp1 = load_preset("paper-exp1")
    assert exp1.sim.profile == "lab"
    counts = {}
    for mode in ("per-config", "kinematic", "nominal"):
        data = exp1.model_dump(mode="json")
        data["extrinsics"]["mode"] = mode
        counts[mode] = plan_summary(campaign_from_dict(data))["calibration_presentations"]
    assert counts["per-config"] == {"visits": 0, "configurations": 300, "placements": 0, "total": 300}
    assert counts["kinematic"]["total"] <= 110 and counts["kinematic"]["configurations"] == 0
    assert counts["nominal"]["total"] == 12
    data = exp1.model_dump(mode="json")
    data["extrinsics"]["mode"] = "kinematic"
    data["plan"]["distance_mm"] += [800, 900]
    more = plan_summary(campaign_from_dict(data))
    assert more["n_configurations"] > 25 and more["calibration_presentations"] == counts["kinematic"]
    assert load_preset("paper-exp2-toe-in").sim.profile == "lab"


#: The campaign tests' small campaign (ideal bench, B 100/150 at alpha 90, alpha 35 infeasible) in kinematic mode.
KINEMATIC_TOML = SMALL + '[extrinsics]\nmode = "kinematic"\n'


def test_campaign_schema_describes_the_extrinsics_sources(capsys):
    assert main(["campaign", "schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    extrinsics = schema["$defs"]["ExtrinsicsSection"]["properties"]
    assert extrinsics["mode"]["enum"] == ["per-config", "kinematic", "nominal", "fixed"]
    assert {"kinematic_file", "repeatability_mm", "repeatability_deg", "tolerances"} <= set(extrinsics)
    assert "yaw_deg" in schema["$defs"]["RigTolerances"]["properties"]


def test_campaign_plan_shows_the_design_and_the_presentations(capsys, tmp_path):
    path = tmp_path / "kin.toml"
    path.write_text(KINEMATIC_TOML)
    assert main(["campaign", "plan", str(path)]) == 0
    text = capsys.readouterr().out
    assert "kinematic design: 9 of 9 visits to run over B 100-150 mm, toe-in 0-0 deg" in text
    assert "design-1_B100_L0_R0" in text
    assert "calibration board presentations: 54: 54 at visits (adding configurations adds none)" in text
    assert main(["campaign", "plan", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert len(summary["design"]) == 9 and summary["extrinsics_mode"] == "kinematic"
    assert PREPARE_ID not in {c["config_id"] for c in summary["configurations"]}


def test_rig_calibrate_kinematics_runs_only_the_design_and_writes_the_model(tmp_path, capsys):
    config = tmp_path / "bench.toml"
    config.write_text(SMALL.replace("calibration_views = 6", "calibration_views = 3"))  # per-config there: 3 < 5
    argv = ["rig", "calibrate-kinematics", "--config", str(config), "--baseline-range", "80", "200",
            "--toe-in-range", "0", "10", "--out", str(tmp_path / "s"), "--yes"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    model = load_model(tmp_path / "s" / "kinematic_model.toml")
    assert model.fit.n_views == 27 and model.span["baseline_mm"] == [80.0, 200.0]
    assert model.span["toe_in_left_deg"] == [0.0, 10.0]
    assert "slide_scale" in out and "kinematic_file" in out
    reader = SessionReader(tmp_path / "s")
    assert reader.results() == [] and len(reader.events(kind="calibration_view")) == 27
    assert not [e for e in reader.events(kind="move") if not e.config_id.startswith("design-")]
    # Never overwritten; --port is needed by every other rig action.
    assert main(argv + ["--model", str(tmp_path / "s" / "kinematic_model.toml")]) == 2
    assert "not overwriting" in capsys.readouterr().err
    assert main(["rig", "status"]) == 2
    assert "--port is required" in capsys.readouterr().err
    assert main(["rig", "--port", str(tmp_path / "no-such-port"), "home", "calibrate-kinematics"]) == 2
    assert "runs on its own" in capsys.readouterr().err
    assert math.isfinite(np.sum(model.covariance_matrix()))


def test_a_kinematic_session_that_kept_only_detections_of_its_design_views_replays_every_number(tmp_path):
    # keep_frames = "measurement": the design visits' views are recorded as detections, not frames; the
    # replay fits the model again from those and must give the recorded model and results.
    config = lab_config(extrinsics={"mode": "kinematic"},
                        capture={"calibration_views": 3, "keep_frames": "measurement"})
    summary = run_campaign(config, tmp_path / "s", yes=True, plan=_two_configurations(config))
    assert summary.exit_status == "success", summary.reason
    views = _events(tmp_path / "s", "calibration_view")
    assert views and not any(e.frames for e in views)
    replayed = replay_session(tmp_path / "s", tmp_path / "replayed")
    assert replayed.differences == [] and replayed.identical == replayed.compared == 2
