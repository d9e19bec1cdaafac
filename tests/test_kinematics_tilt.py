"""The kinematic chain's optional tilt joints (issue 25): parameters only in a model whose axes include a tilt,
the chain against the simulator's own tilt mechanics, predictions from the reported tilts, the file both ways.

The simulator (drivers.sim.mechanics) is written independently of the estimator; its tilt joints in the model's
parametrisation come from ``kinematic_parameters(..., tilting=...)``.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.mechanics import TILTS, kinematic_parameters, pair_state
from drivers.sim.profile import LAB
from stereo_bench.geometry import invert_transform
from stereo_bench.kinematics import (
    AXES,
    NAMES,
    KinematicFileError,
    KinematicModel,
    chain,
    model_from_toml,
    model_toml,
    nominal_parameters,
    predict,
)
from stereo_bench.kinematics.model import TILT_AXES, ParameterValue, model_axes, parameter_specs, vector_specs

EXACT = LAB.model_copy(update={
    "slide": LAB.slide.model_copy(update={"backlash_mm": 0.0}),
    "left_head": LAB.left_head.model_copy(update={"backlash_deg": 0.0, "tilt_backlash_deg": 0.0}),
    "right_head": LAB.right_head.model_copy(update={"backlash_deg": 0.0, "tilt_backlash_deg": 0.0})})
B_REF = 150.0


def _truth_model(profile, tilts, *, sigma: float = 0.0) -> KinematicModel:
    """A model holding the simulator's parameters, with a diagonal covariance of ``sigma`` (units of each)."""
    axes = model_axes(tilts)
    truth = kinematic_parameters(profile, B_REF, tilting=tilts)
    specs = parameter_specs(axes)
    names = [s.name for s in specs if s.name != "right_x_mm"]
    eye = np.eye(3)
    return KinematicModel(
        axes=list(axes), reference_baseline_mm=B_REF, span={a: [-10.0, 250.0] for a in axes},
        parameters={s.name: ParameterValue(value=float(truth[s.name]), sigma=sigma, unit=s.unit, identifiable=True)
                    for s in specs},
        covariance_names=names, covariance=(sigma**2 * np.eye(len(names))).tolist(), image_size=[1920, 1080],
        K1=eye.tolist(), D1=[0.0] * 5, K2=eye.tolist(), D2=[0.0] * 5, repeatability_tilt_left_deg=0.002,
        repeatability_tilt_right_deg=0.002 if "tilt_right_deg" in tilts else 0.0)


def _true_T_right_left(profile, axes, tilts) -> np.ndarray:
    state = pair_state(profile, axes, tilting=tilts)
    return invert_transform(state.T_bench_right) @ state.T_bench_left


def test_a_model_without_tilt_is_the_chain_it_was_and_a_nominal_joint_at_tilt_0_changes_nothing():
    assert model_axes() == AXES and vector_specs(AXES) == parameter_specs(AXES) and len(NAMES) == 22
    p = np.array([kinematic_parameters(LAB, B_REF)[n] for n in NAMES])
    with_joints = np.concatenate([p, nominal_parameters(B_REF, model_axes(TILTS))[len(NAMES):]])
    assert len(with_joints) == 34
    np.testing.assert_array_equal(chain(with_joints, B_REF, 120.0, 4.0, 3.0), chain(p, B_REF, 120.0, 4.0, 3.0))


@pytest.mark.parametrize("tilts", [TILTS, ("tilt_left_deg",)], ids=["both", "left-only"])
def test_the_chain_with_the_simulators_tilt_joints_is_the_simulated_pair_at_any_tilt(tilts):
    """Exact: the model's chain through the simulator's own parameters gives the true R, T at tilts, toe-ins and
    baselines far from the reference (to 1e-9), and a tilt the rig does not drive is at its nominal."""
    model = _truth_model(EXACT, tilts)
    p = model.vector
    rng = np.random.default_rng(4)
    for _ in range(6):
        axes = {"baseline_mm": rng.uniform(60, 240), "toe_in_left_deg": rng.uniform(-5, 15),
                "toe_in_right_deg": rng.uniform(-5, 15), "tilt_left_deg": rng.uniform(-15, 15),
                "tilt_right_deg": rng.uniform(-15, 15) if "tilt_right_deg" in tilts else 0.0}
        true = _true_T_right_left(EXACT, axes, tilts)
        modelled = chain(p, B_REF, *(axes[a] for a in AXES), axes["tilt_left_deg"], axes["tilt_right_deg"])
        np.testing.assert_allclose(modelled, true, atol=1e-9)
        prediction = predict(model, axes, {a: 1 for a in model.axes})
        np.testing.assert_allclose(prediction.R, true[:3, :3], atol=1e-9)
        np.testing.assert_allclose(prediction.T, true[:3, 3], atol=1e-9)
    assert model.tilts == tuple(tilts)


def test_the_backlash_of_a_tilt_follows_its_direction_of_approach_and_an_unknown_one_widens_the_prediction():
    model = _truth_model(LAB, TILTS, sigma=1e-4)
    axes = {"baseline_mm": 100.0, "toe_in_left_deg": 3.0, "toe_in_right_deg": 3.0, "tilt_left_deg": 8.0,
            "tilt_right_deg": -6.0}
    for approach in (1, -1):
        got = predict(model, axes, {a: approach for a in model.axes})
        history = _history(LAB, axes, approach)
        state = pair_state(LAB, axes, history=history, tilting=TILTS)
        true = invert_transform(state.T_bench_right) @ state.T_bench_left
        np.testing.assert_allclose(got.R, true[:3, :3], atol=1e-9)
        np.testing.assert_allclose(got.T, true[:3, 3], atol=1e-9)
    known = predict(model, axes, {a: 1 for a in model.axes})
    unknown = predict(model, axes, {a: 1 for a in AXES})  # the tilts' directions unknown
    assert unknown.structure_sigma["rotation_deg"] > known.structure_sigma["rotation_deg"]
    with pytest.raises(ValueError, match="axes: missing tilt_left_deg, tilt_right_deg"):
        predict(model, {a: axes[a] for a in AXES})


def _history(profile, axes, approach):
    from drivers.sim.mechanics import MOVED, MoveHistory

    history = MoveHistory(profile.model_copy(update={
        "slide": profile.slide.model_copy(update={"repeatability_mm": 0.0}),
        "left_head": profile.left_head.model_copy(update={"repeatability_deg": 0.0, "tilt_repeatability_deg": 0.0}),
        "right_head": profile.right_head.model_copy(update={"repeatability_deg": 0.0, "tilt_repeatability_deg": 0.0}),
    }), 0, quantities=MOVED + TILTS)
    history.moved(axes, end_s=0.0, approach={q: approach for q in MOVED + TILTS})
    return history


def test_the_file_of_a_tilted_model_round_trips_and_an_older_file_reads_as_a_rig_without_tilt():
    model = _truth_model(LAB, TILTS, sigma=1e-3)
    text = model_toml(model)
    assert 'axes = ["baseline_mm", "toe_in_left_deg", "toe_in_right_deg", "tilt_left_deg", "tilt_right_deg"]' in text
    assert "[parameters.right_tilt_axis_z_mm]" in text and "repeatability_tilt_right_deg = 0.002" in text
    back = model_from_toml(text, "m.toml")
    assert back == model
    untilted = _truth_model(LAB, ())
    old = model_toml(untilted)
    # The file an older version wrote, key for key: no axes, no tilt repeatability, no joint.
    assert "\naxes =" not in old and "repeatability_tilt" not in old and "_tilt_scale" not in old
    read = model_from_toml(old, "old.toml")
    assert read.axes == list(AXES) and read.tilts == () and len(read.vector) == 22
    # A tilt parameter in a model whose axes do not include it, or a tilted model without its joint: one line.
    with pytest.raises(KinematicFileError, match=r"old\.toml: .*unknown left_tilt_scale .*do not include that tilt"):
        model_from_toml(old + "\n[parameters.left_tilt_scale]\nvalue = 1.0\nunit = \"1\"\nidentifiable = false\n",
                        "old.toml")
    lines = text.splitlines()
    cut = lines.index("[parameters.right_tilt_scale]  # right tilt angle per degree of commanded tilt")
    with pytest.raises(KinematicFileError, match=r"t\.toml: .*missing right_tilt_scale"):
        model_from_toml("\n".join(lines[:cut] + lines[lines.index("", cut):]), "t.toml")
    with pytest.raises(KinematicFileError, match="axes: baseline_mm"):
        model_from_toml(text.replace('"tilt_left_deg", "tilt_right_deg"', '"tilt_right_deg", "tilt_left_deg"'),
                        "t.toml")
    assert TILT_AXES == TILTS


def test_a_model_with_tilt_joints_on_a_rig_without_tilt_axes_is_refused_before_any_motion(tmp_path):
    """Its predictions take the reported tilts, which such a rig never reports: one line naming the file and the
    tilt, not a failure at every configuration."""
    from stereo_bench.campaign.config import ConfigError, campaign_from_dict
    from stereo_bench.campaign.preflight import preflight
    from stereo_bench.kinematics import save_model

    path = save_model(_truth_model(EXACT, ("tilt_left_deg",)), tmp_path / "tilting.toml")
    config = campaign_from_dict({"plan": {"baseline_mm": [100], "distance_mm": [500], "alpha_deg": [90]},
                                 "extrinsics": {"mode": "kinematic", "kinematic_file": str(path)}})
    with pytest.raises(ConfigError) as error:
        preflight(config)
    message = str(error.value)
    assert "\n" not in message and "extrinsics.kinematic_file" in message and str(path) in message
    assert "tilt_left_deg" in message and "does not drive" in message
    untilted = save_model(_truth_model(EXACT, ()), tmp_path / "untilted.toml")
    preflight(campaign_from_dict({**config.model_dump(mode="json", exclude_unset=True),
                                  "extrinsics": {"mode": "kinematic", "kinematic_file": str(untilted)}}))
