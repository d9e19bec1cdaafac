"""`stereo-bench model paper|predict|surface|compare` and `advise` as a user runs them."""

from __future__ import annotations

import csv
import json
import math
import sys

import pytest

from stereo_bench.cli import main


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_model_paper_json(capsys):
    code, out, _ = run(capsys, "model", "paper", "--k", "0.5", "1", "1.5", "2", "--json")
    assert code == 0
    report = json.loads(out)
    assert [row["K"] for row in report["rows"]] == [0.5, 1.0, 1.5, 2.0]
    for row in report["rows"]:
        assert set(row) >= {"K", "e1", "e2", "gamma_rel"}
        assert row["gamma_rel"] == pytest.approx(math.hypot(row["e1"], row["e2"]))
    assert report["rows"][1]["e1"] == pytest.approx(0.625) and report["rows"][1]["e2"] == pytest.approx(1.25)
    assert report["optimum_K"] == pytest.approx(math.sqrt(2.0), abs=1e-9)
    assert report["optimum_K_numeric"] == pytest.approx(math.sqrt(2.0), abs=1e-6)


def test_model_paper_text_with_distance(capsys):
    code, out, _ = run(capsys, "model", "paper", "--k", "1", "--distance", "500")
    assert code == 0
    assert "optimum K = 1.4142" in out and "0.0741" in out  # gamma at K = 1, Z = 500, 0.1 px


def test_model_predict_json(capsys):
    code, out, _ = run(capsys, "model", "predict", "--baseline", "100", "--distance", "500", "--alpha", "90",
                       "--pixel-sigma", "0.1", "--json")
    assert code == 0
    report = json.loads(out)
    for key in ("sigma_square_mm", "sigma_x_mm", "sigma_z_mm", "feasible", "sensitivities", "paper"):
        assert key in report
    assert report["feasible"] is True and "monte_carlo" not in report
    assert report["sigma_z_mm"] == pytest.approx(report["textbook_parallel_sigma_z_mm"], rel=0.01)
    assert report["sensitivities"]["baseline_mm"]["square_mm_per_unit"] == pytest.approx(0.27, rel=1e-4)


def test_model_predict_monte_carlo(capsys):
    code, out, _ = run(capsys, "model", "predict", "--baseline", "100", "--distance", "500", "--alpha", "88",
                       "--monte-carlo", "2000", "--seed", "4", "--executor", "serial", "--no-sensitivities", "--json")
    assert code == 0
    report = json.loads(out)
    mc = report["monte_carlo"]
    assert mc["n_samples"] == 2000 and mc["seed"] == 4 and mc["executor"]["executor"] == "serial"
    for key in ("sigma_square_mm", "sigma_x_mm", "sigma_z_mm"):
        assert mc[key] == pytest.approx(report[key], rel=0.10)


def test_model_predict_infeasible_is_reported_not_crashed(capsys):
    code, out, _ = run(capsys, "model", "predict", "--baseline", "100", "--distance", "500", "--alpha", "35")
    assert code == 0
    assert "not feasible" in out and "0/54" in out and "n/a" in out


def test_model_predict_takes_the_renderers_intrinsics(capsys, tmp_path):
    import numpy as np

    from stereo_bench.geometry import CameraModel
    from stereo_bench.vision.calibio import write_calibration
    from stereo_bench.vision.calibrate import StereoCalibration
    from stereo_bench.vision.rectify import rectify

    camera = CameraModel.from_sensor(focal_mm=6.0)

    calib = StereoCalibration(K1=camera.K, D1=camera.dist.reshape(1, -1), K2=camera.K, D2=camera.dist.reshape(1, -1),
                              R=np.eye(3), T=np.array([-100.0, 0.0, 0.0]), image_size=camera.image_size)
    write_calibration(tmp_path, calib, rectify(calib), board="checkerboard 9x6")
    code, out, _ = run(capsys, "model", "predict", "--baseline", "100", "--distance", "500", "--intrinsics",
                       str(tmp_path), "--no-sensitivities", "--json")
    assert code == 0
    report = json.loads(out)
    f_px = camera.fx
    assert report["textbook_parallel_sigma_z_mm"] == pytest.approx(500**2 * math.sqrt(2) * 0.1 / (f_px * 100))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["model", "predict", "--baseline", "-1", "--distance", "500"], "--baseline: must be a finite number > 0"),
        (["model", "predict", "--baseline", "100", "--distance", "500", "--alpha", "190"], "--alpha: must be"),
        (["model", "predict", "--baseline", "100", "--distance", "500", "--pixel-sigma", "nan"], "--pixel-sigma"),
        (["model", "predict", "--baseline", "100", "--distance", "500", "--monte-carlo", "1"], "--monte-carlo:"),
        (["model", "predict", "--baseline", "100", "--distance", "500", "--board", "9x9"], "--board/--square"),
        (["model", "predict", "--baseline", "100", "--distance", "500", "--intrinsics", "/nonexistent/x"],
         "/nonexistent/x"),
        (["model", "predict", "--baseline", "100", "--distance", "500", "--monte-carlo", "10", "--scheduler",
          "tcp://127.0.0.1:9"], "--executor dask"),
        (["model", "paper", "--k", "0"], "argument --k: must be a finite number > 0"),
        (["advise", "--distance", "500", "--target-error-mm", "0"], "--target-error-mm: must be"),
    ],
)
def test_bad_input_is_one_line_exit_2(capsys, argv, message):
    code, _, err = run(capsys, *argv)
    assert code == 2
    assert message in err and err.count("\n") == 1


def test_dask_missing_is_one_clear_line(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    code, _, err = run(capsys, "model", "predict", "--baseline", "100", "--distance", "500", "--monte-carlo", "10",
                       "--executor", "dask")
    assert code == 2 and "pip install 'stereo-bench[dask]'" in err and err.count("\n") == 1


def test_model_surface_csv_and_json(capsys, tmp_path):
    out_csv = tmp_path / "bz.csv"
    code, out, _ = run(capsys, "model", "surface", "--over", "bz", "--baselines", "100", "300", "100",
                       "--distances", "400", "600", "200", "--alpha", "converge", "--executor", "serial",
                       "--no-sensitivities", "--out", str(out_csv))
    assert code == 0 and "wrote 6 configurations" in out
    rows = list(csv.DictReader(out_csv.open()))
    assert len(rows) == 6
    assert {"baseline_mm", "distance_mm", "sigma_square_mm", "gamma_xz_mm", "feasible"} <= set(rows[0])
    code, _, err = run(capsys, "model", "surface", "--over", "bz", "--baselines", "100", "300", "100",
                       "--distances", "400", "600", "200", "--out", str(out_csv))
    assert code == 2 and "exists" in err
    out_json = tmp_path / "alpha.json"
    code, _, _ = run(capsys, "model", "surface", "--over", "alpha", "--alphas", "60", "90", "10", "--baseline", "100",
                     "--distance", "500", "--executor", "serial", "--out", str(out_json))
    assert code == 0
    data = json.loads(out_json.read_text())
    assert data["over"] == "alpha" and [r["alpha_deg"] for r in data["rows"]] == [60.0, 70.0, 80.0, 90.0]
    assert data["rows"][-1]["square_per_mm_baseline"] == pytest.approx(0.27, rel=1e-4)


def test_advise_json(capsys):
    code, out, _ = run(capsys, "advise", "--distance", "500", "--target-error-mm", "0.05", "--pixel-sigma", "0.1",
                       "--baselines", "50", "350", "100", "--alphas", "50", "90", "10", "--executor", "serial",
                       "--json")
    assert code == 0
    advice = json.loads(out)
    assert advice["meets_target"] is True
    lo, hi = advice["recommended_baseline_mm"]
    assert 50 <= lo <= hi <= 350
    assert advice["recommended_worst_error_mm"] <= 0.05 and advice["best"]["predicted_error_mm"] <= 0.05
    assert len(advice["rows"]) == 4


def test_advise_text_and_unreachable_target(capsys):
    code, out, _ = run(capsys, "advise", "--distance", "500", "--target-error-mm", "0.001", "--baselines", "100",
                       "300", "100", "--alphas", "70", "90", "10", "--executor", "serial")
    assert code == 1
    assert "no configuration meets 0.001 mm" in out and "alpha range" in out


@pytest.mark.slow
def test_model_compare_coarse(capsys):
    code, out, _ = run(capsys, "model", "compare", "--coarse", "--executor", "serial", "--json")
    assert code == 0
    report = json.loads(out)
    gamma = next(o for o in report["converge"] if o["metric"] == "gamma_xz_mm")
    assert gamma["x"] == pytest.approx(math.sqrt(2.0), abs=2e-3)
    assert report["experiment2_claimed_alpha_measurable"] is False
    code, out, _ = run(capsys, "model", "compare", "--coarse", "--executor", "serial")
    assert code == 0 and "converging rig" in out and "anything measurable at 30-40 deg: False" in out


def test_model_predict_includes_the_planned_calibration(capsys):
    argv = ("model", "predict", "--baseline", "200", "--distance", "500", "--alpha", "80", "--no-sensitivities",
            "--no-rig")
    code, out, _ = run(capsys, *argv, "--json")
    report = json.loads(out)
    assert code == 0 and report["calibration_views"] == 12 and report["sigma_calibration_mm"] > 0
    assert report["sigma_calibration_depth_mm"] > 0
    assert report["sigma_square_total_mm"] == pytest.approx(
        (report["sigma_square_mm"] ** 2 + report["bias_square_mm"] ** 2 + report["sigma_calibration_mm"] ** 2) ** 0.5)
    code, out, _ = run(capsys, *argv, "--json", "--calibration-views", "6", "--calibration-mode", "fixed",
                       "--calibration-board", "9x6", "--calibration-square", "30")
    fewer = json.loads(out)
    assert fewer["sigma_calibration_mm"] > report["sigma_calibration_mm"] and "9x6" in fewer["calibration_note"]
    code, out, _ = run(capsys, *argv, "--json", "--calibration-views", "0")
    alone = json.loads(out)
    assert alone["sigma_calibration_mm"] is None and alone["calibration_views"] == 0
    assert alone["sigma_square_total_mm"] < report["sigma_square_total_mm"]
    code, out, _ = run(capsys, *argv)
    assert "calibration:  square sigma" in out and "shared by every frame" in out
    code, _, err = run(capsys, *argv, "--calibration-views", "3")
    assert code == 2 and "--calibration-views must be 0" in err


def test_advise_reports_the_calibration_it_assumed(capsys):
    code, out, _ = run(capsys, "advise", "--distance", "500", "--target-error-mm", "0.05", "--baselines", "100",
                       "300", "200", "--alphas", "80", "90", "10", "--executor", "serial", "--json")
    advice = json.loads(out)
    assert code == 0 and advice["calibration_views"] == 12 and advice["best"]["sigma_calibration_mm"] > 0
    assert "calibration from 12 views" in advice["message"]
