"""The replay's comparison rule (docs/REPLAY.md) and the numeric environment a session records.

Unit tests of the rule on synthetic rows (each compared number perturbed just inside and just outside its
tolerance, NaN, absent columns, exact columns), of the kinematic model's comparison, of the environment
record; and replays: a session recorded here replayed under another OpenBLAS core type in a subprocess, a
recorded number edited within and beyond the tolerance.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from stereo_bench.campaign.documents import (
    ADDED_COLUMNS,
    COMPARED_COLUMNS,
    TOLERANCES,
    NumericEnvironment,
    StartDocument,
    json_safe,
    parse_document,
)
from stereo_bench.campaign.environment import describe_differences, environment_differences, numeric_environment
from stereo_bench.campaign.reproduce import (
    SCALE_TOLERANCE,
    UNCERTAINTY_TOLERANCE,
    RecordedContext,
    compare_models,
    compare_rows,
    fit_resolution,
    largest,
    row_scale,
    row_uncertainty,
    verdict,
)
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main
from tests.campaigns import SAMPLE_SESSION

ROOT = Path(__file__).resolve().parents[1]

#: A measured row as the small campaign records it (per-config extrinsics, v2 columns).
ROW = {
    "config_id": "B100_Z450_A90", "baseline_mm": 100.0, "distance_mm": 450.0, "alpha_deg": 90.0,
    "status": "measured", "square_mean_mm": 27.00632190575337, "square_std_mm": 0.009321416815188078,
    "n_squares": 186, "error_mm": 0.006321905753370771, "sigma_mm": 0.0003926809634587756,
    "rms_px": 0.02834238612987019, "epipolar_rms_px": 0.023033558707854788, "n_frames": 2, "calib_views_used": 6,
    "extrinsics_mode": "per-config", "baseline_used_mm": 99.99861503127354, "alpha_left_used_deg": 89.99575343767657,
    "alpha_right_used_deg": 90.01004380118661, "u_combined_mm": 0.01673088067531479,
    "U_expanded_mm": 0.03346176135062958,
}
CONTEXT = RecordedContext(image_height_px={"B100_Z450_A90": 540.0}, default_image_height_px=540.0,
                          target_corners=54, calibration_corners=54,
                          structure_sigma={"B100_Z450_A90": {"baseline_mm": 0.05, "alpha_left_deg": 0.01,
                                                             "alpha_right_deg": 0.01}})


def _tolerance(name: str, row: dict = ROW, context: RecordedContext = CONTEXT) -> float:
    scale, u = row_scale(name, row, context), row_uncertainty(name, row, context)
    return min(SCALE_TOLERANCE * scale, UNCERTAINTY_TOLERANCE * u if u is not None else math.inf)


def _changed(name: str, delta: float, row: dict = ROW) -> dict:
    return {**row, name: row[name] + delta}


def test_every_compared_number_states_its_scale_and_uncertainty_and_the_rest_is_exact():
    assert set(TOLERANCES) == {"square_mean_mm", "square_std_mm", "error_mm", "sigma_mm", "rms_px",
                               "epipolar_rms_px", "baseline_used_mm", "alpha_left_used_deg", "alpha_right_used_deg",
                               "u_combined_mm", "U_expanded_mm"}
    assert set(COMPARED_COLUMNS) - set(TOLERANCES) == {"status", "n_squares", "extrinsics_mode"}
    assert all(row_scale(name, ROW, CONTEXT) > 0 and row_uncertainty(name, ROW, CONTEXT) > 0 for name in TOLERANCES)


@pytest.mark.parametrize("name", sorted(TOLERANCES))
@pytest.mark.parametrize("sign", [1, -1])
def test_a_number_just_inside_its_tolerance_is_reproduced_and_just_outside_differs(name, sign):
    tolerance = _tolerance(name)
    inside = compare_rows(ROW, _changed(name, sign * 0.9 * tolerance), CONTEXT)
    outside = compare_rows(ROW, _changed(name, sign * 1.1 * tolerance), CONTEXT)
    assert verdict(inside) == "reproduced" and largest(inside).name == name
    assert largest(inside).share_of_tolerance == pytest.approx(0.9, rel=1e-3)
    (beyond,) = [d for d in outside if d.verdict == "differs"]
    assert beyond.name == name and "beyond the tolerance" in beyond.difference()
    assert verdict(compare_rows(ROW, dict(ROW), CONTEXT)) == "identical"


def test_the_scale_and_the_uncertainty_each_bind():
    # square_mean_mm: s = 27 mm, u = u_c 0.0167 mm: 1e-6 u (1.7e-8 mm) binds before 1e-9 s (2.7e-8 mm).
    assert UNCERTAINTY_TOLERANCE * ROW["u_combined_mm"] < SCALE_TOLERANCE * ROW["square_mean_mm"]
    delta = 2e-8  # inside the scale's tolerance, outside the uncertainty's
    assert compare_rows(ROW, _changed("square_mean_mm", delta), CONTEXT)[1].verdict == "differs"
    # error_mm is square_mean_mm - 27: its scale is the square (27 mm), not its own 0.006 mm.
    assert row_scale("error_mm", ROW, CONTEXT) == ROW["square_mean_mm"]
    small = {**ROW, "u_combined_mm": 1.0}  # a large u: now the scale binds
    assert [d.verdict for d in compare_rows(small, _changed("error_mm", 2e-8, small), CONTEXT)
            if d.name == "error_mm"] == ["reproduced"]
    assert [d.verdict for d in compare_rows(small, _changed("error_mm", 3e-8, small), CONTEXT)
            if d.name == "error_mm"] == ["differs"]


def test_the_epipolar_error_is_held_to_the_image_rows_it_is_a_difference_of():
    # 1e-10 of the 0.023 px value would fail a |Δ| <= 1e-9 |x| rule: the rows it subtracts are ~540 px.
    delta = 3e-11
    assert delta > SCALE_TOLERANCE * ROW["epipolar_rms_px"]
    (epipolar,) = [d for d in compare_rows(ROW, _changed("epipolar_rms_px", delta), CONTEXT)
                   if d.name == "epipolar_rms_px"]
    assert epipolar.verdict == "reproduced" and epipolar.scale == 540.0
    # u = x / sqrt(2 nu), nu = 54 corners x 2 frames
    assert epipolar.u == pytest.approx(ROW["epipolar_rms_px"] / math.sqrt(2 * 108))
    assert "of its scale" in epipolar.text() and epipolar.text().startswith("epipolar_rms_px of B100_Z450_A90, ")


def test_a_session_without_u_combined_falls_back_on_sigma_and_one_without_structure_sigma_on_the_scale():
    v1 = {key: value for key, value in ROW.items() if key not in ADDED_COLUMNS}
    assert row_uncertainty("square_mean_mm", v1, CONTEXT) == ROW["sigma_mm"]
    assert {d.name for d in compare_rows(v1, ROW, CONTEXT)} == set(COMPARED_COLUMNS) - ADDED_COLUMNS
    bare = RecordedContext(default_image_height_px=540.0, target_corners=54, calibration_corners=54)
    assert row_uncertainty("baseline_used_mm", ROW, bare) is None  # a per-config calibration states none
    inside = compare_rows(ROW, _changed("baseline_used_mm", 0.9e-9 * ROW["baseline_used_mm"]), bare)
    (baseline,) = [d for d in inside if d.name == "baseline_used_mm"]
    assert baseline.verdict == "reproduced" and baseline.relative_to_u is None and "u unknown" in baseline.text()


def test_nan_and_absent_values_are_identical_only_to_each_other():
    nan = {**ROW, "square_std_mm": float("nan")}
    assert verdict(compare_rows(nan, {**ROW, "square_std_mm": float("nan")}, CONTEXT)) == "identical"
    assert verdict(compare_rows(nan, {k: v for k, v in ROW.items() if k != "square_std_mm"}, CONTEXT)) == \
        "identical"  # a row stores NaN as absent
    (one,) = [d for d in compare_rows(nan, ROW, CONTEXT) if d.verdict != "identical"]
    assert one.name == "square_std_mm" and one.verdict == "differs" and "recording has no value" in one.difference()
    (other,) = [d for d in compare_rows(ROW, nan, CONTEXT) if d.verdict != "identical"]
    assert other.verdict == "differs" and "replay has no value" in other.difference()
    infinite = [d for d in compare_rows(ROW, {**ROW, "rms_px": math.inf}, CONTEXT) if d.name == "rms_px"]
    assert infinite[0].verdict == "differs"


def test_a_missing_column_differs_unless_the_recording_predates_it():
    missing = {k: v for k, v in ROW.items() if k != "square_mean_mm"}
    assert verdict(compare_rows(ROW, missing, CONTEXT)) == "differs"
    assert verdict(compare_rows(missing, ROW, CONTEXT)) == "differs"
    older = {k: v for k, v in ROW.items() if k != "u_combined_mm"}  # an added column the recording lacks
    assert "u_combined_mm" not in {d.name for d in compare_rows(older, ROW, CONTEXT)}


@pytest.mark.parametrize(("name", "value"), [("n_squares", 187), ("status", "failed"),
                                             ("extrinsics_mode", "kinematic")])
def test_counts_statuses_and_modes_are_exact(name, value):
    (changed,) = [d for d in compare_rows(ROW, {**ROW, name: value}, CONTEXT) if d.verdict != "identical"]
    assert changed.name == name and changed.verdict == "differs" and changed.delta is None
    assert changed.difference() == f"{name} {ROW[name]!r} -> {value!r}"


def test_a_number_that_is_not_a_number_differs():
    (changed,) = [d for d in compare_rows(ROW, {**ROW, "rms_px": "0.028"}, CONTEXT) if d.verdict != "identical"]
    assert changed.verdict == "differs" and "not a number" in changed.difference()


def fitted_model_file() -> str:
    """A kinematic fit of the lab mechanics on exact projections (tests/synthetic_mechanics.py, ~2 s), as its
    model file: so that a fit in another process can be compared with it."""
    from drivers.sim.profile import LAB
    from stereo_bench.kinematics import model_toml
    from tests.synthetic_mechanics import SyntheticRig, fit_design

    return model_toml(fit_design(SyntheticRig(LAB, seed=5), ((60.0, 240.0), (0.0, 13.0)), views=2))


@pytest.fixture(scope="module")
def model():
    from stereo_bench.kinematics import model_from_toml

    return model_from_toml(fitted_model_file())


def test_the_kinematic_model_is_compared_parameter_by_parameter_against_its_sigma(model):
    from stereo_bench.kinematics import FIT_TOLERANCE

    r = fit_resolution(model)
    assert r == pytest.approx(2 * math.sqrt(FIT_TOLERANCE * model.fit.dof))
    name, parameter = next((n, p) for n, p in model.parameters.items() if p.sigma)

    def moved(delta: float):
        parameters = {**model.parameters, name: parameter.model_copy(update={"value": parameter.value + delta})}
        return compare_models(model, model.model_copy(update={"parameters": parameters}))

    assert verdict(compare_models(model, model)) == "identical"
    inside, outside = moved(0.9 * r * parameter.sigma), moved(1.1 * r * parameter.sigma)
    assert verdict(inside) == "reproduced" and largest(inside).name == name and largest(inside).u == parameter.sigma
    assert verdict(outside) == "differs"
    unit = model.model_copy(update={"parameters": {**model.parameters,
                                                   name: parameter.model_copy(update={"unit": "inch"})}})
    assert [d.name for d in compare_models(model, unit) if d.verdict == "differs"] == [f"{name}.unit"]


@pytest.mark.replay
@pytest.mark.slow  # the fit again in a fresh interpreter (~4 s)
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"),
                    reason="OPENBLAS_CORETYPE=Prescott names an x86-64 kernel family")
def test_the_kinematic_fit_under_another_blas_core_type_is_reproduced(model):
    from stereo_bench.kinematics import model_from_toml

    env = {**os.environ, "OPENBLAS_CORETYPE": _other_core_type()}
    fit = "from tests.test_replay_tolerance import fitted_model_file; print(fitted_model_file(), end='')"
    done = subprocess.run([sys.executable, "-c", fit], env=env, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    deviations = compare_models(model, model_from_toml(done.stdout))
    # Was a byte comparison of the model files: any last digit of the iteration's end point failed it.
    assert verdict(deviations) in ("identical", "reproduced"), [d.difference() for d in deviations
                                                               if d.verdict == "differs"]


def test_rows_measured_with_a_model_fitted_again_take_the_fits_resolution():
    kinematic = {**ROW, "extrinsics_mode": "kinematic"}
    fitted = RecordedContext(**{**CONTEXT.__dict__, "fit_resolution": 2e-4})
    delta = 1e-4 * ROW["u_combined_mm"]  # far beyond 1e-6 u, inside 2e-4 u
    assert verdict(compare_rows(kinematic, _changed("square_mean_mm", delta, kinematic), fitted)) == "reproduced"
    assert verdict(compare_rows(kinematic, _changed("square_mean_mm", delta, kinematic), CONTEXT)) == "differs"
    assert verdict(compare_rows(ROW, _changed("square_mean_mm", delta), fitted)) == "differs"  # per-config


def test_the_numeric_environment_is_recorded_and_its_differences_named():
    today = numeric_environment()
    NumericEnvironment.model_validate(today)
    assert today["numpy"] and today["blas"] and today["blas"][0]["package"] == "numpy"
    assert today["blas"][0]["architecture"] and today["blas"][0]["num_threads"] >= 1
    if platform.system() == "Linux" and platform.machine() == "x86_64":
        assert "sse2" in today["cpu"]["vector_extensions"]
    assert environment_differences(today, today) == []
    other = json.loads(json.dumps(today))
    other["blas"][0]["architecture"] = "Katmai"
    other["variables"] = {"OPENBLAS_CORETYPE": "Prescott"}
    other["cpu"]["vector_extensions"] = [x for x in today["cpu"]["vector_extensions"] or [] if x != "sse2"]
    found = environment_differences(today, other)
    assert found[0] == ("BLAS core (numpy)", today["blas"][0]["architecture"], "Katmai")
    assert ("OPENBLAS_CORETYPE", None, "Prescott") in found
    line = describe_differences(found)
    assert f"BLAS core (numpy) {today['blas'][0]['architecture']} -> Katmai" in line
    assert "OPENBLAS_CORETYPE (not set) -> Prescott" in line
    if today["cpu"]["vector_extensions"]:
        assert "vector extensions -sse2" in line


def test_a_start_document_without_the_environment_still_reads():
    start = json.loads((SAMPLE_SESSION / "documents.jsonl").read_text().splitlines()[0])
    assert "numeric_environment" not in start
    assert isinstance(parse_document(start), StartDocument)
    document = parse_document({**start, "numeric_environment": numeric_environment()})
    assert document.numeric_environment.numpy == numeric_environment()["numpy"]


# -- replays -------------------------------------------------------------------------------------------------


def _edit_result(session: Path, config_id: str, column: str, delta: float) -> float:
    """Add ``delta`` to a recorded result's ``column`` (the stream is the source of truth); the old value."""
    lines = (session / "documents.jsonl").read_text().splitlines()
    for i, line in enumerate(lines):
        doc = json.loads(line)
        if doc["type"] == "result" and doc["config_id"] == config_id:
            old = doc["row"][column]
            doc["row"][column] = old + delta
            lines[i] = json.dumps(doc)
    (session / "documents.jsonl").write_text("\n".join(lines) + "\n")
    return old


@pytest.mark.replay
def test_a_session_records_its_numeric_environment_and_its_replay_finds_it_unchanged(small_reference, capsys):
    start = SessionReader(small_reference).start()
    assert json_safe(start.numeric_environment)["blas"] == numeric_environment()["blas"]
    assert main(["replay", str(small_reference)]) == 0
    out = capsys.readouterr().out
    assert "2 identical, 0 reproduced within tolerance, 0 differ" in out
    assert "numeric environment: as recorded" in out


@pytest.mark.replay
def test_a_recorded_number_edited_within_the_tolerance_is_reproduced_and_beyond_it_differs(small_copy, capsys):
    config_id = "B100_Z450_A90"
    square = _edit_result(small_copy, config_id, "square_mean_mm", 0.0)
    _edit_result(small_copy, config_id, "square_mean_mm", 1e-12)  # 4e-14 of 27 mm
    assert main(["replay", str(small_copy)]) == 0  # was 1: any last digit was a difference
    out = capsys.readouterr().out
    assert "1 identical, 1 reproduced within tolerance (largest deviation: square_mean_mm of B100_Z450_A90, " \
           "|Δ| = 1e-12 mm = 3.7e-14 of its scale" in out and ", 0 differ" in out
    assert main(["replay", str(small_copy), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["reproduced"] == 1 and report["identical"] == 1 and report["differences"] == []
    largest_deviation = report["largest_deviation"]
    assert (largest_deviation["column"], largest_deviation["config_id"]) == ("square_mean_mm", config_id)
    assert largest_deviation["abs"] == pytest.approx(1e-12, rel=1e-3)
    assert largest_deviation["relative_to_scale"] == pytest.approx(1e-12 / square, rel=1e-3)

    _edit_result(small_copy, config_id, "square_mean_mm", 1e-7)  # 3.7e-9 of 27 mm: beyond
    assert main(["replay", str(small_copy)]) == 1
    out = capsys.readouterr().out
    assert f"differs: {config_id}: square_mean_mm " in out and "beyond the tolerance" in out and "1 differ" in out
    assert main(["replay", str(small_copy), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert len(report["differences"]) == 1 and report["differences"][0].startswith(f"{config_id}: square_mean_mm")
    assert report["largest_deviation"]["verdict"] == "differs"


def _other_core_type() -> str:
    """A core type every x86-64 runs, other than the one this process was given."""
    current = os.environ.get("OPENBLAS_CORETYPE", "")
    return next(core for core in ("Prescott", "Core2") if core.lower() != current.lower())


@pytest.mark.replay
@pytest.mark.slow  # a replay in a fresh interpreter (~4 s)
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"),
                    reason="OPENBLAS_CORETYPE=Prescott names an x86-64 kernel family")
def test_a_session_recorded_here_replays_under_another_blas_core_type(small_reference, tmp_path):
    core = _other_core_type()
    env = {**os.environ, "OPENBLAS_CORETYPE": core}
    done = subprocess.run([sys.executable, "-m", "stereo_bench", "replay", str(small_reference), "--json"],
                          env=env, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr  # was 1: the last digits moved
    report = json.loads(done.stdout)
    assert report["identical"] + report["reproduced"] == report["compared"] == 2 and report["differences"] == []
    differences = {d["field"]: (d["recorded"], d["today"]) for d in report["numeric_environment"]["differences"]}
    assert differences["OPENBLAS_CORETYPE"] == (os.environ.get("OPENBLAS_CORETYPE"), core)
    if report["reproduced"]:
        assert report["largest_deviation"]["relative_to_scale"] <= SCALE_TOLERANCE


@pytest.mark.replay
def test_the_shipped_session_replays_and_names_its_largest_deviation(capsys):
    assert main(["replay", str(SAMPLE_SESSION)]) == 0
    out = capsys.readouterr().out
    first = out.splitlines()[0]
    assert first.startswith("replayed 2 measured configurations of ") and ", 0 differ" in first
    identical = int(first.split(": ", 1)[1].split(" identical")[0])
    if identical < 2:  # other kernels than the recording's: the number nearest its tolerance is named
        assert "reproduced within tolerance (largest deviation: " in first and " of its scale, " in first
    assert "numeric environment: the recording has none" in out


def test_replay_out_records_the_environment_of_the_replay(tmp_path):
    out = tmp_path / "replayed"
    assert main(["replay", str(SAMPLE_SESSION), "--out", str(out)]) == 0
    environment = SessionReader(out).start().numeric_environment
    assert environment.model_dump(mode="json")["blas"] == numeric_environment()["blas"]
    shutil.rmtree(out)
