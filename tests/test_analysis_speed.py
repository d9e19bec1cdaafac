"""The analysis' fast paths (each configuration's uncertainty budgets, nominal geometry's covariance) give
bit-identical numbers to the plain computations they replace: the same float64 bits, not close ones.

(The replay as a whole against the recorded numbers is in tests/test_campaign_run.py.)
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import cv2
import numpy as np
import pytest

from stereo_bench.campaign.config import RigTolerances
from stereo_bench.campaign.session import SessionReader
from stereo_bench.kinematics.model import _rvec_t
from stereo_bench.kinematics.nominal import (
    _PER_CAMERA_DEVIATIONS,
    _SHARED_TOLERANCES,
    _as_built_camera,
    nominal_covariance,
)
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.covariance import EXTRINSIC_NAMES, ResidualMap
from stereo_bench.vision.measure import measure_square
from stereo_bench.vision.uncertainty import (
    FrameCorners,
    _square_function,
    configuration_budget,
    mapped_systematic_mm,
    noise_bias_mm,
    parameter_step,
    perturbed,
    phase_sum,
    pixel_gradients,
    square_sensitivities,
)
from tests.campaigns import SAMPLE_SESSION
from tests.synthetic_rig import TARGET, Configuration, calibrate

INTRINSIC_NAMES = tuple(f"{side}.{name}" for side in ("left", "right")
                        for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"))


@cache
def calibrations() -> tuple[StereoCalibration, ...]:
    """The shipped session's recorded calibrations (rendered cameras' distortion) and a synthetic one with its
    covariance (pixel locking, residual maps)."""
    reader = SessionReader(SAMPLE_SESSION)
    recorded = [reader.calibration(c) for c in ("B100_Z450_A90", "B150_Z450_A90")]
    synthetic = calibrate(Configuration(120, 450, 85), np.random.default_rng(3), noise_px=0.1)
    assert synthetic.covariance is not None and synthetic.covariance.residual_map is not None
    return (*recorded, synthetic)


def frames_of(calib: StereoCalibration, rng: np.random.Generator, n_frames: int,
              keep: float = 1.0) -> list[FrameCorners]:
    """``n_frames`` noisy views of the target ~450 mm ahead, projected through ``calib``; ``keep``: the
    fraction of corners each view keeps (a partial view, odd corner counts)."""
    frames = []
    for _ in range(n_frames):
        rvec = rng.normal(0, 0.15, 3)
        tvec = np.array([rng.uniform(-60, 0), rng.uniform(-50, 0), rng.uniform(380, 520)])
        points = cv2.Rodrigues(rvec)[0] @ np.asarray(TARGET.object_points, float).T + tvec[:, None]
        ids = np.sort(rng.choice(TARGET.n_corners, max(4, int(keep * TARGET.n_corners)), replace=False))
        left, _ = cv2.projectPoints(points.T[ids], np.zeros(3), np.zeros(3), calib.K1, calib.D1)
        right, _ = cv2.projectPoints(points.T[ids], cv2.Rodrigues(np.asarray(calib.R, float))[0], calib.T,
                                     calib.K2, calib.D2)
        frames.append(FrameCorners(ids, left.reshape(-1, 2) + rng.normal(0, 0.1, (len(ids), 2)),
                                   right.reshape(-1, 2) + rng.normal(0, 0.1, (len(ids), 2)),
                                   float(rng.uniform(0.001, 0.01)), (0.1, 0.12)))
    return frames


def dense_maps(image_size: tuple[int, int], rng: np.random.Generator) -> dict[str, ResidualMap]:
    """Residual maps with every bin well supported, so the map's part of the budget is computed."""
    size = np.asarray(image_size, float)
    return {side: ResidualMap.of(rng.uniform(0, 1, (20000, 2)) * (size - 1), rng.normal(0.003, 0.02, (20000, 2)),
                                 image_size) for side in ("left", "right")}


CASES = [(n_frames, keep) for n_frames in (1, 4, 15) for keep in (1.0, 0.6)]


def plain_square_sensitivities(calib, frames, target, names) -> np.ndarray:
    """One full triangulation (both cameras undistorted) per perturbed calibration, as before."""
    square = _square_function(frames, target)
    return np.array([(square(perturbed(calib, name, parameter_step(name)))
                      - square(perturbed(calib, name, -parameter_step(name)))) / (2 * parameter_step(name))
                     for name in names])


@pytest.mark.parametrize(("n_frames", "keep"), CASES)
def test_square_sensitivities_are_bit_identical_to_one_triangulation_per_perturbation(n_frames, keep):
    rng = np.random.default_rng(n_frames * 10 + int(keep * 10))
    for calib in calibrations():
        frames = frames_of(calib, rng, n_frames, keep)
        for names in (INTRINSIC_NAMES + EXTRINSIC_NAMES, EXTRINSIC_NAMES, ("right.k1", "T.x", "left.cy"),
                      INTRINSIC_NAMES[:9]):
            fast = square_sensitivities(calib, frames, TARGET, names)
            assert np.array_equal(fast, plain_square_sensitivities(calib, frames, TARGET, names)), names
            assert np.all(np.isfinite(fast)) and np.all(fast != 0)


@pytest.mark.parametrize(("n_frames", "keep"), CASES)
def test_budget_parts_sharing_a_frames_triangulation_are_bit_identical_to_their_own(n_frames, keep):
    rng = np.random.default_rng(100 + n_frames * 10 + int(keep * 10))
    for calib in calibrations():
        frames = frames_of(calib, rng, n_frames, keep)
        memo: dict = {}
        biases = [noise_bias_mm(calib, f, TARGET, memo=memo) for f in frames]
        assert biases == [noise_bias_mm(calib, f, TARGET) for f in frames] and len(memo) == n_frames
        shared = pixel_gradients(calib, frames, TARGET, memo=memo)
        plain = pixel_gradients(calib, frames, TARGET)
        assert all(np.array_equal(a, b) for a, b in zip(shared, plain, strict=True))
        assert phase_sum(calib, frames, TARGET, gradients=shared) == phase_sum(calib, frames, TARGET)
        maps = dense_maps(calib.image_size, rng)
        mapped = mapped_systematic_mm(calib, frames, TARGET, maps, 0.05, gradients=shared)
        assert mapped is not None and mapped == mapped_systematic_mm(calib, frames, TARGET, maps, 0.05)


def test_budget_is_bit_identical_with_every_shared_part():
    # Locking, a residual map and a systematic corner error: every part that shares a triangulation runs.
    calib = calibrations()[-1]
    rng = np.random.default_rng(9)
    maps = dense_maps(calib.image_size, rng)
    covariance = replace(calib.covariance, pixel_locking_px=(0.03, -0.01), residual_map=maps)
    calib = replace(calib, covariance=covariance)
    frames = frames_of(calib, rng, 5)
    budget = configuration_budget(frames, calib, TARGET, corner_systematic=0.02, structure_covariance=np.eye(6) * 1e-6)
    assert budget.systematic_model == "residual map" and budget.detector_bias_mm != 0
    field_bias, _ = mapped_systematic_mm(calib, frames, TARGET, maps, 0.02)
    assert budget.field_bias_mm == field_bias
    memo_free = [noise_bias_mm(calib, f, TARGET, extra_px=0.02) for f in frames]
    assert budget.noise_bias_mm == float(np.mean(memo_free))
    assert budget.detector_bias_mm == float((complex(*covariance.pixel_locking_px)
                                             * phase_sum(calib, frames, TARGET)).imag)
    names = list(covariance.names)
    g = plain_square_sensitivities(calib, frames, TARGET, names)
    assert budget.calibration == float(np.sqrt(max(g @ covariance.subset(names).matrix @ g, 0.0)))


def plain_nominal_covariance(baseline_mm, alpha_left_deg, alpha_right_deg, *, tolerances, tilt_left_deg,
                             tilt_right_deg) -> np.ndarray:
    """Both cameras built for every central-difference step, as before."""
    toe_left, toe_right = 90.0 - alpha_left_deg, 90.0 - alpha_right_deg
    keys = [(name, "both") for name in _SHARED_TOLERANCES] + [
        (name, side) for side in ("left", "right") for name in _PER_CAMERA_DEVIATIONS]
    shared_name = {"axis_tilt_x_deg": "axis_tilt_deg", "axis_tilt_z_deg": "axis_tilt_deg",
                   "slide_yaw_deg": "slide_direction_deg", "slide_pitch_deg": "slide_direction_deg"}
    sigma = np.array([float(tolerances[shared_name.get(name, name)]) for name, _ in keys])

    def pair(values):
        by_side = {side: dict.fromkeys(_PER_CAMERA_DEVIATIONS, 0.0) for side in ("left", "right")}
        shared = dict.fromkeys(_SHARED_TOLERANCES, 0.0)
        for (name, side), value in zip(keys, values, strict=True):
            (shared if side == "both" else by_side[side])[name] = float(value)
        T_rig_left = _as_built_camera("left", baseline_mm, toe_left, tilt_left_deg, {**shared, **by_side["left"]})
        T_rig_right = _as_built_camera("right", baseline_mm, toe_right, tilt_right_deg,
                                       {**shared, **by_side["right"]})
        return _rvec_t(np.linalg.inv(T_rig_right) @ T_rig_left)

    J = np.zeros((6, len(keys)))
    for k in range(len(keys)):
        if sigma[k] == 0.0:
            continue
        step = np.zeros(len(keys))
        step[k] = sigma[k]
        J[:, k] = (pair(step) - pair(-step)) / (2.0 * sigma[k])
    return J @ np.diag(sigma**2) @ J.T


@pytest.mark.parametrize(("baseline_mm", "alpha_left_deg", "alpha_right_deg", "tilt_deg"),
                         [(100.0, 90.0, 90.0, 0.0), (150.0, 80.0, 84.0, 0.0), (250.0, 85.0, 85.0, 2.5),
                          (60.0, 95.0, 88.0, -1.0), (0.0, 90.0, 90.0, 0.0)])
def test_nominal_covariance_is_bit_identical_to_building_both_cameras_every_step(baseline_mm, alpha_left_deg,
                                                                                 alpha_right_deg, tilt_deg):
    defaults = RigTolerances().model_dump()
    rng = np.random.default_rng(int(baseline_mm))
    uneven = {name: float(value) * rng.uniform(0.5, 2.0) for name, value in defaults.items()}
    partly_zero = {**defaults, "yaw_deg": 0.0, "baseline_scale": 0.0}
    for tolerances in (defaults, uneven, partly_zero):
        args = dict(tolerances=tolerances, tilt_left_deg=tilt_deg, tilt_right_deg=tilt_deg)
        fast = nominal_covariance(baseline_mm, alpha_left_deg, alpha_right_deg, **args)
        assert np.array_equal(fast, plain_nominal_covariance(baseline_mm, alpha_left_deg, alpha_right_deg, **args))
        assert np.all(np.isfinite(fast)) and np.any(fast != 0)


def budget_bits(budget) -> str:
    """Every number of a budget, exactly (hex floats), for an equality that NaN and -0.0 cannot fool."""
    def exact(value):
        if isinstance(value, float):
            return value.hex()
        if isinstance(value, dict):
            return {k: exact(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [exact(v) for v in value]
        return value
    return repr(exact({**budget.as_dict(), **budget.details()}))


def test_budget_reads_the_measurements_own_triangulation_only_for_the_same_calibration():
    calib = calibrations()[-1]
    calib = replace(calib, covariance=replace(calib.covariance, pixel_locking_px=(0.02, 0.01)))
    rng = np.random.default_rng(21)
    plain = frames_of(calib, rng, 4, keep=0.8)
    measured = []
    for frame in plain:
        square = measure_square(calib, TARGET, frame.ids, frame.left_px, frame.right_px, pixel_sigma_px=0.1)
        assert square.calib is calib and square.jacobian.shape == (len(frame.ids), 3, 4)
        measured.append(replace(frame, triangulated=(square.calib, square.points_mm, square.jacobian)))
    structure = np.eye(6) * 1e-6
    expected = budget_bits(configuration_budget(plain, calib, TARGET, structure_covariance=structure))
    assert budget_bits(configuration_budget(measured, calib, TARGET, structure_covariance=structure)) == expected
    # Another calibration (even an equal copy) triangulates afresh: a stale triangulation is never read.
    moved = replace(calib, T=np.asarray(calib.T, float) * 1.01)
    assert (budget_bits(configuration_budget(measured, moved, TARGET, structure_covariance=structure))
            == budget_bits(configuration_budget(plain, moved, TARGET, structure_covariance=structure)))
    stale = [replace(f, triangulated=(moved, f.triangulated[1] * 2.0, f.triangulated[2])) for f in measured]
    assert budget_bits(configuration_budget(stale, calib, TARGET, structure_covariance=structure)) == expected
