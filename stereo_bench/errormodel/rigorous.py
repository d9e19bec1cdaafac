"""Rigorous error model for any rig: first-order propagation through the real triangulation.

Conventions are the project's (BRIEF §3, :mod:`stereo_bench.geometry`): rig frame at the midpoint of
the optical centres, x along the baseline, y down, z toward the target; α between the baseline and
an optical axis (90° = parallel); millimetres and degrees at the interface.

What is computed, for a rig (B, α_left, α_right), two :class:`CameraModel`s and a checkerboard at a
pose ``T_rig_board`` (the very objects the simulated rig, ``drivers.sim.render.StereoRenderer``,
takes, so a prediction and a simulated measurement describe the same scene):

- **Visibility**: which inner corners project inside both images (``margin_px`` from the border,
  both cameras in front of the board's printed side). ``feasible`` = the whole board is in both
  views; ``measurable`` = at least :data:`MIN_COMMON_CORNERS` corners and one adjacent pair are,
  which is what the pipeline measures (partial views count).
- **Image-noise propagation**: every image coordinate (u, v of each camera) carries independent
  Gaussian noise σ_px. The triangulated point's Jacobian w.r.t. (uL, vL, uR, vR) comes from
  :func:`stereo_bench.vision.triangulate.triangulation_jacobian` with the rig's true calibration
  (R, T from :meth:`RigPose.stereo_extrinsics`, K and distortion from the cameras) evaluated at the
  true projected pixels: Σ_X = σ² J Jᵀ (left camera frame), rotated into the rig frame. The
  measured square (mean of all adjacent corner-pair lengths seen in both views) is propagated by
  :func:`stereo_bench.vision.measure.measure_square` itself. The board centre is a virtual corner.
- **Structural sensitivities**: the true pixels are triangulated with a calibration that is wrong
  by a small step in one structural parameter (baseline, α of both cameras or of one, focal
  length, principal point); central differences give how far the measured square and the
  measured depth of the board centre move per unit of that error.
- **Calibration component** (:func:`calibration_sigmas`): the calibration a configuration will
  get is predicted from its planned views (:class:`CalibrationPlan`: number, board, distance
  range, tilt; placed by :func:`planned_board_poses` with the spread of the simulated campaign's
  choreography, in a few ms instead of its ~80), projected without noise: the
  covariance of its parameters from their Jacobian with the assumed image noise
  (:func:`stereo_bench.vision.covariance.stereo_covariance`), pushed through the square's and the
  centre depth's sensitivity to each parameter at the target's true pixels. One calibration serves
  every frame: this error is not reduced by measuring more frames.

All functions are pure: inputs are left untouched and results are new arrays or pydantic models.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from stereo_bench.errormodel.rig import RigErrors, structure_covariance, target_sigma_mm
from stereo_bench.geometry import (
    VIEW_MARGIN_PX,
    CameraModel,
    RigPose,
    alpha_from_toe_in,
    board_faces_camera,
    board_pose_facing_rig,
    invert_transform,
    transform_points,
)
from stereo_bench.kinematics import ConfigurationViews, DesignConfiguration, KinematicModel, fit_kinematics
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.covariance import (
    EXTRINSIC_NAMES,
    CalibrationCovariance,
    CovarianceUnavailable,
)
from stereo_bench.vision.measure import measure_square
from stereo_bench.vision.pipeline import MIN_COMMON_CORNERS
from stereo_bench.vision.planned import planned_board_poses as planned_views
from stereo_bench.vision.planned import planned_stereo_calibration, project_into_both, true_calibration
from stereo_bench.vision.triangulate import triangulate, triangulation_jacobian
from stereo_bench.vision.uncertainty import (
    FrameCorners,
    noise_bias_mm,
    parameter_step,
    perturbed,
    square_sensitivities,
)

#: Corners closer than this to an image border count as not seen (as in ``geometry.visible_in_both``).
DEFAULT_MARGIN_PX = VIEW_MARGIN_PX
DEFAULT_BOARD = Checkerboard(9, 6, 27.0)
#: The campaign's default calibration board (campaign.config: 11x8 inner corners, 25 mm).
DEFAULT_CALIBRATION_BOARD = Checkerboard(11, 8, 25.0)


def default_camera(name: str = "camera") -> CameraModel:
    """The bench's camera, as the simulator's default: 1920x1080, 4 mm lens, 3 µm pixels (f ≈ 1333 px)."""
    return CameraModel.from_sensor(name=name)


@dataclass(frozen=True, eq=False)
class Setup:
    """Everything a prediction needs: the rig, the board and its pose, the two cameras.

    ``T_rig_board`` (4, 4) maps board coordinates (OpenCV object points, mm) to the rig frame.
    """

    rig: RigPose
    board: Checkerboard
    T_rig_board: np.ndarray
    left: CameraModel
    right: CameraModel

    @classmethod
    def make(
        cls, baseline_mm: float, distance_mm: float, alpha_deg: float = 90.0, *, alpha_right_deg: float | None = None,
        tilt_deg: float = 0.0, board: Checkerboard | None = None, left: CameraModel | None = None,
        right: CameraModel | None = None, T_rig_board: np.ndarray | None = None, board_yaw_deg: float = 0.0,
        board_pitch_deg: float = 0.0, board_offset_mm: tuple[float, float] = (0.0, 0.0),
    ) -> Setup:
        """A setup with the defaults of the bench: the 9x6, 27 mm board facing the rig, centred at Z.

        ``alpha_right_deg`` defaults to ``alpha_deg`` (symmetric rig); ``T_rig_board`` overrides the
        board pose given by distance, yaw, pitch and offset.
        """
        if not baseline_mm > 0:
            raise ValueError(f"baseline_mm must be positive, not {baseline_mm}")
        if not distance_mm > 0:
            raise ValueError(f"distance_mm must be positive, not {distance_mm}")
        alpha_right_deg = alpha_deg if alpha_right_deg is None else alpha_right_deg
        for name, value in (("alpha_deg", alpha_deg), ("alpha_right_deg", alpha_right_deg)):
            if not 0.0 < value < 180.0:
                raise ValueError(f"{name} must lie strictly between 0 and 180 deg, not {value}")
        board = board if board is not None else DEFAULT_BOARD
        if T_rig_board is None:
            T_rig_board = board_pose_facing_rig(
                distance_mm=distance_mm, board_size_mm=board.grid_size_mm, centre_offset_mm=board_offset_mm,
                yaw_deg=board_yaw_deg, pitch_deg=board_pitch_deg,
            )
        return cls(
            rig=RigPose(baseline_mm, alpha_deg, alpha_right_deg, tilt_deg, tilt_deg), board=board,
            T_rig_board=np.array(T_rig_board, dtype=float),
            left=left if left is not None else default_camera("left"),
            right=right if right is not None else default_camera("right"),
        )

    @property
    def board_centre_board(self) -> np.ndarray:
        """(3,) centre of the inner-corner grid in board coordinates (mm)."""
        width, height = self.board.grid_size_mm
        return np.array([width / 2.0, height / 2.0, 0.0])

    @property
    def board_centre_rig(self) -> np.ndarray:
        """(3,) centre of the inner-corner grid in the rig frame (mm)."""
        return transform_points(self.T_rig_board, self.board_centre_board)[0]

    @property
    def distance_mm(self) -> float:
        """Rig-z of the board centre (the Z of the configuration)."""
        return float(self.board_centre_rig[2])

    @property
    def corners_rig(self) -> np.ndarray:
        """(N, 3) every inner corner in the rig frame (mm), in id order."""
        return transform_points(self.T_rig_board, np.asarray(self.board.object_points, dtype=float))


def calibration_of(setup: Setup) -> StereoCalibration:
    """The rig's exact stereo calibration (X_right = R X_left + T, mm) as the pipeline would hold it."""
    return true_calibration(setup.rig, setup.left, setup.right)


def project_both(setup: Setup, points_rig: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True pixels of rig-frame points (N, 3): (left (N, 2), right (N, 2), in_front_of_both (N,) bool)."""
    return project_into_both(setup.rig, setup.left, setup.right, points_rig)


class Visibility(BaseModel):
    """How much of the board a configuration puts in both views (predicted from geometry alone)."""

    model_config = ConfigDict(frozen=True)

    n_corners: int
    n_in_both: int
    n_in_left: int
    n_in_right: int
    n_pairs: int
    fraction_in_both: float
    feasible: bool  # the whole board is in both views
    measurable: bool  # enough is in both views for the pipeline to measure the square
    reason: str  # why not feasible / not measurable; "" when feasible


def visible_corners(setup: Setup, *, margin_px: float = DEFAULT_MARGIN_PX) -> tuple[np.ndarray, Visibility]:
    """(ids (n,) of the corners seen in both views, :class:`Visibility`)."""
    board = setup.board
    left_px, right_px, in_front = project_both(setup, setup.corners_rig)
    faces = [board_faces_camera(invert_transform(T) @ setup.T_rig_board)
             for T in (setup.rig.T_rig_left, setup.rig.T_rig_right)]
    in_left = in_front & setup.left.in_image(left_px, margin_px=margin_px) & faces[0]
    in_right = in_front & setup.right.in_image(right_px, margin_px=margin_px) & faces[1]
    both = in_left & in_right
    ids = np.flatnonzero(both)
    seen = set(ids.tolist())
    n_pairs = int(sum(1 for a, b in board.adjacent_pairs() if a in seen and b in seen))
    n = board.n_corners
    reasons = []
    if not all(faces):
        reasons.append("the " + " and ".join(s for s, f in zip(("left", "right"), faces, strict=True) if not f)
                       + " camera sees the back of the board")
    for side, count in (("left", int(in_left.sum())), ("right", int(in_right.sum()))):
        if count < n and all(faces):
            reasons.append(f"{side} view holds {count}/{n} corners")
    if not reasons and len(ids) < n:
        reasons.append(f"only {len(ids)}/{n} corners are in both views")
    measurable = len(ids) >= MIN_COMMON_CORNERS and n_pairs > 0
    if not measurable:
        reasons.append(f"too little in both views to measure (need {MIN_COMMON_CORNERS} corners and one pair)")
    return ids, Visibility(
        n_corners=n, n_in_both=len(ids), n_in_left=int(in_left.sum()), n_in_right=int(in_right.sum()),
        n_pairs=n_pairs, fraction_in_both=len(ids) / n, feasible=len(ids) == n, measurable=measurable,
        reason="; ".join(reasons),
    )


def point_covariances_rig(setup: Setup, points_rig: np.ndarray, pixel_sigma_px: float) -> np.ndarray:
    """(N, 3, 3) first-order covariance (mm²) of triangulated rig-frame points (N, 3).

    Each image coordinate carries independent noise of ``pixel_sigma_px`` (px, one sigma) in both
    cameras. Points behind a camera get NaN.
    """
    calib = calibration_of(setup)
    left_px, right_px, in_front = project_both(setup, points_rig)
    jac = triangulation_jacobian(calib, left_px, right_px)  # (N, 3, 4), left camera frame
    R_rig_left = setup.rig.T_rig_left[:3, :3]
    jac_rig = np.einsum("ij,njk->nik", R_rig_left, jac)
    cov = pixel_sigma_px**2 * np.einsum("nik,njk->nij", jac_rig, jac_rig)
    cov[~in_front] = np.nan
    return cov


def square_noise_bias_mm(
    calib: StereoCalibration, board: Checkerboard, ids: np.ndarray, left_px: np.ndarray, right_px: np.ndarray,
    pixel_sigma_px: float,
) -> float:
    """Second-order bias (mm) of the measured square from zero-mean image noise.

    A length is the norm of a noisy difference d = X_a - X_b: E|d| ≈ |d| + (tr Σ_d - uᵀ Σ_d u) / (2|d|)
    with Σ_d = Σ_a + Σ_b (independent corners) and u = d / |d|. Depth noise, large at small K,
    lengthens every pair on average. The triangulation's own curvature (a relative bias of order
    σ_d² / d², disparity d) is left out: below 1e-6 of the length on this bench.
    ``left_px``/``right_px`` (n, 2): true pixels of the corners ``ids`` (n,). The measurement's
    uncertainty budget counts the same bias (:func:`stereo_bench.vision.uncertainty.noise_bias_mm`).
    """
    frame = FrameCorners(np.asarray(ids), left_px, right_px, 0.0, (pixel_sigma_px, pixel_sigma_px))
    return noise_bias_mm(calib, frame, board)


def parallel_depth_sigma_mm(distance_mm: float, baseline_mm: float, focal_px: float, pixel_sigma_px: float) -> float:
    """Textbook depth error of a parallel rig: Z² σ_d / (f B), with σ_d = √2 σ_px the disparity noise.

    (The disparity is u_left - u_right; independent noise σ_px in each gives σ_d = √2 σ_px.)
    """
    return distance_mm**2 * math.sqrt(2.0) * pixel_sigma_px / (focal_px * baseline_mm)


def _nan_to_none(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


class Prediction(BaseModel):
    """First-order prediction for one configuration. Lengths in mm, angles in deg, noise in px.

    ``sigma_square_mm``: σ of the measured square (mean of all adjacent pair lengths in both views);
    ``sigma_length_mm``: RMS over pairs of one pair length's σ; ``sigma_x/y/z_mm``: σ of the board
    centre, rig frame; ``gamma_xz_mm`` = √(σx² + σz²) is the paper's γ for that point, ``gamma_mm``
    adds σy. Values that cannot be computed (nothing in view, point behind a camera) are None.
    """

    model_config = ConfigDict(frozen=True)

    baseline_mm: float
    distance_mm: float
    alpha_left_deg: float
    alpha_right_deg: float
    K: float
    pixel_sigma_px: float
    margin_px: float
    feasible: bool
    measurable: bool
    reason: str
    n_in_both: int
    n_pairs: int
    fraction_in_both: float
    square_true_mean_mm: float | None  # noise-free measurement with the true calibration (== square size)
    sigma_square_mm: float | None
    bias_square_mm: float | None  # second-order noise bias of the measured square (see square_noise_bias_mm)
    sigma_length_mm: float | None
    centre_in_both: bool
    sigma_x_mm: float | None
    sigma_y_mm: float | None
    sigma_z_mm: float | None
    gamma_xz_mm: float | None
    gamma_mm: float | None
    # The calibration's own error (see calibration_sigmas); None when not asked for or not placeable.
    calibration_views: int = 0
    sigma_calibration_mm: float | None = None  # of the measured square
    sigma_calibration_depth_mm: float | None = None  # of the board centre's rig z
    calibration_note: str = ""
    # What the rig and boards add (stereo_bench.errormodel.rig; None: not asked for, or not computable).
    extrinsics_mode: str | None = None  # where R, T come from: per-config, nominal, kinematic
    sigma_structure_mm: float | None = None  # of the measured square, from the source R, T's covariance
    sigma_structure_depth_mm: float | None = None
    sigma_target_mm: float | None = None  # the boards' scales: the square against its nominal size
    sigma_target_depth_mm: float | None = None
    rig_note: str = ""


def predict(setup: Setup, pixel_sigma_px: float, *, margin_px: float = DEFAULT_MARGIN_PX,
            calibration: CalibrationPlan | None = None, rig: RigErrors | None = None) -> Prediction:
    """First-order σ of the measured square and of the board centre for image noise ``pixel_sigma_px``.

    ``calibration``: also predict the calibration's own error from these planned views (same noise); with
    ``rig`` in a mode whose R, T do not come from that calibration, the intrinsics' part only.
    ``rig``: also the structure and target terms (:mod:`stereo_bench.errormodel.rig`).
    """
    if not pixel_sigma_px >= 0:
        raise ValueError(f"pixel_sigma_px must be >= 0, not {pixel_sigma_px}")
    ids, vis = visible_corners(setup, margin_px=margin_px)
    calib = calibration_of(setup)
    sq_mean = sq_sigma = len_sigma = bias = float("nan")
    if vis.measurable:
        left_px, right_px, _ = project_both(setup, setup.corners_rig[ids])
        square = measure_square(calib, setup.board, ids, left_px, right_px, pixel_sigma_px=pixel_sigma_px)
        sq_mean, sq_sigma = square.mean_mm, square.sigma_mean_mm
        len_sigma = float(np.sqrt(np.mean(square.sigma_length_mm**2)))
        bias = square_noise_bias_mm(calib, setup.board, ids, left_px, right_px, pixel_sigma_px)
    centre = setup.board_centre_rig
    cl, cr, centre_front = project_both(setup, centre)
    centre_in_both = bool(centre_front[0] and setup.left.in_image(cl, margin_px=margin_px)[0]
                          and setup.right.in_image(cr, margin_px=margin_px)[0])
    sx = sy = sz = float("nan")
    if centre_front[0]:
        cov = point_covariances_rig(setup, centre, pixel_sigma_px)[0]
        sx, sy, sz = (float(v) for v in np.sqrt(np.diag(cov)))
    pose = setup.rig
    calibration_fields = {}
    kinematic = None
    if calibration is not None and rig is not None and rig.mode == "kinematic":
        kinematic = kinematic_sigmas(setup, rig, calibration, pixel_sigma_px, margin_px=margin_px)
    if kinematic is not None:
        square_cal, depth_cal, _, _, note = kinematic
        calibration_fields = {"calibration_views": calibration.n_views, "sigma_calibration_mm": square_cal,
                              "sigma_calibration_depth_mm": depth_cal, "calibration_note": note}
    elif calibration is not None:
        square_cal, depth_cal, note = calibration_sigmas(
            setup, calibration, pixel_sigma_px, margin_px=margin_px,
            intrinsics_only=rig is not None and not rig.extrinsics_from_calibration)
        if rig is not None and rig.intrinsics_visits > 1:
            square_cal, depth_cal = (None if v is None else v * rig.intrinsics_scale for v in (square_cal, depth_cal))
            note += (f", as if seen at each of {rig.intrinsics_visits} design visits (intrinsics and R, T apart: "
                     "an over-prediction; a campaign's design gives the joint one)")
        calibration_fields = {"calibration_views": calibration.n_views, "sigma_calibration_mm": square_cal,
                              "sigma_calibration_depth_mm": depth_cal, "calibration_note": note}
    rig_fields = {} if rig is None else _rig_fields(setup, rig, margin_px)
    if kinematic is not None:
        rig_fields["sigma_structure_mm"], rig_fields["sigma_structure_depth_mm"] = kinematic[2:4]
    return Prediction(
        **calibration_fields, **rig_fields,
        baseline_mm=pose.baseline_mm, distance_mm=setup.distance_mm, alpha_left_deg=pose.alpha_left_deg,
        alpha_right_deg=pose.alpha_right_deg, K=pose.baseline_mm / setup.distance_mm, pixel_sigma_px=pixel_sigma_px,
        margin_px=margin_px, feasible=vis.feasible, measurable=vis.measurable, reason=vis.reason,
        n_in_both=vis.n_in_both, n_pairs=vis.n_pairs, fraction_in_both=vis.fraction_in_both,
        square_true_mean_mm=_nan_to_none(sq_mean), sigma_square_mm=_nan_to_none(sq_sigma),
        bias_square_mm=_nan_to_none(bias),
        sigma_length_mm=_nan_to_none(len_sigma), centre_in_both=centre_in_both,
        sigma_x_mm=_nan_to_none(sx), sigma_y_mm=_nan_to_none(sy), sigma_z_mm=_nan_to_none(sz),
        gamma_xz_mm=_nan_to_none(math.hypot(sx, sz)), gamma_mm=_nan_to_none(math.sqrt(sx * sx + sy * sy + sz * sz)),
    )


def _rig_fields(setup: Setup, rig: RigErrors, margin_px: float) -> dict:
    r = setup.rig
    covariance = structure_covariance(rig, r.baseline_mm, r.alpha_left_deg, r.alpha_right_deg, r.tilt_left_deg)
    square, depth = (0.0, 0.0) if covariance is None else structure_sigmas(setup, covariance, margin_px=margin_px)
    target, target_depth = target_sigma_mm(rig, setup.board.square_mm, setup.distance_mm)
    return {"extrinsics_mode": rig.mode, "sigma_structure_mm": square, "sigma_structure_depth_mm": depth,
            "sigma_target_mm": target, "sigma_target_depth_mm": target_depth, "rig_note": rig.describe()}


# ----------------------------------------------------------------------------------------------
# Structural sensitivities

StructuralParameter = Literal[
    "baseline_mm", "alpha_both_deg", "alpha_left_deg", "alpha_right_deg",
    "focal_both_px", "focal_right_px", "cx_both_px", "cx_right_px", "cy_right_px",
]

#: name -> (unit, central-difference step in that unit)
STRUCTURAL_PARAMETERS: dict[str, tuple[str, float]] = {
    "baseline_mm": ("mm", 0.01),
    "alpha_both_deg": ("deg", 1e-3),
    "alpha_left_deg": ("deg", 1e-3),
    "alpha_right_deg": ("deg", 1e-3),
    "focal_both_px": ("px", 0.05),
    "focal_right_px": ("px", 0.05),
    "cx_both_px": ("px", 0.01),
    "cx_right_px": ("px", 0.01),
    "cy_right_px": ("px", 0.01),
}


def _shift_camera(camera: CameraModel, *, focal: float = 0.0, cx: float = 0.0, cy: float = 0.0) -> CameraModel:
    K = np.array(camera.K, dtype=float)
    K[0, 0] += focal
    K[1, 1] += focal
    K[0, 2] += cx
    K[1, 2] += cy
    return replace(camera, K=K)


def believed_setup(setup: Setup, parameter: str, delta: float) -> Setup:
    """The setup a calibration wrong by ``delta`` (in the parameter's unit) in one structural parameter describes.

    alpha: a positive δ turns a camera outward (α grows; 90° is parallel). ``*_both_*`` changes both
    cameras by δ. Focal length changes fx and fy together.
    """
    rig = setup.rig
    left, right = setup.left, setup.right
    if parameter == "baseline_mm":
        rig = replace(rig, baseline_mm=rig.baseline_mm + delta)
    elif parameter == "alpha_both_deg":
        rig = replace(rig, alpha_left_deg=rig.alpha_left_deg + delta, alpha_right_deg=rig.alpha_right_deg + delta)
    elif parameter == "alpha_left_deg":
        rig = replace(rig, alpha_left_deg=rig.alpha_left_deg + delta)
    elif parameter == "alpha_right_deg":
        rig = replace(rig, alpha_right_deg=rig.alpha_right_deg + delta)
    elif parameter == "focal_both_px":
        left, right = _shift_camera(left, focal=delta), _shift_camera(right, focal=delta)
    elif parameter == "focal_right_px":
        right = _shift_camera(right, focal=delta)
    elif parameter == "cx_both_px":
        left, right = _shift_camera(left, cx=delta), _shift_camera(right, cx=delta)
    elif parameter == "cx_right_px":
        right = _shift_camera(right, cx=delta)
    elif parameter == "cy_right_px":
        right = _shift_camera(right, cy=delta)
    else:
        raise ValueError(f"unknown structural parameter {parameter!r}; known: {', '.join(STRUCTURAL_PARAMETERS)}")
    return replace(setup, rig=rig, left=left, right=right)


def square_means(points: np.ndarray, ids: np.ndarray, board: Checkerboard) -> np.ndarray:
    """Measured square(s): mean length (mm) of the board's adjacent pairs among ``ids``.

    ``points`` (..., n, 3) triangulated corners in the order of ``ids`` (n,); returns shape (...).
    The same statistic as ``measure_square(...).mean_mm``, vectorised over leading sample axes.
    """
    position = {corner_id: i for i, corner_id in enumerate(np.asarray(ids).tolist())}
    pairs = np.array([(position[a], position[b]) for a, b in board.adjacent_pairs()
                      if a in position and b in position], int).reshape(-1, 2)
    if not len(pairs):
        return np.full(points.shape[:-2], np.nan)
    return np.linalg.norm(points[..., pairs[:, 0], :] - points[..., pairs[:, 1], :], axis=-1).mean(axis=-1)


def measured_with(
    setup: Setup, believed: Setup, ids: np.ndarray, corner_left_px: np.ndarray, corner_right_px: np.ndarray,
    centre_left_px: np.ndarray, centre_right_px: np.ndarray,
) -> tuple[float, np.ndarray]:
    """(square mean mm, board centre (3,) in the believed rig frame mm) from pixels triangulated with ``believed``."""
    calib = calibration_of(believed)
    square = float("nan")
    if len(ids):
        square = float(square_means(triangulate(calib, corner_left_px, corner_right_px), ids, setup.board))
    centre_left = triangulate(calib, centre_left_px, centre_right_px)
    return square, transform_points(believed.rig.T_rig_left, centre_left)[0]


class Sensitivity(BaseModel):
    """Change of the measurement per unit error of one structural parameter (first order)."""

    model_config = ConfigDict(frozen=True)

    parameter: str
    unit: str
    square_mm_per_unit: float | None  # measured square (mean) per unit error
    depth_mm_per_unit: float | None  # measured rig-z of the board centre per unit error
    lateral_mm_per_unit: float | None  # measured rig-x of the board centre per unit error


def sensitivities(
    setup: Setup, parameters: tuple[str, ...] | None = None, *, margin_px: float = DEFAULT_MARGIN_PX
) -> dict[str, Sensitivity]:
    """d(measured square)/dp, d(centre depth)/dp, d(centre x)/dp for each structural parameter p.

    Computed by triangulating the TRUE pixels (corners in both views, and the board centre) with a
    calibration perturbed by ±step in p (central differences, steps in :data:`STRUCTURAL_PARAMETERS`):
    what a calibration wrong in p does to a measurement. Square terms are None when nothing is
    measurable; centre terms None when the centre is behind a camera.
    """
    parameters = tuple(STRUCTURAL_PARAMETERS) if parameters is None else tuple(parameters)
    ids, vis = visible_corners(setup, margin_px=margin_px)
    corner_l, corner_r, _ = project_both(setup, setup.corners_rig[ids])
    centre_l, centre_r, centre_front = project_both(setup, setup.board_centre_rig)
    result = {}
    for parameter in parameters:
        if parameter not in STRUCTURAL_PARAMETERS:
            raise ValueError(f"unknown structural parameter {parameter!r}; known: {', '.join(STRUCTURAL_PARAMETERS)}")
        unit, step = STRUCTURAL_PARAMETERS[parameter]
        plus = measured_with(setup, believed_setup(setup, parameter, step), ids, corner_l, corner_r, centre_l, centre_r)
        minus = measured_with(setup, believed_setup(setup, parameter, -step), ids, corner_l, corner_r, centre_l,
                              centre_r)
        d_square = (plus[0] - minus[0]) / (2 * step) if vis.measurable else float("nan")
        d_centre = (plus[1] - minus[1]) / (2 * step) if centre_front[0] else np.full(3, np.nan)
        result[parameter] = Sensitivity(
            parameter=parameter, unit=unit, square_mm_per_unit=_nan_to_none(d_square),
            depth_mm_per_unit=_nan_to_none(float(d_centre[2])), lateral_mm_per_unit=_nan_to_none(float(d_centre[0])),
        )
    return result


# ----------------------------------------------------------------------------------------------
# The calibration's own error, predicted from the planned calibration views


@dataclass(frozen=True)
class CalibrationPlan:
    """The calibration views a configuration will be calibrated from, as the campaign plans them.

    ``distance_mm``: (near, far) of the board along the rig's viewing direction; None: the simulated
    campaign's rule for a target at Z, (max(250, 0.6 Z), 1.3 Z). ``mode``: "joint" refines the
    intrinsics with R, T; "fixed" takes them from mono calibrations of the same views.
    ``max_tilt_deg``: largest tilt of the board out of facing the rig.
    """

    n_views: int = 12
    board: Checkerboard = DEFAULT_CALIBRATION_BOARD
    distance_mm: tuple[float, float] | None = None
    mode: Literal["joint", "fixed"] = "joint"
    max_tilt_deg: float = 40.0

    def __post_init__(self):
        if self.n_views < 5:
            raise ValueError(f"a stereo calibration needs at least 5 views, not {self.n_views}")
        if self.mode not in ("joint", "fixed"):
            raise ValueError(f"mode must be 'joint' or 'fixed', not {self.mode!r}")
        if self.distance_mm is not None and not 0 < self.distance_mm[0] <= self.distance_mm[1]:
            raise ValueError(f"distance_mm must be (near, far) with 0 < near <= far, not {self.distance_mm}")

    def distance_range(self, target_distance_mm: float) -> tuple[float, float]:
        if self.distance_mm is not None:
            return tuple(float(v) for v in self.distance_mm)
        return max(250.0, 0.6 * target_distance_mm), 1.3 * target_distance_mm


def planned_board_poses(setup: Setup, plan: CalibrationPlan) -> list[np.ndarray]:
    """T_rig_board (4x4, mm) of ``plan.n_views`` calibration views, deterministic, whole board in both images
    (:func:`stereo_bench.vision.planned.planned_board_poses` over ``plan``'s distance range for this setup's Z).

    Raises:
        ValueError: a view cannot be placed (the views overlap too little for this board).
    """
    return planned_views(setup.rig, plan.board, setup.left, setup.right, n_views=plan.n_views,
                         distance_mm=plan.distance_range(setup.distance_mm), max_tilt_deg=plan.max_tilt_deg)


def planned_calibration(setup: Setup, plan: CalibrationPlan, pixel_sigma_px: float) -> StereoCalibration:
    """The rig's true calibration with the covariance its planned views would give (image noise ``pixel_sigma_px``;
    :func:`stereo_bench.vision.planned.planned_stereo_calibration`).

    Raises:
        ValueError: the planned views cannot be placed in both cameras (with the reason).
        CovarianceUnavailable: the views leave the parameters undetermined.
    """
    return planned_stereo_calibration(setup.rig, plan.board, setup.left, setup.right, planned_board_poses(setup, plan),
                                      pixel_sigma_px=pixel_sigma_px, mode=plan.mode)


def _depth_sensitivities(calib: StereoCalibration, setup: Setup, names: tuple[str, ...]) -> np.ndarray | None:
    """(P,) d(rig z of the board centre)/d(parameter), from its true pixels; None when behind a camera."""
    left_px, right_px, in_front = project_both(setup, setup.board_centre_rig)
    if not in_front[0]:
        return None
    R_rig_left, t_rig_left = setup.rig.T_rig_left[:3, :3], setup.rig.T_rig_left[:3, 3]

    def depth(c: StereoCalibration) -> float:
        return float((R_rig_left @ triangulate(c, left_px, right_px)[0] + t_rig_left)[2])
    out = np.empty(len(names))
    for i, name in enumerate(names):
        step = parameter_step(name)
        out[i] = (depth(perturbed(calib, name, step)) - depth(perturbed(calib, name, -step))) / (2 * step)
    return out


def calibration_sigmas(
    setup: Setup, plan: CalibrationPlan, pixel_sigma_px: float, *, margin_px: float = DEFAULT_MARGIN_PX,
    intrinsics_only: bool = False,
) -> tuple[float | None, float | None, str]:
    """(sigma of the measured square, sigma of the board centre's rig z, note): mm, from the calibration alone.

    None with the reason in the note when the planned views cannot be placed or determine nothing,
    or nothing of the target is measurable. The square's sensitivities are those of the measurement
    (:func:`stereo_bench.vision.uncertainty.square_sensitivities`) at the target's true pixels.
    ``intrinsics_only``: R, T come from elsewhere (the rig's geometry or its model): only the intrinsics' part.
    """
    if not pixel_sigma_px > 0:
        return 0.0, 0.0, "no image noise: a perfect calibration"
    try:
        calib = planned_calibration(setup, plan, pixel_sigma_px)
    except (ValueError, CovarianceUnavailable) as error:
        return None, None, f"calibration not predictable: {error}"
    covariance: CalibrationCovariance = calib.covariance
    if intrinsics_only:
        covariance = covariance.subset([n for n in covariance.names if n.startswith(("left.", "right."))])
    square, depth = _through_the_measurement(setup, calib, covariance.names, covariance.matrix, pixel_sigma_px,
                                             margin_px)
    what = "the intrinsics of " if intrinsics_only else ""
    return square, depth, (f"{what}{plan.n_views} planned views of the {plan.board.cols}x{plan.board.rows} board "
                           f"({plan.mode})")


@dataclass(frozen=True)
class _Corners:
    """The detection interface the fit reads: corner ids and their pixels."""

    ids: np.ndarray
    corners_px: np.ndarray


def planned_kinematic_model(design: Sequence[DesignConfiguration], distance_mm: float, plan, pixel_sigma_px: float,
                            *, repeatability_mm: float, repeatability_deg: float, left: CameraModel,
                            right: CameraModel) -> KinematicModel:
    """The kinematic fit a campaign will make, predicted: its design's planned views fitted at a stated image noise.

    In kinematic mode the intrinsics and R, T come from one joint adjustment over every design visit's views
    (:func:`stereo_bench.kinematics.fit_kinematics`), and their errors are correlated: a focal length error is
    met by the right camera's position, so through a measurement they partly cancel, as a per-configuration
    calibration's intrinsics and R, T do. The design's views are :func:`planned_board_poses` at each visit (exact
    pixels), fitted at the stated noise (the weight against the landing priors is that noise's); the prediction
    then uses the joint covariance the campaign's budget carries (docs/ERROR_MODEL.md section 5).

    ``distance_mm``: where the design's target would stand (the board's views range about it, as the campaign's
    choreography shows them); ``plan``: a :class:`CalibrationPlan` (views per
    visit, board); ``pixel_sigma_px``: image noise per coordinate (> 0). Every visit is reached from below on
    every axis (a campaign knows its approach). Memoised: an advisor's grid evaluates one model many times.

    Raises:
        ValueError: a visit's views cannot be placed in both cameras, or the fit fails.
    """
    if not pixel_sigma_px > 0:
        raise ValueError(f"pixel_sigma_px must be > 0, not {pixel_sigma_px}")
    design_key = tuple((float(d.baseline_mm), float(d.toe_in_left_deg), float(d.toe_in_right_deg)) for d in design)
    key = (design_key, float(distance_mm), plan, float(pixel_sigma_px), float(repeatability_mm),
           float(repeatability_deg), left, right)  # cameras hash by K, dist and size
    if key not in _MODELS:
        if len(_MODELS) >= 16:
            _MODELS.pop(next(iter(_MODELS)))
        _MODELS[key] = _planned(design_key, float(distance_mm), plan, float(pixel_sigma_px), float(repeatability_mm),
                                float(repeatability_deg), left, right)
    return _MODELS[key]


_MODELS: dict[tuple, KinematicModel] = {}


def _planned(design: tuple, distance_mm: float, plan, pixel_sigma_px: float, repeatability_mm: float,
             repeatability_deg: float, left: CameraModel, right: CameraModel) -> KinematicModel:
    points = np.asarray(plan.board.object_points, float)
    configurations = []
    for baseline_mm, toe_in_left_deg, toe_in_right_deg in design:
        setup = Setup.make(baseline_mm, distance_mm, alpha_from_toe_in(toe_in_left_deg),
                           alpha_right_deg=alpha_from_toe_in(toe_in_right_deg), left=left, right=right)
        views = []
        for T_rig_board in planned_board_poses(setup, plan):
            left_px, right_px, in_front = project_both(setup, transform_points(T_rig_board, points))
            ids = np.flatnonzero(in_front & setup.left.in_image(left_px) & setup.right.in_image(right_px))
            views.append((_Corners(ids, left_px[ids]), _Corners(ids, right_px[ids])))
        axes = {"baseline_mm": baseline_mm, "toe_in_left_deg": toe_in_left_deg, "toe_in_right_deg": toe_in_right_deg}
        configurations.append(ConfigurationViews(axes=axes, approach=dict.fromkeys(axes, 1), views=views))
    intrinsics = (np.asarray(left.K, float), np.asarray(left.dist, float).reshape(1, -1),
                  np.asarray(right.K, float), np.asarray(right.dist, float).reshape(1, -1))
    fit = fit_kinematics(configurations, points, tuple(int(v) for v in left.image_size), intrinsics=intrinsics,
                         refine_intrinsics=True, repeatability_mm=repeatability_mm,
                         repeatability_left_deg=repeatability_deg, repeatability_right_deg=repeatability_deg,
                         pixel_sigma_px=pixel_sigma_px)
    return fit.model


def kinematic_sigmas(setup: Setup, rig: RigErrors, plan: CalibrationPlan, pixel_sigma_px: float, *,
                     margin_px: float = DEFAULT_MARGIN_PX) -> tuple[float | None, float | None, float | None,
                                                                   float | None, str] | None:
    """(calibration σ of the square, of the centre's rig z, structure σ of the square, of the depth, note) in
    kinematic mode, as the campaign's budget splits them (:func:`stereo_bench.campaign.sources.kinematic_source`):
    the calibration term the joint covariance of the model's intrinsics and the R, T it predicts here, the
    structure term the rig's landing repeatability. The model is ``rig.kinematic_model`` (a model file) or the
    fit of ``rig.design``'s planned views at ``pixel_sigma_px`` (:func:`planned_kinematic_model`).

    None when neither is given, the model holds no joint covariance, or the design's views cannot be placed
    (the caller falls back on one configuration's intrinsics).
    """
    from stereo_bench.kinematics import joint_covariance
    from stereo_bench.kinematics import predict as predict_kinematic

    model, what = rig.kinematic_model, "the kinematic model file's fit"
    if model is None:
        if rig.design is None or not pixel_sigma_px > 0:
            return None
        try:
            model = planned_kinematic_model(rig.design, rig.design_distance_mm, plan, pixel_sigma_px,
                                            repeatability_mm=rig.repeatability_mm,
                                            repeatability_deg=rig.repeatability_deg, left=setup.left,
                                            right=setup.right)
        except (ValueError, np.linalg.LinAlgError):
            return None
        what = (f"the planned kinematic fit: {plan.n_views} views at each of the design's {len(rig.design)} "
                f"visits (intrinsics and R, T jointly)")
    r = setup.rig
    axes = {"baseline_mm": r.baseline_mm, "toe_in_left_deg": 90.0 - r.alpha_left_deg,
            "toe_in_right_deg": 90.0 - r.alpha_right_deg}
    prediction = predict_kinematic(model, axes, dict.fromkeys(axes, 1))
    joint = joint_covariance(model, prediction)
    if joint is None:
        return None
    names = tuple(model.intrinsics_covariance_names) + tuple(EXTRINSIC_NAMES)
    square, depth = _through_the_measurement(setup, calibration_of(setup), names, joint[0], pixel_sigma_px, margin_px)
    structure = structure_sigmas(setup, prediction.rig_covariance, margin_px=margin_px)
    return square, depth, structure[0], structure[1], what


def structure_sigmas(setup: Setup, structure_covariance: np.ndarray, *, margin_px: float = DEFAULT_MARGIN_PX,
                     ) -> tuple[float | None, float | None]:
    """(sigma of the measured square, sigma of the board centre's rig z), mm, from a (6, 6) covariance of the
    stereo extrinsics (rvec [rad], T [mm]); the same sensitivities as the budget's structure component
    (:func:`stereo_bench.vision.uncertainty.configuration_budget`), at the target's true pixels. None where
    nothing is measurable (square) or the centre is behind a camera (depth)."""
    return _through_the_measurement(setup, calibration_of(setup), EXTRINSIC_NAMES,
                                    np.asarray(structure_covariance, float), 0.0, margin_px)


def _through_the_measurement(setup: Setup, calib: StereoCalibration, names: Sequence[str], covariance: np.ndarray,
                             pixel_sigma_px: float, margin_px: float) -> tuple[float | None, float | None]:
    """(σ of the measured square, σ of the board centre's rig z), mm, of the calibration parameters ``names`` with
    ``covariance``, through the measurement at the target's true pixels (the budget's sensitivities, noise
    ``pixel_sigma_px`` on the frame). None where nothing is measurable (square) or the centre is behind a
    camera (depth)."""
    square = None
    ids, vis = visible_corners(setup, margin_px=margin_px)
    if vis.measurable:
        left_px, right_px, _ = project_both(setup, setup.corners_rig[ids])
        frame = FrameCorners(ids, left_px, right_px, 0.0, (pixel_sigma_px, pixel_sigma_px))
        g = square_sensitivities(calib, [frame], setup.board, names)
        square = float(np.sqrt(max(g @ covariance @ g, 0.0)))
    g_depth = _depth_sensitivities(calib, setup, names)
    depth = None if g_depth is None else float(np.sqrt(max(g_depth @ covariance @ g_depth, 0.0)))
    return square, depth
