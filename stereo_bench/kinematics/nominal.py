"""The nominal rig: the ideal geometry and the covariance its stated as-built tolerances give.

:func:`nominal_extrinsics` is the ideal geometry a user who trusts the rig's scales gets;
:func:`nominal_covariance` propagates the tolerances of :data:`TOLERANCE_NAMES` to it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from stereo_bench.geometry import RigPose, rotation_deg
from stereo_bench.kinematics.model import _axis_angle, _rvec_t


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
