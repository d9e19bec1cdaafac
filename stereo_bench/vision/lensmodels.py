"""Lens models a stereo calibration can fit, and the rule that picks one from held-out views.

Every model is a set of OpenCV calibration flags over OpenCV's distortion vector ``(k1 k2 p1 p2 k3 [k4 k5 k6
[s1 s2 s3 s4]])``, so every model's coefficients go through ``cv2.undistortPoints``, ``stereoRectify``,
``initUndistortRectifyMap`` and ``projectPoints`` unchanged (rectify, triangulate, covariance and the
uncertainty's parameter perturbation need nothing per model). Names (``calibrate --lens-model``):

- ``fixed-aspect``: k1 k2 p1 p2, fx = fy (square pixels);
- ``opencv4``: k1 k2 p1 p2, fx and fy free (the project's model before lens models were chosen);
- ``opencv5``: + k3;
- ``rational``: k1..k6 p1 p2 (OpenCV's rational model, the numerator's k3 and the denominator);
- ``thin-prism``: k1 k2 p1 p2 + s1..s4 (a tilted or decentred element).

Fisheye (``cv2.fisheye``, an equidistant angle polynomial) is not a candidate: its four coefficients mean
something else than the first four of OpenCV's vector, so every file consumer (OpenCV's stereo_calib sample
included) would read them as k1 k2 p1 p2 and rectify wrongly without a word, and it needs its own undistort,
rectify, projection Jacobian (covariance) and perturbation paths. The rational model follows lenses up to
about :data:`FISHEYE_DIAGONAL_FOV_DEG` of diagonal field of view; :func:`diagonal_fov_deg` is reported with
the choice so that a wider lens is noticed (see docs/CALIBRATION.md).

Held-out comparison (:func:`held_out`): a linearised leave-one-view-out of the stereo fit. With the poses
projected out, each view's residuals r_v (px) and Jacobian Jhat_v give the normal matrix S = sum Jhat^T Jhat
and gradient g = sum Jhat^T r; without view v the solution moves by delta_v = -(S - S_v)^-1 (g - g_v), and
view v's held-out residual is r_v + Jhat_v delta_v (its own pose re-fitted), its held-out square the mean
adjacent-corner length triangulated with the moved calibration. One Jacobian per model instead of N refits.

Choice rule (:func:`choose`): models are ordered simplest first (fewest free parameters); a richer model
replaces the current choice only when its held-out mean squared reprojection error is lower by more than
:data:`CHOICE_Z` standard errors of the paired per-view difference (the noise of the comparison: the
complexity penalty), and its held-out square error is not worse by more than as many standard errors. The
reprojection comparison is of log(per-view MSE) (views differ by factors, and one poor view would otherwise set
the noise alone); the square's of per-view squared errors (mm^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from stereo_bench.vision.covariance import (
    CovarianceUnavailable,
    _solve,
    _stereo_views,
    free_intrinsics,
)

#: Standard errors a richer model must gain on held-out views (and may not lose on the square) to be chosen.
CHOICE_Z = 2.0
#: Diagonal field of view (deg) beyond which a fisheye model would be called for (rational models stop
#: following such lenses near the image corners). Reported, not acted on: fisheye is not a candidate.
FISHEYE_DIAGONAL_FOV_DEG = 120.0
#: A held-out estimate is refused (the model dropped from the comparison) when a view's leverage makes
#: (S - S_v) singular: its condition number above this.
MAX_CONDITION = 1e14

#: Fraction of the leave-one-out step the square's directional derivative is taken over (central differences).
SQUARE_STEP = 0.01

_NOT_RATIONAL = cv2.CALIB_FIX_K4 | cv2.CALIB_FIX_K5 | cv2.CALIB_FIX_K6


@dataclass(frozen=True)
class LensModel:
    name: str
    flags: int  # OpenCV calibration flags (mono and stereo)
    description: str
    square_pixels: bool = False  # fx = fy (CALIB_FIX_ASPECT_RATIO from an initial ratio of 1)

    def n_free(self, n_dist: int) -> int:
        """Free intrinsics per camera (fx = fy counts once)."""
        try:
            names = free_intrinsics(self.flags & ~cv2.CALIB_FIX_ASPECT_RATIO, n_dist)
        except CovarianceUnavailable:
            return 99
        return len(names) - (1 if self.square_pixels else 0)


MODELS: dict[str, LensModel] = {m.name: m for m in (
    LensModel("fixed-aspect", cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_ASPECT_RATIO, "k1 k2 p1 p2, fx = fy", True),
    LensModel("opencv4", cv2.CALIB_FIX_K3, "k1 k2 p1 p2"),
    LensModel("opencv5", 0, "k1 k2 p1 p2 k3"),
    LensModel("thin-prism", cv2.CALIB_FIX_K3 | _NOT_RATIONAL | cv2.CALIB_THIN_PRISM_MODEL, "k1 k2 p1 p2 s1-s4"),
    LensModel("rational", cv2.CALIB_RATIONAL_MODEL, "k1-k6 p1 p2"),
)}
#: The model of every calibration before lens models were chosen (and of given intrinsics' fits).
DEFAULT_MODEL = "opencv4"
AUTO = "auto"
CHOICES = (AUTO, *MODELS)


def lens_model(name: str) -> LensModel:
    if name not in MODELS:
        raise ValueError(f"unknown lens model {name!r}: one of {', '.join(CHOICES)}")
    return MODELS[name]


def diagonal_fov_deg(K: np.ndarray, image_size: tuple[int, int]) -> float:
    """The pinhole diagonal field of view (deg) of intrinsics ``K`` (3, 3) px over ``image_size`` (w, h) px."""
    width, height = image_size
    K = np.asarray(K, float)
    corners = np.array([[0, 0], [width, height], [width, 0], [0, height]], float)
    rays = (corners - K[:2, 2]) / [K[0, 0], K[1, 1]]
    angles = np.arctan(np.linalg.norm(rays, axis=1))
    return float(np.degrees(angles[0] + angles[1]))


@dataclass(frozen=True)
class HeldOut:
    """One model's linearised leave-one-view-out result: per view held-out RMS reprojection (px per corner, both
    cameras: sqrt of the mean squared 2-D residual, as OpenCV's RMS) and square error (mm: the view's mean
    triangulated adjacent-corner length minus the board's)."""

    model: str
    n_free: int  # free intrinsics per camera
    fit_rms_px: float
    reprojection_px: np.ndarray  # (n_views,)
    square_error_mm: np.ndarray  # (n_views,)
    note: str = ""

    @property
    def reprojection_rms_px(self) -> float:
        return float(np.sqrt(np.mean(self.reprojection_px**2))) if self.reprojection_px.size else math.nan

    @property
    def square_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.square_error_mm**2))) if self.square_error_mm.size else math.nan

    def as_dict(self) -> dict:
        return {"model": self.model, "free_intrinsics_per_camera": self.n_free, "fit_rms_px": self.fit_rms_px,
                "held_out_rms_px": self.reprojection_rms_px, "held_out_square_rms_mm": self.square_rms_mm,
                "note": self.note}


#: Where each name of :func:`_apply` lives: K's entry or the distortion vector's index.
_K_ENTRY = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
_D_INDEX = {name: i for i, name in enumerate(("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4",
                                               "tx", "ty"))}


def _apply(names: tuple[str, ...], delta: np.ndarray, K: np.ndarray, D: np.ndarray,
           square_pixels: bool) -> tuple[np.ndarray, np.ndarray]:
    K, D = K.copy(), D.copy().reshape(-1)
    for name, d in zip(names, delta, strict=True):
        if name == "f":  # fx = a fy with a held
            ratio = square_pixels_ratio(K)
            K[1, 1] += d
            K[0, 0] = K[1, 1] * ratio
        elif name in _K_ENTRY:
            K[_K_ENTRY[name]] += d
        else:
            D[_D_INDEX[name]] += d
    return K, D.reshape(1, -1)


def square_pixels_ratio(K: np.ndarray) -> float:
    return float(K[0, 0] / K[1, 1])


def adjacency(object_points) -> dict:
    """Per view (keyed by the array's id) its adjacent corner pairs, for :func:`held_out` of several models."""
    return {id(obj): _adjacent(obj) for obj in object_points}


def _adjacent(object_points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, b, length) of the board's horizontally and vertically adjacent corner pairs among ``object_points``."""
    obj = np.asarray(object_points, float).reshape(-1, 3)
    distance = np.linalg.norm(obj[:, None] - obj[None], axis=2)
    square = np.min(distance[distance > 0])
    a, b = np.nonzero(np.triu(np.abs(distance - square) < 1e-6 * square, 1))
    return a, b, distance[a, b]


#: Undistortion to 1e-10 (OpenCV's default 5 iterations leave ~0.01 px at a distorted image's edge), as
#: stereo_bench.vision.rectify.undistort_points, which this module cannot import (it imports calibrate).
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
_P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
_EYE3 = np.eye(3)
_EYE3.flags.writeable = False
_UNDISTORT_ITER = hasattr(cv2, "undistortPointsIter")  # OpenCV 4.x: the criteria overload lives there


def _normalised(points_px: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    src = np.asarray(points_px, np.float64).reshape(-1, 1, 2)
    if _UNDISTORT_ITER:
        out = cv2.undistortPointsIter(src, K, D, _EYE3, None, _UNDISTORT_CRITERIA)
    else:
        out = cv2.undistortPoints(src, K, D, R=_EYE3, P=None, criteria=_UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def _square_error_mm(K1, D1, K2, D2, R, T, left, right, a, b, length) -> float:
    P2 = np.hstack([R, np.asarray(T, float).reshape(3, 1)])
    homogeneous = cv2.triangulatePoints(_P1, P2, _normalised(left, K1, D1).T.copy(),
                                        _normalised(right, K2, D2).T.copy())
    points = (homogeneous[:3] / homogeneous[3]).T
    return float(np.mean(np.linalg.norm(points[a] - points[b], axis=1) - length))


def _unmoved_square_errors_mm(K1, D1, K2, D2, R, T, object_points, left_points, right_points,
                              adjacency: dict | None) -> list[float]:
    """Per view :func:`_square_error_mm` of the calibration as it is, the views' corners in one call per camera."""
    lefts = [np.asarray(p, float).reshape(-1, 2) for p in left_points]
    rights = [np.asarray(p, float).reshape(-1, 2) for p in right_points]
    P2 = np.hstack([R, np.asarray(T, float).reshape(3, 1)])
    homogeneous = cv2.triangulatePoints(_P1, P2, _normalised(np.vstack(lefts), K1, D1).T.copy(),
                                        _normalised(np.vstack(rights), K2, D2).T.copy())
    points = (homogeneous[:3] / homogeneous[3]).T
    out, start = [], 0
    for obj, left in zip(object_points, lefts, strict=True):
        a, b, length = adjacency[id(obj)] if adjacency and id(obj) in adjacency else _adjacent(obj)
        view = points[start:start + len(left)]
        out.append(float(np.mean(np.linalg.norm(view[a] - view[b], axis=1) - length)))
        start += len(left)
    return out


def _moved_square_mm(delta, names_l, names_r, square_pixels, K1, D1, K2, D2, rvec0, T, left, right, a, b,
                     length) -> float:
    """A view's square error (mm) with the stereo parameters moved by ``delta`` (left, right intrinsics, rvec, T)."""
    nl = len(names_l)
    K1v, D1v = _apply(tuple(names_l), delta[:nl], K1, D1, square_pixels)
    K2v, D2v = _apply(tuple(names_r), delta[nl:2 * nl], K2, D2, square_pixels)
    Rv = cv2.Rodrigues(rvec0 + delta[2 * nl:2 * nl + 3])[0]
    return _square_error_mm(K1v, D1v, K2v, D2v, Rv, T + delta[2 * nl + 3:], left, right, a, b, length)


def held_out(model: LensModel, object_points, left_points, right_points, K1, D1, K2, D2, R, T, rvecs, tvecs,
             fit_rms_px: float, adjacency: dict | None = None) -> HeldOut:
    """Linearised leave-one-view-out of a joint stereo fit (module docstring); per view (N_i, 3) mm and
    (N_i, 2) px, the fit's K (3, 3), D (1, k), R (3, 3), T (3,) mm and per view left poses (rad, mm).
    ``adjacency``: :func:`adjacency` of these object points, when the caller compares several models."""
    n_dist = np.asarray(D1).size
    free = free_intrinsics(model.flags & ~cv2.CALIB_FIX_ASPECT_RATIO, n_dist)
    views = _stereo_views(object_points, left_points, right_points, K1, D1, K2, D2, R, T, rvecs, tvecs, free, free)
    n = len(free)
    names_l, names_r = list(free), list(free)
    if model.square_pixels:  # fx = a fy: one column a J_fx + J_fy, named "f"
        ratio_l, ratio_r = square_pixels_ratio(K1), square_pixels_ratio(K2)
        keep = [i for i in range(2 * n + 6) if i not in (0, n)]
        for view in views:
            J = view.J_global
            J[:, 1] = ratio_l * J[:, 0] + J[:, 1]
            J[:, n + 1] = ratio_r * J[:, n] + J[:, n + 1]
        views = [replace(view, J_global=view.J_global[:, keep]) for view in views]
        names_l, names_r = ["f", *free[2:]], ["f", *free[2:]]
    solution = _solve(views, locking=False, jhat=True)
    S = np.linalg.inv(solution.S_inv)
    grads = [Jh.T @ v.residual for Jh, v in zip(solution.Jhat, views, strict=True)]
    g = np.sum(grads, axis=0)
    scale = np.sqrt(np.diag(S))
    reprojection, square = [], []
    note = ""
    rvec0 = cv2.Rodrigues(np.asarray(R, np.float64))[0].reshape(3)
    T = np.asarray(T, float).reshape(3)
    K1, D1, K2, D2 = (np.asarray(x, float) for x in (K1, D1, K2, D2))
    # Every view's square with the fit unmoved (delta = 0), all corners in one undistortion and triangulation per
    # camera: both work point by point, so each view's points are the bits of its own call.
    # (The intrinsics as _moved_square_mm makes them of a zero step: fx = a fy recomputes fx.)
    zero = np.zeros(len(names_l))
    K1z, D1z = _apply(tuple(names_l), zero, K1, D1, model.square_pixels)
    K2z, D2z = _apply(tuple(names_r), zero, K2, D2, model.square_pixels)
    unmoved = _unmoved_square_errors_mm(K1z, D1z, K2z, D2z, cv2.Rodrigues(rvec0)[0], T, object_points, left_points,
                                        right_points, adjacency)
    for view, Jh, g_v, obj, left, right, at_zero in zip(views, solution.Jhat, grads, object_points, left_points,
                                                        right_points, unmoved, strict=True):
        S_minus = (S - Jh.T @ Jh) / scale / scale[:, None]  # unit diagonal: px, unitless and rad alike
        if np.linalg.cond(S_minus) > MAX_CONDITION:
            note = "a view's removal leaves the parameters undetermined"
            reprojection.append(math.nan)
            square.append(math.nan)
            continue
        delta = -np.linalg.solve(S_minus, (g - g_v) / scale) / scale
        moved = view.residual + Jh @ delta
        reprojection.append(float(np.sqrt(2.0 * np.mean(moved**2))))  # per corner, as OpenCV's RMS
        a, b, length = adjacency[id(obj)] if adjacency and id(obj) in adjacency else _adjacent(obj)
        left, right = np.asarray(left, float).reshape(-1, 2), np.asarray(right, float).reshape(-1, 2)

        # Linear in delta like the residual: along a direction the views barely determine (the rational model's
        # numerator against its denominator) delta is large and the lens moved by all of it is another lens.
        at = [_moved_square_mm(step * delta, names_l, names_r, model.square_pixels, K1, D1, K2, D2, rvec0, T, left,
                               right, a, b, length) for step in (SQUARE_STEP, -SQUARE_STEP)]
        square.append(at_zero + (at[0] - at[1]) / (2 * SQUARE_STEP))
    return HeldOut(model.name, model.n_free(n_dist), float(fit_rms_px), np.array(reprojection), np.array(square),
                   note)


@dataclass(frozen=True)
class Choice:
    chosen: str
    requested: str  # "auto" or the model's name
    comparison: tuple[HeldOut, ...]
    reason: str
    diagonal_fov_deg: float = math.nan

    def as_dict(self) -> dict:
        return {"chosen": self.chosen, "requested": self.requested, "reason": self.reason,
                "choice_z": CHOICE_Z, "diagonal_fov_deg": self.diagonal_fov_deg,
                "comparison": [h.as_dict() for h in self.comparison]}

    def table(self) -> str:
        """The comparison as text lines (one per model, the chosen one marked)."""
        lines = ["lens model     free  fit RMS px  held-out RMS px  held-out square RMS mm"]
        for h in self.comparison:
            mark = "*" if h.model == self.chosen else " "
            lines.append(f"{mark}{h.model:13s} {h.n_free:5d}  {h.fit_rms_px:10.4f}  {h.reprojection_rms_px:15.4f}  "
                         f"{h.square_rms_mm:22.4f}" + (f"  ({h.note})" if h.note else ""))
        return "\n".join(lines)


def _paired(worse: np.ndarray, better: np.ndarray) -> tuple[float, float]:
    """(mean, standard error) of worse - better over the views both have."""
    ok = np.isfinite(worse) & np.isfinite(better)
    d = worse[ok] - better[ok]
    if d.size < 2:
        return 0.0, math.inf
    return float(d.mean()), float(d.std(ddof=1) / math.sqrt(d.size))


def choose(results: list[HeldOut]) -> tuple[str, str]:
    """(chosen model name, reason) by the rule of the module docstring; ``results`` in any order."""
    usable = [r for r in results if np.all(np.isfinite(r.reprojection_px)) and r.reprojection_px.size >= 2]
    if not usable:
        return results[0].model, "no model has a held-out estimate: the first candidate kept"
    ordered = sorted(usable, key=lambda r: r.n_free)
    current = ordered[0]
    reason = f"{current.model}: the simplest candidate"
    for richer in ordered[1:]:
        # Per view the log of the held-out MSE ratio: views differ in their errors by factors (distance, tilt),
        # and one poor view would otherwise decide the comparison's noise alone.
        gain, se = _paired(np.log(current.reprojection_px**2), np.log(richer.reprojection_px**2))
        loss, se_sq = _paired(richer.square_error_mm**2, current.square_error_mm**2)
        if gain > CHOICE_Z * se and not loss > CHOICE_Z * se_sq:
            reason = (f"{richer.model} over {current.model}: held-out MSE lower by a factor {math.exp(gain):.3g} "
                      f"(log ratio {gain:.3g} > {CHOICE_Z:g} x {se:.2g})")
            current = richer
    return current.model, reason
