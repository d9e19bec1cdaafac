"""A fixed-board kinematic campaign on the rendered lab bench (half resolution): the board placed once by the
simulated operator, the rig moved in front of it, one fit with one board pose, two configurations between the
design's levels measured with its predictions against the bench's truth; then replayed."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from stereo_bench.campaign.execute import replay_session, run_campaign
from stereo_bench.campaign.recorded import RecordedStart
from stereo_bench.campaign.session import SessionReader
from stereo_bench.kinematics import model_from_toml
from tests.campaigns import results_csv
from tests.test_campaign_extrinsics import _two_configurations, lab_config

pytestmark = pytest.mark.slow


def lens_calibration(root):
    """The lens calibration made once (a calib_dir in ``root``): one per-config calibration of 12 presented views."""
    lens = lab_config(capture={"calibration_views": 12},
                      plan={"baseline_mm": [140], "distance_mm": [450], "toe_in_deg": [5]})
    assert run_campaign(lens, root / "lens", yes=True).exit_status == "success"
    calib_dir = root / "calib_dir"
    shutil.copytree(next((root / "lens" / "calib").glob("*/*")), calib_dir)
    return calib_dir


@pytest.fixture(scope="module")
def fixed_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("fixed-board")
    calib_dir = lens_calibration(root)
    config = lab_config(extrinsics={"mode": "kinematic", "design": "fixed-board", "calib_dir": str(calib_dir)})
    out = root / "session"
    # B 110 / toe-in 3 and B 170 / toe-in 7: between this design's levels too (B 80/120/160/200, toe-in 0/3.3/6.7/10)
    summary = run_campaign(config, out, yes=True, plan=_two_configurations(config))
    assert summary.exit_status == "success", summary.reason
    return out


def test_the_board_is_placed_once_and_every_visit_captured_without_presentations(fixed_session):
    reader = SessionReader(fixed_session)
    design = RecordedStart.of(reader.start()).visits
    assert len(design) == 32 and all(v.board_fixed for v in design)
    assert len({tuple(v.fixed_board_pose) for v in design}) == 1
    views = reader.events(kind="calibration_view", attempt=None)
    assert len(views) == 32 * 3 and all(e.config_id.startswith("design-") for e in views)
    prompts = [e.data.prompt for e in reader.events(kind="prompt", attempt=None)]
    assert "calibration_board" not in prompts and "calibration_view" not in prompts
    (model,) = reader.events(kind="kinematic_model", attempt=None)
    assert model.data.design == "fixed-board" and model.data.n_views == 96 and model.data.error is None
    assert len(model.data.identifiability) == 22
    assert all(row["identified"] for row in model.data.identifiability), model.data.identifiability
    assert 0.45 < model.data.fixed_board["left_share"] < 0.55  # the simulator's carriages move symmetrically


def test_the_predictions_and_the_square_hold_against_the_truth(fixed_session):
    # Measured at half resolution (scripts/bench_fixed_board.py --half: baseline within 0.08 mm, alphas 0.24 deg;
    # 1080p in docs/EXTRINSICS.md); within 4 stated sigmas, and the bounds those runs saw with room.
    assert_predictions_hold(fixed_session)


def assert_predictions_hold(session) -> None:
    """Both configurations measured with the kinematic prediction, which holds against the bench's truth: baseline
    within 0.15 mm, alphas 0.35 deg, rotation 0.05 deg and 4 stated sigmas; the square within 2 u_c of the truth."""
    reader = SessionReader(session)
    rows = {row["config_id"]: row for row in results_csv(session)}
    assert set(rows) == {"B110_Z500_A87", "B170_Z500_A83"}
    structures = {e.config_id: e.data for e in reader.events(kind="structure")}
    truths = {e.config_id: e.data for e in reader.events(kind="truth")}
    for config_id, row in rows.items():
        assert row["status"] == "measured" and row["extrinsics_mode"] == "kinematic"
        kinematic, truth = structures[config_id].sources["kinematic"], truths[config_id]
        for key, bound in (("baseline_mm", 0.15), ("alpha_left_deg", 0.35), ("alpha_right_deg", 0.35),
                           ("rotation_deg", 0.05)):
            error = kinematic.structure[key] - truth.structure[key]
            assert abs(error) <= bound, (config_id, key, error)
            if key in kinematic.structure_sigma:
                assert abs(error) <= 4 * kinematic.structure_sigma[key], (config_id, key, error)
        u = float(row["u_combined_mm"])
        assert abs(kinematic.error_true_mm) <= 2 * u and math.isfinite(u)


@pytest.mark.replay
def test_a_fixed_board_session_replays_to_the_last_digit(fixed_session, tmp_path):
    summary = replay_session(fixed_session, tmp_path / "replayed")
    assert summary.differences == [] and summary.identical == summary.compared == 2
    again = SessionReader(tmp_path / "replayed")
    (model,) = again.events(kind="kinematic_model", attempt=None)
    original = SessionReader(fixed_session).events(kind="kinematic_model", attempt=None)[0]
    assert again.read_bytes(model.files["kinematic_model.toml"]) == \
        SessionReader(fixed_session).read_bytes(original.files["kinematic_model.toml"])
    assert np.allclose(model.data.fixed_board["T_ref_board"], original.data.fixed_board["T_ref_board"])


@pytest.mark.parametrize(("capture", "views"), [("enter", 3), ("auto", 2)])
def test_rig_calibrate_kinematics_fits_a_fixed_board_model_alone(tmp_path, capsys, capture, views):
    """Also with views taken automatically (the simulated hand): a fixed board is captured, not streamed (two
    frames per visit there: the capture mode is what differs; with one frame per visit the left pan axis's z is
    determined worse than its tolerance and held nominal)."""
    from stereo_bench.cli import main
    from stereo_bench.kinematics import load_model
    from tests.campaigns import SMALL

    config = tmp_path / "bench.toml"
    assert "[capture]" in SMALL and "[extrinsics]" not in SMALL
    config.write_text(SMALL.replace("[capture]", f'[capture]\ncalibration_capture = "{capture}"')
                      + f"\n[extrinsics]\nfixed_board_views = {views}\n"
                      # The board alone (the plan's table would add a lens calibration of presented views here:
                      # the resume test below takes one; streamed by the simulated hand it costs this test 80 s)
                      + 'fixed_board_lens = "none"\n')
    argv = ["rig", "calibrate-kinematics", "--config", str(config), "--design", "fixed-board", "--baseline-range",
            "80", "200", "--toe-in-range", "0", "10", "--out", str(tmp_path / "s"), "--yes"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "fixed board: placed once" in captured.err and f"32 visits x {views} views" in captured.err
    # What the fitted model's R, T are worth where the campaign measures: its own sigma, at each configuration.
    (line,) = [line for line in captured.out.splitlines() if line.startswith("predicted R, T at the ")]
    assert "measured configurations (the fitted model, its " in line and "sigma |T| " in line, line
    model = load_model(tmp_path / "s" / "kinematic_model.toml")
    assert model.fit.n_views == 32 * views and model.span["baseline_mm"] == [80.0, 200.0]
    assert all(p.identifiable for p in model.parameters.values())
    reader = SessionReader(tmp_path / "s")
    assert reader.results() == [] and len(reader.events(kind="calibration_view")) == 32 * views
    (event,) = reader.events(kind="kinematic_model", attempt=None)
    assert event.data.design == "fixed-board" and len(event.data.identifiability) == 22
    assert reader.events(kind="calibration_selection", attempt=None) == []


def test_without_calib_dir_the_lens_is_calibrated_from_presentations_once_even_across_a_resume(tmp_path):
    """No calib_dir: the plan's table says the board alone cannot place the left pan axis' depth (it trades against
    the focal lengths) and a 12-view lens prior can, so the run presents 12 views first, calibrates them and records
    that calibration, then places the board and visits the design. Stopped half-way through the design, the board may
    have been moved since its views: one board pose is the fit's premise, so the resume starts the design over (its
    placement first) and fits only its own views; the lens calibration is read back, its presentations are not asked
    for again, and it is the fit's prior. The fit identifies what the plan said; the predictions hold against the
    truth; the stopped attempt's views stay recorded, and the session replays."""
    import threading

    from stereo_bench.campaign.bench import SimulatedPresenter
    from stereo_bench.campaign.execute import RunControl
    from stereo_bench.campaign.plan import plan_summary

    config = lab_config(extrinsics={"mode": "kinematic", "design": "fixed-board", "fixed_board_views": 1},
                        capture={"calibration_views": 12})
    plan = _two_configurations(config)
    lens = [v for v in plan.visits if v.purpose == "intrinsics"]
    design = [v for v in plan.visits if v.purpose == "kinematic"]
    assert [v.config_id for v in lens] == ["intrinsics-B80_Z500_A90"] and plan.visits[0] == lens[0]
    planned = plan_summary(config)
    assert planned["lens_calibration"]["gains"] == ["left_axis_z_mm"]
    assert planned["calibration_presentations"]["total"] == 12
    said = {row["name"] for row in planned["identifiability"] if row["identified"]}
    assert len(said) == 22
    n_visits = len(design)
    out, control, done = tmp_path / "s", RunControl(), threading.Event()

    def stop_mid_design() -> None:
        stream = out / "documents.jsonl"
        while not done.is_set():
            if stream.exists() and stream.read_text().count('"calibration_view"') >= 12 + n_visits // 3:
                control.request_stop("test: stopped mid-design")
                return
            done.wait(0.005)

    placements = []
    original = SimulatedPresenter.place_board

    def counted(self, T_rig_board):
        placements.append(np.array(T_rig_board))
        return original(self, T_rig_board)

    watcher = threading.Thread(target=stop_mid_design, daemon=True)
    watcher.start()
    try:
        SimulatedPresenter.place_board = counted
        first = run_campaign(config, out, plan=plan, control=control, yes=True)
        assert first.exit_status == "interrupted"
        reader = SessionReader(out)
        stopped_views = len([e for e in reader.events(kind="calibration_view", attempt=1)
                             if e.config_id.startswith("design-")])
        assert 0 < stopped_views < n_visits
        (calibration,) = reader.events(kind="calibration", attempt=1)
        assert calibration.config_id == lens[0].config_id
        second = run_campaign(config, out, plan=plan, yes=True, resume=True)
    finally:
        SimulatedPresenter.place_board = original
        done.set()
    assert second.exit_status == "success", second.reason
    assert len(placements) == 2  # placed again before the design's first visit of the resume
    reader = SessionReader(out)
    views = {attempt: [e.config_id for e in reader.events(kind="calibration_view", attempt=attempt)]
             for attempt in (1, 2)}
    assert views[1].count(lens[0].config_id) == 12  # presented once
    assert len(views[1]) == 12 + stopped_views  # kept, not overwritten
    assert len(views[2]) == n_visits and all(cid.startswith("design-") for cid in views[2])  # not presented again
    assert lens[0].config_id not in {e.config_id for e in reader.events(kind="move", attempt=2)}
    (model,) = reader.events(kind="kinematic_model", attempt=None)
    assert model.attempt == 2 and model.data.n_views == n_visits and model.data.error is None
    assert model.data.lens_visit == lens[0].config_id
    fitted = model_from_toml(reader.read_bytes(model.files["kinematic_model.toml"]).decode())
    assert fitted.fit.intrinsics == "refined jointly, lens calibration as prior"
    # Every parameter the plan said the design would identify (with the lens prior), the fit identified.
    assert said <= {row["name"] for row in model.data.identifiability if row["identified"]}
    # Seen on this seed: baseline within 0.065 mm, alphas 0.090 deg, rotation 0.028 deg, each within 1.7 stated sigmas
    # (half resolution, one frame per visit); without the lens calibration (fixed_board_lens = "none") the same run
    # holds both pan axes' depths nominal and is 1.3-3.4 mm off in baseline, 5-14 sigmas (docs/EXTRINSICS.md).
    assert_predictions_hold(out)
    assert replay_session(out).differences == []
