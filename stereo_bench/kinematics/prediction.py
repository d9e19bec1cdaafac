"""Prediction from the kinematic model: R, T and their uncertainty at any axis positions.

:func:`predict` gives R, T at any axis positions with the covariance of (rvec, T) (rad, mm)
propagated from the parameters' covariance, the repeatability and (approach unknown) the backlash.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from stereo_bench.geometry import stereo_structure
from stereo_bench.kinematics.model import (
    _INDEX,
    KinematicModel,
    _effective,
    _effective_tilts,
    _rvec,
    _rvec_t,
    chain,
    vector_specs,
)


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
    """R, T of the pair at axis positions ``axes`` (``baseline_mm``, ``toe_in_left_deg``, ``toe_in_right_deg``; and
    the reported tilts a model with tilt joints has among its ``axes``).

    ``approach``: per axis the direction of the move that reached it (+1 increased, -1 decreased, 0 or
    missing: unknown). With an unknown direction the prediction sits midway and the backlash adds
    (b / 2)^2 to the variance. The covariance also holds the parameters' covariance and the rig's
    landing repeatability.
    """
    model_axes = tuple(model.axes)
    missing = [a for a in model_axes if a not in axes]
    if missing:
        raise ValueError(f"axes: missing {', '.join(missing)}")
    approach = dict(approach or {})
    p = model.vector
    B_ref = model.reference_baseline_mm
    tilted = len(model_axes) > 3
    specs = vector_specs(model_axes)

    def at(params: np.ndarray, values: Sequence[float]) -> np.ndarray:
        return _rvec_t(chain(params, B_ref, *values))

    def effective_of(params: np.ndarray) -> np.ndarray:
        values = _effective(axes, approach, params)
        if tilted:
            return np.array([*values, *_effective_tilts({a: axes[a] for a in model_axes}, approach, params)])
        return np.array(values)

    effective = effective_of(p)
    x = at(p, effective)
    # Parameters' covariance, by central differences.
    free = model.free
    J = np.zeros((6, len(free)))
    for k, name in enumerate(free):
        i = _INDEX[name]
        h = 1e-4 * max(1.0, abs(p[i])) if specs[i].unit != "1" else 1e-6
        up, down = p.copy(), p.copy()
        up[i] += h
        down[i] -= h
        J[:, k] = (at(up, effective_of(up)) - at(down, effective_of(down))) / (2 * h)
    parameter_part = J @ model.covariance_matrix() @ J.T if free else np.zeros((6, 6))
    # Landing repeatability and unknown backlash, through the axes (the chain's: both tilts once it has joints,
    # a tilt the model's rig does not drive with no variance).
    n_axes = len(effective)
    J_axes = np.zeros((6, n_axes))
    for k in range(n_axes):
        step = np.zeros(n_axes)
        step[k] = 1e-4
        J_axes[:, k] = (at(p, effective + step) - at(p, effective - step)) / 2e-4
    repeatability = [model.repeatability_mm, model.repeatability_left_deg, model.repeatability_right_deg]
    backlash_names = ["slide_backlash_mm", "left_backlash_deg", "right_backlash_deg"]
    chain_axes = list(model.axes[:3])
    if tilted:
        for axis, sigma in (("tilt_left_deg", model.repeatability_tilt_left_deg),
                            ("tilt_right_deg", model.repeatability_tilt_right_deg)):
            driven = axis in model_axes
            repeatability.append(sigma if driven else 0.0)
            backlash_names.append(f"{axis.split('_')[1]}_tilt_backlash_deg")
            chain_axes.append(axis if driven else "")
    variances = np.array(repeatability) ** 2
    backlash = p[[_INDEX[name] for name in backlash_names]]
    unknown = np.array([bool(axis) and approach.get(axis, 0) == 0 for axis in chain_axes])
    variances = variances + np.where(unknown, (backlash / 2.0) ** 2, 0.0)
    rig_part = J_axes @ np.diag(variances) @ J_axes.T
    covariance = parameter_part + rig_part
    R = cv2.Rodrigues(x[:3])[0]
    extrapolated = [a for a in model_axes if not (model.span[a][0] - 1e-6 <= float(axes[a]) <= model.span[a][1] + 1e-6)]
    return Prediction(R=R, T=x[3:].copy(), rvec=x[:3].copy(), covariance=covariance,
                      structure=stereo_structure(R, x[3:]),
                      structure_sigma=structure_sigma(R, x[3:], covariance),
                      extrapolated=extrapolated, parameter_jacobian=J, rig_covariance=rig_part)


def joint_covariance(model: KinematicModel, prediction: Prediction) -> tuple[np.ndarray, np.ndarray] | None:
    """The fit's joint covariance of the intrinsics and the R, T ``prediction`` gives: ((P + 6, P + 6) matrix over
    the model's ``intrinsics_covariance_names`` then (rvec [rad], T [mm]), the (P, 6) cross block); None when the
    model file holds no intrinsics or cross covariance (an older file).

    The design's one fit estimated the intrinsics and the kinematic parameters together, and their errors are
    correlated (a focal length against the right camera's position): through a measurement they partly cancel,
    as a per-configuration calibration's intrinsics and R, T do. The rig's own part (landing repeatability,
    unknown backlash) is not in it: ``prediction.rig_covariance``.
    """
    C_i = model.intrinsics_covariance_matrix()
    cross = model.cross_covariance_matrix()
    J = prediction.parameter_jacobian
    if C_i is None or cross is None or J is None:
        return None
    C_x = J @ model.covariance_matrix() @ J.T
    C_ix = cross @ J.T
    return np.block([[C_i, C_ix], [C_ix.T, C_x]]), C_ix
