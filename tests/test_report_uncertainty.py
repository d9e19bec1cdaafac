"""The report's uncertainty and structure (issues 11 and 12, item 3 of each): error ± U in the tables, U as error bars,
the budget table, the normalised-error plot, the extrinsics side by side and the structural-error section; sessions
without those records say what is missing."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
from report_sessions import (
    BUDGETS,
    GRID,
    INFEASIBLE,
    NOMINAL_SQUARE_MM,
    SQUARE_TRUE_MM,
    SQUARES_RECORDED,
    SWEEP,
    TARGET_PRINT_U_MM,
    expected,
    write_structured_session,
)
from test_report import SAMPLE_SESSION, check_page, row, write_session

from stereo_bench.campaign.documents import parse_document
from stereo_bench.cli import main
from stereo_bench.report import figures
from stereo_bench.report.build import build_report, structural_points
from stereo_bench.report.collect import budget_of, read_session, structure_of
from stereo_bench.report.tables import distance_baseline_tables, uncertainty_decimals

MODES = ("per-config", "kinematic", "nominal")


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict:
    """Three sessions of one campaign, one per extrinsics mode, and their report."""
    root = tmp_path_factory.mktemp("built")
    sessions = [write_structured_session(root / mode, f"exp-{mode}", mode, GRID + SWEEP, infeasible=INFEASIBLE)
                for mode in MODES]
    summary = build_report(sessions, root / "report")
    return {"root": root, "sessions": sessions, "report": root / "report", "summary": summary}


# -- reading the records ---------------------------------------------------------------------------------
def test_the_budget_is_read_with_unknown_components_kept_unknown():
    budget = budget_of({"u_combined_mm": 0.5, "U_expanded_mm": 1.0, "uncertainty_mm": {
        "noise": 0.0004, "calibration": None, "structure": 0.5, "target": 0.001, "combined": 0.5, "expanded": 1.0,
        "k": 2.0}})
    assert budget.components["calibration"] is None and budget.unknown == ["calibration"] and not budget.complete
    assert budget.dominant == "structure" and budget.share("structure") == pytest.approx(1.0)
    assert budget.share("calibration") is None  # unknown is not 0 %
    # the columns alone: k from U / u_c, the components not recorded (not zero)
    only = budget_of({"u_combined_mm": 0.002, "U_expanded_mm": 0.006})
    assert only.k == pytest.approx(3.0) and not only.components_recorded and only.dominant is None
    assert budget_of({"uncertainty_mm": {"combined": 0.002, "k": 2.0}}).expanded == pytest.approx(0.004)
    assert budget_of({"sigma_mm": 0.0002}) is None  # a row of an older session: no budget


EYE, T, FRAME = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [-100.0, 0.0, 0.0], {
    "source": "sim", "shape": [480, 640], "dtype": "uint8"}


def _event(kind: str, data: dict):
    """A typed event document as a session reader yields it (the header's values do not matter here)."""
    return parse_document({"type": "event", "seq": 0, "time": "2026-01-01T00:00:00.000000Z", "monotonic": 0.0,
                           "attempt": 1, "config_id": "c", "kind": kind, "data": data})


def test_the_structure_is_read_from_its_event_then_the_row_then_the_truth():
    e = expected(100.0, 500.0, 80.0, "kinematic")
    row_ = {"config_id": e.config_id, "baseline_mm": 100.0, "alpha_deg": 80.0, "tilt_deg": 0.0, "status": "measured",
            "square_mean_mm": 27.01, "extrinsics_mode": "kinematic", "baseline_used_mm": 96.2,
            "alpha_left_used_deg": 79.5, "alpha_right_used_deg": 80.2, "square_true_mm": 27.02}
    truth = _event("truth", {"profile": "lab", "R": EYE, "T": T, "structure": e.truth,
                             "target": {"kind": "target", "square_true_mm": 99.0}})
    out = structure_of(row_, [truth])
    assert out.mode == "kinematic" and out.mode_origin == "result row"
    assert out.extrinsics["used"] == {"baseline_mm": 96.2, "alpha_left_deg": 79.5, "alpha_right_deg": 80.2,
                                      "rotation_deg": None}
    assert out.extrinsics["kinematic"] == out.extrinsics["used"]  # the kinematic mode used the kinematic prediction
    assert out.extrinsics["truth"] == e.truth and out.origin["truth"] == "truth event"
    assert out.square_true_mm == 27.02  # the row's column comes before the truth event's
    # the nominal structure of the commanded B and alpha: B, alpha and a rotation of twice the toe-in
    assert out.extrinsics["nominal"] == pytest.approx({"baseline_mm": 100.0, "alpha_left_deg": 80.0,
                                                       "alpha_right_deg": 80.0, "rotation_deg": 20.0})
    assert out.squares_mm == {"kinematic": 27.01} and out.extrinsics["calibrated"] is None
    # the structure event wins over the row and the truth event, and brings each source's square and budget
    event = _event("structure", {
        "mode": "kinematic", "used": "kinematic", "axes": {}, "truth": {"structure": e.structures["calibrated"]},
        "sources": {"kinematic": {"R": EYE, "T": T, "structure": e.structures["kinematic"], "square_mean_mm": 27.0123,
                                  "structure_sigma": {"baseline_mm": 0.02}, "uncertainty": {"combined": 0.002}},
                    "nominal": {"R": EYE, "T": T, "structure": e.nominal, "square_mean_mm": 28.1,
                                "note": "tolerances only",
                                "uncertainty": {"noise": 0.001, "calibration": None, "structure": 0.3,
                                                "target": 0.001, "combined": 0.3, "k": 2.0}}}})
    out = structure_of(row_, [truth, event])
    assert out.extrinsics["used"] == e.structures["kinematic"] == out.extrinsics["kinematic"]
    assert out.extrinsics["truth"] == e.structures["calibrated"] and out.origin["truth"] == "structure event"
    assert out.sigma["used"] == out.sigma["kinematic"] == {"baseline_mm": 0.02}
    assert out.squares_mm == {"kinematic": 27.01, "nominal": 28.1}  # the row's own square wins for its mode
    assert out.budgets["nominal"].unknown == ["calibration"] and out.budgets["nominal"].expanded == pytest.approx(0.6)
    assert out.budgets["kinematic"].combined == 0.002  # the row has no budget: the event's for the same source
    assert out.notes == {"nominal": "tolerances only"}
    # a simulated frame's metadata (sessions before the truth event): mean over the measurement frames
    frames = [_event("measurement_frame", {"index": 0, "left": {**FRAME, "meta": {"truth": {
        "structure": {**e.truth, "baseline_mm": baseline}, "board": {"print_scale": scale}}}}, "right": FRAME})
        for baseline, scale in ((95.9, 1.001), (96.1, 1.003))]
    out = structure_of({**row_, "square_true_mm": None}, frames)
    assert out.extrinsics["truth"]["baseline_mm"] == pytest.approx(96.0)
    assert out.origin["truth"] == "simulated frames' metadata" and out.square_true_mm is None  # no config: no nominal


# -- tables and figures ------------------------------------------------------------------------------------
def test_table_cells_show_error_plus_minus_U_and_say_when_U_is_missing():
    rows = [row(50, 300, 90, square=27.0125), row(50, 400, 90, square=26.99), row(100, 300, 90, square=27.0)]
    known = {"B50_Z300_A90": (0.0050, True), "B50_Z400_A90": (0.0123, False)}
    (table,) = distance_baseline_tables(rows, uncertainty=lambda r: known.get(r["config_id"], (None, True)))
    cells = {c.config_id: c for line in table.cells for c in line if c.measured}
    assert cells["B50_Z300_A90"].error_text() == "+0.0125 ± 0.0050"
    assert cells["B50_Z400_A90"].error_text() == "-0.0100 ± 0.0123*"  # U without an unknown component
    # no budget: the noise σ, said so; two significant digits of the uncertainty, the error to the same place
    assert cells["B100_Z300_A90"].error_text() == "+0.00000 ± 0.00020 (σ noise)"
    lines = table.error_csv().splitlines()
    assert lines[1] == "50,+0.0125 +- 0.0050,-0.0100 +- 0.0123*"
    assert lines[2] == "100,+0.00000 +- 0.00020 (sigma noise),"
    assert table.has_uncertainty()


def test_an_uncertainty_is_stated_to_two_significant_digits():
    assert uncertainty_decimals(0.0025) == 4 and uncertainty_decimals(0.0123) == 4  # at least 4
    assert uncertainty_decimals(0.000043) == 6 and uncertainty_decimals(0.35, None, 0.0011) == 4
    assert uncertainty_decimals(1e-12) == 7 and uncertainty_decimals(None, 0.0) == 4  # at most 7; none known


def _bars(figure) -> list[tuple[float, str]]:
    """(half height, line style) of every error bar drawn."""
    return [bar for ax in figure.axes for bar in _bars_of(ax)]


def _bars_of(ax) -> list[tuple[float, str]]:
    out = []
    for container in ax.containers:
        if hasattr(container, "lines") and container.lines[2]:
            collection = container.lines[2][0]
            style = collection.get_linestyle()[0]
            for segment in collection.get_segments():
                out.append((round(float(abs(segment[1][1] - segment[0][1])) / 2, 9),
                            "solid" if style[1] is None else "dashed"))
    return out


def test_error_bars_are_U_dashed_when_incomplete_and_never_zero_when_unknown():
    rows = [row(50, 300, 90, square=27.01, sigma=0.0002), row(50, 400, 90, square=27.02, sigma=0.0003),
            row(100, 300, 90, square=27.03, sigma=None), row(100, 400, 90, square=27.0, sigma=0.0004)]
    uncertainties = {"B50_Z300_A90": (0.004, True), "B50_Z400_A90": (0.009, False)}
    figure = figures.error_figure(rows, {}, x_key="distance_mm", series_keys=("baseline_mm",), title="8",
                                  uncertainties=uncertainties)
    bars = sorted(_bars(figure))
    # U (solid), U of an incomplete budget (dashed), the noise sigma of a row without a budget (dotted), and no
    # bar at all for the row that has neither
    assert [half for half, _ in bars] == [0.0004, 0.004, 0.009]
    assert dict((half, style) for half, style in bars) == {0.004: "solid", 0.009: "dashed", 0.0004: "dashed"}
    labels = [text.get_text() for legend in figure.axes[0].get_children()
              if isinstance(legend, type(figure.axes[0].get_legend())) for text in legend.get_texts()]
    assert "measured ± U (expanded)" in labels and "± σ, image noise only (no budget)" in labels


def test_normalised_coverage_figures():
    assert figures.coverage([1.0, -1.0, 3.0, None]) == (3, pytest.approx(np.sqrt(11 / 3)), pytest.approx(2 / 3))
    assert figures.coverage([None]) == (0, None, None)
    points = [figures.NormalisedPoint("a", 0.5, 0.4), figures.NormalisedPoint("b", -150.0, None, complete=False)]
    figure = figures.normalised_figure(points, title="n")
    ax = figure.axes[0]
    assert ax.get_yscale() == "symlog" and ax.get_ylim()[0] <= -150  # the far point is on the plot
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a", "b*"]
    assert figures.png_bytes(figure).startswith(b"\x89PNG")


# -- a report of sessions with the new records -----------------------------------------------------------
def test_report_tables_show_error_plus_minus_U(built):
    report = built["report"]
    text = (report / "index.html").read_text(encoding="utf-8")
    for mode in MODES:
        e = expected(50.0, 300.0, 90.0, mode)
        error = e.squares_mm[mode] - NOMINAL_SQUARE_MM
        incomplete = "*" if None in BUDGETS[mode].values() else ""
        assert f"{error:+.4f} ± {e.expanded:.4f}{incomplete}" in text
        lines = (report / "tables" / f"s{MODES.index(mode) + 1}-exp-{mode}_table1_A90_error.csv").read_text()
        assert f"{error:+.4f} +- {e.expanded:.4f}{incomplete}" in lines.splitlines()[1]
    assert "(σ noise)" not in text  # every measured row has a budget
    check_page(report)


def test_report_budget_table_marks_the_dominant_component_and_unknown_ones(built):
    report = built["report"]
    for i, mode in enumerate(MODES, start=1):
        rows = read_csv(report / "tables" / f"s{i}-exp-{mode}_budget.csv")
        assert len(rows) == len(GRID + SWEEP)  # measured configurations only
        for r in rows:
            e = expected(float(r["config_id"].split("_")[0][1:]), float(r["config_id"].split("_")[1][1:]),
                         float(r["config_id"].split("_")[2][1:]), mode)
            assert float(r["u_combined_mm"]) == pytest.approx(e.combined)
            assert float(r["U_expanded_mm"]) == pytest.approx(2 * e.combined) and float(r["k"]) == 2.0
            known = {name: v for name, v in BUDGETS[mode].items() if v is not None}
            assert r["dominant"] == max(known, key=known.get)
            assert r["unknown"] == " ".join(n for n, v in BUDGETS[mode].items() if v is None)
            assert (r["u_calibration_mm"] == "") == (BUDGETS[mode]["calibration"] is None)  # unknown: empty, not 0
            error = e.squares_mm[mode] - NOMINAL_SQUARE_MM
            assert float(r["normalised_error"]) == pytest.approx(error / e.combined)
            # against the true printed square, u_c without the board's own print uncertainty (combined_vs_true)
            vs_true = np.sqrt(e.combined**2 - TARGET_PRINT_U_MM**2)
            assert float(r["normalised_error_true"]) == pytest.approx((e.squares_mm[mode] - SQUARE_TRUE_MM) / vs_true)
    text = (report / "index.html").read_text(encoding="utf-8")
    assert text.count("class='unknown'") == len(GRID + SWEEP)  # the nominal session's calibration component
    assert "<td class='dominant'>0.35000</td>" in text  # nominal: the structure dominates
    assert "<td class='dominant'>0.00110</td>" in text  # per-config: the target dominates


def test_report_has_a_normalised_error_plot_per_session_with_a_budget(built):
    files = built["summary"].files
    for i, mode in enumerate(MODES, start=1):
        assert f"figures/s{i}-exp-{mode}_normalised.png" in files
        assert f"tables/s{i}-exp-{mode}_budget.csv" in files
    text = (built["report"] / "index.html").read_text(encoding="utf-8")
    # the per-config session: its error against the nominal 27 mm is the print scale's (outside ±2 u_c), against
    # the true square 0.47 u_c: both figures are stated
    z_nominal = (expected(50.0, 300.0, 90.0, "per-config").squares_mm["per-config"] - 27.0) / \
        expected(50.0, 300.0, 90.0, "per-config").combined
    assert f"RMS of error / u_c {z_nominal:.2f}, |error| ≤ U for 0%" in text
    assert "|measured − true| ≤ U for 100%" in text


def test_report_structural_section_has_a_panel_per_mode(built):
    sessions = [read_session(path, key=f"s{i}") for i, path in enumerate(built["sessions"], start=1)]
    for s, mode in zip(sessions, MODES, strict=True):
        s.key = f"s{MODES.index(mode) + 1}-exp-{mode}"
    rows, expanded, duplicates = structural_points(sessions)
    assert list(rows) == list(MODES)
    for mode, points in rows.items():
        measured = [p for p in points if p["status"] == "measured"]
        assert len(measured) == len(GRID + SWEEP)  # one point per geometry across the three sessions
        for point in measured:
            geometry = (point["baseline_mm"], point["distance_mm"], point["alpha_deg"])
            e = expected(*geometry, mode)
            assert point["error_mm"] == pytest.approx(e.squares_mm[mode] - NOMINAL_SQUARE_MM)
            # drawn from the session that measured with the mode: it carries that session's U
            assert point["config_id"].startswith(f"s{MODES.index(mode) + 1}-") and point["_used"]
            assert expanded[point["config_id"]][0] == pytest.approx(e.expanded)
        assert [p["status"] for p in points if p["status"] != "measured"] == ["infeasible"]
    # every mode in every session that recorded it: per-config 1, kinematic 2, nominal 3 sessions
    assert duplicates == sum(len(SQUARES_RECORDED[m]) for m in MODES) * len(GRID + SWEEP) - 3 * len(GRID + SWEEP)
    files = built["summary"].files
    for name in ("structural_fig8_A90", "structural_fig9_A90", "structural_fig11"):
        assert f"figures/{name}.png" in files
    figure = figures.structural_figure(list(rows.items()), x_key="distance_mm", series_keys=("baseline_mm",),
                                       title="8", uncertainties=expanded)
    assert [ax.get_title() for ax in figure.axes] == [figures.SOURCE_LABELS[m] for m in MODES]
    for ax, mode in zip(figure.axes, MODES, strict=True):  # each panel's error bars: its own session's U
        assert {half for half, _ in _bars_of(ax)} == {round(expected(50.0, 300.0, 90.0, mode).expanded, 9)}
    text = (built["report"] / "index.html").read_text(encoding="utf-8")
    assert 'id="structural-error"' in text and "Not in these sessions" not in text
    points = read_csv(built["report"] / "tables" / "structural.csv")
    assert {p["source"] for p in points} == set(MODES)


def test_report_shows_the_extrinsics_side_by_side(built):
    text = (built["report"] / "index.html").read_text(encoding="utf-8")
    e = expected(100.0, 500.0, 80.0, "kinematic")
    # the configuration block of the kinematic session: used, kinematic, nominal and truth, calibrated absent
    block = text[text.index('id="s2-exp-kinematic-B100_Z500_A80"'):]
    block = block[:block.index("</table>")]
    assert "used by the measurement: kinematic" in block and "truth (simulator)" in block
    assert f"<td>{e.truth['baseline_mm']:.3f}</td>" in block and f"<td>{e.nominal['alpha_left_deg']:.3f}</td>" in block
    assert "calibrated (board views here)" not in block
    rows = read_csv(built["report"] / "tables" / "s2-exp-kinematic_structure.csv")
    mine = {r["source"]: r for r in rows if r["config_id"] == e.config_id}
    assert set(mine) == {"used", "kinematic", "nominal", "truth"}
    assert float(mine["truth"]["baseline_mm"]) == pytest.approx(96.0)
    assert float(mine["nominal"]["rotation_deg"]) == pytest.approx(20.0)
    assert float(mine["kinematic"]["square_mm"]) == pytest.approx(e.squares_mm["kinematic"])
    assert float(mine["nominal"]["error_mm"]) == pytest.approx(e.squares_mm["nominal"] - 27.0)
    assert "figures/s2-exp-kinematic_structure.png" in built["summary"].files  # each source minus the truth


# -- sessions without the new records ------------------------------------------------------------------
def test_an_old_session_reports_and_says_what_is_missing(tmp_path):
    session = tmp_path / "session"
    shutil.copytree(SAMPLE_SESSION, session)
    assert main(["report", str(session), "--out", str(tmp_path / "out"), "--no-images"]) == 0
    report = tmp_path / "out"
    check_page(report)
    text = (report / "index.html").read_text(encoding="utf-8")
    assert "No uncertainty budget is recorded in this session" in text
    assert "(σ noise)" in text and "CSV of error ± σ" in text and "± U" not in text
    lines = (report / "tables" / "s1-sample-session_table1_A90_error.csv").read_text().splitlines()
    assert lines[1].endswith("+0.00496 +- 0.00039 (sigma noise)")  # B 100, Z 450: the recorded error and sigma
    assert "Not in these sessions: kinematic model, nominal (commanded B, α)" in text
    assert not (report / "figures" / "s1-sample-session_normalised.png").exists()
    assert not (report / "tables" / "s1-sample-session_budget.csv").exists()
    # the calibrated extrinsics come from the recorded calibration files; no truth in this recording
    rows = read_csv(report / "tables" / "s1-sample-session_structure.csv")
    used = {r["config_id"]: r for r in rows if r["source"] == "used"}
    assert float(used["B100_Z450_A90"]["baseline_mm"]) == pytest.approx(100.01599, abs=1e-4)  # |T| of calib
    assert used["B100_Z450_A90"]["origin"] == "calibration file"
    assert "truth" not in {r["source"] for r in rows}
    assert "figures/structural_fig9_A90.png" in {str(p.relative_to(report)) for p in report.rglob("*.png")}


def test_a_session_with_columns_but_no_structure_event_or_truth(tmp_path):
    """The result row alone (no structure, no truth event, no budget components): the report still draws U."""
    session = write_structured_session(tmp_path / "k", "columns-only", "kinematic", GRID, truth=False,
                                       structure_event=False)
    rows = read_csv(session / "results.csv")
    assert rows[0]["U_expanded_mm"] and rows[0]["extrinsics_mode"] == "kinematic"
    summary = build_report([session], tmp_path / "out", images=False)
    text = (tmp_path / "out" / "index.html").read_text(encoding="utf-8")
    assert "Not recorded in this session: calibrated extrinsics, the truth" in text
    # the kinematic prediction is what the measurement used (the row's columns); without a truth, it is drawn
    # against the nominal geometry
    assert "figures/s1-columns-only_structure.png" in summary.files
    assert "(no truth recorded: the nominal geometry is the reference)" in text
    assert "Not in these sessions: per-config extrinsics (calibrated here), nominal (commanded B, α)" in text
    assert "figures/s1-columns-only_normalised.png" in summary.files
    budget = read_csv(tmp_path / "out" / "tables" / "s1-columns-only_budget.csv")
    assert all(r["normalised_error_true"] == "" for r in budget)  # no truth: not drawn, not invented
    check_page(tmp_path / "out")


def test_a_session_whose_rows_have_no_new_columns_and_nothing_measured(tmp_path):
    session = write_session(tmp_path / "failing", "failing", [row(100, 400, 90, "failed", reason="no board")])
    build_report([session], tmp_path / "out")
    text = (tmp_path / "out" / "index.html").read_text(encoding="utf-8")
    assert "No configuration was measured: no uncertainty budget." in text
    assert "No configuration was measured in these sessions: no structural error to show." in text
    check_page(tmp_path / "out")
