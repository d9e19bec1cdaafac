"""The report's first screen (stereo_bench.report.answer): the error per source against nominal and as printed, the
predicted terms, the paper's tables beside ours and the verdicts on its claims."""

from __future__ import annotations

import math
import shutil

import pytest

from stereo_bench.cli import main
from stereo_bench.report.answer import (
    PAPER_TABLE1_MM,
    PAPER_TABLE2_MM,
    AnswerPoint,
    _table1,
    _table2,
    answer_of,
)
from stereo_bench.report.collect import read_session


def test_the_first_screen_of_a_simulated_session(small_reference):
    answer = answer_of(read_session(small_reference, key="s1"))
    measured = [p for p in answer.points]
    assert len(measured) == 2 and answer.sources[0] == "per-config"
    assert answer.pixel_sigma_px is not None and "reprojection RMS" in answer.pixel_sigma_note
    for point in measured:
        # The simulated bench knows the board as printed: its scale is a term of its own, not the rig's error.
        assert point.square_true_mm is not None
        error = point.errors_nominal_mm["per-config"]
        assert point.error_true_mm("per-config") == pytest.approx(error - point.print_scale_mm)
        terms = point.predicted_mm
        assert terms["noise"] > 0 and terms["calibration"] > 0 and terms["target"] > 0
        assert point.paper_gamma_mm > terms["noise"]  # gamma is a point's error; the square averages 54 corners
    assert any("print's own error" in line for line in answer.lines)
    claim_k, claim_alpha = answer.claims
    assert "K = 0.071-0.833" in claim_k.evidence[0] and claim_k.verdict.startswith("not supported")
    assert "α" in claim_alpha.claim and any("Table 2" in e for e in claim_alpha.evidence)
    assert answer.table1 == [] and answer.table2 == []  # B 100/150 at Z 450: no cell of the paper's grid


def _point(b, z, a, square, true=27.02):
    return AnswerPoint(f"B{b:g}_Z{z:g}_A{a:g}", b, z, a, "per-config", true, {"per-config": square - 27.0})


def test_the_papers_tables_beside_ours():
    cells = _table1([_point(50.0, 300.0, 90.0, 27.03), _point(250.0, 700.0, 90.0, 27.01)])
    assert len(cells) == len(PAPER_TABLE1_MM)
    by_key = {c.key: c for c in cells}
    assert by_key["B50_Z300"].paper_mm == 26.9195 and by_key["B50_Z300"].ours_mm["per-config"] == pytest.approx(27.03)
    assert by_key["B250_Z700"].paper_mm == 28.7729 and by_key["B100_Z300"].ours_mm == {}
    alpha = _table2([_point(600.0, 200.0, a, 27.0 + a / 1000) for a in (15.0, 25.0, 35.0)])
    assert [c.paper_mm for c in alpha] == list(PAPER_TABLE2_MM.values())
    notes = {c.key: c.note for c in alpha}
    # The paper's 25 and 35 deg values are its Table 1 cells B 50 / Z 500 and B 100 / Z 300 to the last digit.
    assert "B50/Z500" in notes["alpha25"] and "B100/Z300" in notes["alpha35"] and notes["alpha55"] == ""
    assert {c.key: c.ours_mm.get("per-config") for c in alpha}["alpha35"] == pytest.approx(27.035)
    assert _table1([_point(60.0, 300.0, 90.0, 27.0)]) == []


def test_the_report_opens_with_the_answer(small_reference, tmp_path):
    session = tmp_path / "small"
    shutil.copytree(small_reference, session)
    assert main(["report", str(session), "--no-images"]) == 0
    page = (session / "report" / "index.html").read_text()
    first = page.index("How the error depends on B, Z and α")
    assert first < page.index("Measured square per") and first < page.index("Uncertainty budget")
    assert "The paper's claims" in page and "docs/ERROR_MODEL.md" in page
    assert (session / "report" / "figures" / "s1-small_answer.png").stat().st_size > 10_000


def test_the_comparison_names_why_image_noise_does_not_explain_the_error(tmp_path):
    from stereo_bench.campaign.execute import run_campaign
    from tests.campaigns import LAB, small_config

    session = tmp_path / "lab"
    assert run_campaign(small_config(LAB), session, yes=True).exit_status == "success"
    assert main(["report", str(session), "--no-images"]) == 0
    page = (session / "report" / "index.html").read_text()
    # The lab bench's frames carry ~1e-3 px of sensor noise, while its corners scatter ~0.2 px about the model.
    assert "Here the median ratio is" in page and "scatter about the calibrated model by 0.2" in page


def test_a_trend_is_claimed_only_over_values_that_vary():
    from stereo_bench.report.answer import _claims

    sweep = [_point(600.0, 200.0, a, 27.0 + a / 1000) for a in (15.0, 25.0, 35.0, 45.0)]  # one K, four alphas
    claim_k, claim_alpha = _claims(sweep, ["per-config"])
    assert not any("smallest |error|" in e for e in claim_k.evidence)
    assert any("the smallest |error|" in e and "at α = 15°" in e for e in claim_alpha.evidence)


def test_a_kinematic_session_shows_the_kinematic_fits_calibration_term(tmp_path):
    """The joint term of the plan's design fit (docs/ERROR_MODEL.md section 5) beside the landing repeatability, and
    far below the old intrinsics-apart split (22-32 against 1.6-6.8 um on the lab bench)."""
    from stereo_bench.errormodel.rig import RigErrors
    from stereo_bench.errormodel.rigorous import CalibrationPlan, Setup, predict
    from tests.report_sessions import write_structured_session

    geometries = [(60.0, 400.0, 90.0), (150.0, 550.0, 84.0), (240.0, 700.0, 80.0)]
    session = write_structured_session(tmp_path, "kin", "kinematic", geometries, kinematic_fit_rms_px=0.21)
    answer = answer_of(read_session(session, key="k"))
    # No configuration calibrates: the noise is the design fit's (RMS / sqrt 2 per coordinate).
    assert answer.pixel_sigma_px == pytest.approx(0.21 / math.sqrt(2.0))
    assert "kinematic fit" in answer.pixel_sigma_note
    for point in answer.points:
        joint = point.predicted_mm.get("calibration (kinematic)")
        assert joint is not None and joint > 0 and point.predicted_mm.get("structure (kinematic)") is not None
        apart = predict(Setup.make(point.baseline_mm, point.distance_mm, point.alpha_deg), answer.pixel_sigma_px,
                        calibration=CalibrationPlan(), rig=RigErrors(mode="kinematic", intrinsics_visits=9))
        assert joint < 0.6 * apart.sigma_calibration_mm
    assert any("kinematic: RMS |error|" in line for line in answer.lines)


def test_the_answer_figure_of_errors_that_are_all_zero_or_unknown_draws_a_linear_axis_without_a_warning():
    """A log axis needs a value above zero: a session whose squares came out exactly nominal (or had no truth) got
    matplotlib's "no positive values" warning and an empty log axis; it gets a linear one that says why."""
    import warnings

    from stereo_bench.report.figures import answer_figure

    points = [_point(100, 400, 90, 27.0, true=27.0), _point(150, 400, 90, 27.0, true=None)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figure = answer_figure(points, ["per-config"], title="t", against_true=True)
    (ax,) = figure.axes
    assert ax.get_yscale() == "linear" and "(log)" not in ax.get_ylabel()
    assert any(text.get_text() == "no error above zero to draw" for text in ax.texts)
    logged = answer_figure([_point(100, 400, 90, 27.05)], ["per-config"], title="t", against_true=True)
    assert logged.axes[0].get_yscale() == "log"
