"""Uncertainty budget of the measured square, in the GUM's terms (JCGM 100:2008).

The measurand is the square size a configuration reports: the mean over its frames of each frame's
mean adjacent-corner length (mm). Its standard-uncertainty components:

- ``noise``: random corner noise of the measurement frames, propagated through the triangulation
  (each frame's ``sigma_mean_mm``); independent from frame to frame, so n frames divide it:
  sqrt(sum sigma_i^2) / n. The same noise also biases every length upward (a length is the norm of
  a noisy difference: E|d| = |d| + (tr S_d - u^T S_d u) / (2 |d|), S_d its covariance, u = d/|d|):
  at a small B/Z the depth noise makes this bias as large as the random part (B 100, Z 500 mm,
  0.1 px: 0.003 mm), and averaging frames does not shrink it. It is not corrected (the measured
  value stays what the pipeline reports); as GUM F.2.4.5 allows for an uncorrected known bias, it is
  added in quadrature. A third part is the corner detector's systematic error: its residual pixel
  locking: the saddle-point estimate is pulled by an amount periodic in each coordinate's sub-pixel
  phase (on the simulator e = A sin(2 pi frac(p)), A 0.021-0.034 px, R^2 0.9, 2.5 times the random
  noise). For a static target it repeats in every frame, and on a regular grid seen nearly
  square-on the phases are alike, so the errors add up instead of averaging (rendered 1080p, B 100
  mm, Z 500 mm, parallel: the left image 0.014 px left, the right 0.014 px right, a square 0.0023 mm
  long with the TRUE calibration, 9 random sigmas; the model below predicts 0.0021 mm). The
  calibration's residuals measure the locking (``covariance.pixel_locking_px``: its first harmonic,
  fitted over every corner of every view); on the measured corners it predicts a bias of the square
  b = Im(a C) (:func:`phase_sum`), reported as ``detector_bias_mm`` and, uncorrected, counted like
  the noise bias. The amplitude carries over from the calibration views to the target only
  approximately (it depends on the edges' angle to the pixel grid, contrast and blur: on the
  simulator the target's corners lock 1.0-1.4 times as strongly as the calibration views'), so b
  gets a relative standard uncertainty of :data:`LOCKING_TRANSFER_U_REL`. Corner error the fit
  shows beyond the random noise and the locking (:func:`corner_systematic_px`, when significant)
  has no known pattern; part of it is smooth across the board (edges curved by a lens term the model
  lacks), which no averaging over corners removes, part differs from corner to corner (JPEG blocks,
  the board's texture) and repeats in every frame of a static target. When the calibration binned its
  residuals over the image (:class:`~stereo_bench.vision.covariance.ResidualMap`), the smooth part is
  read where the measured corners are: each bin's mean residual is the model's miss there, its effect
  on the square a bias with the bins' standard errors as its uncertainty; the rest of the excess is
  counted independent from corner to corner and shared by the frames (:func:`mapped_systematic_mm`).
  On the lab bench the excess (~0.015 px at 1080p) is nearly all corner-to-corner: the bins' means
  over the target are ~0.003 px, so a whole-image shift and magnification of 0.015 px overstated the
  square's uncertainty 2.5 times (per-config coverage RMS 0.42). Without a map (a calibration read
  from a file, a rig model) the excess is propagated, as the GUM does for an unknown correlation, as
  an unknown shift and magnification of each image (:func:`coherent_displacement_mm`). The detector
  part, sqrt(b^2 (1 + 0.5^2) + rest^2), is not divided by the number of frames; noise = sqrt(sum
  sigma_i^2 / n^2 + bias^2 + detector^2), every part in ``details()``.
- ``calibration``: the calibration's covariance C (:mod:`stereo_bench.vision.covariance`) pushed
  through the square's sensitivity to each calibrated parameter, g = d(square)/d(parameters)
  evaluated at the measured corners: sqrt(g^T C g). One calibration serves every frame of a
  configuration, so its error is shared: n frames do not divide it.
- ``structure``: the stereo extrinsics' uncertainty beyond what the calibration says, from another
  source. With extrinsics calibrated at the configuration (``extrinsics_from_calibration``), the
  calibration component carries R, T and the structure covariance is how far the rig may have moved
  since (its repeatability; zero when it has not moved). With kinematic or nominal extrinsics the
  R, T come from the rig model or the rig's stated tolerances: their covariance is the structure
  component and the calibration component covers the intrinsics only. None (unknown) when no source
  is given: not included in ``combined``, listed in ``unknown``; zero only when the source says zero.
- ``target``: the boards' certified scale. Triangulated lengths are in units of the calibration
  board's square (R, T are scaled by it), and the measured board's true square differs from its
  nominal by its own scale error: u = nominal x sqrt(u_rel,target^2 + u_rel,calibration board^2);
  zero when the same board is calibrated on and measured (the scale cancels).

``combined`` u_c is the root sum of squares of the known components (they are independent: the
calibration views, the measurement frames, the rig model and the boards' certificates are separate
sources), ``expanded`` U = k u_c with k = 2 (about 95 % for a near-normal error).

Not in the budget: anything the calibration's residuals cannot see (a bent board, a lens model that
fits the calibration views but not the measured region), and second-order effects of the
calibration's error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from stereo_bench.targets import Target
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.covariance import EXTRINSIC_NAMES, CalibrationCovariance
from stereo_bench.vision.detect import common_corners
from stereo_bench.vision.rectify import undistort_points
from stereo_bench.vision.triangulate import triangulate, triangulate_normalised, triangulation_jacobian

#: A stereo_bench.vision.pipeline.PairMeasurement (``square``, ``left``, ``right``): not imported, the pipeline
#: imports this module (it adds the calibration's held-out check, :func:`with_adequacy`).
PairMeasurement = Any
K_COVERAGE = 2.0
#: Default relative standard uncertainty of a board's square (scale). 1e-4 is 2.7 um on the 27 mm
#: square: the conservative end of what inspection reports of precision (glass, ceramic,
#: photolithographic) targets state, feature positions within +-2 um (e.g. calibvision.com's
#: reports; dot-vision's show a few um over 30 mm). A UV print on aluminium composite or a paper
#: print is not certified at that level (an office print is easily 1e-3 off in scale): give its own
#: value (``BoardScale``, ``--board-scale-u``), ideally measured.
DEFAULT_BOARD_SCALE_U_REL = 1e-4
#: Relative standard uncertainty of a printed measured target's square when nothing states it: an office
#: laser/inkjet print is +-0.1 % in scale from the paper feed (rectangular: 0.1 % / sqrt(3)).
PRINTED_TARGET_SCALE_U_REL = 0.001 / math.sqrt(3.0)
COMPONENTS = ("noise", "calibration", "structure", "target")
#: Fewer held-out views than this say too little about the model's adequacy: the component is not computed.
MIN_ADEQUACY_VIEWS = 8
#: A calibration view whose held-out square lies further than this many standard deviations from every other
#: view's is dropped from the fit (:func:`scale_outlier`): were the views' errors Gaussian, a calibration of 100
#: views would drop one falsely about once in 1000 (2 n Q(4.5) = 7e-4). The real sets' largest among the views
#: kept: 4.1 sigma (smiler488_box's view 19; 4.3 in its leave-one-out calibrations); opencv_sample's pair 7, dropped:
#: 5.6 (docs/UNCERTAINTY.md).
ADEQUACY_OUTLIER_SIGMAS = 4.5
#: Student's t for a 95.45 % two-sided interval (the k = 2 of a normal distribution) by degrees of freedom,
#: JCGM 100:2008 Table G.2; between the rows linear in 1/nu.
_T_9545 = ((1, 13.97), (2, 4.53), (3, 3.31), (4, 2.87), (5, 2.65), (6, 2.52), (7, 2.43), (8, 2.37), (9, 2.32),
           (10, 2.28), (11, 2.25), (12, 2.23), (13, 2.21), (14, 2.20), (15, 2.18), (16, 2.17), (17, 2.16),
           (18, 2.15), (19, 2.14), (20, 2.13), (25, 2.11), (30, 2.09), (35, 2.07), (40, 2.06), (45, 2.06),
           (50, 2.05), (100, 2.025))


def coverage_factor(dof: float) -> float:
    """k for about 95 % coverage with ``dof`` effective degrees of freedom (2.0 at infinity; JCGM 100 G.2)."""
    if not dof < 100:
        return float(K_COVERAGE + (_T_9545[-1][1] - K_COVERAGE) * 100.0 / dof) if math.isfinite(dof) else K_COVERAGE
    if dof <= 1:
        return _T_9545[0][1]
    for (n0, t0), (n1, t1) in zip(_T_9545[:-1], _T_9545[1:], strict=True):
        if n0 <= dof <= n1:
            w = (1 / dof - 1 / n0) / (1 / n1 - 1 / n0)
            return float(t0 + w * (t1 - t0))
    return K_COVERAGE


def effective_dof(components: Sequence[tuple[float, float]]) -> float:
    """Welch-Satterthwaite: nu_eff = u_c^4 / sum(u_i^4 / nu_i) over (u_i, nu_i) (nu_i inf: known exactly)."""
    u_c2 = sum(u * u for u, _ in components)
    denominator = sum(u**4 / nu for u, nu in components if math.isfinite(nu) and nu > 0 and u > 0)
    return float(u_c2**2 / denominator) if denominator > 0 else float("inf")
#: Relative standard uncertainty of the detector bias predicted from the calibration's fitted pixel
#: locking (the amplitude transfers from the calibration views to the target only approximately).
LOCKING_TRANSFER_U_REL = 0.5

#: Central-difference step per parameter kind: small against its uncertainty, large against the
#: 1e-10 convergence of the iterative undistortion (the square is linear in each over this range).
_STEP = {"fx": 0.05, "fy": 0.05, "cx": 0.05, "cy": 0.05, "k1": 1e-4, "k2": 1e-4, "k3": 1e-4, "k4": 1e-4, "k5": 1e-4,
         "k6": 1e-4, "p1": 1e-5, "p2": 1e-5, "s1": 1e-5, "s2": 1e-5, "s3": 1e-5, "s4": 1e-5, "tx": 1e-5, "ty": 1e-5,
         "rvec": 1e-5, "T": 0.01}
_DIST_INDEX = {name: i for i, name in enumerate(("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3",
                                                  "s4", "tx", "ty"))}


@dataclass(frozen=True)
class BoardScale:
    """Relative standard uncertainties of the boards' scale (certificate or stated tolerance).

    ``target_u_rel``: the measured board's square; ``calibration_board_u_rel``: the calibration
    board's; ``same_board``: the calibration used the very board that is measured (scale cancels).
    """

    target_u_rel: float = DEFAULT_BOARD_SCALE_U_REL
    calibration_board_u_rel: float = DEFAULT_BOARD_SCALE_U_REL
    same_board: bool = False

    def __post_init__(self):
        for name in ("target_u_rel", "calibration_board_u_rel"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, not {value}")

    def u_mm(self, nominal_mm: float) -> float:
        if self.same_board:
            return 0.0
        return float(nominal_mm * math.hypot(self.target_u_rel, self.calibration_board_u_rel))


@dataclass(frozen=True, eq=False)
class FrameCorners:
    """One measurement frame: corner ids (N,), raw pixels (N, 2) left and right, the noise sigma of its
    square mean (mm) and the corner noise per coordinate (left, right; px) it was propagated from (the image's
    sensor noise through the detector: :func:`~stereo_bench.vision.detect.corner_noise_px`).

    ``planar_fit_rms_px`` (left, right): the corners' per-coordinate residual about the board plane's best
    homography, sqrt(SSR / (2N - 8)) (:func:`~stereo_bench.vision.measure.planar_fit_rms_px`): the frame's own
    Type A evidence of its corner error, random and systematic together; NaN: not known."""

    ids: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    sigma_mean_mm: float
    pixel_sigma_px: tuple[float, float]
    # (calibration, points (N, 3), Jacobian (N, 3, 4)) the measurement already triangulated these corners with
    # (the same calls :func:`_triangulated` makes); None: not known.
    triangulated: tuple[StereoCalibration, np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    planar_fit_rms_px: tuple[float, float] = (float("nan"), float("nan"))

    @classmethod
    def from_pair(cls, pair: PairMeasurement) -> FrameCorners:
        # The very corners measure_pair triangulated (common_corners of the same detections).
        ids, left_px, right_px = common_corners(pair.left, pair.right)
        square = pair.square
        triangulated = None
        if square.calib is not None and square.jacobian is not None:
            triangulated = (square.calib, square.points_mm, square.jacobian)
        return cls(ids=ids, left_px=left_px, right_px=right_px, sigma_mean_mm=square.sigma_mean_mm,
                   pixel_sigma_px=tuple(square.pixel_sigma_px), triangulated=triangulated,
                   planar_fit_rms_px=tuple(float(v) for v in pair.planar_fit_rms_px))


def _frames(frames: Sequence[PairMeasurement | FrameCorners]) -> list[FrameCorners]:
    return [f if isinstance(f, FrameCorners) else FrameCorners.from_pair(f) for f in frames]


def perturbed(calib: StereoCalibration, name: str, delta: float) -> StereoCalibration:
    """``calib`` with one parameter (a covariance name: ``left.fx``, ``right.k1``, ``rvec.y``, ``T.x`` ...) moved."""
    return replace(calib, **_perturbed_fields(calib, name, delta))


def _perturbed_fields(calib: StereoCalibration, name: str, delta: float) -> dict[str, np.ndarray]:
    """The fields of ``calib`` that :func:`perturbed` replaces (``R``; ``T``; ``K1`` and ``D1``; or ``K2`` and
    ``D2``), for a caller that needs only those (without a new calibration's copy of every field)."""
    side, _, what = name.partition(".")
    if side == "rvec":
        rvec = cv2.Rodrigues(np.asarray(calib.R, np.float64))[0].reshape(3)
        rvec["xyz".index(what)] += delta
        return {"R": cv2.Rodrigues(rvec)[0]}
    if side == "T":
        T = np.array(calib.T, float).reshape(3)
        T["xyz".index(what)] += delta
        return {"T": T}
    if side not in ("left", "right"):
        raise KeyError(f"unknown calibration parameter {name!r}")
    K = np.array(calib.K1 if side == "left" else calib.K2, float)
    D = np.array(calib.D1 if side == "left" else calib.D2, float).reshape(1, -1)
    if what in ("fx", "fy", "cx", "cy"):
        K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[what]] += delta
    elif what in _DIST_INDEX and _DIST_INDEX[what] < D.size:
        D[0, _DIST_INDEX[what]] += delta
    else:
        raise KeyError(f"unknown calibration parameter {name!r}")
    return {"K1": K, "D1": D} if side == "left" else {"K2": K, "D2": D}


def parameter_step(name: str) -> float:
    """Central-difference step for a calibration parameter (a covariance name), in its unit."""
    return _STEP[name.partition(".")[0] if name.startswith(("rvec.", "T.")) else name.partition(".")[2]]


class _Square:
    """f(calib, left_px=None, right_px=None) -> the configuration's square (mm): mean over frames of each
    frame's mean adjacent length. ``left``/``right``: the frames' stacked pixels (sum N_i, 2), which
    ``left_px``/``right_px`` replace; :meth:`of_points` the square of their triangulated points.
    """

    def __init__(self, left: np.ndarray, right: np.ndarray, a_idx: np.ndarray, b_idx: np.ndarray,
                 weights: np.ndarray):
        self.left, self.right, self.a_idx, self.b_idx, self.weights = left, right, a_idx, b_idx, weights

    def of_points(self, points: np.ndarray) -> float:
        """The square of the stacked corners' triangulated points (sum N_i, 3)."""
        return float(self.weights @ np.linalg.norm(points[self.a_idx] - points[self.b_idx], axis=1))

    def __call__(self, calib: StereoCalibration, left_px: np.ndarray | None = None,
                 right_px: np.ndarray | None = None) -> float:
        return self.of_points(triangulate(calib, self.left if left_px is None else left_px,
                                          self.right if right_px is None else right_px))


def _square_function(frames: list[FrameCorners], target: Target) -> _Square:
    """The configuration's square as a function of the calibration and the stacked pixels (:class:`_Square`)."""
    left = np.vstack([f.left_px for f in frames])
    right = np.vstack([f.right_px for f in frames])
    offsets = np.cumsum([0] + [len(f.ids) for f in frames])
    a_idx, b_idx, weights = [], [], []
    for frame, offset in zip(frames, offsets[:-1], strict=True):
        pairs = _adjacent_index_pairs(frame, target)
        if not len(pairs):
            raise ValueError("a frame has no adjacent corner pair seen in both views")
        a_idx.append(offset + pairs[:, 0])
        b_idx.append(offset + pairs[:, 1])
        weights.append(np.full(len(pairs), 1.0 / (len(pairs) * len(frames))))
    return _Square(left, right, np.concatenate(a_idx), np.concatenate(b_idx), np.concatenate(weights))


def _adjacent_index_pairs(frame: FrameCorners, target: Target) -> np.ndarray:
    """(K, 2) row indices into ``frame``'s corners of the target's adjacent pairs seen in both views."""
    position = {int(c): i for i, c in enumerate(frame.ids)}
    return np.array([(position[a], position[b]) for a, b in target.adjacent_pairs()
                     if a in position and b in position], int).reshape(-1, 2)


def _triangulated(calib: StereoCalibration, frame: FrameCorners, memo: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 3), Jacobian (N, 3, 4)) of ``frame``'s corners with ``calib``.

    The measurement's own when it triangulated the frame with this very calibration object (the budget of the
    frames a source measured: :meth:`FrameCorners.from_pair`). ``memo`` (a dict, or None): the results kept by
    frame, so the noise bias, the phase sum and the residual map's gradients of one budget triangulate each
    frame once instead of three times. Either way the same calls on the same numbers: the same bits.
    """
    if frame.triangulated is not None and frame.triangulated[0] is calib:
        return frame.triangulated[1], frame.triangulated[2]
    if memo is not None and id(frame) in memo:
        return memo[id(frame)][1]
    result = (triangulate(calib, frame.left_px, frame.right_px),
              triangulation_jacobian(calib, frame.left_px, frame.right_px))
    if memo is not None:
        memo[id(frame)] = (frame, result)  # the frame is kept with its result: its id stays its own
    return result


def pixel_gradients(calib: StereoCalibration, frames: Sequence[PairMeasurement | FrameCorners],
                    target: Target, *, memo: dict | None = None) -> list[np.ndarray]:
    """Per frame (N_i, 4): d(configuration square)/d(u_left, v_left, u_right, v_right) of each corner (mm/px).

    First order through the triangulation's Jacobian, as :func:`~stereo_bench.vision.measure.measure_square`
    propagates the noise; the configuration square weighs each frame 1/n. ``memo``: see :func:`_triangulated`.
    """
    frames = _frames(frames)
    out = []
    for frame in frames:
        pairs = _adjacent_index_pairs(frame, target)
        points, jac = _triangulated(calib, frame, memo)  # (N, 3), (N, 3, 4)
        d = points[pairs[:, 0]] - points[pairs[:, 1]]
        u = d / np.linalg.norm(d, axis=1)[:, None] / (len(pairs) * len(frames))
        gradient = np.zeros((len(frame.ids), 4))
        np.add.at(gradient, pairs[:, 0], np.einsum("kj,kjc->kc", u, jac[pairs[:, 0]]))
        np.add.at(gradient, pairs[:, 1], -np.einsum("kj,kjc->kc", u, jac[pairs[:, 1]]))
        out.append(gradient)
    return out


def phase_sum(calib: StereoCalibration, frames: Sequence[PairMeasurement | FrameCorners], target: Target, *,
              gradients: list[np.ndarray] | None = None) -> complex:
    """C = sum_k g_k exp(2 pi i frac(p_k)) over every corner coordinate p_k of every frame (g: :func:`pixel_gradients`).

    A corner error e(p) = Im(a exp(2 pi i frac(p))) (a = a_sin + i a_cos, px) moves the square by
    Im(a C): corners of alike phase (a regular grid seen square-on) add up, spread phases cancel.
    ``gradients``: :func:`pixel_gradients` of the same arguments, when the caller has them.
    """
    frames = _frames(frames)
    total = 0j
    if gradients is None:
        gradients = pixel_gradients(calib, frames, target)
    for frame, gradient in zip(frames, gradients, strict=True):
        pixels = np.column_stack([frame.left_px, frame.right_px])  # (N, 4) like the gradient's columns
        total += np.sum(gradient * np.exp(2j * np.pi * np.mod(pixels, 1.0)))
    return complex(total)


#: Steps (px, and relative) of the coherent image shift and magnification differentiated for the detector term.
_SHIFT_STEP_PX, _MAGNIFICATION_STEP = 0.01, 1e-5


def coherent_displacement_mm(calib: StereoCalibration, frames: Sequence[PairMeasurement | FrameCorners],
                             target: Target, sigma_px: float) -> float:
    """Standard uncertainty (mm) of the square from a corner error of ``sigma_px`` per coordinate that is smooth
    across the board: in each image an unknown shift (sigma_px per axis) and magnification about the corners'
    centroid (sigma_px at their RMS radius), independent between the images, shared by the frames."""
    frames = _frames(frames)
    square = _square_function(frames, target)
    left, right = np.vstack([f.left_px for f in frames]), np.vstack([f.right_px for f in frames])
    offsets = np.cumsum([0] + [len(f.ids) for f in frames])
    variance = 0.0
    for side, pixels in (("left", left), ("right", right)):
        centroid = np.vstack([np.broadcast_to(pixels[a:b].mean(axis=0), (b - a, 2))
                              for a, b in zip(offsets[:-1], offsets[1:], strict=True)])
        radial = pixels - centroid
        radius = float(np.sqrt(np.mean(np.sum(radial**2, axis=1))))

        def slope(delta: np.ndarray, step: float, side: str = side) -> float:
            plus = (left + delta, right) if side == "left" else (left, right + delta)
            minus = (left - delta, right) if side == "left" else (left, right - delta)
            return (square(calib, *plus) - square(calib, *minus)) / (2 * step)
        for axis in (0, 1):
            delta = np.zeros_like(pixels)
            delta[:, axis] = _SHIFT_STEP_PX
            variance += (slope(delta, _SHIFT_STEP_PX) * sigma_px) ** 2
        variance += (slope(_MAGNIFICATION_STEP * radial, _MAGNIFICATION_STEP) * sigma_px / radius) ** 2
    return float(math.sqrt(variance))


#: A bin of the residual map speaks for the corners in it when it holds at least this many calibration corners.
MIN_MAP_CORNERS = 8


def mapped_systematic_mm(calib: StereoCalibration, frames: Sequence[PairMeasurement | FrameCorners], target: Target,
                         maps: dict, sigma_px: float, *,
                         gradients: list[np.ndarray] | None = None) -> tuple[float, float] | None:
    """(bias, standard uncertainty) mm of the square from the corner error beyond noise and locking, read from the
    calibration's residual maps (``maps``: "left", "right" -> ResidualMap) where the measured corners lie.

    The smooth part: each bin's mean residual r_b (projected - observed) says the model puts a corner r_b off
    there, so the square moves by b = -sum_b G_b . r_b (G_b: the square's pixel gradient summed over the
    corners in bin b, every frame), uncertain by the bins' standard errors. The rest of the excess
    ``sigma_px`` (its variance less the map's mean squared miss) is independent from corner to corner and
    the same in every frame of a static target. None when a measured corner lies in a bin with fewer than
    :data:`MIN_MAP_CORNERS` calibration corners (the map does not speak for it). ``gradients``:
    :func:`pixel_gradients` of the same arguments, when the caller has them.
    """
    frames = _frames(frames)
    if not maps or any(side not in maps for side in ("left", "right")):
        return None
    if gradients is None:
        gradients = pixel_gradients(calib, frames, target)
    bias = variance = 0.0
    explained, weight = 0.0, 0.0
    per_corner: dict[tuple[str, int], np.ndarray] = {}
    for side, columns in (("left", slice(0, 2)), ("right", slice(2, 4))):
        residual_map = maps[side]
        pixels = np.vstack([f.left_px if side == "left" else f.right_px for f in frames])
        gradient = np.vstack([g[:, columns] for g in gradients])
        bins = residual_map.bins_of(pixels)
        count = residual_map.count.ravel()
        if np.any(count[bins] < MIN_MAP_CORNERS):
            return None
        mean = residual_map.mean.reshape(-1, 2)
        error = residual_map.standard_error().reshape(-1, 2)
        G = np.zeros_like(mean)
        np.add.at(G, bins, gradient)
        bias -= float(np.sum(G * mean))
        variance += float(np.sum((G * error) ** 2))
        # How much of the excess the map's smooth miss explains over the calibration corners (noise removed).
        supported = count >= MIN_MAP_CORNERS
        explained += float(np.sum(count[supported, None] * np.maximum(mean[supported] ** 2 - error[supported] ** 2,
                                                                      0.0)))
        weight += 2.0 * float(np.sum(count[supported]))
        ids = np.concatenate([f.ids for f in frames])
        for corner, g in zip(ids, gradient, strict=True):
            key = (side, int(corner))
            per_corner[key] = per_corner.get(key, 0.0) + g
    independent = math.sqrt(max(sigma_px**2 - explained / max(weight, 1.0), 0.0))
    variance += independent**2 * float(sum(np.sum(g**2) for g in per_corner.values()))
    return bias, float(math.sqrt(variance))


def frames_residual_px(frames: Sequence[FrameCorners]) -> tuple[float, float]:
    """(sigma, dof): the frames' planar-fit residuals pooled over both cameras, sqrt(sum nu_i s_i^2 / sum nu_i) px
    per coordinate with nu_i = 2 N_i - 8 per image (the homography's eight parameters), (NaN, 0) without one."""
    ssr = dof = 0.0
    for frame in frames:
        nu = 2 * len(frame.ids) - 8
        for value in frame.planar_fit_rms_px:
            if nu > 0 and math.isfinite(value):
                ssr, dof = ssr + nu * value**2, dof + nu
    return (math.sqrt(ssr / dof), dof) if dof > 0 else (float("nan"), 0.0)


def corner_reference(covariance: CalibrationCovariance | None, frames: Sequence[FrameCorners] = (),
                     ) -> tuple[float, float, tuple[float, float] | None, str]:
    """(sigma px, dof, pixel locking, source) of the corner error the residuals show, random and systematic together.

    The calibration's residual sigma, sqrt(SSR / (n_coordinates - n_parameters)), when its covariance estimated
    it; otherwise (no covariance: a calibration file without one, given intrinsics, a rig model; or a sigma
    assumed, not estimated) the measured frames' own planar-fit residual (:func:`frames_residual_px`), so that
    the corner error is never taken from the image's sensor noise alone. (NaN, 0, None, "") when neither is known.
    """
    if covariance is not None and covariance.dof > 0 and math.isfinite(covariance.sigma_px):
        return float(covariance.sigma_px), float(covariance.dof), covariance.pixel_locking_px, \
            "the calibration's residuals"
    sigma, dof = frames_residual_px(frames)
    if dof > 0:
        return sigma, dof, None, "the frames' planar-fit residuals"
    return float("nan"), 0.0, None, ""


def corner_systematic_px(covariance: CalibrationCovariance | None, random_px: float,
                         frames: Sequence[FrameCorners] = ()) -> float:
    """Systematic corner error per coordinate (px) the residuals show beyond the random noise and the fitted locking.

    sqrt(sigma^2 - random^2 - (a_sin^2 + a_cos^2) / 2) when sigma^2 exceeds the rest by more than three standard
    errors of a residual variance (sqrt(2 / dof) relative), else 0. sigma, its dof and the locking are
    :func:`corner_reference`'s: the calibration's residuals, or without them the frames' planar fit; 0 when
    neither is known (nothing to compare with) or ``random_px`` is not positive.
    """
    sigma, dof, locking, _ = corner_reference(covariance, frames)
    if not dof > 0 or not math.isfinite(sigma) or not random_px > 0:
        return 0.0
    locking = locking or (0.0, 0.0)
    explained = random_px**2 + 0.5 * (locking[0] ** 2 + locking[1] ** 2)
    if sigma**2 <= explained * (1.0 + 3.0 * math.sqrt(2.0 / dof)):
        return 0.0
    return float(math.sqrt(sigma**2 - explained))


def noise_bias_mm(calib: StereoCalibration, frame: FrameCorners, target: Target, *, memo: dict | None = None,
                  extra_px: float = 0.0) -> float:
    """Expected lengthening (mm) of the frame's mean adjacent length by its corner noise (second order).

    Independent corners of per-coordinate noise ``frame.pixel_sigma_px`` (each image's) and ``extra_px`` (both
    images: the corner error beyond the sensor noise, which lengthens a length as much whether it changes from
    frame to frame or not): S_d = S_a + S_b, each point's S = J diag(noise^2) J^T through the triangulation;
    bias = mean over pairs of (tr S_d - u^T S_d u) / (2 |d|). ``memo``: see :func:`_triangulated`.
    """
    pairs = _adjacent_index_pairs(frame, target)
    if not len(pairs):
        return float("nan")
    points, jac = _triangulated(calib, frame, memo)  # (N, 3), (N, 3, 4)
    s_left, s_right = frame.pixel_sigma_px
    v_left, v_right = s_left**2 + extra_px**2, s_right**2 + extra_px**2
    cov = np.einsum("nik,k,njk->nij", jac, np.array([v_left, v_left, v_right, v_right]), jac)
    return float(np.mean(_lengthening_per_pair(points, cov, pairs[:, 0], pairs[:, 1])))


def _lengthening_per_pair(points: np.ndarray, cov: np.ndarray, a_idx: np.ndarray, b_idx: np.ndarray) -> np.ndarray:
    """(K,) mm: the expected lengthening of each length |points[a] - points[b]| by independent point errors of
    covariance ``cov`` (N, 3, 3) mm^2, to second order: (tr S_d - u^T S_d u) / (2 |d|), S_d = S_a + S_b."""
    d = points[a_idx] - points[b_idx]
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    cov_d = cov[a_idx] + cov[b_idx]
    transverse = np.trace(cov_d, axis1=1, axis2=2) - np.einsum("ki,kij,kj->k", u, cov_d, u)
    return transverse / (2.0 * length)


def square_sensitivities(
    calib: StereoCalibration, frames: Sequence[PairMeasurement | FrameCorners], target: Target, names: Sequence[str],
) -> np.ndarray:
    """(P,) d(square)/d(parameter) for ``names`` (mm per px, per unit, per rad, per mm), at the measured corners.

    The square is the configuration's (mean over ``frames`` of each frame's mean adjacent length);
    central differences over the triangulation the pipeline itself uses.

    The same numbers as ``square(perturbed(calib, name, +-step))`` per parameter, with two calls fewer each:
    a camera's parameter leaves the other camera's undistorted corners (and R, T leave both) as they were,
    so they are undistorted once; and the intrinsics' perturbations share R, T, so their points go through
    one triangulation (OpenCV undistorts and triangulates point by point: the same bits).
    """
    square = _square_function(_frames(frames), target)
    return _sensitivities(calib, square, names, square.of_points)


def _sensitivities(calib: StereoCalibration, square: _Square, names: Sequence[str], reduce,
                   normalised: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """:func:`square_sensitivities` of a built square function; ``reduce(points (M, 3))`` -> a value or an array
    of values (per frame: the gradient is then (P, F)). ``normalised``: the square's corners undistorted with
    ``calib`` (left, right), when the caller has them."""
    left_norm, right_norm = normalised or (undistort_points(square.left, calib.K1, calib.D1),
                                           undistort_points(square.right, calib.K2, calib.D2))
    values: list[list] = [[None, None] for _ in names]  # the square at +step and -step
    intrinsic: list[tuple[int, int, np.ndarray, np.ndarray]] = []
    for i, name in enumerate(names):
        step = parameter_step(name)
        side = name.partition(".")[0]
        for j, delta in enumerate((step, -step)):
            moved = _perturbed_fields(calib, name, delta)
            if side == "left":
                intrinsic.append((i, j, undistort_points(square.left, moved["K1"], moved["D1"]), right_norm))
            elif side == "right":
                intrinsic.append((i, j, left_norm, undistort_points(square.right, moved["K2"], moved["D2"])))
            else:
                points = triangulate_normalised(moved.get("R", calib.R), moved.get("T", calib.T), left_norm, right_norm)
                values[i][j] = reduce(points)
    if intrinsic:
        points = triangulate_normalised(calib.R, calib.T, np.vstack([e[2] for e in intrinsic]),
                                        np.vstack([e[3] for e in intrinsic])).reshape(len(intrinsic), -1, 3)
        for (i, j, _, _), moved_points in zip(intrinsic, points, strict=True):
            values[i][j] = reduce(moved_points)
    return np.array([(np.asarray(plus, float) - np.asarray(minus, float)) / (2 * parameter_step(name))
                     for (plus, minus), name in zip(values, names, strict=True)])


@dataclass(frozen=True)
class ModelAdequacy:
    """How well a calibration measures its own board in views it did not see (leave-one-view-out).

    Per calibration view v the calibration without v (:attr:`CalibrationCovariance.view_deltas`) measures v's
    squares: relative error r_v = (mean adjacent length - square) / square, predicted standard uncertainty p_v
    from the fit's corner sigma (independent corners, p_v^2 = c_v^2 + sigma_fit^2 G_v^2: c_v the calibration's
    part, G_v^2 the sum of the square's squared pixel gradients) and the calibration's covariance
    (:meth:`variance_of`). The same corners lengthen each held-out square on average (second order, as
    :func:`noise_bias_mm`): l_v = s beta_v, beta_v per unit corner variance, s the corner variance the squares
    show (``corner_px`` squared, below). ``u_rel`` = sqrt(max(mean (r - l)^2 - mean p^2, 0)) (a Type A estimate
    truncated at zero, not tested for significance: a test would drop a real excess of few views): the relative
    error of a square the model makes beyond what its noise predicts (bias and scatter together), with ``dof`` =
    n - 1. The lengthening is the noise's, not the model's: a budget carries its own target's as its noise bias,
    and counting it here as well counted it twice (the simulated lab bench's still target: RMS(err/u_c) 0.64).
    ``sigmas_rel``: p_v per view (empty when read from a file that did not record it).
    ``corner_px``: the corner error per coordinate, independent from corner to corner, that the held-out squares
    show: sqrt(s) with mean r^2 = mean c^2 + s mean G^2 + s^2 mean beta^2, at most sigma_fit (what exceeds it is
    ``u_rel``'s) and at least 0: below sigma_fit when the residuals' excess is smooth across a board (neighbouring
    corners err alike, so a square's two ends move together and it lengthens less). ``rms_rel``,
    ``predicted_rel`` (p's RMS), ``bias_rel`` (mean r), ``lengthening_rel`` (mean l) and ``errors_rel`` (per
    view) are what it rests on.
    """

    u_rel: float
    dof: float
    n_views: int
    rms_rel: float
    predicted_rel: float
    bias_rel: float
    corner_px: float = float("nan")
    errors_rel: tuple[float, ...] = ()
    lengthening_rel: float = 0.0
    sigmas_rel: tuple[float, ...] = ()

    def as_dict(self) -> dict:
        return {"u_rel": self.u_rel, "dof": self.dof, "n_views": self.n_views, "rms_rel": self.rms_rel,
                "predicted_rel": self.predicted_rel, "bias_rel": self.bias_rel, "corner_px": self.corner_px,
                "errors_rel": list(self.errors_rel), "lengthening_rel": self.lengthening_rel,
                "sigmas_rel": list(self.sigmas_rel)}

    @classmethod
    def from_dict(cls, data: dict) -> ModelAdequacy:
        return cls(u_rel=float(data["u_rel"]), dof=float(data["dof"]), n_views=int(data["n_views"]),
                   rms_rel=float(data["rms_rel"]), predicted_rel=float(data["predicted_rel"]),
                   bias_rel=float(data["bias_rel"]), corner_px=float(data.get("corner_px", float("nan"))),
                   errors_rel=tuple(float(v) for v in data.get("errors_rel", ())),
                   lengthening_rel=float(data.get("lengthening_rel", 0.0)),
                   sigmas_rel=tuple(float(v) for v in data.get("sigmas_rel", ())))


@dataclass(frozen=True)
class ScaleOutlier:
    """One calibration view whose held-out squares disagree with all the others' (:func:`scale_outlier`).
    ``position``: the view's place in the adequacy's views (the fit's ``views_used`` order); the rest relative."""

    position: int
    z: float
    error_rel: float
    others_mean_rel: float
    expected_rel: float  # the standard deviation the others give this view's error: its own noise and their excess

    def reason(self) -> str:
        return (f"its squares, held out, measure {100 * self.error_rel:+.2f} % against the other views' "
                f"{100 * self.others_mean_rel:+.2f} % +- {100 * self.expected_rel:.2f} % ({self.z:.1f} sigma, "
                f"limit {ADEQUACY_OUTLIER_SIGMAS:g}): something in this view that is in no other (a board bent or "
                "moved in this pair, a mismatched corner, a pair not taken together)")


def scale_outlier(adequacy: ModelAdequacy | None) -> ScaleOutlier | None:
    """The view whose held-out square is further than :data:`ADEQUACY_OUTLIER_SIGMAS` from every other view's, or None.

    Each view v against the others alone: z_v = |r_v - mean_o r| / sqrt(p_v^2 + e_o^2 + var_o r / (n - 1)), with
    e_o^2 = max(var_o r - mean_o p^2, 0) the excess the other views show (a model that fits no view well widens
    every view's expectation alike, so a class of views that all err is left to ``u_rel``, not picked apart),
    ``p`` the views' predicted sigmas. The largest z, if above the limit. None with fewer than
    :data:`MIN_ADEQUACY_VIEWS` + 1 views, or an adequacy read from a file without per-view sigmas.
    """
    if adequacy is None or len(adequacy.errors_rel) < MIN_ADEQUACY_VIEWS + 1 \
            or len(adequacy.sigmas_rel) != len(adequacy.errors_rel):
        return None
    r, p = np.asarray(adequacy.errors_rel, float), np.asarray(adequacy.sigmas_rel, float)
    n = len(r)
    # Each view's others by subtraction from the sums over all views.
    mean_o = (r.sum() - r) / (n - 1)
    var_o = np.maximum((np.sum(r**2) - r**2) / (n - 1) - mean_o**2, 0.0)
    excess_sq = np.maximum(var_o - (np.sum(p**2) - p**2) / (n - 1), 0.0)
    expected = np.sqrt(p**2 + excess_sq)
    z = np.abs(r - mean_o) / np.sqrt(expected**2 + var_o / (n - 1))
    v = int(np.argmax(z))
    if not z[v] > ADEQUACY_OUTLIER_SIGMAS:
        return None
    return ScaleOutlier(v, float(z[v]), float(r[v]), float(mean_o[v]), float(expected[v]))


class _ObjectGrid:
    """The adjacent pairs of one view's board points (N, 3): pairs one grid pitch (the smallest spacing) apart."""

    def __init__(self, object_points: np.ndarray):
        obj = self.points = np.asarray(object_points, float).reshape(-1, 3)
        distance = np.linalg.norm(obj[:, None] - obj[None], axis=2)
        self.square_mm = float(np.min(distance[distance > 0]))
        a, b = np.nonzero(np.triu(np.abs(distance - self.square_mm) < 1e-6 * self.square_mm, 1))
        self.pairs = np.column_stack([a, b])

    def adjacent_pairs(self) -> np.ndarray:
        return self.pairs


def _view_squares(object_points: Sequence[np.ndarray], left_points: Sequence[np.ndarray],
                  right_points: Sequence[np.ndarray]) -> tuple[_Square, np.ndarray, np.ndarray, np.ndarray]:
    """Every view's square in one square function over all views' corners (each view's adjacent pairs weighted
    1/K_v): (square, each pair's view (K,), each corner's view (N,), each view's nominal square (n,) mm). Views of
    the same board points (a whole board in every view) share their grid's pairs."""
    grids: dict[bytes, _ObjectGrid] = {}
    a_idx, b_idx, weights, owner, corner_owner, nominal, offset = [], [], [], [], [], [], 0
    for v, obj in enumerate(object_points):
        obj = np.asarray(obj, float).reshape(-1, 3)
        grid = grids.get(obj.tobytes())
        if grid is None:
            grid = grids[obj.tobytes()] = _ObjectGrid(obj)
        a_idx.append(offset + grid.pairs[:, 0])
        b_idx.append(offset + grid.pairs[:, 1])
        weights.append(np.full(len(grid.pairs), 1.0 / len(grid.pairs)))
        owner.append(np.full(len(grid.pairs), v))
        corner_owner.append(np.full(len(obj), v))
        nominal.append(grid.square_mm)
        offset += len(obj)
    left = np.vstack([np.asarray(p, float).reshape(-1, 2) for p in left_points])
    right = np.vstack([np.asarray(p, float).reshape(-1, 2) for p in right_points])
    square = _Square(left, right, np.concatenate(a_idx), np.concatenate(b_idx), np.concatenate(weights))
    return square, np.concatenate(owner), np.concatenate(corner_owner), np.array(nominal)


def model_adequacy(calib: StereoCalibration, object_points: Sequence[np.ndarray], left_points: Sequence[np.ndarray],
                   right_points: Sequence[np.ndarray]) -> ModelAdequacy | None:
    """The leave-one-view-out check of a stereo calibration on its own board (:class:`ModelAdequacy`).

    ``object_points``, ``left_points``, ``right_points``: per view (N_v, 3) mm and (N_v, 2) px, the views
    ``calib.covariance.view_deltas`` belong to (the views the fit used, in its order). Linearised: no refit,
    the held-out square to first order in the view's change, sqrt-sum of a few triangulations per view
    (scripts/coverage_real.py: the one-step deltas equal refitting without the view to 1-4 % in the scatter of
    abs(T), fx, cx). None without view deltas or with fewer than
    :data:`MIN_ADEQUACY_VIEWS` views.

    The squares' sensitivities: to R and T by re-triangulating every corner (central differences); to the
    intrinsics by the moved undistortions carried through the triangulation to first order
    (:func:`_intrinsic_sensitivities`), and the pixel gradient through the same triangulation Jacobian.
    """
    covariance = calib.covariance
    if covariance is None or covariance.view_deltas is None or len(object_points) < MIN_ADEQUACY_VIEWS:
        return None
    if len(covariance.view_deltas) != len(object_points):
        raise ValueError("model_adequacy: one view per row of the covariance's view deltas")
    names = list(covariance.names)
    sigma_px = covariance.sigma_px
    square, owner_arr, corner_owner, nominal_arr = _view_squares(object_points, left_points, right_points)
    n = len(nominal_arr)

    def per_view(points: np.ndarray) -> np.ndarray:
        lengths = np.linalg.norm(points[square.a_idx] - points[square.b_idx], axis=1)
        return np.bincount(owner_arr, weights=square.weights * lengths, minlength=n)

    intrinsic = [name for name in names if name.partition(".")[0] in ("left", "right")]
    extrinsic = [name for name in names if name not in intrinsic]
    left_norm = undistort_points(square.left, calib.K1, calib.D1)
    right_norm = undistort_points(square.right, calib.K2, calib.D2)
    # R and T re-triangulate every corner (central differences) on another thread while the intrinsics'
    # sensitivities are linearised here: both are numpy and OpenCV work on large arrays, which releases the GIL.
    with ThreadPoolExecutor(max_workers=1) as pool:
        moved_extrinsics = pool.submit(_sensitivities, calib, square, extrinsic, per_view, (left_norm, right_norm))
        points = triangulate_normalised(calib.R, calib.T, left_norm, right_norm)
        measured = per_view(points)
        jac_norm = _normalised_jacobian(calib, left_norm, right_norm)  # (N, 3, 4) per normalised coordinate
        # Each view's own square (weights 1/K_v) per corner's normalised coordinates, through the triangulation.
        d = points[square.a_idx] - points[square.b_idx]
        u = d / np.linalg.norm(d, axis=1)[:, None] * square.weights[:, None]
        gradient_norm = np.zeros((len(points), 4))
        np.add.at(gradient_norm, square.a_idx, np.einsum("kj,kjc->kc", u, jac_norm[square.a_idx]))
        np.add.at(gradient_norm, square.b_idx, -np.einsum("kj,kjc->kc", u, jac_norm[square.b_idx]))
        g_intrinsic = _intrinsic_sensitivities(calib, square, intrinsic, gradient_norm, corner_owner, n)
        # The square's pixel gradient per corner: the normalised one through each camera's undistortion.
        undistortion = (_undistortion_jacobian(square.left, calib.K1, calib.D1),
                        _undistortion_jacobian(square.right, calib.K2, calib.D2))
        gradient = np.concatenate([np.einsum("ni,nij->nj", gradient_norm[:, :2], undistortion[0]),
                                   np.einsum("ni,nij->nj", gradient_norm[:, 2:], undistortion[1])], axis=1)
        g_extrinsic = moved_extrinsics.result()
    g = np.zeros((n, len(names)))  # (n, P) in the covariance's order
    for columns, values in ((intrinsic, g_intrinsic), (extrinsic, g_extrinsic)):
        for name, column in zip(columns, values, strict=True):
            g[:, names.index(name)] = column
    # Per unit corner variance (px^2): each view's lengthening, relative.
    lengthening_unit = _lengthening_per_view(square, points, jac_norm, undistortion, owner_arr, n) / nominal_arr
    # First order in each view's leave-one-out change, like the change itself (no refit, no re-triangulation).
    errors = (measured + np.einsum("np,np->n", g, covariance.view_deltas) - nominal_arr) / nominal_arr
    calibration = np.array([covariance.variance_of(g_v, names)[0] for g_v in g]) / nominal_arr**2
    pixel = np.bincount(corner_owner, weights=np.sum(gradient**2, axis=1), minlength=n) / nominal_arr**2
    sigmas = np.sqrt(calibration + sigma_px**2 * pixel)
    errors_arr = np.asarray(errors)
    mean_calibration, mean_pixel = float(np.mean(calibration)), float(np.mean(pixel))
    # The corner variance s, independent from corner to corner, that the held-out squares show: their mean square
    # is c^2 + s G^2 (scatter) + s^2 beta^2 (the lengthening, second order as noise_bias_mm's), at most the fit's.
    a, b, c = float(np.mean(lengthening_unit**2)), mean_pixel, mean_calibration - float(np.mean(errors_arr**2))
    s = (-b + math.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a) if a > 0 else -c / b if b > 0 else 0.0
    corner_variance = min(max(s, 0.0), sigma_px**2)
    # That lengthening is noise too, and a budget carries it as its own noise bias: not the model's excess.
    lengthening = corner_variance * lengthening_unit
    mean_square = float(np.mean((errors_arr - lengthening) ** 2))
    mean_predicted = mean_calibration + sigma_px**2 * mean_pixel
    corner = math.sqrt(corner_variance)
    return ModelAdequacy(u_rel=float(math.sqrt(max(mean_square - mean_predicted, 0.0))), dof=float(n - 1), n_views=n,
                         rms_rel=float(math.sqrt(np.mean(errors_arr**2))),
                         predicted_rel=float(math.sqrt(mean_predicted)),
                         bias_rel=float(np.mean(errors_arr)), corner_px=float(corner),
                         errors_rel=tuple(float(e) for e in errors_arr),
                         lengthening_rel=float(np.mean(lengthening)), sigmas_rel=tuple(float(v) for v in sigmas))


def _lengthening_per_view(square: _Square, points: np.ndarray, jac_norm: np.ndarray,
                          undistortion: tuple[np.ndarray, np.ndarray], owner: np.ndarray, n_views: int) -> np.ndarray:
    """(n_views,) mm per px^2: each view's expected lengthening of its mean adjacent length by independent corner
    noise of unit variance per coordinate in both images (:func:`_lengthening_per_pair`, as :func:`noise_bias_mm`;
    the pixels carried through each camera's undistortion). ``points`` (N, 3) and ``jac_norm`` (N, 3, 4): the square's
    corners triangulated and their :func:`_normalised_jacobian`; ``undistortion``: each camera's
    :func:`_undistortion_jacobian` (N, 2, 2) at them; ``owner`` (K,) each adjacent pair's view."""
    jac_px = np.concatenate([np.einsum("nik,nkj->nij", jac_norm[:, :, :2], undistortion[0]),
                             np.einsum("nik,nkj->nij", jac_norm[:, :, 2:], undistortion[1])], axis=2)  # (N, 3, 4 px)
    cov = np.einsum("nik,njk->nij", jac_px, jac_px)
    per_pair = _lengthening_per_pair(points, cov, square.a_idx, square.b_idx)
    return np.bincount(owner, weights=square.weights * per_pair, minlength=n_views)


#: Central-difference steps of :func:`model_adequacy`'s Jacobians: of the triangulation in the normalised
#: coordinates (2e-6 of the coordinates' ~0.5; ~1e-3 px, as :func:`triangulation_jacobian`'s step) and of the
#: undistortion in the pixels.
_NORMALISED_STEP, _PIXEL_STEP_PX = 1e-6, 1e-3


def _normalised_jacobian(calib: StereoCalibration, left_norm: np.ndarray, right_norm: np.ndarray) -> np.ndarray:
    """(N, 3, 4) derivatives of each triangulated point (mm) w.r.t. its undistorted normalised coordinates
    (x_left, y_left, x_right, y_right): central differences, the eight triangulations in one call."""
    n = len(left_norm)
    steps = np.zeros((4, 2, n, 4))  # (coordinate k, +/-, point, (x_l, y_l, x_r, y_r))
    steps[np.arange(4), 0, :, np.arange(4)] = _NORMALISED_STEP
    steps[np.arange(4), 1, :, np.arange(4)] = -_NORMALISED_STEP
    moved = triangulate_normalised(calib.R, calib.T, (left_norm + steps[..., :2]).reshape(-1, 2),
                                   (right_norm + steps[..., 2:]).reshape(-1, 2)).reshape(4, 2, n, 3)
    return np.moveaxis((moved[:, 0] - moved[:, 1]) / (2 * _NORMALISED_STEP), 0, 2)


def _undistortion_jacobian(points_px: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """(N, 2, 2) derivatives of the undistorted normalised coordinates w.r.t. the pixels: central differences,
    the four undistortions in one call."""
    points_px = np.asarray(points_px, float).reshape(-1, 2)
    n = len(points_px)
    steps = np.zeros((2, 2, n, 2))  # (pixel coordinate j, +/-, point, (u, v))
    steps[np.arange(2), 0, :, np.arange(2)] = _PIXEL_STEP_PX
    steps[np.arange(2), 1, :, np.arange(2)] = -_PIXEL_STEP_PX
    moved = undistort_points((points_px + steps).reshape(-1, 2), K, D).reshape(2, 2, n, 2)
    return np.moveaxis((moved[:, 0] - moved[:, 1]) / (2 * _PIXEL_STEP_PX), 0, 2)  # (N, 2 normalised, 2 px)


def _intrinsic_sensitivities(calib: StereoCalibration, square: _Square, names: Sequence[str],
                             gradient_norm: np.ndarray, owner: np.ndarray, n_views: int) -> np.ndarray:
    """(P, n_views) d(each view's square)/d(intrinsic parameter) for ``names`` (``left.*``, ``right.*``):
    :func:`_sensitivities`' central differences of the undistortion, carried through the triangulation to first
    order (``gradient_norm`` (N, 4): each corner's d(its view's square)/d(normalised coordinates)) instead of
    triangulating every moved corner again; ``owner`` (N,) each corner's view. The same derivative: the moved
    corners lie ~1e-4 of their coordinates away, where the triangulation is linear to ~1e-8 of the difference."""
    out = np.zeros((len(names), n_views))
    for i, name in enumerate(names):
        step = parameter_step(name)
        side = name.partition(".")[0]
        pixels, K, D, columns = ((square.left, "K1", "D1", slice(0, 2)) if side == "left" else
                                 (square.right, "K2", "D2", slice(2, 4)))
        plus, minus = (undistort_points(pixels, moved[K], moved[D]) for moved in
                       (_perturbed_fields(calib, name, step), _perturbed_fields(calib, name, -step)))
        change = np.sum(gradient_norm[:, columns] * (plus - minus), axis=1) / (2 * step)
        out[i] = np.bincount(owner, weights=change, minlength=n_views)
    return out


def with_adequacy(calib: StereoCalibration, object_points: Sequence[np.ndarray], left_points: Sequence[np.ndarray],
                  right_points: Sequence[np.ndarray]) -> StereoCalibration:
    """``calib`` with its :func:`model_adequacy` (``adequacy``), from the views it was given (indexed by
    ``calib.views_used``, as :func:`~stereo_bench.vision.calibrate.calibrate_stereo` takes them); unchanged
    without view deltas."""
    covariance = calib.covariance
    if covariance is None or covariance.view_deltas is None:
        return calib
    used = calib.views_used
    return replace(calib, adequacy=model_adequacy(calib, [object_points[i] for i in used],
                                                  [left_points[i] for i in used], [right_points[i] for i in used]))


def independent_displacement_mm(frames: list[FrameCorners], gradients: list[np.ndarray], sigma_px: float) -> float:
    """Standard uncertainty (mm) of the square from a corner error of ``sigma_px`` per coordinate independent from
    corner to corner and the same in every frame of a static target (a corner's gradients add over the frames).
    ``gradients``: :func:`pixel_gradients` of ``frames``."""
    per_corner: dict[int, np.ndarray] = {}
    for frame, gradient in zip(frames, gradients, strict=True):
        for corner, g in zip(frame.ids, gradient, strict=True):
            per_corner[int(corner)] = per_corner.get(int(corner), 0.0) + g
    return float(sigma_px * math.sqrt(sum(float(np.sum(g**2)) for g in per_corner.values())))


@dataclass(frozen=True)
class UncertaintyBudget:
    """Standard uncertainties (mm) of the measured square; None = unknown (not in ``combined``)."""

    measured_mm: float
    nominal_mm: float
    n_frames: int
    noise: float  # sqrt(noise_random^2 + noise_bias^2)
    calibration: float | None
    structure: float | None
    target: float
    k: float = K_COVERAGE
    structure_source: str = ""
    calibration_note: str = ""
    sensitivities: dict[str, float] = field(default_factory=dict)  # d(square)/d(parameter), parameter units
    noise_random_mm: float = float("nan")  # sqrt(sum sigma_i^2) / n: the campaign's sigma_mm
    noise_bias_mm: float = float("nan")  # expected lengthening by the noise (uncorrected)
    noise_systematic_mm: float = float("nan")  # the detector's systematic error, shared by the frames
    detector_bias_mm: float = float("nan")  # its predictable part: the fitted pixel locking on these corners
    corner_systematic_px: float = float("nan")  # systematic corner error the locking fit leaves (per coordinate)
    corner_random_px: float = float("nan")  # the frames' sensor-noise corner sigma (RMS, per coordinate)
    corner_reference_px: float = float("nan")  # the residuals' corner sigma it was compared with (corner_reference)
    corner_reference: str = ""  # which residuals: the calibration's, or the frames' planar fit
    field_bias_mm: float = float("nan")  # the smooth part of that error where the corners are (residual map)
    systematic_model: str = ""  # how that error was counted: "residual map" or "coherent shift and magnification"
    pixel_locking_px: tuple[float, float] | None = None  # (a_sin, a_cos) from the calibration's residuals
    # The model-adequacy component (mm): the calibration's held-out squares beyond their prediction (ModelAdequacy
    # u_rel x the measured square); None: not computed (no leave-one-view-out check with the calibration).
    adequacy: float | None = None
    adequacy_dof: float = float("inf")
    calibration_dof: float = float("inf")  # finite when the calibration's views' jackknife gave its variance
    effective_dof: float = float("inf")  # Welch-Satterthwaite over the components; k is Student's t for it

    @property
    def corner_sigma_px(self) -> float:
        """The corner error per coordinate (px) the noise component counts, random and systematic together."""
        return float(math.hypot(self.corner_random_px, self.corner_systematic_px))

    @property
    def components(self) -> dict[str, float | None]:
        return {name: getattr(self, name) for name in COMPONENTS}

    def _known(self) -> dict[str, float]:
        known = {name: value for name, value in self.components.items() if value is not None}
        if self.adequacy is not None:
            known["adequacy"] = self.adequacy
        return known

    @property
    def unknown(self) -> list[str]:
        return [name for name, value in self.components.items() if value is None]

    @property
    def combined(self) -> float:
        return float(math.sqrt(sum(v * v for v in self._known().values())))

    @property
    def expanded(self) -> float:
        return self.k * self.combined

    @property
    def error_mm(self) -> float:
        return self.measured_mm - self.nominal_mm

    @property
    def dominant(self) -> str:
        known = self._known()
        return max(known, key=known.get)

    def as_dict(self) -> dict:
        """The ``uncertainty_mm`` record: noise, calibration, structure, target, combined, expanded, k; and
        ``adequacy`` only when the calibration's held-out check computed it."""
        extra = {} if self.adequacy is None else {"adequacy": self.adequacy}
        return {**self.components, **extra, "combined": self.combined, "expanded": self.expanded, "k": self.k}

    def details(self) -> dict:
        """What the components rest on (JSON-ready)."""
        return {
            "n_frames": self.n_frames, "unknown": self.unknown, "dominant": self.dominant,
            "noise_random_mm": self.noise_random_mm, "noise_bias_mm": self.noise_bias_mm,
            "noise_systematic_mm": self.noise_systematic_mm, "detector_bias_mm": self.detector_bias_mm,
            "corner_systematic_px": self.corner_systematic_px, "corner_random_px": self.corner_random_px,
            "corner_sigma_px": self.corner_sigma_px, "corner_reference_px": self.corner_reference_px,
            "corner_reference": self.corner_reference or None, "field_bias_mm": self.field_bias_mm,
            "systematic_model": self.systematic_model or None,
            "pixel_locking_px": None if self.pixel_locking_px is None else list(self.pixel_locking_px),
            "complete": not self.unknown, "structure_source": self.structure_source or None,
            "calibration_note": self.calibration_note or None,
            "normalised_error": self.error_mm / self.combined if self.combined > 0 else None,
            # The measured square less the two predictable biases, for a caller that corrects them.
            "corrected_mm": self.measured_mm - self.noise_bias_mm - self.detector_bias_mm,
            "sensitivities": self.sensitivities,
            # Degrees of freedom, only where one is finite (a component evaluated from few views).
            **({} if math.isinf(self.effective_dof) else {
                "effective_dof": self.effective_dof, "calibration_dof": self.calibration_dof,
                "adequacy_dof": self.adequacy_dof}),
        }


def configuration_budget(
    frames: Sequence[PairMeasurement | FrameCorners], calib: StereoCalibration, target: Target, *,
    covariance: CalibrationCovariance | None | str = "calib", structure_covariance: np.ndarray | None = None,
    extrinsics_from_calibration: bool = True, structure_source: str = "", board_scale: BoardScale | None = None,
    k: float | None = None,
    corner_systematic: float | None = None, adequacy: ModelAdequacy | None | str = "calib",
) -> UncertaintyBudget:
    """The uncertainty budget of one configuration's measured square.

    Args:
        frames: the configuration's measurement frames (pipeline ``PairMeasurement``s or
            :class:`FrameCorners`), all measured with ``calib``.
        calib: the calibration the frames were triangulated with.
        target: the measured board (its adjacent pairs and nominal square).
        covariance: of the calibration's parameters; default ``calib.covariance`` (None: unknown).
        structure_covariance: (6, 6) covariance over (rvec x y z in rad, T x y z in mm) of the
            stereo extrinsics (X_right = R X_left + T, R = Rodrigues(rvec)) beyond the
            calibration: with ``extrinsics_from_calibration`` the rig's possible change since the
            calibration (repeatability; zeros: it has not moved), else the uncertainty of the
            source R, T came from (the kinematic rig model's covariance plus the rig's
            repeatability, or the rig's stated tolerances). None: the structure component is unknown.
        extrinsics_from_calibration: the R, T of ``calib`` are the calibration's (default). False:
            they come from the rig model or its nominal geometry; the calibration component then
            covers the intrinsics only.
        structure_source: a short description of that source, reported with the budget.
        board_scale: the boards' scale uncertainties (default :class:`BoardScale`()).
        k: coverage factor of the expanded uncertainty; None: Student's t (95.45 %) for the Welch-Satterthwaite
            effective degrees of freedom (2 when every component's are infinite).
        adequacy: the calibration's leave-one-view-out check (:class:`ModelAdequacy`); default
            ``calib.adequacy``; None: not known (no adequacy component). With it, the corner error beyond
            noise and locking that no residual map locates is counted independent from corner to corner
            (its coherent part, if any, shows in the held-out squares and so in the adequacy component)
            instead of bounded as a coherent shift and magnification.
        corner_systematic: the detector's systematic corner error per coordinate (px) beyond the
            pixel locking the calibration fitted, when known from elsewhere (a detector
            characterisation); None: :func:`corner_systematic_px` of the calibration's residuals.

    Returns: :class:`UncertaintyBudget` (``as_dict()`` for the ``uncertainty_mm`` record).
    """
    frames = _frames(frames)
    if not frames:
        raise ValueError("no measurement frames: nothing to budget")
    board_scale = board_scale or BoardScale()
    adequacy = getattr(calib, "adequacy", None) if isinstance(adequacy, str) else adequacy
    covariance = calib.covariance if isinstance(covariance, str) else covariance
    note = "" if covariance is not None else (calib.covariance_note or "the calibration has no covariance")
    names: list[str] = []
    if covariance is not None:
        names = [n for n in covariance.names if extrinsics_from_calibration or n.startswith(("left.", "right."))]
    if structure_covariance is not None:
        structure_covariance = np.asarray(structure_covariance, float)
        if structure_covariance.shape != (6, 6) or not np.all(np.isfinite(structure_covariance)):
            raise ValueError("structure_covariance must be a finite (6, 6) matrix over (rvec, T)")
    wanted = names + [n for n in EXTRINSIC_NAMES if structure_covariance is not None and n not in names]
    gradient = dict(zip(wanted, square_sensitivities(calib, frames, target, wanted), strict=True)) if wanted else {}

    u_calibration, calibration_dof = None, float("inf")
    if covariance is not None:
        g = np.array([gradient[n] for n in names])
        variance, calibration_dof, _ = covariance.variance_of(g, names)
        u_calibration = float(np.sqrt(variance))
    u_structure = None
    if structure_covariance is not None:
        g = np.array([gradient[n] for n in EXTRINSIC_NAMES])
        u_structure = float(np.sqrt(max(g @ structure_covariance @ g, 0.0)))
    sigmas = np.array([f.sigma_mean_mm for f in frames], float)
    random = float(np.sqrt(np.sum(sigmas**2)) / len(sigmas))
    memo: dict = {}  # each frame's points and Jacobian, shared by the noise bias and the pixel gradients
    random_px = float(np.sqrt(np.mean([np.mean(np.square(f.pixel_sigma_px)) for f in frames])))
    reference_px, _, _, reference_source = corner_reference(covariance, frames)
    if corner_systematic is None:
        corner_systematic = corner_systematic_px(covariance, random_px, frames)
        if adequacy is not None and math.isfinite(adequacy.corner_px) and corner_systematic > 0:
            # The corner error the held-out squares show (at most the fit's sigma), less the random part counted
            # apart: what of the residuals' excess acts on a square as corner-to-corner error.
            corner_systematic = min(corner_systematic, math.sqrt(max(adequacy.corner_px**2 - random_px**2, 0.0)))
    # Every corner error independent from corner to corner lengthens the lengths, the sensor noise's and the rest's.
    bias = float(np.mean([noise_bias_mm(calib, f, target, memo=memo, extra_px=corner_systematic) for f in frames]))
    locking = None if covariance is None else covariance.pixel_locking_px
    detector_bias = rest = 0.0
    field_bias, systematic_model = float("nan"), ""
    mapping = corner_systematic > 0 and covariance is not None and covariance.residual_map is not None
    # The phase sum and the residual map read the same pixel gradients: computed once for both.
    gradients = pixel_gradients(calib, frames, target, memo=memo) if locking is not None or mapping else None
    if locking is not None:
        detector_bias = float((complex(*locking) * phase_sum(calib, frames, target, gradients=gradients)).imag)
    if corner_systematic > 0:
        mapped = None
        if mapping:
            mapped = mapped_systematic_mm(calib, frames, target, covariance.residual_map, corner_systematic,
                                          gradients=gradients)
        if mapped is not None:
            field_bias, u_field = mapped
            rest = float(math.sqrt(field_bias**2 + u_field**2))
            systematic_model = "residual map"
        elif adequacy is not None and math.isfinite(adequacy.corner_px):
            if gradients is None:
                gradients = pixel_gradients(calib, frames, target, memo=memo)
            rest = independent_displacement_mm(frames, gradients, corner_systematic)
            systematic_model = "independent corners, from held-out views"
        else:
            rest = coherent_displacement_mm(calib, frames, target, corner_systematic)
            systematic_model = "coherent shift and magnification"
    systematic = float(math.sqrt(detector_bias**2 * (1.0 + LOCKING_TRANSFER_U_REL**2) + rest**2))
    measured = _square_function(frames, target)(calib)
    u_noise = float(math.sqrt(random**2 + bias**2 + systematic**2))
    u_adequacy = None if adequacy is None else float(adequacy.u_rel * abs(measured))
    u_target = board_scale.u_mm(target.square_mm)
    dof = effective_dof([(u_noise, math.inf), (u_calibration or 0.0, calibration_dof), (u_structure or 0.0, math.inf),
                         (u_target, math.inf), (u_adequacy or 0.0, math.inf if adequacy is None else adequacy.dof)])
    return UncertaintyBudget(
        measured_mm=measured, nominal_mm=float(target.square_mm), n_frames=len(frames),
        noise=u_noise, calibration=u_calibration,
        structure=u_structure, target=u_target, k=float(coverage_factor(dof) if k is None else k),
        adequacy=u_adequacy, adequacy_dof=math.inf if adequacy is None else adequacy.dof,
        calibration_dof=calibration_dof, effective_dof=dof,
        structure_source=structure_source, calibration_note=note, sensitivities=gradient, noise_random_mm=random,
        noise_bias_mm=bias, noise_systematic_mm=systematic, corner_systematic_px=float(corner_systematic),
        corner_random_px=random_px, corner_reference_px=reference_px, corner_reference=reference_source,
        detector_bias_mm=detector_bias, pixel_locking_px=locking, field_bias_mm=field_bias,
        systematic_model=systematic_model,
    )
