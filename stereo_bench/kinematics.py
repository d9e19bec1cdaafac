"""The kinematic rig model: R and T of the stereo pair at any configuration, from the rig's axis positions.

A stereo pair on a slide and two pan heads is a kinematic chain. Its relative pose at baseline B and
toe-ins t_L, t_R is, with S the left camera's frame at toe-in 0 (its carriage fixed)::

    T_S_L = Rot(left pan axis, + k_L * t_L')
    T_S_R = Trans(k_s * (B' - B_ref) * d) @ T_S_R0 @ Rot(right pan axis, - k_R * t_R')
    T_R_L = inv(T_S_R) @ T_S_L          ->  R, T with X_right = R @ X_left + T

``Rot(axis, angle)`` turns about a line (direction and a point) fixed to the camera's head; the pan
axes are given in their own camera's frame at toe-in 0 (direction: the camera's y axis turned by
``*_axis_tilt_x_deg`` about x, then ``*_axis_tilt_z_deg`` about z; position: where the axis crosses
the camera's y = 0 plane, ``*_axis_x_mm``, ``*_axis_z_mm``, so about -20 mm for a camera whose optical
centre stands 20 mm in front of its pan axis). ``d`` is the slide direction in S (x axis turned by
``slide_yaw_deg`` about y, ``slide_pitch_deg`` about z), ``k_s`` its scale (separation change per mm
of commanded baseline), ``T_S_R0`` the right camera at B_ref and toe-in 0 (rotation vector in deg,
translation in mm). Commanded values are corrected for backlash by the direction of approach a
(+1: the quantity last increased): B' = B - a * b_s / 2, t' = t - a * b / 2.

Identifiable from stereo views (and what is not):

- The angle zeros are NOT identifiable: a zero error of the left head turns the whole frame S
  (it is absorbed by the gauge), a zero error of the right head and the slide's zero offset are
  absorbed by T_S_R0. The meaningful "zeros" are predictions: the true alphas at commanded toe-in 0.
- The pan axis of a camera, its angle scale and backlash need at least two toe-ins of that camera
  in the design; the slide direction, scale and backlash at least two baselines; a backlash also
  needs approaches from both sides. What the design cannot identify is held at its nominal value
  (pan about the optical centre, vertical axis, scale 1, no backlash), marked ``identifiable =
  false`` with the reason, and predictions outside the design's span are flagged as extrapolated.
- The position of a pan axis along itself is meaningless (2 of its 3 coordinates are parameters).

The fit (:func:`fit_kinematics`) is one joint bundle adjustment of every calibration view of a small
design of configurations (:func:`kinematic_design`), as mrcal and Kalibr calibrate multi-camera rigs:
unknowns are the kinematic parameters, one board pose per view, optionally the intrinsics, and per
configuration the random landing error of each axis (a prior of the rig's repeatability), so the
parameters' covariance, from the Jacobian, accounts for moves that do not land twice alike.
:func:`predict` gives R, T at any axis positions with the covariance of (rvec, T) (rad, mm)
propagated from the parameters' covariance, the repeatability and (approach unknown) the backlash.
:func:`nominal_extrinsics` is the ideal geometry a user who trusts the rig's scales gets.

Pure functions on numpy arrays; OpenCV for PnP and the initial intrinsics, scipy for least squares.
Units: mm and deg at the interface and in the file, radians inside.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from drivers.files import MAX_TOML_BYTES, InputFileError, decode_utf8, parse_toml, read_regular_file
from stereo_bench import atomic
from stereo_bench.geometry import RigPose, alpha_from_toe_in, rotation_deg, stereo_structure

AXES = ("baseline_mm", "toe_in_left_deg", "toe_in_right_deg")
FILE_SCHEMA = "stereo-bench kinematic rig model 1"


@dataclass(frozen=True)
class ParameterSpec:
    name: str
    unit: str
    nominal: float
    group: str
    description: str


def _spec(name: str, unit: str, nominal: float, group: str, description: str) -> ParameterSpec:
    return ParameterSpec(name, unit, nominal, group, description)


PARAMETERS: tuple[ParameterSpec, ...] = (
    _spec("left_axis_tilt_x_deg", "deg", 0.0, "left_axis", "left pan axis: the left camera's y axis turned about x"),
    _spec("left_axis_tilt_z_deg", "deg", 0.0, "left_axis", "left pan axis: then turned about z"),
    _spec("left_axis_x_mm", "mm", 0.0, "left_axis", "left pan axis crosses the left camera's y = 0 plane at this x"),
    _spec("left_axis_z_mm", "mm", 0.0, "left_axis", "... and this z (negative: behind the optical centre)"),
    _spec("left_angle_scale", "1", 1.0, "left_axis", "left pan angle per degree of commanded toe-in"),
    _spec("right_axis_tilt_x_deg", "deg", 0.0, "right_axis", "right pan axis: the right camera's y axis turned "
                                                              "about x"),
    _spec("right_axis_tilt_z_deg", "deg", 0.0, "right_axis", "right pan axis: then turned about z"),
    _spec("right_axis_x_mm", "mm", 0.0, "right_axis", "right pan axis crosses the right camera's y = 0 plane at "
                                                      "this x"),
    _spec("right_axis_z_mm", "mm", 0.0, "right_axis", "... and this z (negative: behind the optical centre)"),
    _spec("right_angle_scale", "1", 1.0, "right_axis", "right pan angle per degree of commanded toe-in"),
    _spec("slide_yaw_deg", "deg", 0.0, "slide", "slide direction: the left camera's x axis (at toe-in 0) turned "
                                                "about y"),
    _spec("slide_pitch_deg", "deg", 0.0, "slide", "slide direction: then turned about z"),
    _spec("slide_scale", "1", 1.0, "slide", "pan-axis separation change per mm of commanded baseline"),
    _spec("right_rot_x_deg", "deg", 0.0, "right_pose", "right camera at B_ref and toe-in 0 in the left camera's "
                                                       "frame at toe-in 0: rotation vector x"),
    _spec("right_rot_y_deg", "deg", 0.0, "right_pose", "... rotation vector y"),
    _spec("right_rot_z_deg", "deg", 0.0, "right_pose", "... rotation vector z"),
    _spec("right_x_mm", "mm", math.nan, "right_pose", "... position x (about B_ref)"),
    _spec("right_y_mm", "mm", 0.0, "right_pose", "... position y"),
    _spec("right_z_mm", "mm", 0.0, "right_pose", "... position z"),
    _spec("slide_backlash_mm", "mm", 0.0, "slide_backlash", "lost motion of the slide on reversal"),
    _spec("left_backlash_deg", "deg", 0.0, "left_backlash", "lost motion of the left pan head on reversal"),
    _spec("right_backlash_deg", "deg", 0.0, "right_backlash", "lost motion of the right pan head on reversal"),
)
NAMES = tuple(p.name for p in PARAMETERS)
_INDEX = {name: i for i, name in enumerate(NAMES)}
N_PARAMS = len(PARAMETERS)


# --------------------------------------------------------------------------------------------------
# Rotations and the chain


def _rotation_matrices(rvecs: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of (N, 3) rotation vectors (rad), Rodrigues' formula, broadcast."""
    rvecs = np.asarray(rvecs, dtype=float).reshape(-1, 3)
    theta = np.linalg.norm(rvecs, axis=1)
    small = theta < 1e-12
    k = rvecs / np.where(small, 1.0, theta)[:, None]
    K = np.zeros((len(rvecs), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
    K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    R = np.eye(3) + s * K + (1.0 - c) * (K @ K)
    R[small] = np.eye(3)
    return R


def _rvec(R: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(R, dtype=float))[0].reshape(3)


def _axis_angle(direction: np.ndarray, rad: float) -> np.ndarray:
    """(3, 3) rotation by ``rad`` about the unit vector ``direction`` (one rotation: no batch overhead)."""
    x, y, z = float(direction[0]), float(direction[1]), float(direction[2])
    c, s = math.cos(rad), math.sin(rad)
    C = 1.0 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


def _rotation_vector_matrix(rvec: np.ndarray) -> np.ndarray:
    theta = math.sqrt(float(rvec[0]) ** 2 + float(rvec[1]) ** 2 + float(rvec[2]) ** 2)
    if theta < 1e-15:
        return np.eye(3)
    return _axis_angle(np.asarray(rvec, dtype=float) / theta, theta)


def _about_line(direction: np.ndarray, point: np.ndarray, rad: float) -> np.ndarray:
    """4x4 rigid rotation by ``rad`` about the line through ``point`` along the unit ``direction``."""
    R = _axis_angle(direction, rad)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = point - R @ point
    return T


def _pan_line(p: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(unit direction, point) of a pan axis in its camera's frame, from parameter vector ``p``."""
    i = _INDEX[f"{side}_axis_tilt_x_deg"]
    tilt_x, tilt_z, x, z = p[i], p[i + 1], p[i + 2], p[i + 3]
    direction = rotation_deg("x", tilt_x) @ rotation_deg("z", tilt_z) @ np.array([0.0, 1.0, 0.0])
    return direction, np.array([x, 0.0, z])


def _effective(axes: Mapping[str, float], approach: Mapping[str, int], p: np.ndarray) -> tuple[float, float, float]:
    """Commanded values corrected for backlash by the direction of approach."""
    b = axes["baseline_mm"] - approach.get("baseline_mm", 0) * p[_INDEX["slide_backlash_mm"]] / 2.0
    tl = axes["toe_in_left_deg"] - approach.get("toe_in_left_deg", 0) * p[_INDEX["left_backlash_deg"]] / 2.0
    tr = axes["toe_in_right_deg"] - approach.get("toe_in_right_deg", 0) * p[_INDEX["right_backlash_deg"]] / 2.0
    return b, tl, tr


def chain(p: np.ndarray, reference_baseline_mm: float, baseline_mm: float, toe_in_left_deg: float,
          toe_in_right_deg: float) -> np.ndarray:
    """T_right_left (4x4, mm) of the model with parameters ``p`` (N_PARAMS,) at effective axis values.

    Effective values are already corrected for backlash (see :func:`_effective`).
    """
    p = np.asarray(p, dtype=float)
    left_dir, left_point = _pan_line(p, "left")
    right_dir, right_point = _pan_line(p, "right")
    T_S_L = _about_line(left_dir, left_point, math.radians(p[_INDEX["left_angle_scale"]] * toe_in_left_deg))
    T_R0_R = _about_line(right_dir, right_point, -math.radians(p[_INDEX["right_angle_scale"]] * toe_in_right_deg))
    d = (rotation_deg("y", p[_INDEX["slide_yaw_deg"]]) @ rotation_deg("z", p[_INDEX["slide_pitch_deg"]])
         @ np.array([1.0, 0.0, 0.0]))
    i = _INDEX["right_rot_x_deg"]
    T_S_R0 = np.eye(4)
    T_S_R0[:3, :3] = _rotation_vector_matrix(np.radians(p[i : i + 3]))
    T_S_R0[:3, 3] = p[i + 3 : i + 6]
    T_S_R = T_S_R0 @ T_R0_R
    T_S_R[:3, 3] += p[_INDEX["slide_scale"]] * (baseline_mm - reference_baseline_mm) * d
    R_SR, t_SR = T_S_R[:3, :3], T_S_R[:3, 3]
    T_R_S = np.eye(4)
    T_R_S[:3, :3] = R_SR.T
    T_R_S[:3, 3] = -R_SR.T @ t_SR
    return T_R_S @ T_S_L


def nominal_parameters(reference_baseline_mm: float) -> np.ndarray:
    """Parameters of the ideal rig: pan about the optical centres, vertical axes, every scale exact."""
    p = np.array([spec.nominal for spec in PARAMETERS])
    p[_INDEX["right_x_mm"]] = reference_baseline_mm
    return p


def nominal_extrinsics(baseline_mm: float, alpha_left_deg: float = 90.0, alpha_right_deg: float = 90.0, *,
                       tilt_left_deg: float = 0.0, tilt_right_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), T (3,) mm) of the ideal geometry at commanded B and alphas: X_right = R @ X_left + T.

    What a user who trusts the rig's scales gets: each camera turns about its optical centre, B is the
    distance between the centres, alpha the angle between the baseline and the optical axis.
    """
    return RigPose(baseline_mm, alpha_left_deg, alpha_right_deg, tilt_left_deg, tilt_right_deg).stereo_extrinsics()


#: The as-built deviations from the ideal geometry that :func:`nominal_covariance` propagates: shared by
#: both cameras, the slide's zero, scale and direction (two angles) and the optical centres' offset ahead of
#: the pan axes (the same
#: lens and head on both sides); per camera, the centre's own offset about that (forward, sideways, height),
#: the camera's yaw (pan zero and mount), pitch and roll, the pan axis' tilt (two directions), the pan scale
#: and its per-move landing (backlash and repeatability). Units mm, deg and 1 as named.
TOLERANCE_NAMES = ("baseline_zero_mm", "baseline_scale", "slide_direction_deg", "centre_forward_mm",
                   "centre_forward_each_mm", "centre_sideways_mm", "centre_height_mm", "yaw_deg", "pitch_deg",
                   "roll_deg", "axis_tilt_deg", "pan_scale", "pan_repeat_deg")
_SHARED_TOLERANCES = ("baseline_zero_mm", "baseline_scale", "slide_yaw_deg", "slide_pitch_deg", "centre_forward_mm")
_PER_CAMERA_DEVIATIONS = ("centre_forward_each_mm", "centre_sideways_mm", "centre_height_mm", "yaw_deg",
                          "pitch_deg", "roll_deg", "axis_tilt_x_deg", "axis_tilt_z_deg", "pan_scale", "pan_repeat_deg")


def _as_built_camera(side: str, baseline_mm: float, toe_in_deg: float, tilt_deg: float,
                     d: Mapping[str, float]) -> np.ndarray:
    """T_rig_cam (4x4) of one camera with deviations ``d`` (keys of the shared and per-camera deviations).

    Zero deviations give :func:`stereo_bench.geometry.camera_pose_in_rig`: the camera turns about a vertical
    axis through its optical centre. The pan axis stands on the carriage at x = -+(B (1 + scale) + zero) / 2;
    the optical centre sits (sideways, -height, forward) from it in the head's frame, which the pan turns.
    """
    sign = 1.0 if side == "left" else -1.0
    separation = baseline_mm * (1.0 + d["baseline_scale"]) + d["baseline_zero_mm"]
    slide = (rotation_deg("y", d["slide_yaw_deg"]) @ rotation_deg("z", d["slide_pitch_deg"])
             @ np.array([1.0, 0.0, 0.0]))
    axis = (rotation_deg("x", d["axis_tilt_x_deg"]) @ rotation_deg("z", d["axis_tilt_z_deg"])
            @ np.array([0.0, 1.0, 0.0]))
    pan = sign * math.radians(toe_in_deg * (1.0 + d["pan_scale"]) + d["yaw_deg"] + d["pan_repeat_deg"])
    R_pan = _axis_angle(axis, pan)
    R_mount = rotation_deg("z", d["roll_deg"]) @ rotation_deg("x", d["pitch_deg"])
    T = np.eye(4)
    T[:3, :3] = R_pan @ R_mount @ rotation_deg("x", -tilt_deg)
    offset = np.array([d["centre_sideways_mm"], -d["centre_height_mm"],
                       d["centre_forward_mm"] + d["centre_forward_each_mm"]])
    T[:3, 3] = -sign * separation / 2.0 * slide + R_pan @ offset
    return T


def nominal_covariance(baseline_mm: float, alpha_left_deg: float = 90.0, alpha_right_deg: float = 90.0, *,
                       tolerances: Mapping[str, float], tilt_left_deg: float = 0.0,
                       tilt_right_deg: float = 0.0) -> np.ndarray:
    """(6, 6) covariance over (rvec [rad], T [mm]) of :func:`nominal_extrinsics` from the rig's stated tolerances.

    ``tolerances``: standard uncertainty of each of :data:`TOLERANCE_NAMES` (per camera where it applies:
    each camera's deviation is independent of the other's; ``axis_tilt_deg`` and ``slide_direction_deg`` in
    each of two directions;
    ``centre_forward_mm`` is one offset shared by both cameras, ``centre_forward_each_mm`` each camera's own).
    First-order propagation through the as-built chain (central differences); the nominal geometry is the
    chain at zero deviations, so a deviation the rig really has is an error the covariance must cover:
    the optical centres ahead of the pan axes shorten the optical baseline by ~2 f sin t with toe-in t.
    """
    missing = [name for name in TOLERANCE_NAMES if name not in tolerances]
    if missing:
        raise ValueError(f"tolerances: missing {', '.join(missing)}")
    toe_left, toe_right = 90.0 - alpha_left_deg, 90.0 - alpha_right_deg
    keys = [(name, "both") for name in _SHARED_TOLERANCES] + [
        (name, side) for side in ("left", "right") for name in _PER_CAMERA_DEVIATIONS]
    def tolerance(name: str) -> float:
        shared = {"axis_tilt_x_deg": "axis_tilt_deg", "axis_tilt_z_deg": "axis_tilt_deg",
                  "slide_yaw_deg": "slide_direction_deg", "slide_pitch_deg": "slide_direction_deg"}
        return float(tolerances[shared.get(name, name)])

    sigma = np.array([tolerance(name) for name, _ in keys])
    # A per-camera deviation leaves the other camera as it was: each camera (the right one inverted) is kept
    # by its deviations' exact bits (-0.0 apart from 0.0) and built once, not in every one of the 4/5 of the
    # steps that leave it alone; the same calls on the same numbers give the same bits.
    built: dict[tuple, np.ndarray] = {}

    def camera(side: str, toe_in_deg: float, tilt_deg: float, deviations: dict[str, float]) -> np.ndarray:
        key = (side, *(value.hex() for value in deviations.values()))
        if key not in built:
            T_rig_camera = _as_built_camera(side, baseline_mm, toe_in_deg, tilt_deg, deviations)
            built[key] = T_rig_camera if side == "left" else np.linalg.inv(T_rig_camera)
        return built[key]

    def pair(values: np.ndarray) -> np.ndarray:
        by_side = {side: dict.fromkeys(_PER_CAMERA_DEVIATIONS, 0.0) for side in ("left", "right")}
        shared = dict.fromkeys(_SHARED_TOLERANCES, 0.0)
        for (name, side), value in zip(keys, values, strict=True):
            (shared if side == "both" else by_side[side])[name] = float(value)
        T_rig_left = camera("left", toe_left, tilt_left_deg, {**shared, **by_side["left"]})
        T_right_rig = camera("right", toe_right, tilt_right_deg, {**shared, **by_side["right"]})
        return _rvec_t(T_right_rig @ T_rig_left)

    J = np.zeros((6, len(keys)))
    for k in range(len(keys)):
        if sigma[k] == 0.0:
            continue
        step = np.zeros(len(keys))
        step[k] = sigma[k]  # the chain is smooth over one sigma; central differences are exact to second order
        J[:, k] = (pair(step) - pair(-step)) / (2.0 * sigma[k])
    return J @ np.diag(sigma**2) @ J.T


# --------------------------------------------------------------------------------------------------
# The design


@dataclass(frozen=True)
class DesignConfiguration:
    """One configuration of the calibration design (commanded values)."""

    baseline_mm: float
    toe_in_left_deg: float
    toe_in_right_deg: float

    def axes(self) -> dict[str, float]:
        return {"baseline_mm": self.baseline_mm, "toe_in_left_deg": self.toe_in_left_deg,
                "toe_in_right_deg": self.toe_in_right_deg}

    @property
    def alpha_left_deg(self) -> float:
        return alpha_from_toe_in(self.toe_in_left_deg)

    @property
    def alpha_right_deg(self) -> float:
        return alpha_from_toe_in(self.toe_in_right_deg)


def _levels(low: float, high: float, n: int) -> list[float]:
    if high < low:
        raise ValueError(f"range ({low:g}, {high:g}) is empty")
    if high == low or n == 1:
        return [float(low)]
    return [float(v) for v in np.linspace(low, high, n)]


def kinematic_design(baseline_range_mm: tuple[float, float], toe_in_left_range_deg: tuple[float, float] = (0.0, 0.0),
                     toe_in_right_range_deg: tuple[float, float] | None = None, *,
                     levels: int = 3) -> list[DesignConfiguration]:
    """The configurations to calibrate, in the order to visit them: 3 baselines x 3 toe-ins per camera.

    Baselines and toe-ins are ``levels`` evenly spaced values spanning each range (one value for an
    empty range: that part of the model is then not identified and held nominal). Each baseline
    is visited with three toe-in pairs: equal toe-ins and the two pairs one level apart, rotated
    over the baselines, so the two heads' scales and axes separate and every pair of neighbouring
    levels occurs (large asymmetric pairs, whose views may not overlap, are avoided). The order
    B0 B1 B2 B1 B0 B2 B0 B1 B2 approaches baselines from both sides (backlash); toe-ins change
    in both directions too.
    """
    if levels not in (2, 3):
        raise ValueError(f"levels must be 2 or 3, not {levels}")
    toe_in_right_range_deg = toe_in_right_range_deg or toe_in_left_range_deg
    bs = _levels(*baseline_range_mm, levels)
    tl = _levels(*toe_in_left_range_deg, levels)
    tr = _levels(*toe_in_right_range_deg, levels)
    n = levels
    # (i_left, i_right) level pairs per baseline level, every neighbouring pair across the baselines.
    if n == 3:
        pairs = [[(0, 0), (1, 2), (2, 1)], [(1, 1), (0, 1), (2, 1)], [(2, 2), (1, 0), (1, 2)]]
        order = [0, 1, 2, 1, 0, 2, 0, 1, 2]
    else:
        pairs = [[(0, 0), (1, 0)], [(1, 1), (0, 1)]]
        order = [0, 1, 0, 1]
    used = {b: 0 for b in range(n)}
    design = []
    for b_index in order:
        i, j = pairs[b_index][used[b_index] % len(pairs[b_index])]
        used[b_index] += 1
        # A range with one value repeats it: a configuration visited again (from another side) still
        # tells the backlash and the landing scatter.
        design.append(DesignConfiguration(bs[min(b_index, len(bs) - 1)], tl[min(i, len(tl) - 1)],
                                          tr[min(j, len(tr) - 1)]))
    return design


def approach_directions(previous: Mapping[str, float] | None, current: Mapping[str, float],
                        before: Mapping[str, int] | None = None) -> dict[str, int]:
    """Per axis the direction of the move that reached ``current``: +1 increased, -1 decreased.

    An axis that did not move keeps its direction in ``before`` (0 if unknown).
    """
    before = before or {}
    out = {}
    for axis in AXES:
        if previous is None or axis not in previous or axis not in current:
            out[axis] = int(before.get(axis, 0))
            continue
        delta = float(current[axis]) - float(previous[axis])
        out[axis] = (1 if delta > 0 else -1) if abs(delta) > 1e-9 else int(before.get(axis, 0))
    return out


# --------------------------------------------------------------------------------------------------
# The model (and its file)


class ParameterValue(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    value: float = Field(allow_inf_nan=False)
    sigma: float | None = Field(None, ge=0, allow_inf_nan=False)
    unit: str
    identifiable: bool
    note: str = ""


class FitSummary(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    rms_px: float
    pixel_sigma_px: float
    n_configurations: int
    n_views: int
    n_observations: int
    intrinsics: str
    design: list[dict[str, float]]
    per_configuration_rms_px: list[float] = Field(default_factory=list)
    dof: int | None = Field(None, description="degrees of freedom of pixel_sigma_px (coordinates - unknowns)")


class KinematicModel(BaseModel):
    """A fitted kinematic rig model: every parameter with its standard deviation, and their covariance."""

    model_config = ConfigDict(extra="forbid", strict=True)

    schema_id: str = Field(FILE_SCHEMA, alias="schema")
    reference_baseline_mm: float = Field(allow_inf_nan=False)
    repeatability_mm: float = Field(0.0, ge=0, description="std of the slide's landing error per move")
    repeatability_left_deg: float = Field(0.0, ge=0, description="std of the left head's landing error per move")
    repeatability_right_deg: float = Field(0.0, ge=0, description="std of the right head's landing error per move")
    span: dict[str, list[float]] = Field(description="min and max of each axis over the design")
    parameters: dict[str, ParameterValue]
    covariance_names: list[str]
    covariance: list[list[float]]
    image_size: list[int]
    K1: list[list[float]]
    D1: list[float]
    K2: list[list[float]]
    D2: list[float]
    fit: FitSummary | None = None
    # Of the intrinsics the fit refined (left.fx ... right.p2, px and 1): what the measurement's calibration
    # component rests on. Empty: not estimated (fixed intrinsics, or a file written before it was saved).
    intrinsics_covariance_names: list[str] = Field(default_factory=list)
    intrinsics_covariance: list[list[float]] = Field(default_factory=list)
    # Cov(intrinsics, kinematic parameters): rows intrinsics_covariance_names, columns covariance_names. One fit
    # estimates both, and their errors are correlated (a focal length against the right camera's position).
    cross_covariance: list[list[float]] = Field(default_factory=list)
    # (a_sin, a_cos) px: the corner detector's pixel locking fitted to the fit's residuals
    # (stereo_bench.vision.covariance.pixel_locking); None: not significant or not estimated.
    pixel_locking_px: list[float] | None = None

    @model_validator(mode="after")
    def _check(self) -> KinematicModel:
        missing = [n for n in NAMES if n not in self.parameters]
        if missing:
            raise ValueError(f"parameters: missing {', '.join(missing)}")
        unknown = [n for n in self.parameters if n not in _INDEX]
        if unknown:
            raise ValueError(f"parameters: unknown {', '.join(unknown)}")
        n = len(self.covariance_names)
        if any(name not in _INDEX for name in self.covariance_names):
            raise ValueError("covariance_names: names a parameter that does not exist")
        if len(self.covariance) != n or any(len(row) != n for row in self.covariance):
            raise ValueError(f"covariance must be {n}x{n} (one row and column per covariance_names entry)")
        m = len(self.intrinsics_covariance_names)
        if len(self.intrinsics_covariance) != m or any(len(row) != m for row in self.intrinsics_covariance):
            raise ValueError(f"intrinsics_covariance must be {m}x{m} (one row and column per "
                             "intrinsics_covariance_names entry)")
        if self.cross_covariance and (len(self.cross_covariance) != m or any(len(row) != n
                                                                            for row in self.cross_covariance)):
            raise ValueError(f"cross_covariance must be {m}x{n} (intrinsics_covariance_names x covariance_names)")
        if self.pixel_locking_px is not None and len(self.pixel_locking_px) != 2:
            raise ValueError("pixel_locking_px must be [a_sin, a_cos]")
        if self.schema_id != FILE_SCHEMA:
            raise ValueError(f"schema: expected {FILE_SCHEMA!r}, not {self.schema_id!r}")
        return self

    @property
    def vector(self) -> np.ndarray:
        return np.array([self.parameters[name].value for name in NAMES])

    @property
    def free(self) -> list[str]:
        return list(self.covariance_names)

    def covariance_matrix(self) -> np.ndarray:
        return np.asarray(self.covariance, dtype=float).reshape(len(self.covariance_names), len(self.covariance_names))

    def intrinsics(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (np.asarray(self.K1, float), np.asarray(self.D1, float).reshape(1, -1),
                np.asarray(self.K2, float), np.asarray(self.D2, float).reshape(1, -1))

    def cross_covariance_matrix(self) -> np.ndarray | None:
        """(P, K) Cov(intrinsics, kinematic parameters); None when the file has none."""
        if not self.cross_covariance:
            return None
        return np.asarray(self.cross_covariance, dtype=float).reshape(len(self.intrinsics_covariance_names),
                                                                      len(self.covariance_names))

    def intrinsics_covariance_matrix(self) -> np.ndarray | None:
        """(P, P) covariance of ``intrinsics_covariance_names``; None when the file has none."""
        if not self.intrinsics_covariance_names:
            return None
        m = len(self.intrinsics_covariance_names)
        return np.asarray(self.intrinsics_covariance, dtype=float).reshape(m, m)


class KinematicFileError(ValueError):
    """A kinematic model file that cannot be used; one line naming the file and the field."""


def save_model(model: KinematicModel, path: str | Path) -> Path:
    """Write ``model`` as a readable TOML file (every parameter with value, sigma, unit; the covariance).

    Atomically, and never over an existing file (FileExistsError): a file that appeared since the caller checked
    the path is not replaced.
    """
    return atomic.write_text(Path(path), model_toml(model), overwrite=False)


def model_toml(model: KinematicModel) -> str:
    """The readable TOML text :func:`save_model` writes (checked to read back)."""
    data = model.model_dump(mode="json", by_alias=True)
    lines = ["# stereo-bench kinematic rig model: T_right_left at any (B, toe-ins) from the rig's axis positions.",
             "# Parameters in mm, deg and 1; covariance over the identifiable ones, same units and order.", ""]
    for key in ("schema", "reference_baseline_mm", "repeatability_mm", "repeatability_left_deg",
                "repeatability_right_deg", "image_size", "covariance_names"):
        lines.append(f"{key} = {_toml_value(data[key])}")
    lines.append("covariance = [")
    lines.extend(f"  {_toml_value(row)}," for row in data["covariance"])
    lines.append("]")
    for key in ("K1", "K2"):
        lines.append(f"{key} = {_toml_value(data[key])}")
    for key in ("D1", "D2"):
        lines.append(f"{key} = {_toml_value(data[key])}")
    if data.get("pixel_locking_px") is not None:
        lines.append("# the corner detector's pixel locking (a_sin, a_cos) px, from the fit's residuals")
        lines.append(f"pixel_locking_px = {_toml_value(data['pixel_locking_px'])}")
    if data["intrinsics_covariance_names"]:
        lines.append("# covariance of the intrinsics the fit refined (px and 1), marginal over everything else")
        lines.append(f"intrinsics_covariance_names = {_toml_value(data['intrinsics_covariance_names'])}")
        lines.append("intrinsics_covariance = [")
        lines.extend(f"  {_toml_value(row)}," for row in data["intrinsics_covariance"])
        lines.append("]")
    if data["cross_covariance"]:
        lines.append("# Cov(intrinsics, parameters): rows intrinsics_covariance_names, columns covariance_names")
        lines.append("cross_covariance = [")
        lines.extend(f"  {_toml_value(row)}," for row in data["cross_covariance"])
        lines.append("]")
    lines += ["", "[span]"]
    lines.extend(f"{axis} = {_toml_value(values)}" for axis, values in data["span"].items())
    for name in NAMES:
        spec = PARAMETERS[_INDEX[name]]
        lines += ["", f"[parameters.{name}]  # {spec.description}"]
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in data["parameters"][name].items()
                     if value is not None)
    if data.get("fit") is not None:
        lines += ["", "[fit]"]
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in data["fit"].items() if value is not None)
    text = "\n".join(lines) + "\n"
    tomllib.loads(text)  # never write a file that does not read back
    return text


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"cannot write {value} to TOML")
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def load_model(path: str | Path) -> KinematicModel:
    """Read and validate a kinematic model file; :class:`KinematicFileError` names the file and field.

    Read as every input file is (:func:`drivers.files.read_regular_file`: a regular file of bounded size).
    """
    try:
        text = decode_utf8(read_regular_file(path, what="kinematic model file", max_bytes=MAX_TOML_BYTES), path)
    except InputFileError as error:
        raise KinematicFileError(str(error)) from None
    return model_from_toml(text, str(path))


def model_from_toml(text: str, source: str = "kinematic model") -> KinematicModel:
    """Parse and validate the TOML text of a model; :class:`KinematicFileError` names ``source`` and the field."""
    path = source
    try:
        data = parse_toml(text, path)
    except InputFileError as error:
        raise KinematicFileError(str(error)) from None
    try:
        return KinematicModel.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ())) or "(top level)"
        message = first.get("msg", "invalid").removeprefix("Value error, ")
        raise KinematicFileError(f"{path}: {where}: {message}") from None


# --------------------------------------------------------------------------------------------------
# Prediction


@dataclass(frozen=True)
class Prediction:
    """R, T (X_right = R X_left + T, mm) predicted at one configuration, with its uncertainty.

    ``covariance`` (6, 6) is over (rvec [rad], T [mm]); ``structure`` the optical baseline, alphas
    and rotation angle (:func:`stereo_bench.geometry.stereo_structure`) and ``structure_sigma`` their
    standard deviations; ``extrapolated`` names the axes outside the design's span.
    """

    R: np.ndarray
    T: np.ndarray
    rvec: np.ndarray
    covariance: np.ndarray
    structure: dict[str, float]
    structure_sigma: dict[str, float]
    extrapolated: list[str] = field(default_factory=list)
    # The parts of ``covariance``: d(rvec, T)/d(free parameters) (6, K) in the order of the model's
    # covariance_names, and the rig's own part (landing repeatability; the backlash when the approach is
    # unknown), so covariance = J C J^T + rig_covariance.
    parameter_jacobian: np.ndarray | None = None
    rig_covariance: np.ndarray | None = None


def _rvec_t(T_right_left: np.ndarray) -> np.ndarray:
    return np.concatenate([_rvec(T_right_left[:3, :3]), T_right_left[:3, 3]])


def _structure_vector(x: np.ndarray) -> np.ndarray:
    s = stereo_structure(cv2.Rodrigues(x[:3])[0], x[3:])
    return np.array([s["baseline_mm"], s["alpha_left_deg"], s["alpha_right_deg"], s["rotation_deg"]])


STRUCTURE_KEYS = ("baseline_mm", "alpha_left_deg", "alpha_right_deg", "rotation_deg")


def structure_sigma(R: np.ndarray, T: np.ndarray, covariance: np.ndarray) -> dict[str, float]:
    """Standard uncertainties of :func:`stereo_bench.geometry.stereo_structure`'s optical baseline, alphas and
    rotation angle, from the (6, 6) covariance of (rvec [rad], T [mm]) (first order, central differences)."""
    x = np.concatenate([_rvec(R), np.asarray(T, dtype=float).reshape(3)])
    J = np.zeros((4, 6))
    for k in range(6):
        h = 1e-7 if k < 3 else 1e-5
        up, down = x.copy(), x.copy()
        up[k] += h
        down[k] -= h
        J[:, k] = (_structure_vector(up) - _structure_vector(down)) / (2 * h)
    variances = np.diag(J @ np.asarray(covariance, dtype=float) @ J.T)
    return {key: float(math.sqrt(max(v, 0.0))) for key, v in zip(STRUCTURE_KEYS, variances, strict=True)}


def predict(model: KinematicModel, axes: Mapping[str, float], approach: Mapping[str, int] | None = None,
            ) -> Prediction:
    """R, T of the pair at axis positions ``axes`` (``baseline_mm``, ``toe_in_left_deg``, ``toe_in_right_deg``).

    ``approach``: per axis the direction of the move that reached it (+1 increased, -1 decreased, 0 or
    missing: unknown). With an unknown direction the prediction sits midway and the backlash adds
    (b / 2)^2 to the variance. The covariance also holds the parameters' covariance and the rig's
    landing repeatability.
    """
    missing = [a for a in AXES if a not in axes]
    if missing:
        raise ValueError(f"axes: missing {', '.join(missing)}")
    approach = dict(approach or {})
    p = model.vector
    B_ref = model.reference_baseline_mm

    def at(params: np.ndarray, values: Sequence[float]) -> np.ndarray:
        return _rvec_t(chain(params, B_ref, *values))

    effective = np.array(_effective(axes, approach, p))
    x = at(p, effective)
    # Parameters' covariance, by central differences.
    free = model.free
    J = np.zeros((6, len(free)))
    for k, name in enumerate(free):
        i = _INDEX[name]
        h = 1e-4 * max(1.0, abs(p[i])) if PARAMETERS[i].unit != "1" else 1e-6
        up, down = p.copy(), p.copy()
        up[i] += h
        down[i] -= h
        J[:, k] = (at(up, _effective(axes, approach, up)) - at(down, _effective(axes, approach, down))) / (2 * h)
    parameter_part = J @ model.covariance_matrix() @ J.T if free else np.zeros((6, 6))
    # Landing repeatability and unknown backlash, through the axes.
    J_axes = np.zeros((6, 3))
    for k in range(3):
        step = np.zeros(3)
        step[k] = 1e-4
        J_axes[:, k] = (at(p, effective + step) - at(p, effective - step)) / 2e-4
    variances = np.array([model.repeatability_mm, model.repeatability_left_deg, model.repeatability_right_deg]) ** 2
    backlash = p[[_INDEX["slide_backlash_mm"], _INDEX["left_backlash_deg"], _INDEX["right_backlash_deg"]]]
    unknown = np.array([approach.get(axis, 0) == 0 for axis in AXES])
    variances = variances + np.where(unknown, (backlash / 2.0) ** 2, 0.0)
    rig_part = J_axes @ np.diag(variances) @ J_axes.T
    covariance = parameter_part + rig_part
    R = cv2.Rodrigues(x[:3])[0]
    extrapolated = [a for a in AXES if not (model.span[a][0] - 1e-6 <= float(axes[a]) <= model.span[a][1] + 1e-6)]
    return Prediction(R=R, T=x[3:].copy(), rvec=x[:3].copy(), covariance=covariance,
                      structure=stereo_structure(R, x[3:]),
                      structure_sigma=structure_sigma(R, x[3:], covariance),
                      extrapolated=extrapolated, parameter_jacobian=J, rig_covariance=rig_part)


# --------------------------------------------------------------------------------------------------
# The fit


@dataclass(frozen=True)
class ConfigurationViews:
    """Calibration views taken at one visit of one configuration.

    ``axes``: the reported ``baseline_mm``, ``toe_in_left_deg``, ``toe_in_right_deg``; ``approach``:
    per axis the direction of the move that reached them (+1 increased, -1 decreased, 0 unknown);
    ``views``: (left, right) detections (objects with ``ids`` (N,) into the board's object points and
    ``corners_px`` (N, 2), e.g. :class:`stereo_bench.vision.detect.Detection`), None where the
    board was not found. Views not found by both cameras are not used.
    """

    axes: Mapping[str, float]
    approach: Mapping[str, int]
    views: Sequence[tuple[Any, Any]]


@dataclass
class KinematicFit:
    """A fitted model and what the fit saw: per used view its board pose and residual RMS."""

    model: KinematicModel
    T_left_board: list[np.ndarray]  # per used view (4x4)
    view_rms_px: np.ndarray  # per used view
    view_configuration: np.ndarray  # per used view: index into the configurations
    views_dropped: list[tuple[int, int, str]]  # (configuration, view index, why)
    landing: np.ndarray  # (n_configurations, 3): estimated landing errors (mm, deg, deg)


def _rotate(R: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3): each (3, 3) R[n] applied to points[n] (explicit sums: faster than a batched einsum)."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    return np.column_stack([R[:, 0, 0] * x + R[:, 0, 1] * y + R[:, 0, 2] * z,
                            R[:, 1, 0] * x + R[:, 1, 1] * y + R[:, 1, 2] * z,
                            R[:, 2, 0] * x + R[:, 2, 1] * y + R[:, 2, 2] * z])


def _project(points: np.ndarray, intr: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of (N, 3) camera points through (fx, fy, cx, cy, k1, k2, p1, p2, k3)."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = intr
    x = points[:, 0] / points[:, 2]
    y = points[:, 1] / points[:, 2]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    return np.column_stack([fx * xd + cx, fy * yd + cy])


def _intrinsic_vector(K: np.ndarray, D: np.ndarray) -> np.ndarray:
    D = np.asarray(D, dtype=float).ravel()
    if D.size > 5 and np.any(D[5:] != 0.0):
        raise ValueError("the kinematic fit takes the 5-coefficient distortion model (k1 k2 p1 p2 k3)")
    D = np.concatenate([D, np.zeros(max(0, 5 - D.size))])[:5]
    K = np.asarray(K, dtype=float)
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *D])


def _K_D(intr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fx, fy, cx, cy = intr[:4]
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), intr[4:].reshape(1, 5)


#: The fits stop when a step lowers the cost by less than this share of it: where they stop depends on the
#: arithmetic (BLAS kernels) within sqrt(FIT_TOLERANCE chi^2) sigmas of the minimum (docs/REPLAY.md).
FIT_TOLERANCE = 1e-12


def _levenberg_marquardt(residuals, linearize, solve, x0: np.ndarray, *, max_iterations: int = 50,
                         tolerance: float = FIT_TOLERANCE) -> tuple[np.ndarray, Any]:
    """Minimise |residuals(x)|^2 from ``x0``. Returns (x, the linearisation at x).

    ``linearize(x, r)`` returns whatever ``solve(linearisation, lam)`` needs to give the damped
    Gauss-Newton step (Levenberg-Marquardt with the normal matrix's diagonal as scaling).
    """
    x = np.array(x0, dtype=float)
    r = residuals(x)
    cost = float(r @ r)
    lam = 1e-4
    lin = linearize(x, r)
    for _ in range(max_iterations):
        improved = False
        for _ in range(12):
            try:
                step = solve(lin, lam)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            r_new = residuals(x + step)
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        decrease = (cost - cost_new) / max(cost, 1e-300)
        x, r, cost = x + step, r_new, cost_new
        lam = max(lam / 10.0, 1e-9)
        lin = linearize(x, r)
        if decrease < tolerance:
            break
    return x, lin


def _solve_dense(lin: tuple[np.ndarray, np.ndarray], lam: float) -> np.ndarray:
    A, g = lin
    return np.linalg.solve(A + lam * np.diag(np.maximum(np.diag(A), 1e-12)), -g)


def _identifiable(configurations: Sequence[ConfigurationViews]) -> tuple[set[str], dict[str, str]]:
    """(parameter groups the design identifies, reason per group it does not)."""
    free, notes = {"right_pose"}, {}
    groups = {"baseline_mm": ("slide", "slide_backlash"), "toe_in_left_deg": ("left_axis", "left_backlash"),
              "toe_in_right_deg": ("right_axis", "right_backlash")}
    for axis, (geometry, backlash) in groups.items():
        values = {round(float(c.axes[axis]), 9) for c in configurations}
        if len(values) < 2:
            notes[geometry] = notes[backlash] = f"not identifiable: the design holds {axis} at one value"
            continue
        free.add(geometry)
        directions = {int(c.approach.get(axis, 0)) for c in configurations}
        if {1, -1} <= directions:
            free.add(backlash)
        else:
            notes[backlash] = f"not identifiable: every design configuration approached {axis} from the same side"
    return free, notes


def _average_transform(transforms: Sequence[np.ndarray]) -> np.ndarray:
    rvecs = np.array([_rvec(T[:3, :3]) for T in transforms])
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvecs.mean(axis=0))[0]
    out[:3, 3] = np.mean([T[:3, 3] for T in transforms], axis=0)
    return out


def _pose_matrix(pose: np.ndarray) -> np.ndarray:
    """4x4 transform of a (rvec rad, t mm) 6-vector."""
    T = np.eye(4)
    T[:3, :3] = _rotation_vector_matrix(pose[:3])
    T[:3, 3] = pose[3:]
    return T


def _pnp(object_points: np.ndarray, pixels: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """T_cam_board (4x4) of a planar board view."""
    obj = np.asarray(object_points, np.float64).reshape(-1, 1, 3)
    img = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, D, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("solvePnP failed on a calibration view")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, D, rvec, tvec)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.reshape(3)
    return T


def _initial_parameters(free: np.ndarray, B_ref: float, configurations: Sequence[ConfigurationViews],
                        T_rl: list[np.ndarray | None]) -> np.ndarray:
    """Kinematic parameters from the per-configuration relative poses (small least squares from nominal)."""
    p = nominal_parameters(B_ref)
    usable = [i for i, T in enumerate(T_rl) if T is not None]
    # The right camera at B_ref, toe-in 0 from the configuration nearest to it, under the nominal chain.
    c0 = min(usable, key=lambda i: (abs(configurations[i].axes["toe_in_left_deg"])
                                    + abs(configurations[i].axes["toe_in_right_deg"]),
                                    abs(configurations[i].axes["baseline_mm"] - B_ref)))
    axes = configurations[c0].axes
    T_S_L = np.eye(4)
    T_S_L[:3, :3] = rotation_deg("y", axes["toe_in_left_deg"])
    T_S_R = T_S_L @ np.linalg.inv(T_rl[c0])
    T_S_R[:3, 3] -= (axes["baseline_mm"] - B_ref) * np.array([1.0, 0.0, 0.0])
    T_S_R[:3, :3] = T_S_R[:3, :3] @ rotation_deg("y", axes["toe_in_right_deg"])
    i = _INDEX["right_rot_x_deg"]
    p[i : i + 3] = np.degrees(_rvec(T_S_R[:3, :3]))
    p[i + 3 : i + 6] = T_S_R[:3, 3]
    index = np.flatnonzero(free)

    def residuals(x: np.ndarray) -> np.ndarray:
        q = p.copy()
        q[index] = x
        out = []
        for c in usable:
            conf = configurations[c]
            model = chain(q, B_ref, *_effective(conf.axes, conf.approach, q))
            dR = _rvec(model[:3, :3].T @ T_rl[c][:3, :3])
            out.append(np.concatenate([1000.0 * dR, model[:3, 3] - T_rl[c][:3, 3]]))
        return np.concatenate(out)

    def normal(x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        J = np.empty((r.size, x.size))
        for k in range(x.size):
            h = 1e-6 * max(1.0, abs(x[k]))
            step = x.copy()
            step[k] += h
            J[:, k] = (residuals(step) - r) / h
        return J.T @ J, J.T @ r

    x, _ = _levenberg_marquardt(residuals, normal, _solve_dense, p[index], max_iterations=100)
    p[index] = x
    return p


class _Bundle:
    """The joint bundle adjustment: kinematic parameters, landing errors, intrinsics, board poses.

    Unknown vector: [free kinematic (nk), landing errors (ne), intrinsics (ni), board poses (6 V)].
    Residuals, grouped view by view: pixel errors / sigma_px of every corner in the left then the
    right camera; then the landing errors / their prior sigma. The normal equations are solved by the
    Schur complement of the board poses (6x6 blocks), whose reduced matrix's inverse is the
    covariance of the global unknowns.
    """

    def __init__(self, p0, free_index, B_ref, configurations, views, object_points, intr_left, intr_right,
                 refine_intrinsics, landing_sigmas, sigma_px):
        self.p0, self.free_index, self.B_ref = p0, free_index, B_ref
        self.configurations = configurations
        self.n_configs = len(configurations)
        self.landing_sigmas = np.asarray(landing_sigmas, dtype=float)  # (3,) mm, deg, deg
        self.landing_axes = np.flatnonzero(self.landing_sigmas > 0)
        self.intr0 = (intr_left, intr_right)
        self.refine = refine_intrinsics
        self.sigma_px = sigma_px
        self.nk = len(free_index)
        self.ne = self.n_configs * len(self.landing_axes)
        self.ni = 16 if refine_intrinsics else 0  # fx fy cx cy k1 k2 p1 p2 per camera; k3 stays
        self.n_global = self.nk + self.ne + self.ni
        self.view_config = np.array([v[0] for v in views])
        self.V = len(views)
        self.obs = {}
        for cam, slot in (("left", 1), ("right", 3)):
            vid = np.concatenate([np.full(len(v[slot]), i) for i, v in enumerate(views)])
            ids = np.concatenate([v[slot] for v in views])
            px = np.concatenate([v[slot + 1] for v in views])
            self.obs[cam] = (vid, np.asarray(object_points, float)[ids], px)
        n_left, n_right = len(self.obs["left"][0]), len(self.obs["right"][0])
        self.m_px = 2 * (n_left + n_right)
        # Rows (u, v of each corner) reordered so that each view's rows are one slice.
        raw_view = np.concatenate([np.repeat(self.obs["left"][0], 2), np.repeat(self.obs["right"][0], 2)])
        self.order = np.argsort(raw_view, kind="stable")
        counts = np.bincount(raw_view, minlength=self.V)
        edges = np.concatenate([[0], np.cumsum(counts)])
        self.view_slices = [slice(int(edges[v]), int(edges[v + 1])) for v in range(self.V)]
        is_right = np.concatenate([np.zeros(2 * n_left, bool), np.ones(2 * n_right, bool)])[self.order]
        # Which configuration's landing errors a row depends on (-1: none; left rows do not).
        row_config = np.where(is_right, self.view_config[raw_view[self.order]], -1)
        prior_config = np.repeat(np.arange(self.n_configs), len(self.landing_axes))
        self.row_config = np.concatenate([row_config, prior_config])
        self.row_is_right = np.concatenate([is_right, np.zeros(self.ne, bool)])
        self.m = self.m_px + self.ne

    def unpack(self, x: np.ndarray):
        p = self.p0.copy()
        p[self.free_index] = x[: self.nk]
        landing = np.zeros((self.n_configs, 3))
        if self.ne:
            landing[:, self.landing_axes] = x[self.nk : self.nk + self.ne].reshape(self.n_configs, -1)
        intr_l, intr_r = (i.copy() for i in self.intr0)
        if self.refine:
            o = self.nk + self.ne
            intr_l[:8], intr_r[:8] = x[o : o + 8], x[o + 8 : o + 16]
        poses = x[self.n_global :].reshape(self.V, 6)
        return p, landing, intr_l, intr_r, poses

    def residuals(self, x: np.ndarray) -> np.ndarray:
        p, landing, intr_l, intr_r, poses = self.unpack(x)
        T_rl = np.empty((self.n_configs, 4, 4))
        for c, conf in enumerate(self.configurations):
            T_rl[c] = chain(p, self.B_ref, *(np.array(_effective(conf.axes, conf.approach, p)) + landing[c]))
        R_views = _rotation_matrices(poses[:, :3])
        vid, obj, px = self.obs["left"]
        X = _rotate(R_views[vid], obj) + poses[vid, 3:]
        left = (_project(X, intr_l) - px).ravel()
        vid, obj, px = self.obs["right"]
        X = _rotate(R_views[vid], obj) + poses[vid, 3:]
        cfg = self.view_config[vid]
        X = _rotate(T_rl[cfg, :3, :3], X) + T_rl[cfg, :3, 3]
        right = (_project(X, intr_r) - px).ravel()
        out = [np.concatenate([left, right])[self.order] / self.sigma_px]
        if self.ne:
            out.append((landing[:, self.landing_axes] / self.landing_sigmas[self.landing_axes]).ravel())
        return np.concatenate(out)

    def _global_columns(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(n_global, m) transposed Jacobian of the global unknowns, forward differences.

        Unknowns that touch disjoint rows share one evaluation: the landing errors of one axis over
        all configurations, and each intrinsic of the left camera with the same one of the right.
        """
        Gt = np.zeros((self.n_global, self.m))

        def diff(indices: list[int]) -> tuple[np.ndarray, np.ndarray]:
            step = x.copy()
            h = np.array([1e-6 * max(1.0, abs(x[k])) for k in indices])
            step[indices] += h
            return self.residuals(step) - r, h

        for k in range(self.nk):
            d, h = diff([k])
            Gt[k] = d / h[0]
        n_axes = len(self.landing_axes)
        for a in range(n_axes):
            columns = [self.nk + c * n_axes + a for c in range(self.n_configs)]
            d, h = diff(columns)
            for c, column in enumerate(columns):
                Gt[column] = np.where(self.row_config == c, d, 0.0) / h[c]
        if self.refine:
            o = self.nk + self.ne
            for j in range(8):
                d, h = diff([o + j, o + 8 + j])
                Gt[o + j] = np.where(self.row_is_right, 0.0, d) / h[0]
                Gt[o + 8 + j] = np.where(self.row_is_right, d, 0.0) / h[1]
        return Gt

    def linearize(self, x: np.ndarray, r: np.ndarray) -> dict:
        """Blocks of J^T J and J^T r: global (U, g_g), global-pose (W_v), pose (V_v, g_v) per view."""
        Gt = self._global_columns(x, r)
        Pt = np.empty((6, self.m))
        for k in range(6):
            step = x.copy()
            h = 1e-7 if k < 3 else 1e-5
            step[self.n_global + k :: 6] += h
            Pt[k] = (self.residuals(step) - r) / h
        W = np.empty((self.V, self.n_global, 6))
        Vb = np.empty((self.V, 6, 6))
        gv = np.empty((self.V, 6))
        for v, rows in enumerate(self.view_slices):
            Jv = Pt[:, rows]
            W[v] = Gt[:, rows] @ Jv.T
            Vb[v] = Jv @ Jv.T
            gv[v] = Jv @ r[rows]
        # numpy's own loop, not BLAS: a threaded GEMM of this shape spins for 10-100x longer on a loaded
        # 2-core machine (measured 0.3-1.3 s against 15 ms single-threaded).
        U = np.einsum("ik,jk->ij", Gt, Gt, optimize=False)
        return {"U": U, "g": np.einsum("ik,k->i", Gt, r, optimize=False), "W": W, "V": Vb, "gv": gv}

    def solve(self, lin: dict, lam: float) -> np.ndarray:
        """The damped Gauss-Newton step (Levenberg-Marquardt, diagonal scaling) by the Schur complement."""
        U = lin["U"] + lam * np.diag(np.maximum(np.diag(lin["U"]), 1e-12))
        Vb = lin["V"] + lam * np.maximum(np.diagonal(lin["V"], axis1=1, axis2=2), 1e-12)[:, :, None] * np.eye(6)
        V_inv = np.linalg.inv(Vb)
        WV = np.einsum("vgk,vkl->vgl", lin["W"], V_inv)
        S = U - np.einsum("vgk,vhk->gh", WV, lin["W"])
        rhs = -lin["g"] + np.einsum("vgk,vk->g", WV, lin["gv"])
        dg = np.linalg.solve(S, rhs)
        dv = np.einsum("vkl,vl->vk", V_inv, -lin["gv"] - np.einsum("vgk,g->vk", lin["W"], dg))
        return np.concatenate([dg, dv.ravel()])

    def pixel_locking(self, x: np.ndarray) -> tuple[float, float] | None:
        """The corner detector's pixel locking fitted to the residuals at ``x`` (as a calibration covariance's)."""
        from stereo_bench.vision.covariance import pixel_locking

        observed = np.concatenate([self.obs["left"][2].ravel(), self.obs["right"][2].ravel()])[self.order]
        residual = self.residuals(x)[: self.m_px] * self.sigma_px  # projected - observed, px
        return pixel_locking(observed, residual)

    def global_covariance(self, lin: dict) -> np.ndarray:
        """Covariance of the global unknowns (board poses marginalised): inverse of the Schur complement."""
        V_inv = np.linalg.inv(lin["V"])
        S = lin["U"] - np.einsum("vgk,vkl,vhl->gh", lin["W"], V_inv, lin["W"])
        return np.linalg.inv(S)

    def minimise(self, x0: np.ndarray) -> tuple[np.ndarray, dict]:
        return _levenberg_marquardt(self.residuals, self.linearize, self.solve, x0)


def fit_kinematics(
    configurations: Sequence[ConfigurationViews], object_points: np.ndarray, image_size: tuple[int, int], *,
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None, refine_intrinsics: bool = True,
    repeatability_mm: float = 0.0, repeatability_left_deg: float = 0.0, repeatability_right_deg: float = 0.0,
    reference_baseline_mm: float | None = None, min_corners: int = 6,
) -> KinematicFit:
    """Fit the kinematic model to calibration views at a design of configurations (one joint adjustment).

    Args:
        configurations: one entry per visit of a configuration (see :class:`ConfigurationViews`).
        object_points: (N, 3) board coordinates (mm) indexed by corner id.
        image_size: (width, height) px of both cameras.
        intrinsics: (K1, D1, K2, D2) from a prior calibration (5-coefficient distortion); None:
            calibrated from the same views, each camera alone, first.
        refine_intrinsics: refine fx fy cx cy k1 k2 p1 p2 of both cameras in the adjustment (k3 stays).
        repeatability_*: std of each axis' landing error per move (the rig's repeatability): a prior
            on one landing error per axis and configuration, so the parameters' covariance accounts
            for moves that land differently; 0 assumes exact landings.
        reference_baseline_mm: B_ref of the model (default: the middle of the design's baselines).
        min_corners: a view needs this many corners in each camera.

    Raises:
        ValueError: too few usable views, or a design that identifies nothing.
    """
    from stereo_bench.vision.calibrate import DEFAULT_FLAGS, calibrate_mono

    if not configurations:
        raise ValueError("the kinematic fit needs calibration views from at least one configuration")
    object_points = np.asarray(object_points, dtype=float).reshape(-1, 3)
    views, dropped = [], []
    for c, conf in enumerate(configurations):
        for i, (left, right) in enumerate(conf.views):
            if left is None or right is None:
                dropped.append((c, i, "board not found in both cameras"))
            elif min(len(left.ids), len(right.ids)) < min_corners:
                dropped.append((c, i, f"fewer than {min_corners} corners in a camera"))
            else:
                views.append((c, np.asarray(left.ids), np.asarray(left.corners_px, float),
                              np.asarray(right.ids), np.asarray(right.corners_px, float)))
    if len(views) < 3:
        raise ValueError(f"the kinematic fit needs at least 3 views seen by both cameras, got {len(views)}")
    seen = {v[0] for v in views}
    missing = [c for c in range(len(configurations)) if c not in seen]
    if missing:
        raise ValueError(f"configurations {missing} have no view seen by both cameras: take views there or "
                         "leave them out of the design")
    groups, notes = _identifiable(configurations)
    free = np.array([spec.group in groups for spec in PARAMETERS])
    free_index = np.flatnonzero(free)
    baselines = [float(c.axes["baseline_mm"]) for c in configurations]
    B_ref = float(reference_baseline_mm if reference_baseline_mm is not None
                  else 0.5 * (min(baselines) + max(baselines)))

    if intrinsics is None:
        # A start for the adjustment, which refines them on every view: 30 views spread over the design
        # calibrate as well as 100 at a tenth of the time.
        some = views[:: max(1, len(views) // 30)]
        mono = [calibrate_mono([object_points[v[slot]] for v in some], [v[slot + 1] for v in some], image_size,
                               flags=DEFAULT_FLAGS) for slot in (1, 3)]
        intrinsics = (mono[0].K, mono[0].dist, mono[1].K, mono[1].dist)
    intr_l = _intrinsic_vector(intrinsics[0], intrinsics[1])
    intr_r = _intrinsic_vector(intrinsics[2], intrinsics[3])

    # Board poses per view, relative poses per configuration, then the kinematic start.
    K1, D1 = _K_D(intr_l)
    K2, D2 = _K_D(intr_r)
    T_lb = [_pnp(object_points[v[1]], v[2], K1, D1) for v in views]
    T_rb = [_pnp(object_points[v[3]], v[4], K2, D2) for v in views]
    per_config: list[list[np.ndarray]] = [[] for _ in configurations]
    for v, (tl, tr) in enumerate(zip(T_lb, T_rb, strict=True)):
        per_config[views[v][0]].append(tr @ np.linalg.inv(tl))
    T_rl = [_average_transform(ts) if ts else None for ts in per_config]
    p0 = _initial_parameters(free, B_ref, configurations, T_rl)

    sigmas = (repeatability_mm, repeatability_left_deg, repeatability_right_deg)
    # The pixel weight to start from: what the single-view poses leave (6 pose unknowns per view).
    squares, dof = 0.0, 0
    for v, (tl, tr) in enumerate(zip(T_lb, T_rb, strict=True)):
        for T, ids, px, (K, D) in ((tl, views[v][1], views[v][2], (K1, D1)), (tr, views[v][3], views[v][4], (K2, D2))):
            seen = cv2.projectPoints(object_points[ids].reshape(-1, 1, 3), _rvec(T[:3, :3]), T[:3, 3], K, D)[0]
            squares += float(((seen.reshape(-1, 2) - px) ** 2).sum())
            dof += 2 * len(ids) - 6
    sigma_px = max(math.sqrt(squares / max(dof, 1)), 1e-3)
    for _ in range(3):
        bundle = _Bundle(p0, free_index, B_ref, configurations, views, object_points, intr_l, intr_r,
                         refine_intrinsics, sigmas, sigma_px)
        x0 = np.concatenate([p0[free_index], np.zeros(bundle.ne),
                             np.concatenate([intr_l[:8], intr_r[:8]]) if refine_intrinsics else [],
                             np.concatenate([np.concatenate([_rvec(T[:3, :3]), T[:3, 3]]) for T in T_lb])])
        x, lin = bundle.minimise(x0)
        r = bundle.residuals(x)
        pixel = r[: bundle.m_px] * sigma_px
        dof = max(1, bundle.m_px - (x.size - bundle.ne))
        estimate = float(math.sqrt(pixel @ pixel / dof))
        converged = abs(estimate / sigma_px - 1.0) < 0.05
        # The pixel weight sets the balance against the landing priors: fit again with the sigma the
        # residuals show, until it agrees with the one assumed.
        sigma_px = estimate
        p0, _, intr_l, intr_r, poses = bundle.unpack(x)
        T_lb = [_pose_matrix(pose) for pose in poses]
        if converged:
            break
    # Whitened by the sigma_px it found, inv(J^T J) (poses marginalised) is the covariance.
    covariance = bundle.global_covariance(lin)
    p, landing, intr_l, intr_r, poses = bundle.unpack(x)
    cov_k = covariance[: bundle.nk, : bundle.nk]
    intrinsic_names: list[str] = []
    cov_i = cross = np.zeros((0, 0))
    if refine_intrinsics:
        o = bundle.nk + bundle.ne
        intrinsic_names = [f"{side}.{name}" for side in ("left", "right")
                           for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")]
        cov_i = covariance[o : o + 16, o : o + 16]
        cross = covariance[o : o + 16, : bundle.nk]
    locking = bundle.pixel_locking(x)
    sig = np.sqrt(np.clip(np.diag(cov_k), 0.0, None))
    parameters = {}
    for i, spec in enumerate(PARAMETERS):
        if free[i]:
            k = int(np.searchsorted(free_index, i))
            parameters[spec.name] = ParameterValue(value=float(p[i]), sigma=float(sig[k]), unit=spec.unit,
                                                   identifiable=True)
        else:
            parameters[spec.name] = ParameterValue(value=float(p[i]), sigma=None, unit=spec.unit, identifiable=False,
                                                   note=notes.get(spec.group, "") + " (held nominal)")
    residual = (r[: bundle.m_px] * sigma_px).reshape(-1, 2)  # view by view (u, v) pairs
    view_of_row = np.repeat(np.arange(bundle.V), [(sl.stop - sl.start) // 2 for sl in bundle.view_slices])
    per_view = np.array([math.sqrt(float((residual[view_of_row == v] ** 2).sum(axis=1).mean()))
                         for v in range(bundle.V)])
    per_config_rms = [math.sqrt(float((residual[bundle.view_config[view_of_row] == c] ** 2).sum(axis=1).mean()))
                      for c in range(len(configurations))]
    K1, D1 = _K_D(intr_l)
    K2, D2 = _K_D(intr_r)
    span = {axis: [float(min(c.axes[axis] for c in configurations)), float(max(c.axes[axis] for c in configurations))]
            for axis in AXES}
    model = KinematicModel(
        reference_baseline_mm=B_ref, repeatability_mm=repeatability_mm,
        repeatability_left_deg=repeatability_left_deg, repeatability_right_deg=repeatability_right_deg,
        span=span, parameters=parameters, covariance_names=[NAMES[i] for i in free_index],
        covariance=cov_k.tolist(), image_size=[int(image_size[0]), int(image_size[1])],
        K1=K1.tolist(), D1=D1.ravel().tolist(), K2=K2.tolist(), D2=D2.ravel().tolist(),
        fit=FitSummary(
            rms_px=float(math.sqrt((residual**2).sum(axis=1).mean())), pixel_sigma_px=sigma_px,
            n_configurations=len(configurations), n_views=bundle.V, n_observations=len(residual),
            intrinsics="refined jointly" if refine_intrinsics else "fixed",
            design=[{a: float(c.axes[a]) for a in AXES} for c in configurations],
            per_configuration_rms_px=per_config_rms, dof=int(dof),
        ),
        intrinsics_covariance_names=intrinsic_names, intrinsics_covariance=cov_i.tolist(),
        cross_covariance=cross.tolist(),
        pixel_locking_px=None if locking is None else [float(locking[0]), float(locking[1])],
    )
    return KinematicFit(model=model, T_left_board=[_pose_matrix(pose) for pose in poses], view_rms_px=per_view,
                        view_configuration=bundle.view_config.copy(), views_dropped=dropped, landing=landing)
