"""Reports: table layouts pinned, figures drawn, statuses marked, the page well-formed, files atomic and safe."""

from __future__ import annotations

import csv
import io
import json
import shutil
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereo_bench.campaign.session import SessionWriter
from stereo_bench.cli import main
from stereo_bench.report import figures
from stereo_bench.report.build import MANIFEST, ReportError, build_report
from stereo_bench.report.collect import DEFAULT_PIXEL_SIGMA_PX, predict_configuration, read_session
from stereo_bench.report.tables import alpha_tables, distance_baseline_tables, with_plan

SAMPLE_SESSION = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"


def row(b, z, a, status="measured", square=None, *, fraction=1.0, reason=None, sigma=0.0002):
    out = {"config_id": f"B{b}_Z{z}_A{a}", "baseline_mm": float(b), "distance_mm": float(z), "alpha_deg": float(a),
           "toe_in_deg": 90.0 - a, "tilt_deg": 0.0, "fraction_in_both": fraction, "status": status, "reason": reason,
           "square_mean_mm": None, "error_mm": None, "sigma_mm": None, "n_squares": 0}
    if status == "measured":
        out.update(square_mean_mm=square, error_mm=square - 27.0, sigma_mm=sigma, n_squares=93, n_frames=1,
                   fraction_in_both_measured=fraction)
    return out


GRID_ROWS = [
    row(50, 300, 90, square=26.91954),
    row(50, 400, 90, square=27.30541, fraction=0.8),
    row(100, 300, 90, "failed", reason="calibration board found in only 3 of 6 view pairs (need 5)"),
    row(100, 400, 90, "infeasible", reason="0 of 54 target corners in both views"),
    row(150, 300, 90, "limit", reason="baseline_mm 400 above the soft limit 350"),
]


# -- tables ----------------------------------------------------------------------------------------------
def test_table1_layout_is_pinned():
    (table,) = distance_baseline_tables(GRID_ROWS, prefix="s1_")
    assert table.key == "s1_table1_A90"
    assert table.text_rows() == [
        ["B (mm) \\ Z (mm)", "300", "400"],
        ["50", "26.9195", "27.3054†"],
        ["100", "failed", "infeasible"],
        ["150", "limit", ""],
    ]
    assert table.to_csv().splitlines() == [
        "B (mm) \\ Z (mm),300,400", "50,26.91954,27.30541", "100,failed,infeasible", "150,limit,",
    ]
    assert table.statuses() == {"measured": 2, "failed": 1, "infeasible": 1, "limit": 1}
    assert table.cells[0][1].partial and not table.cells[0][0].partial
    assert table.cells[1][0].reason.startswith("calibration board")
    assert alpha_tables(GRID_ROWS) == []  # one alpha: no Table 2


def test_table2_layout_is_pinned_and_one_table1_per_alpha():
    rows = [row(100, 500, a, "infeasible", reason="no overlap") for a in (5, 15, 25, 35, 45)]
    rows.append(row(100, 500, 55, square=26.99968, fraction=0.78))
    (table,) = alpha_tables(rows, prefix="s2_")
    assert table.key == "s2_table2"
    assert table.text_rows() == [
        ["B, Z \\ α (deg)", "5", "15", "25", "35", "45", "55"],
        ["B = 100 mm, Z = 500 mm", "infeasible", "infeasible", "infeasible", "infeasible", "infeasible", "26.9997†"],
    ]
    assert distance_baseline_tables(rows) == []  # one B, one Z: no Table 1
    mixed = GRID_ROWS + [row(50, 300, 60, square=27.1), row(50, 400, 60, square=27.2)]
    tables = distance_baseline_tables(mixed)
    assert [t.key for t in tables] == ["table1_A60", "table1_A90"]
    (two,) = alpha_tables(mixed)
    assert [two.row_name(i) for i in range(len(two.cells))] == [
        "B = 50 mm, Z = 300 mm", "B = 50 mm, Z = 400 mm", "B = 100 mm, Z = 300 mm", "B = 100 mm, Z = 400 mm",
        "B = 150 mm, Z = 300 mm"]
    assert two.text_rows()[1] == ["B = 50 mm, Z = 300 mm", "27.1000", "26.9195"]


def test_planned_configurations_without_a_result_are_not_run():
    plan = [{"config_id": r["config_id"], "baseline_mm": r["baseline_mm"], "distance_mm": r["distance_mm"],
             "alpha_deg": r["alpha_deg"], "fraction_in_both": 1.0} for r in GRID_ROWS]
    plan.append({"config_id": "B150_Z400_A90", "baseline_mm": 150.0, "distance_mm": 400.0, "alpha_deg": 90.0})
    rows = with_plan(GRID_ROWS[:2], plan)
    assert [r["status"] for r in rows] == ["measured", "measured", "not run", "not run", "not run", "not run"]
    (table,) = distance_baseline_tables(rows)
    assert table.text_rows()[3] == ["150", "not run", "not run"]


# -- figures ---------------------------------------------------------------------------------------------
def test_figures_are_drawn_with_and_without_measurements():
    predictions = {r["config_id"]: {"available": True, "sigma_mm": 0.0002, "expected_error_mm": 1e-5}
                   for r in GRID_ROWS if r["status"] == "measured"}
    for figure in (
        figures.error_figure(GRID_ROWS, predictions, x_key="distance_mm", series_keys=("baseline_mm",), title="8"),
        figures.error_figure(GRID_ROWS, predictions, x_key="baseline_mm", series_keys=("distance_mm",), title="9"),
        figures.error_figure([r for r in GRID_ROWS if r["status"] != "measured"], {}, x_key="alpha_deg", title="11"),
        figures.comparison_figure(GRID_ROWS, predictions, title="c"),
        figures.calibration_figure([("a", "measured", {"rms_px": 0.03, "per_view_rms_px": [[0.03, 0.02]] * 6,
                                                       "views_rejected": [{"index": 2, "reason": "outlier"}]}),
                                    ("b", "infeasible", None)], title="q"),
    ):
        data = figures.png_bytes(figure)
        assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 5000
    axes = figures.error_figure(GRID_ROWS, predictions, x_key="distance_mm", series_keys=("baseline_mm",),
                                title="8").axes[0]
    # the measured points carry error bars of exactly their propagated sigma
    bars = [c for c in axes.containers if hasattr(c, "lines") and c.lines[2]]
    segments = [seg for bar in bars for seg in bar.lines[2][0].get_segments()]
    half_heights = sorted({round(float(abs(s[1][1] - s[0][1])) / 2, 9) for s in segments})
    assert half_heights == [0.0002]


# -- the rigorous prediction -----------------------------------------------------------------------------
def test_prediction_uses_the_measured_pixel_noise_and_frames(tmp_path):
    session = read_session(SAMPLE_SESSION, key="s1")
    measured = [c for c in session.configs if c.status == "measured"]
    infeasible = [c for c in session.configs if c.status == "infeasible"]
    assert measured and infeasible
    for config in measured:
        p = config.prediction
        assert p["available"] and p["pixel_sigma_source"].startswith("measured corner noise")
        assert p["pixel_sigma_px"] == pytest.approx(np.sqrt(np.mean(np.square(
            [v for f in config.frames for v in f["pixel_sigma_px"]]))))
        # the mean of n frames: sigma / sqrt(n); the recorded sigma comes from the same noise, so they agree
        assert p["sigma_mm"] == pytest.approx(p["sigma_frame_mm"] / np.sqrt(config.row["n_frames"]))
        assert p["sigma_mm"] == pytest.approx(config.row["sigma_mm"], rel=0.1)
    for config in infeasible:
        assert not config.prediction["available"]
        assert config.prediction["pixel_sigma_source"].startswith("mean corner noise measured in this session")
    default = predict_configuration(measured[0].row, session.config, DEFAULT_PIXEL_SIGMA_PX, "assumed")
    assert default["sigma_frame_mm"] > 5 * measured[0].prediction["sigma_frame_mm"]  # 0.1 px vs ~0.009 px


# -- a whole report of a recorded session ----------------------------------------------------------------
class _PageChecker(HTMLParser):
    """Checks that every opened element is closed in order (void elements excepted) and collects the images."""

    VOID = {"meta", "img", "br", "hr", "link", "input", "col", "wbr", "source"}

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.images: list[dict] = []
        self.links: list[str] = []
        self.ids: list[str] = []
        self.classes: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs)
        if tag == "a" and "href" in attrs:
            self.links.append(attrs["href"])
        if "id" in attrs:
            self.ids.append(attrs["id"])
        self.classes += (attrs.get("class") or "").split()
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1] if self.stack else 'nothing'}")
        else:
            self.stack.pop()


def check_page(report: Path) -> _PageChecker:
    text = (report / "index.html").read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>")
    checker = _PageChecker()
    checker.feed(text)
    checker.close()
    assert not checker.errors and not checker.stack, (checker.errors, checker.stack)
    assert len(checker.ids) == len(set(checker.ids)), "ids must be unique (config ids repeat across sessions)"
    assert "http://" not in text and "https://" not in text and "<script" not in text.lower()
    for image in checker.images:
        assert (report / image["src"]).is_file(), image["src"]
        assert not Path(image["src"]).is_absolute() and ".." not in Path(image["src"]).parts
        assert image.get("alt") and int(image["width"]) > 0 and int(image["height"]) > 0
    for link in checker.links:
        if link.startswith("#"):
            assert link[1:] in checker.ids, link
        else:
            assert (report / link).is_file(), link
    return checker


def test_report_of_the_sample_session(tmp_path):
    session = tmp_path / "session"
    shutil.copytree(SAMPLE_SESSION, session)
    before = {p.relative_to(session): p.read_bytes() for p in session.rglob("*") if p.is_file()}
    assert main(["report", str(session)]) == 0
    report = session / "report"  # the default: inside the session, beside (never over) the recording
    after = {p.relative_to(session): p.read_bytes() for p in session.rglob("*")
             if p.is_file() and not p.is_relative_to(report)}
    assert after == before
    checker = check_page(report)
    srcs = sorted(image["src"] for image in checker.images)
    assert "figures/s1-sample-session_comparison.png" in srcs
    assert "figures/s1-sample-session_calibration.png" in srcs
    assert "figures/s1-sample-session_fig9_A90.png" in srcs  # two B at one Z
    assert "figures/s1-sample-session_fig11.png" in srcs  # two alpha at one (B, Z)
    for config_id in ("B100_Z450_A90", "B150_Z450_A90"):  # measured: corners and rectified pair
        assert f"images/s1-sample-session/{config_id}_corners.jpg" in srcs
        assert f"images/s1-sample-session/{config_id}_rectified.jpg" in srcs
    # infeasible: no frames, only the 3-D view of the rig (which shows why: the board outside a view)
    assert sorted(src for src in srcs if src.startswith("images/") and "A35" in src) == [
        f"images/s1-sample-session/{c}_rig.png" for c in ("B100_Z450_A35", "B150_Z450_A35")]
    assert all(f"images/s1-sample-session/{c}_rig.png" in srcs for c in ("B100_Z450_A90", "B150_Z450_A90"))
    corners = cv2.imread(str(report / "images" / "s1-sample-session" / "B100_Z450_A90_corners.jpg"))
    assert corners.shape[:2] == (392, 1400)  # 960x540 pair + 8 px gap, downscaled to 1400 px wide
    # Table 1 of alpha = 35 deg (both infeasible) and Table 2 (alpha 35 infeasible at both B)
    assert checker.classes.count("s-infeasible") == 4 and checker.classes.count("s-measured") == 4
    manifest = json.loads((report / MANIFEST).read_text())
    assert manifest["sessions"][0]["counts"] == {"measured": 2, "infeasible": 2}
    assert sorted(manifest["files"]) == sorted(str(p.relative_to(report)) for p in report.rglob("*")
                                               if p.is_file() and p.name != MANIFEST)
    with open(report / "tables" / "results.csv", newline="") as handle:
        results = list(csv.DictReader(handle))
    assert [r["status"] for r in results] == ["measured", "infeasible", "infeasible", "measured"]
    assert all(float(r["predicted_sigma_mm"]) > 0 for r in results if r["status"] == "measured")
    assert all(r["predicted_sigma_mm"] == "" for r in results if r["status"] == "infeasible")

    # re-running replaces the report as a whole: a stray file is gone, no temporary directory is left
    (report / "stale.txt").write_text("old")
    assert main(["report", str(session), "--no-images"]) == 0
    assert not (report / "stale.txt").exists() and not (report / "images").exists()
    assert sorted(p.name for p in session.iterdir() if p.name.startswith(".")) == []


def write_session(directory: Path, name: str, rows: list[dict], *, planned_only: list[dict] = ()) -> Path:
    """A session with result rows and no frames (what a run whose configurations all failed records)."""
    plan = [{"config_id": r["config_id"], "baseline_mm": r["baseline_mm"], "distance_mm": r["distance_mm"],
             "alpha_deg": r["alpha_deg"], "toe_in_deg": r["toe_in_deg"], "tilt_deg": 0.0,
             "fraction_in_both": r["fraction_in_both"]} for r in [*rows, *planned_only]]
    config = {"name": name, "plan": {"baseline_mm": [100.0], "distance_mm": [500.0]}}
    with SessionWriter(directory).open() as writer:
        writer.start(config=config, plan=plan, software={"stereo_bench": "test"})
        for r in rows:
            writer.result(r["config_id"], r)
        writer.stop(exit_status="interrupted" if planned_only else "success", reason="stopped by the operator")
    return directory


def test_a_session_with_failures_still_reports_and_marks_them(tmp_path):
    rows = [row(50, 400, 90, square=27.01), *GRID_ROWS[2:]]
    session = write_session(tmp_path / "failing", "failing <b>&</b> campaign", rows,
                            planned_only=[row(150, 400, 90, "x")])
    summary = build_report([session], tmp_path / "out", images=True)
    assert summary.counts() == {"measured": 1, "failed": 1, "infeasible": 1, "limit": 1, "not run": 1}
    checker = check_page(tmp_path / "out")
    for status in ("s-failed", "s-infeasible", "s-limit", "s-not-run", "s-measured"):
        assert status in checker.classes
    text = (tmp_path / "out" / "index.html").read_text()
    assert "failing &lt;b&gt;&amp;&lt;/b&gt; campaign" in text and "<b>&</b>" not in text  # escaped
    assert "calibration board found in only 3 of 6 view pairs" in text  # the reason is shown
    assert "interrupted" in text
    table = (tmp_path / "out" / "tables" / "s1-failing-b-b-campaign_table1_A90.csv").read_text()
    assert list(csv.reader(io.StringIO(table))) == [
        ["B (mm) \\ Z (mm)", "300", "400"], ["50", "", "27.01"], ["100", "failed", "infeasible"],
        ["150", "limit", "not run"]]


def test_several_sessions_in_one_report_need_out(tmp_path, capsys):
    a = write_session(tmp_path / "a", "exp-a", [row(100, 400, 90, square=27.0)])
    b = write_session(tmp_path / "b", "exp-b", [row(100, 500, 55, square=27.0), row(100, 500, 45, "infeasible"),
                                                row(100, 400, 90, square=27.0)])  # a config id of session a too
    assert main(["report", str(a), str(b)]) == 2
    assert "needs --out" in capsys.readouterr().err
    assert main(["report", str(a), str(b), "--out", str(tmp_path / "both"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["counts"] == {"measured": 3, "infeasible": 1}
    checker = check_page(tmp_path / "both")
    assert {"s1-exp-a", "s2-exp-b", "s1-exp-a-B100_Z400_A90", "s2-exp-b-B100_Z500_A45"} <= set(checker.ids)
    assert "tables/s2-exp-b_table2.csv" in out["files"]


def test_bad_sessions_and_destinations_are_one_line_errors(tmp_path, capsys):
    missing = tmp_path / "missing"
    assert main(["report", str(missing)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(missing) in err[0]

    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "documents.jsonl").write_text('{"type": "start", "schema_version": 1}\nnot json\n{"type": "x"}\n')
    assert main(["report", str(corrupt)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(corrupt / "documents.jsonl") in err[0] and "line 2" in err[0]

    session = write_session(tmp_path / "ok", "ok", [row(100, 400, 90, square=27.0)])
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "data.txt").write_text("keep me")
    for out in (precious, session, tmp_path):
        assert main(["report", str(session), "--out", str(out)]) == 2
        assert "refusing" in capsys.readouterr().err
    assert (precious / "data.txt").read_text() == "keep me"
    with pytest.raises(ReportError, match="refusing to write the report over the session"):
        build_report([session], session)


def test_missing_frame_files_are_reported_not_fatal(tmp_path, capsys):
    session = tmp_path / "session"
    shutil.copytree(SAMPLE_SESSION, session)
    for path in (session / "frames" / "B100_Z450_A90").rglob("*.png"):
        path.unlink()
    assert main(["report", str(session), "--out", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "side file missing" in err
    text = (tmp_path / "out" / "index.html").read_text()
    assert "frame unreadable" in text
    check_page(tmp_path / "out")
