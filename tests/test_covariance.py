"""Calibration covariance: exact against a brute-force Jacobian, and true to the scatter it claims."""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np
import pytest

from stereo_bench.vision.calibrate import DEFAULT_FLAGS, calibrate_mono, calibrate_stereo
from stereo_bench.vision.covariance import (
    EXTRINSIC_NAMES,
    CalibrationCovariance,
    CovarianceUnavailable,
    extrinsic_sigmas,
    free_intrinsics,
    stereo_covariance,
)
from tests.test_calibrate import CAMERA, synthetic_views

NOISE_PX = 0.1


def _stereo_residuals(params: np.ndarray, objects, lefts, rights, K1, D1, K2, D2, n_views: int) -> np.ndarray:
    """Reprojection residuals of a joint stereo fit; params = fx fy cx cy k1 k2 p1 p2 (each camera), rvec, T,
    then 6 pose values per view. Written from scratch (no composeRT, no projectPoints jacobian)."""
    def camera(K, D, p):
        K = K.copy()
        K[0, 0], K[1, 1], K[0, 2], K[1, 2] = p[:4]
        D = D.copy().reshape(-1)
        D[:4] = p[4:8]
        return K, D
    K1, D1 = camera(K1, D1, params[:8])
    K2, D2 = camera(K2, D2, params[8:16])
    R, _ = cv2.Rodrigues(params[16:19])
    T = params[19:22]
    out = []
    for v in range(n_views):
        rvec, tvec = params[22 + 6 * v:25 + 6 * v], params[25 + 6 * v:28 + 6 * v]
        Rv, _ = cv2.Rodrigues(rvec)
        points_left = np.asarray(objects[v], float) @ Rv.T + tvec
        points_right = points_left @ R.T + T
        for points, K, D, observed in ((points_left, K1, D1, lefts[v]), (points_right, K2, D2, rights[v])):
            pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, D)
            out.append((pixels.reshape(-1, 2) - observed).ravel())
    return np.concatenate(out)


def test_stereo_covariance_equals_the_brute_force_inverse_over_all_parameters():
    # Dense numerical Jacobian over intrinsics, R, T AND every board pose, inverted whole: the Schur
    # complement and the composeRT chain rule must give the same block.
    _, objects, lefts, rights = synthetic_views(6, np.random.default_rng(11), noise_px=NOISE_PX)
    flags = DEFAULT_FLAGS | cv2.CALIB_USE_INTRINSIC_GUESS
    rms, K1, D1, K2, D2, R, T, _, _, rvecs, tvecs, _ = cv2.stereoCalibrateExtended(
        [np.float32(o).reshape(-1, 1, 3) for o in objects], [np.float32(p).reshape(-1, 1, 2) for p in lefts],
        [np.float32(p).reshape(-1, 1, 2) for p in rights], CAMERA.K.copy(), CAMERA.dist.reshape(1, -1).copy(),
        CAMERA.K.copy(), CAMERA.dist.reshape(1, -1).copy(), CAMERA.image_size, None, None, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    cov = stereo_covariance(objects, lefts, rights, K1, D1, K2, D2, R, T, rvecs, tvecs, flags=flags)

    def intr(K, D):
        return [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *np.ravel(D)[:4]]
    params = np.concatenate([intr(K1, D1), intr(K2, D2), cv2.Rodrigues(R)[0].ravel(), np.ravel(T)]
                            + [np.concatenate([np.ravel(r), np.ravel(t)]) for r, t in zip(rvecs, tvecs, strict=True)])
    steps = np.concatenate([[1e-3] * 4 + [1e-6] * 4] * 2 + [[1e-7] * 3, [1e-4] * 3] + [[1e-7] * 3 + [1e-4] * 3] * 6)
    args = (objects, lefts, rights, K1, D1, K2, D2, 6)
    J = np.column_stack([
        (_stereo_residuals(params + np.eye(len(params))[i] * h, *args)
         - _stereo_residuals(params - np.eye(len(params))[i] * h, *args)) / (2 * h)
        for i, h in enumerate(steps)
    ])
    residual = _stereo_residuals(params, *args)
    sigma2 = residual @ residual / (len(residual) - len(params))
    brute = sigma2 * np.linalg.inv(J.T @ J)[:22, :22]
    assert cov.names[:8] == tuple("left." + n for n in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"))
    assert cov.names[16:] == EXTRINSIC_NAMES
    assert cov.sigma_px == pytest.approx(np.sqrt(sigma2), rel=1e-6)
    assert cov.sigma_px == pytest.approx(rms / np.sqrt(2), rel=0.05)  # OpenCV's RMS is of 2-D distances
    np.testing.assert_allclose(np.sqrt(np.diag(cov.matrix)), np.sqrt(np.diag(brute)), rtol=1e-3)
    correlation = cov.matrix / np.sqrt(np.outer(np.diag(cov.matrix), np.diag(cov.matrix)))
    brute_corr = brute / np.sqrt(np.outer(np.diag(brute), np.diag(brute)))
    np.testing.assert_allclose(correlation, brute_corr, atol=2e-3)


def test_mono_covariance_agrees_with_opencvs_own_standard_deviations():
    _, objects, lefts, _ = synthetic_views(10, np.random.default_rng(12), noise_px=NOISE_PX)
    mono = calibrate_mono(objects, lefts, CAMERA.image_size)
    assert mono.covariance.names == ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")  # k3 fixed: not listed
    for name, sigma in mono.covariance.sigmas().items():
        assert sigma == pytest.approx(mono.std_intrinsics[name], rel=1e-4), name


def test_free_parameters_follow_the_flags_and_coupling_flags_are_refused():
    assert free_intrinsics(cv2.CALIB_FIX_K3, 5) == ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
    assert free_intrinsics(cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_PRINCIPAL_POINT, 5) == (
        "fx", "fy", "k1", "k2")
    assert free_intrinsics(cv2.CALIB_RATIONAL_MODEL, 8)[-4:] == ("k3", "k4", "k5", "k6")
    assert free_intrinsics(cv2.CALIB_FIX_INTRINSIC, 5) == ()
    with pytest.raises(CovarianceUnavailable, match="ASPECT_RATIO"):
        free_intrinsics(cv2.CALIB_FIX_ASPECT_RATIO, 5)


def test_fixed_intrinsics_without_their_covariance_leave_the_covariance_unknown():
    _, objects, lefts, rights = synthetic_views(8, np.random.default_rng(13), noise_px=NOISE_PX)
    given = (CAMERA.K, CAMERA.dist.reshape(1, -1), CAMERA.K, CAMERA.dist.reshape(1, -1))
    calib = calibrate_stereo(objects, lefts, rights, CAMERA.image_size, intrinsics=given, mode="fixed")
    assert calib.covariance is None and "unknown" in calib.covariance_note
    # With a covariance for the given intrinsics, R and T carry it.
    intrinsic = CalibrationCovariance(
        tuple(f"{side}.{n}" for side in ("left", "right") for n in ("fx", "fy", "cx", "cy")),
        np.diag([0.5**2] * 8), sigma_px=NOISE_PX)
    calib = calibrate_stereo(objects, lefts, rights, CAMERA.image_size, intrinsics=given, mode="fixed",
                             intrinsics_covariance=intrinsic)
    assert calib.covariance.names == intrinsic.names + EXTRINSIC_NAMES
    np.testing.assert_allclose(calib.covariance.subset(intrinsic.names).matrix, intrinsic.matrix)
    nearly_exact = CalibrationCovariance(intrinsic.names, intrinsic.matrix * 1e-8, sigma_px=NOISE_PX)
    alone = calibrate_stereo(objects, lefts, rights, CAMERA.image_size, intrinsics=given, mode="fixed",
                             intrinsics_covariance=nearly_exact).covariance
    assert calib.covariance.sigma("T.z") > 2 * alone.sigma("T.z")  # a 0.5 px focal sigma dominates depth


def test_extrinsic_sigmas_in_operator_units():
    R = cv2.Rodrigues(np.array([0.0, 0.3, 0.0]))[0]
    T = np.array([-100.0, 0.0, 0.0])
    cov = CalibrationCovariance(EXTRINSIC_NAMES, np.diag([1e-6, 4e-6, 1e-6, 0.04, 0.01, 0.25]), sigma_px=0.1)
    sigmas = extrinsic_sigmas(R, T, cov)
    assert sigmas["baseline_mm"] == pytest.approx(0.2)  # along T: sigma of T.x
    assert sigmas["T_mm"] == pytest.approx([0.2, 0.1, 0.5])
    assert sigmas["rvec_deg"] == pytest.approx(np.degrees([1e-3, 2e-3, 1e-3]).tolist())
    assert sigmas["rotation_deg"] == pytest.approx(np.degrees(2e-3))  # about the rotation's own axis (y)


# ------------------------------------------------------------------------------------------------
# Monte Carlo: the same board poses, fresh corner noise N times; each parameter's scatter against the
# sigma the calibration reported (RMS over the runs, since each run estimates sigma from its residuals).

N_RUNS = 100
CHECKED = ("left.fx", "left.fy", "left.cx", "left.cy", "left.k1", "left.k2", "right.fx", "right.cy",
           "rvec.x", "rvec.y", "rvec.z", "T.x", "T.y", "T.z")


def _value(calib, name: str) -> float:
    if name == "abs_T":
        return calib.baseline_mm
    side, what = name.split(".")
    if side in ("rvec", "T"):
        vector = cv2.Rodrigues(calib.R)[0].ravel() if side == "rvec" else calib.T
        return float(vector["xyz".index(what)])
    K, D = (calib.K1, calib.D1) if side == "left" else (calib.K2, calib.D2)
    if what in ("fx", "fy", "cx", "cy"):
        return float(K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[what]])
    return float(np.ravel(D)[("k1", "k2", "p1", "p2", "k3").index(what)])


def _sigma(calib, name: str) -> float:
    if name == "abs_T":
        return extrinsic_sigmas(calib.R, calib.T, calib.covariance)["baseline_mm"]
    return calib.covariance.sigma(name)


@cache
def _monte_carlo(mode: str) -> dict[str, tuple[float, float]]:
    """name -> (scatter of the estimates, RMS of the reported sigmas) over N_RUNS noisy calibrations.

    ``fixed-given``: the intrinsics (and their covariance) come from mono calibrations of 8 other
    views, freshly noised too, and the stereo fit keeps them fixed.
    """
    _, objects, lefts, rights = synthetic_views(8, np.random.default_rng(21), noise_px=0.0)
    _, mono_objects, mono_lefts, mono_rights = synthetic_views(8, np.random.default_rng(23), noise_px=0.0)
    rng = np.random.default_rng(22)
    values, sigmas = [], []
    for _ in range(N_RUNS):
        noisy = [[p + rng.normal(0, NOISE_PX, p.shape) for p in side] for side in (lefts, rights)]
        if mode == "fixed-given":
            monos = [calibrate_mono(mono_objects, [p + rng.normal(0, NOISE_PX, p.shape) for p in side],
                                    CAMERA.image_size) for side in (mono_lefts, mono_rights)]
            given = CalibrationCovariance(
                monos[0].covariance.prefixed("left.").names + monos[1].covariance.prefixed("right.").names,
                np.block([[monos[0].covariance.matrix, np.zeros((8, 8))],
                          [np.zeros((8, 8)), monos[1].covariance.matrix]]),
                sigma_px=NOISE_PX)
            calib = calibrate_stereo(objects, *noisy, CAMERA.image_size, mode="fixed", intrinsics_covariance=given,
                                     intrinsics=(monos[0].K, monos[0].dist, monos[1].K, monos[1].dist))
        else:
            calib = calibrate_stereo(objects, *noisy, CAMERA.image_size, mode=mode)
        values.append([_value(calib, n) for n in CHECKED + ("abs_T",)])
        sigmas.append([_sigma(calib, n) for n in CHECKED + ("abs_T",)])
    values, sigmas = np.array(values), np.array(sigmas)
    return {n: (float(values[:, i].std(ddof=1)), float(np.sqrt(np.mean(sigmas[:, i] ** 2))))
            for i, n in enumerate(CHECKED + ("abs_T",))}


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["joint", "fixed", "fixed-given"])
def test_reported_sigmas_match_the_monte_carlo_scatter_within_25_percent(mode):
    # N = 100 puts a ratio's standard error at 7 %: 25 % is over 3 standard errors.
    result = _monte_carlo(mode)
    ratios = {n: scatter / reported for n, (scatter, reported) in result.items()}
    assert all(0.75 <= r <= 1.25 for r in ratios.values()), ratios


def locked(pixels: np.ndarray, amplitude_px: float) -> np.ndarray:
    """A detector with pixel locking: each coordinate pulled by amplitude sin(2 pi frac(p))."""
    return pixels + amplitude_px * np.sin(2 * np.pi * np.mod(pixels, 1.0))


def test_calibration_residuals_measure_the_detectors_pixel_locking():
    _, objects, lefts, rights = synthetic_views(10, np.random.default_rng(14), noise_px=0.0)
    rng = np.random.default_rng(15)
    noisy = [[locked(p, 0.03) + rng.normal(0, 0.01, p.shape) for p in side] for side in (lefts, rights)]
    locking = calibrate_stereo(objects, *noisy, CAMERA.image_size).covariance.pixel_locking_px
    assert locking[0] == pytest.approx(0.03, abs=0.003) and abs(locking[1]) < 0.003
    # Without locking the fit finds none.
    plain = [[p + rng.normal(0, 0.01, p.shape) for p in side] for side in (lefts, rights)]
    assert calibrate_stereo(objects, *plain, CAMERA.image_size).covariance.pixel_locking_px is None


def test_fixed_intrinsics_from_these_views_equal_the_separate_mono_linearisations():
    # The shortcut (mono linearisations from the stereo fit's own rows) against the mono fits' own.
    from stereo_bench.vision.covariance import mono_linearisation

    _, objects, lefts, rights = synthetic_views(8, np.random.default_rng(16), noise_px=NOISE_PX)
    calib = calibrate_stereo(objects, lefts, rights, CAMERA.image_size, mode="fixed")
    monos = [calibrate_mono(objects, side, CAMERA.image_size) for side in (lefts, rights)]
    views = list(range(8))
    exact = tuple(mono_linearisation(objects, side, m.K, m.dist, m.rvecs, m.tvecs, flags=DEFAULT_FLAGS,
                                     view_indices=views, side=name)
                  for m, side, name in ((monos[0], lefts, "left"), (monos[1], rights, "right")))
    flags = DEFAULT_FLAGS | cv2.CALIB_FIX_INTRINSIC
    *_, rvecs, tvecs, _ = cv2.stereoCalibrateExtended(
        [np.float32(o).reshape(-1, 1, 3) for o in objects], [np.float32(p).reshape(-1, 1, 2) for p in lefts],
        [np.float32(p).reshape(-1, 1, 2) for p in rights], calib.K1.copy(), calib.D1.copy(), calib.K2.copy(),
        calib.D2.copy(), CAMERA.image_size, None, None, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    separate = stereo_covariance(objects, lefts, rights, calib.K1, calib.D1, calib.K2, calib.D2, calib.R, calib.T,
                                 rvecs, tvecs, flags=flags, intrinsics_from=exact, view_indices=views)
    assert calib.covariance.names == separate.names
    np.testing.assert_allclose(np.sqrt(np.diag(calib.covariance.matrix)), np.sqrt(np.diag(separate.matrix)),
                               rtol=2e-3)
