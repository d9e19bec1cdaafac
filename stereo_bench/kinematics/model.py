"""The kinematic rig model: its parameters, the chain that gives R and T from the axis positions, the fitted model.

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

A rig that drives a camera's tilt (issue 25: ``tilt_left_deg`` / ``tilt_right_deg`` among the model's ``axes``) has a
tilt joint after the pan, and S is then the left camera at toe-in 0 AND tilt 0::

    T_S_L = Rot(left pan axis, + k_L * t_L') @ Rot(left tilt axis, - k_tL * u_L')
    T_S_R = Trans(k_s * (B' - B_ref) * d) @ T_S_R0 @ Rot(right pan axis, - k_R * t_R')
            @ Rot(right tilt axis, - k_tR * u_R')

(u > 0 looks down, for both cameras.) Each tilt axis is given in its camera's frame at toe-in 0 and tilt 0: the
camera's x axis turned by ``*_tilt_axis_yaw_deg`` about y, then ``*_tilt_axis_roll_deg`` about z, crossing the
camera's x = 0 plane at ``*_tilt_axis_y_mm``, ``*_tilt_axis_z_mm`` (about +8 and -12 mm for a pivot below and behind
the optical centre); ``*_tilt_scale`` and ``*_tilt_backlash_deg`` as the pan's. Their parameters exist only in a
model whose axes include that tilt; a model without (every file written before tilt joints) is the chain above it.

Units: mm and deg at the interface and in the file, radians inside.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from stereo_bench.geometry import rotation_deg

AXES = ("baseline_mm", "toe_in_left_deg", "toe_in_right_deg")
#: The tilts a model may add to AXES, in this order (a rig config that maps them to an axis: grblHAL's A/B).
TILT_AXES = ("tilt_left_deg", "tilt_right_deg")
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
N_PARAMS = len(PARAMETERS)


def _tilt_specs(side: str) -> tuple[ParameterSpec, ...]:
    group = f"{side}_tilt"
    return (
        _spec(f"{side}_tilt_axis_yaw_deg", "deg", 0.0, group,
              f"{side} tilt axis: the {side} camera's x axis (at toe-in 0, tilt 0) turned about y"),
        _spec(f"{side}_tilt_axis_roll_deg", "deg", 0.0, group, f"{side} tilt axis: then turned about z"),
        _spec(f"{side}_tilt_axis_y_mm", "mm", 0.0, group,
              f"{side} tilt axis crosses the {side} camera's x = 0 plane at this y (> 0: below the optical centre)"),
        _spec(f"{side}_tilt_axis_z_mm", "mm", 0.0, group, "... and this z (negative: behind the optical centre)"),
        _spec(f"{side}_tilt_scale", "1", 1.0, group, f"{side} tilt angle per degree of commanded tilt"),
        _spec(f"{side}_tilt_backlash_deg", "deg", 0.0, f"{side}_tilt_backlash",
              f"lost motion of the {side} tilt on reversal"),
    )


#: The tilt joints' parameters: after PARAMETERS in the vector of a model whose axes include a tilt.
TILT_PARAMETERS: tuple[ParameterSpec, ...] = _tilt_specs("left") + _tilt_specs("right")
_INDEX = {spec.name: i for i, spec in enumerate(PARAMETERS + TILT_PARAMETERS)}


def model_axes(tilts=()) -> tuple[str, ...]:
    """The axes of a model of a rig that drives ``tilts`` (of TILT_AXES): AXES, then those tilts in order."""
    unknown = [t for t in tilts if t not in TILT_AXES]
    if unknown:
        raise ValueError(f"tilts: {', '.join(unknown)} not of {', '.join(TILT_AXES)}")
    return AXES + tuple(t for t in TILT_AXES if t in tilts)


def vector_specs(axes=AXES) -> tuple[ParameterSpec, ...]:
    """The parameters of the vector :func:`chain` takes for a model with ``axes``: PARAMETERS (22), and every tilt
    joint's (both cameras') when any tilt is among them; a tilt not driven keeps its joint's nominal values."""
    return PARAMETERS + TILT_PARAMETERS if any(a in TILT_AXES for a in axes) else PARAMETERS


def parameter_specs(axes=AXES) -> tuple[ParameterSpec, ...]:
    """The parameters a model with ``axes`` has (in its file, its fit): PARAMETERS and the driven tilts' joints."""
    return PARAMETERS + tuple(spec for spec in TILT_PARAMETERS if f"tilt_{spec.name.split('_')[0]}_deg" in axes)


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
    """The rotation vector (3,) rad of ``R`` (3, 3), exact down to the identity.

    cv2.Rodrigues returns 0 for every rotation under 1e-5 rad (its ``s < 1e-5`` branch), so a central
    difference of R, T at parallel cameras (toe-ins 0, R the identity) saw no rotation at all and a prediction
    there lost the rotational part of its covariance (the square's calibration term at B 60, α 90°: 27 µm
    instead of ~6). The log map from the antisymmetric part: w = sin(θ) axis, θ axis = w θ / sin θ.
    """
    R = np.asarray(R, dtype=float)
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = float(np.linalg.norm(w))
    theta = math.atan2(s, 0.5 * (float(np.trace(R)) - 1.0))
    if theta > math.pi - 1e-3:
        return cv2.Rodrigues(R)[0].reshape(3)  # near a half turn the antisymmetric part vanishes
    if theta < 1e-4:
        return w * (1.0 + theta * theta / 6.0)  # theta / sin(theta), to well below 1e-16 relative
    return w * (theta / s)


def _rvec_t(T_right_left: np.ndarray) -> np.ndarray:
    return np.concatenate([_rvec(T_right_left[:3, :3]), T_right_left[:3, 3]])


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


def _tilt_line(p: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(unit direction, point) of a tilt axis in its camera's frame (toe-in 0, tilt 0), from a tilted vector ``p``."""
    i = _INDEX[f"{side}_tilt_axis_yaw_deg"]
    yaw, roll, y, z = p[i], p[i + 1], p[i + 2], p[i + 3]
    direction = rotation_deg("y", yaw) @ rotation_deg("z", roll) @ np.array([1.0, 0.0, 0.0])
    return direction, np.array([0.0, y, z])


def _effective_tilts(axes: Mapping[str, float], approach: Mapping[str, int], p: np.ndarray) -> tuple[float, float]:
    """Commanded tilts corrected for backlash (0 for a tilt the vector ``p`` has no joint for, or ``axes`` lacks)."""
    if len(p) <= N_PARAMS:
        return 0.0, 0.0
    out = []
    for axis in TILT_AXES:
        side = axis.split("_")[1]
        value = float(axes.get(axis, 0.0))
        backlash = p[_INDEX[f"{side}_tilt_backlash_deg"]]
        out.append(value - approach.get(axis, 0) * backlash / 2.0 if axis in axes else 0.0)
    return out[0], out[1]


def _effective(axes: Mapping[str, float], approach: Mapping[str, int], p: np.ndarray) -> tuple[float, float, float]:
    """Commanded values corrected for backlash by the direction of approach (the tilts: :func:`_effective_tilts`)."""
    b = axes["baseline_mm"] - approach.get("baseline_mm", 0) * p[_INDEX["slide_backlash_mm"]] / 2.0
    tl = axes["toe_in_left_deg"] - approach.get("toe_in_left_deg", 0) * p[_INDEX["left_backlash_deg"]] / 2.0
    tr = axes["toe_in_right_deg"] - approach.get("toe_in_right_deg", 0) * p[_INDEX["right_backlash_deg"]] / 2.0
    return b, tl, tr


def _tilt_joint(p: np.ndarray, side: str, tilt_deg: float) -> np.ndarray:
    """4x4 turn of a camera's tilt joint by the effective ``tilt_deg`` (> 0 looks down: about -x)."""
    direction, point = _tilt_line(p, side)
    return _about_line(direction, point, -math.radians(p[_INDEX[f"{side}_tilt_scale"]] * tilt_deg))


def chain(p: np.ndarray, reference_baseline_mm: float, baseline_mm: float, toe_in_left_deg: float,
          toe_in_right_deg: float, tilt_left_deg: float = 0.0, tilt_right_deg: float = 0.0) -> np.ndarray:
    """T_right_left (4x4, mm) of the model with parameters ``p`` at effective axis values.

    ``p``: (N_PARAMS,), or with the tilt joints (``len(vector_specs(axes))``), which turn by the effective tilts.
    Effective values are already corrected for backlash (see :func:`_effective`, :func:`_effective_tilts`).
    """
    p = np.asarray(p, dtype=float)
    left_dir, left_point = _pan_line(p, "left")
    right_dir, right_point = _pan_line(p, "right")
    T_S_L = _about_line(left_dir, left_point, math.radians(p[_INDEX["left_angle_scale"]] * toe_in_left_deg))
    T_R0_R = _about_line(right_dir, right_point, -math.radians(p[_INDEX["right_angle_scale"]] * toe_in_right_deg))
    if len(p) > N_PARAMS:
        T_S_L = T_S_L @ _tilt_joint(p, "left", tilt_left_deg)
        T_R0_R = T_R0_R @ _tilt_joint(p, "right", tilt_right_deg)
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


def nominal_parameters(reference_baseline_mm: float, axes=AXES) -> np.ndarray:
    """Parameters of the ideal rig: pan (and tilt) about the optical centres, vertical axes, every scale exact;
    the vector of a model with ``axes`` (:func:`vector_specs`)."""
    p = np.array([spec.nominal for spec in vector_specs(axes)])
    p[_INDEX["right_x_mm"]] = reference_baseline_mm
    return p


# --------------------------------------------------------------------------------------------------
# The model


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


class ResidualMapRecord(BaseModel):
    """One camera's fit residuals binned over the image (:class:`stereo_bench.vision.covariance.ResidualMap`):
    ``bins`` (nx, ny); ``count`` (ny * nx) corners per bin, ``mean_px`` and ``sumsq_px2`` (ny * nx * 2) their
    mean residual (projected - observed) and sum of squares per coordinate, row-major."""

    model_config = ConfigDict(extra="forbid", strict=True)

    image_size: list[int]
    bins: list[int]
    count: list[float]
    mean_px: list[float]
    sumsq_px2: list[float]

    @classmethod
    def of(cls, observed_px: np.ndarray, residual_px: np.ndarray, image_size) -> ResidualMapRecord:
        """From one camera's observed pixels and residuals (projected - observed), (N, 2) or interleaved."""
        from stereo_bench.vision.covariance import ResidualMap

        size = (int(image_size[0]), int(image_size[1]))
        m = ResidualMap.of(observed_px, residual_px, size)
        ny, nx = m.count.shape
        return cls(image_size=list(size), bins=[nx, ny], count=[float(v) for v in m.count.ravel()],
                   mean_px=[float(v) for v in m.mean.ravel()], sumsq_px2=[float(v) for v in m.sumsq.ravel()])

    @model_validator(mode="after")
    def _shapes(self) -> ResidualMapRecord:
        if len(self.bins) != 2 or min(self.bins) < 1 or len(self.image_size) != 2:
            raise ValueError("bins and image_size must each be two positive integers")
        n = self.bins[0] * self.bins[1]
        if len(self.count) != n or len(self.mean_px) != 2 * n or len(self.sumsq_px2) != 2 * n:
            raise ValueError(f"count must hold {n} values and mean_px, sumsq_px2 {2 * n} (bins {self.bins})")
        return self


class KinematicModel(BaseModel):
    """A fitted kinematic rig model: every parameter with its standard deviation, and their covariance."""

    model_config = ConfigDict(extra="forbid", strict=True)

    schema_id: str = Field(FILE_SCHEMA, alias="schema")
    # The axes the chain takes: AXES, then the tilts the rig drives (TILT_AXES). Absent (every file written before
    # tilt joints): AXES.
    axes: list[str] = Field(default_factory=lambda: list(AXES))
    reference_baseline_mm: float = Field(allow_inf_nan=False)
    repeatability_mm: float = Field(0.0, ge=0, description="std of the slide's landing error per move")
    repeatability_left_deg: float = Field(0.0, ge=0, description="std of the left head's landing error per move")
    repeatability_right_deg: float = Field(0.0, ge=0, description="std of the right head's landing error per move")
    repeatability_tilt_left_deg: float = Field(0.0, ge=0, description="std of the left tilt's landing error per move")
    repeatability_tilt_right_deg: float = Field(0.0, ge=0, description="std of the right tilt's landing error per "
                                                                        "move")
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
    # Per camera the fit's residuals binned over the image: where the model misses the corners, so that the
    # budget treats the corner error beyond noise as a per-config calibration's (the smooth part from the map,
    # the rest independent from corner to corner). Empty: a file written before it was saved.
    residual_maps: dict[str, ResidualMapRecord] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _check(self) -> KinematicModel:
        if tuple(self.axes[:3]) != AXES or [a for a in self.axes[3:] if a in TILT_AXES] != [
                a for a in TILT_AXES if a in self.axes[3:]] or any(a not in TILT_AXES for a in self.axes[3:]):
            raise ValueError(f"axes: {', '.join(AXES)}, then any of {', '.join(TILT_AXES)} in that order")
        names = {spec.name for spec in parameter_specs(self.axes)}
        missing = [spec.name for spec in parameter_specs(self.axes) if spec.name not in self.parameters]
        if missing:
            raise ValueError(f"parameters: missing {', '.join(missing)}")
        unknown = [n for n in self.parameters if n not in names]
        if unknown:
            raise ValueError(f"parameters: unknown {', '.join(unknown)}" + (
                " (a tilt joint's: the model's axes do not include that tilt)" if any(n in _INDEX for n in unknown)
                else ""))
        n = len(self.covariance_names)
        if any(name not in names for name in self.covariance_names):
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
        """The parameter vector :func:`chain` takes (:func:`vector_specs`; a tilt not driven at its nominal)."""
        return np.array([self.parameters[spec.name].value if spec.name in self.parameters else spec.nominal
                         for spec in vector_specs(self.axes)])

    @property
    def specs(self) -> tuple[ParameterSpec, ...]:
        """The model's parameters, in file order (:func:`parameter_specs`)."""
        return parameter_specs(self.axes)

    @property
    def tilts(self) -> tuple[str, ...]:
        """The tilts the model's rig drives (of TILT_AXES)."""
        return tuple(a for a in self.axes if a in TILT_AXES)

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

    def residual_map_objects(self) -> dict | None:
        """``residual_maps`` as :class:`stereo_bench.vision.covariance.ResidualMap` per camera; None when empty."""
        if not self.residual_maps:
            return None
        from stereo_bench.vision.covariance import ResidualMap

        out = {}
        for side, record in self.residual_maps.items():
            nx, ny = record.bins
            out[side] = ResidualMap((int(record.image_size[0]), int(record.image_size[1])),
                                    np.asarray(record.count, float).reshape(ny, nx),
                                    np.asarray(record.mean_px, float).reshape(ny, nx, 2),
                                    np.asarray(record.sumsq_px2, float).reshape(ny, nx, 2))
        return out

    def intrinsics_covariance_matrix(self) -> np.ndarray | None:
        """(P, P) covariance of ``intrinsics_covariance_names``; None when the file has none."""
        if not self.intrinsics_covariance_names:
            return None
        m = len(self.intrinsics_covariance_names)
        return np.asarray(self.intrinsics_covariance, dtype=float).reshape(m, m)

