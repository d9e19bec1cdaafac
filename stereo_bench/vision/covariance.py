"""Covariance of calibrated camera parameters from the Jacobian of the reprojection residuals.

The idea is mrcal's (doc/uncertainty.org): at the least-squares optimum a perturbation ``dq`` of the
observed corners moves the parameters by ``dp = (J^T J)^-1 J^T dq``; with independent corner noise
of standard deviation sigma per image coordinate, ``Var(p) = sigma^2 (J^T J)^-1``. ``J`` covers every
parameter the solver moved, the per-view board poses included: a calibration's intrinsics and R, T
are only as good as the poses they were solved together with.

The board poses are nuisance parameters. ``J^T J`` has the block form [[A, B], [B^T, C]] with C
block-diagonal (6 x 6 per view: a pose touches only its own view's residuals), so the covariance of
the wanted parameters is ``sigma^2 S^-1`` with the Schur complement ``S = A - sum_v B_v C_v^-1 B_v^T``:
an inverse the size of the wanted parameters, whatever the number of views. Equivalently
``S = Jhat^T Jhat`` with ``Jhat_v = J_a,v - J_pose,v C_v^-1 B_v^T`` (the Jacobian with each view's
pose projected out); ``Jhat`` gives the influence of each observation on the parameters,
``dp_a = S^-1 Jhat^T dq``, which is what an estimate that depends on another estimate from the same
data (fixed intrinsics from mono calibrations of the same views) needs.

sigma is the residual standard deviation of the fit: ``sigma^2 = SSR / (n_coordinates - n_parameters)``
(a Type A evaluation; the corner noise plus whatever the lens model cannot fit). The residuals also
show the corner detector's pixel locking, an error periodic in each coordinate's sub-pixel phase
phi = frac(p): regressed on sin(2 pi phi) and cos(2 pi phi) (both axes, both cameras, every view)
they give its first harmonic (:attr:`CalibrationCovariance.pixel_locking_px`), which a measurement
of a static target does not average away (see :mod:`stereo_bench.vision.uncertainty`). The Jacobian
is exact: ``cv2.projectPoints`` returns d(pixels)/d(rvec, tvec, fx, fy, cx, cy, dist) and
``cv2.composeRT`` the chain rule through X_right = R X_left + T.

Parameters (names in :attr:`CalibrationCovariance.names`): per camera ``fx fy cx cy`` (px) and the
distortion coefficients the solver estimated (``k1 k2 p1 p2 k3 ...``, unitless), prefixed ``left.``
/ ``right.`` for a stereo pair; ``rvec.x rvec.y rvec.z`` (rad, the rotation vector of R) and
``T.x T.y T.z`` (mm). Parameters held fixed by the flags are not listed: their values are exact by
construction of the model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")
FOCAL_CENTRE_NAMES = ("fx", "fy", "cx", "cy")
EXTRINSIC_NAMES = ("rvec.x", "rvec.y", "rvec.z", "T.x", "T.y", "T.z")
#: Column of each intrinsic in cv2.projectPoints' jacobian (after rvec 0-2 and tvec 3-5).
_COLUMN = {"fx": 6, "fy": 7, "cx": 8, "cy": 9, **{name: 10 + i for i, name in enumerate(DIST_NAMES)}}
_FIXED_BY_FLAG = {
    "CALIB_FIX_K1": ("k1",), "CALIB_FIX_K2": ("k2",), "CALIB_FIX_K3": ("k3",), "CALIB_FIX_K4": ("k4",),
    "CALIB_FIX_K5": ("k5",), "CALIB_FIX_K6": ("k6",), "CALIB_ZERO_TANGENT_DIST": ("p1", "p2"),
    "CALIB_FIX_TANGENT_DIST": ("p1", "p2"), "CALIB_FIX_PRINCIPAL_POINT": ("cx", "cy"),
    "CALIB_FIX_FOCAL_LENGTH": ("fx", "fy"), "CALIB_FIX_S1_S2_S3_S4": ("s1", "s2", "s3", "s4"),
    "CALIB_FIX_TAUX_TAUY": ("tx", "ty"),
}
# Flags that tie parameters together (fx = a * fy, fx_left = fx_right): the free parameters are then
# not a subset of the coefficients, and this module does not model them.
_COUPLING_FLAGS = ("CALIB_FIX_ASPECT_RATIO", "CALIB_SAME_FOCAL_LENGTH")


#: Bins of the residual map over the image (columns, rows): ~120 px squares at 1080p, so a bin holds
#: tens of a 12-view calibration's corners where the boards went.
RESIDUAL_MAP_BINS = (16, 9)


@dataclass(frozen=True, eq=False)
class ResidualMap:
    """One camera's calibration residuals binned by image position: where the model misses the corners.

    ``count`` (ny, nx) corners per bin, ``mean`` (ny, nx, 2) their mean residual (projected - observed, px),
    ``sumsq`` (ny, nx, 2) the sum of squared residuals per coordinate. A smooth error the model cannot
    follow (a lens term it lacks) shows as a mean that differs from zero where it acts; random noise,
    pixel locking and corner-to-corner errors average out of the means.
    """

    image_size: tuple[int, int]
    count: np.ndarray
    mean: np.ndarray
    sumsq: np.ndarray

    @classmethod
    def of(cls, observed_px: np.ndarray, residual_px: np.ndarray, image_size: tuple[int, int],
           bins: tuple[int, int] = RESIDUAL_MAP_BINS) -> ResidualMap:
        """From interleaved (u0, v0, u1, ...) observed pixels and residuals of one camera."""
        observed = np.asarray(observed_px, float).reshape(-1, 2)
        residual = np.asarray(residual_px, float).reshape(-1, 2)
        index = cls._index(observed, image_size, bins)
        nx, ny = bins
        count = np.bincount(index, minlength=nx * ny).astype(float)
        total = np.stack([np.bincount(index, weights=residual[:, c], minlength=nx * ny) for c in (0, 1)], axis=-1)
        sumsq = np.stack([np.bincount(index, weights=residual[:, c] ** 2, minlength=nx * ny) for c in (0, 1)], axis=-1)
        mean = total / np.maximum(count, 1.0)[:, None]
        return cls(tuple(int(v) for v in image_size), count.reshape(ny, nx), mean.reshape(ny, nx, 2),
                   sumsq.reshape(ny, nx, 2))

    @staticmethod
    def _index(pixels: np.ndarray, image_size: tuple[int, int], bins: tuple[int, int]) -> np.ndarray:
        nx, ny = bins
        u = np.clip((pixels[:, 0] / image_size[0] * nx).astype(int), 0, nx - 1)
        v = np.clip((pixels[:, 1] / image_size[1] * ny).astype(int), 0, ny - 1)
        return v * nx + u

    def bins_of(self, pixels: np.ndarray) -> np.ndarray:
        """(N,) flat bin index of each of (N, 2) pixels."""
        ny, nx = self.count.shape
        return self._index(np.asarray(pixels, float).reshape(-1, 2), self.image_size, (nx, ny))

    def standard_error(self) -> np.ndarray:
        """(ny, nx, 2) standard error of each bin's mean (from the scatter in the bin)."""
        n = np.maximum(self.count, 1.0)[..., None]
        variance = np.maximum(self.sumsq / n - self.mean**2, 0.0) * n / np.maximum(n - 1.0, 1.0)
        return np.sqrt(variance / n)


#: The views' jackknife replaces the matrix's variance of a quantity when it exceeds it by more than this many
#: standard errors of a variance (sqrt(2 / (n - 1)) relative): the rule corner_systematic_px uses for the residuals.
JACKKNIFE_SIGNIFICANCE = 3.0
#: Fewer views than this give the jackknife too few degrees of freedom to speak for a variance.
MIN_JACKKNIFE_VIEWS = 8


class CovarianceUnavailable(ValueError):
    """The covariance cannot be computed (unsupported flags, singular normal matrix); the message says why."""


@dataclass(frozen=True, eq=False)
class CalibrationCovariance:
    """Covariance (P, P) of calibrated parameters ``names`` (P,): px, unitless, rad and mm as named.

    ``sigma_px`` is the per-coordinate corner noise the matrix is scaled by (the fit's residual
    standard deviation) and ``dof`` its degrees of freedom (0: not estimated from residuals).
    """

    names: tuple[str, ...]
    matrix: np.ndarray
    sigma_px: float
    dof: int = 0
    # (a_sin, a_cos) px: the detector's corner error e(p) = a_sin sin(2 pi frac(p)) + a_cos cos(2 pi frac(p))
    # per coordinate, fitted to the residuals; None when not estimated.
    pixel_locking_px: tuple[float, float] | None = None
    # Per camera ("left", "right"; "" for a mono calibration) the residuals binned over the image: where the
    # model misses the corners (stereo_bench.vision.uncertainty uses it for the corner error beyond noise and
    # locking). None when not computed (a calibration read from a file, a prediction).
    residual_map: dict[str, ResidualMap] | None = None
    # (n_views, P): per calibration view v the linearised leave-one-view-out change of every parameter,
    # theta_(-v) - theta (:func:`view_deltas`); None when not computed (a file, a prediction, fixed intrinsics).
    view_deltas: np.ndarray | None = None

    def __post_init__(self):
        matrix = np.asarray(self.matrix, float)
        if matrix.shape != (len(self.names), len(self.names)):
            raise ValueError(f"covariance matrix {matrix.shape} does not match {len(self.names)} parameter names")
        if len(set(self.names)) != len(self.names):
            raise ValueError("covariance parameter names repeat")
        object.__setattr__(self, "matrix", 0.5 * (matrix + matrix.T))

    def index(self, names: Sequence[str]) -> np.ndarray:
        position = {name: i for i, name in enumerate(self.names)}
        missing = [name for name in names if name not in position]
        if missing:
            raise KeyError(f"no covariance for {', '.join(missing)}")
        return np.array([position[name] for name in names], int)

    def sigma(self, name: str) -> float:
        """Standard uncertainty of one parameter: :meth:`variance_of` its unit gradient."""
        return float(np.sqrt(self.variance_of(np.ones(1), [name])[0]))

    def sigmas(self) -> dict[str, float]:
        return {name: self.sigma(name) for name in self.names}

    def variance_of(self, gradient: np.ndarray, names: Sequence[str]) -> tuple[float, float, str]:
        """(variance, degrees of freedom, source) of the scalar ``gradient @ parameters[names]``.

        From the matrix (``"residuals"``: sigma^2 g^T S^-1 g, infinite degrees of freedom for this purpose:
        the residual sigma's own are many thousands), unless the calibration's views scatter it
        significantly more: the jackknife over the views (:attr:`view_deltas`),
        var_J = (n-1)/n sum_v (g . d_v - mean)^2, with n - 1 degrees of freedom (``"views"``), when
        var_J > var (1 + :data:`JACKKNIFE_SIGNIFICANCE` sqrt(2 / (n - 1))), i.e. more than that many
        standard errors of a variance estimated from n - 1 degrees of freedom. The matrix assumes
        independent corner errors; a per-view error the model does not fit (a bent or moving board, a lens
        term it lacks, left and right not taken together) is correlated over a view's corners, which only
        the scatter over views shows (real sets: abs(T) 1.7-2.2 and fx 2-5 times the matrix's sigma).
        """
        g = np.asarray(gradient, float).reshape(-1)
        i = self.index(names)
        variance = float(max(g @ self.matrix[np.ix_(i, i)] @ g, 0.0))
        deltas = self.view_deltas
        if deltas is None or len(deltas) < MIN_JACKKNIFE_VIEWS:
            return variance, float("inf"), "residuals"
        n = len(deltas)
        values = deltas[:, i] @ g
        jackknife = float((n - 1) / n * np.sum((values - values.mean()) ** 2))
        if jackknife > variance * (1.0 + JACKKNIFE_SIGNIFICANCE * np.sqrt(2.0 / (n - 1))):
            return jackknife, float(n - 1), "views"
        return variance, float("inf"), "residuals"

    def subset(self, names: Sequence[str]) -> CalibrationCovariance:
        """The marginal covariance of ``names`` (in that order)."""
        i = self.index(names)
        return CalibrationCovariance(tuple(names), self.matrix[np.ix_(i, i)], self.sigma_px, self.dof,
                                     self.pixel_locking_px, self.residual_map,
                                     None if self.view_deltas is None else self.view_deltas[:, i])

    def prefixed(self, prefix: str) -> CalibrationCovariance:
        return CalibrationCovariance(tuple(prefix + n for n in self.names), self.matrix, self.sigma_px, self.dof,
                                     self.pixel_locking_px, self.residual_map, self.view_deltas)

    def with_prefix(self, prefix: str) -> tuple[str, ...]:
        return tuple(n for n in self.names if n.startswith(prefix))


def dist_names(n_coefficients: int) -> tuple[str, ...]:
    if n_coefficients not in (4, 5, 8, 12, 14):
        raise CovarianceUnavailable(f"{n_coefficients} distortion coefficients: OpenCV uses 4, 5, 8, 12 or 14")
    return DIST_NAMES[:n_coefficients]


def free_intrinsics(flags: int, n_dist: int) -> tuple[str, ...]:
    """Names of the intrinsics a solver with ``flags`` estimates (empty for ``CALIB_FIX_INTRINSIC``)."""
    if flags & cv2.CALIB_FIX_INTRINSIC:
        return ()
    for name in _COUPLING_FLAGS:
        if hasattr(cv2, name) and flags & getattr(cv2, name):
            raise CovarianceUnavailable(f"{name} couples parameters: no covariance model for it here")
    fixed: set[str] = set()
    for name, params in _FIXED_BY_FLAG.items():
        if hasattr(cv2, name) and flags & getattr(cv2, name):
            fixed.update(params)
    return tuple(n for n in FOCAL_CENTRE_NAMES + dist_names(n_dist) if n not in fixed)


def _projection(object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray, D: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (2N,) interleaved u0 v0 u1 ..., jacobian (2N, 10 + n_dist)) of board points (N, 3)."""
    pixels, jac = cv2.projectPoints(
        np.asarray(object_points, np.float64).reshape(-1, 1, 3), np.asarray(rvec, np.float64).reshape(3, 1),
        np.asarray(tvec, np.float64).reshape(3, 1), np.asarray(K, np.float64), np.asarray(D, np.float64).reshape(1, -1))
    return pixels.reshape(-1), jac


@dataclass(frozen=True)
class _View:
    """One view's linearised residuals: rows (u, v per corner) of one or both cameras."""

    key: tuple  # (view index, side) per block, in row order
    sizes: tuple[int, ...]  # rows per block
    J_global: np.ndarray  # (m, P)
    J_pose: np.ndarray  # (m, 6)
    J_external: np.ndarray | None  # (m, E): parameters the solver held at given values
    residual: np.ndarray  # (m,) projected - observed, px
    observed: np.ndarray  # (m,) the observed coordinates, interleaved like the residual


@dataclass(frozen=True)
class _Solution:
    S_inv: np.ndarray  # (P, P)
    Jhat: list[np.ndarray] | None  # per view (m, P): the Jacobian with the view's pose projected out
    ssr: float
    n_rows: int
    n_parameters: int  # P + 6 per view
    pixel_locking_px: tuple[float, float] | None
    assumed_sigma_px: float | None = None  # given instead of estimated from the residuals
    residual_map: dict[str, ResidualMap] | None = None
    view_deltas: np.ndarray | None = None  # (n, P) linearised leave-one-view-out changes (view_deltas)

    @property
    def dof(self) -> int:
        return 0 if self.assumed_sigma_px is not None else self.n_rows - self.n_parameters

    @property
    def sigma_px(self) -> float:
        if self.assumed_sigma_px is not None:
            return self.assumed_sigma_px
        return float(np.sqrt(self.ssr / self.dof)) if self.dof > 0 else float("nan")


def _residual_maps(views: list[_View], image_size: tuple[int, int]) -> dict[str, ResidualMap]:
    """Per camera side the residuals of ``views`` binned over the image."""
    observed: dict[str, list[np.ndarray]] = {}
    residual: dict[str, list[np.ndarray]] = {}
    for view in views:
        start = 0
        for (_, side), size in zip(view.key, view.sizes, strict=True):
            observed.setdefault(side, []).append(view.observed[start:start + size])
            residual.setdefault(side, []).append(view.residual[start:start + size])
            start += size
    return {side: ResidualMap.of(np.concatenate(observed[side]), np.concatenate(residual[side]), image_size)
            for side in observed}


def _solve(views: list[_View], *, locking: bool = True, jhat: bool = False,
           image_size: tuple[int, int] | None = None, leave_out: bool = False) -> _Solution:
    """Schur complement of the per-view poses; raises CovarianceUnavailable if the problem is singular.

    All views at once: each view's rows are zero-padded to the longest view's (zero rows add nothing
    to the normal equations), so the per-view algebra runs as a few batched numpy calls. ``jhat``:
    also the pose-projected Jacobian (only estimates that depend on other estimates need it). ``leave_out``:
    also each view's linearised leave-one-out change of the parameters (:func:`view_deltas`).
    """
    sizes = [len(view.residual) for view in views]
    n, m, P = len(views), max(sizes), views[0].J_global.shape[1]
    J_global, J_pose = np.zeros((n, m, P)), np.zeros((n, m, 6))
    for i, view in enumerate(views):
        J_global[i, :sizes[i]], J_pose[i, :sizes[i]] = view.J_global, view.J_pose
    J_pose_t = J_pose.transpose(0, 2, 1)
    C = J_pose_t @ J_pose  # (n, 6, 6)
    Bt = J_pose_t @ J_global  # (n, 6, P)
    try:
        C_inv_Bt = np.linalg.solve(C, Bt)  # (n, 6, P)
    except np.linalg.LinAlgError:
        raise CovarianceUnavailable("a view's board pose is undetermined") from None
    stacked = J_global.reshape(n * m, P)
    S = stacked.T @ stacked - (Bt.transpose(0, 2, 1) @ C_inv_Bt).sum(axis=0)
    try:
        S_inv = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        raise CovarianceUnavailable("the calibration parameters are not determined by these views") from None
    if not np.all(np.isfinite(S_inv)) or np.any(np.diag(S_inv) <= 0):
        raise CovarianceUnavailable("the calibration parameters are not determined by these views")
    Jhat = None
    deltas = None
    if jhat or leave_out:
        projected = J_global - J_pose @ C_inv_Bt
        Jhat = [projected[i, :size] for i, size in enumerate(sizes)] if jhat else None
        if leave_out:
            deltas = view_deltas(S, projected, [view.residual for view in views])
    residual = np.concatenate([view.residual for view in views])
    return _Solution(
        S_inv=S_inv, Jhat=Jhat, ssr=float(residual @ residual),
        n_rows=len(residual), n_parameters=P + 6 * n,
        pixel_locking_px=pixel_locking(np.concatenate([v.observed for v in views]), residual) if locking else None,
        residual_map=_residual_maps(views, image_size) if locking and image_size is not None else None,
        view_deltas=deltas,
    )


def view_deltas(S: np.ndarray, projected: np.ndarray, residuals: Sequence[np.ndarray]) -> np.ndarray | None:
    """(n, P) per view v the linearised leave-one-view-out change of the parameters, theta_(-v) - theta.

    ``S`` (P, P) the reduced normal matrix (poses eliminated), ``projected`` (n, m, P) each view's Jacobian
    with its pose projected out (rows zero-padded), ``residuals`` per view (m_v,) projected - observed px.
    At the optimum the views' reduced gradients g_v = Jhat_v^T r_v sum to zero, so without view v the gradient
    is -g_v and one Gauss-Newton step moves the parameters by (S - S_v)^-1 g_v, S_v = Jhat_v^T Jhat_v (its own
    pose leaves with it). Exact for a linear model; for a calibration it agrees with refitting without the view
    (scripts/coverage_real.py compares them). None when a view's removal leaves S singular.
    """
    n, m, _ = projected.shape
    padded = np.zeros((n, m))
    for i, r in enumerate(residuals):
        padded[i, :len(r)] = r
    g = np.einsum("nmp,nm->np", projected, padded)
    S_v = projected.transpose(0, 2, 1) @ projected
    try:
        return np.linalg.solve(S[None] - S_v, g[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return None


def pixel_locking(observed_px: np.ndarray, residual_px: np.ndarray) -> tuple[float, float] | None:
    """(a_sin, a_cos) px of the corner error e(p) = a_sin sin(2 pi frac(p)) + a_cos cos(2 pi frac(p)).

    Least squares of the observed-minus-projected coordinates (-``residual_px``) on the two
    harmonics of each coordinate's sub-pixel phase (``observed_px``, same (m,) layout). The fit's
    parameters absorb little of it: neighbouring corners of a view differ in phase. None with
    fewer than 20 coordinates, or when the amplitude is within 3 standard errors of zero (noise).
    """
    if len(observed_px) < 20:
        return None
    phase = 2.0 * np.pi * np.mod(observed_px, 1.0)
    design = np.stack([np.sin(phase), np.cos(phase)])  # (2, m)
    target = -np.asarray(residual_px, float)
    coefficients = np.linalg.solve(design @ design.T, design @ target)
    scatter = np.sqrt(np.sum((target - coefficients @ design) ** 2) / (len(target) - 2))
    standard_error = scatter / np.sqrt(0.5 * len(target))  # each harmonic has mean square 1/2
    if np.hypot(*coefficients) < 3.0 * standard_error:
        return None
    return float(coefficients[0]), float(coefficients[1])


def _mono_views(object_points, image_points, K, D, rvecs, tvecs, free: tuple[str, ...], indices, side: str,
                external: tuple[str, ...] = ()) -> list[_View]:
    cols = [_COLUMN[n] for n in free]
    ext_cols = [_COLUMN[n] for n in external]
    views = []
    for index, obj, img, rvec, tvec in zip(indices, object_points, image_points, rvecs, tvecs, strict=True):
        pixels, jac = _projection(obj, rvec, tvec, K, D)
        views.append(_View(
            key=((index, side),), sizes=(len(pixels),), J_global=jac[:, cols], J_pose=jac[:, :6],
            J_external=jac[:, ext_cols] if external else None,
            residual=pixels - np.asarray(img, np.float64).reshape(-1), observed=np.asarray(img, np.float64).reshape(-1),
        ))
    return views


def mono_covariance(
    object_points: Sequence[np.ndarray], image_points: Sequence[np.ndarray], K: np.ndarray, D: np.ndarray,
    rvecs: Sequence[np.ndarray], tvecs: Sequence[np.ndarray], *, flags: int, image_size: tuple[int, int] | None = None,
) -> CalibrationCovariance:
    """Covariance of one camera's estimated intrinsics (names ``fx fy cx cy k1 ...``) after cv2.calibrateCamera.

    Args:
        object_points, image_points: per view (N_i, 3) mm and (N_i, 2) px, the views the solver used.
        K (3, 3), D (1, n): the solution; rvecs, tvecs: per view the board pose it found.
        flags: the solver's flags (which intrinsics were free).
    """
    free = free_intrinsics(flags, np.asarray(D).size)
    if not free:
        raise CovarianceUnavailable("all intrinsics were fixed: nothing was estimated")
    views = _mono_views(object_points, image_points, K, D, rvecs, tvecs, free, range(len(object_points)), "")
    solution = _solve(views, image_size=image_size, leave_out=True)
    return CalibrationCovariance(free, solution.sigma_px**2 * solution.S_inv, solution.sigma_px, solution.dof,
                                 solution.pixel_locking_px, solution.residual_map, solution.view_deltas)


@dataclass(frozen=True)
class MonoLinearisation:
    """How one camera's intrinsics, estimated from some views, respond to those views' corners.

    d(intrinsics) = S_inv @ sum_v jhat[v].T @ d(observed pixels of view v); ``jhat[(view index,
    side)]`` (2 N_v, P) is the view's Jacobian with its pose projected out, ``S_inv`` (P, P).
    """

    names: tuple[str, ...]
    S_inv: np.ndarray
    jhat: dict[tuple, np.ndarray]


def mono_linearisation(
    object_points: Sequence[np.ndarray], image_points: Sequence[np.ndarray], K: np.ndarray, D: np.ndarray,
    rvecs: Sequence[np.ndarray], tvecs: Sequence[np.ndarray], *, flags: int, view_indices: Sequence[int], side: str,
) -> MonoLinearisation:
    """The influence of each view's corners on a mono calibration's intrinsics (views keyed by ``view_indices``)."""
    free = free_intrinsics(flags, np.asarray(D).size)
    views = _mono_views(object_points, image_points, K, D, rvecs, tvecs, free, list(view_indices), side)
    solution = _solve(views, locking=False, jhat=True)  # the stereo fit of the same corners measures the locking
    # dp = S^-1 Jhat^T dq: the residual is projected - observed, and the fit moves to follow the corners.
    return MonoLinearisation(names=free, S_inv=solution.S_inv,
                             jhat={v.key[0]: Jh for v, Jh in zip(views, solution.Jhat, strict=True)})


def _stereo_views(object_points, left_points, right_points, K1, D1, K2, D2, R, T, rvecs, tvecs,
                  free_left, free_right, external_left=(), external_right=(), view_indices=None) -> list[_View]:
    rvec_rt = cv2.Rodrigues(np.asarray(R, np.float64))[0]
    T = np.asarray(T, np.float64).reshape(3, 1)
    nl, nr = len(free_left), len(free_right)
    P = nl + nr + 6
    E = len(external_left) + len(external_right)
    cols_l, cols_r = [_COLUMN[n] for n in free_left], [_COLUMN[n] for n in free_right]
    ext_l, ext_r = [_COLUMN[n] for n in external_left], [_COLUMN[n] for n in external_right]
    view_indices = range(len(object_points)) if view_indices is None else view_indices
    views = []
    for index, obj, left, right, rvec, tvec in zip(view_indices, object_points, left_points, right_points, rvecs,
                                                   tvecs, strict=True):
        px_l, jac_l = _projection(obj, rvec, tvec, K1, D1)
        rvec_r, tvec_r, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = cv2.composeRT(
            np.asarray(rvec, np.float64).reshape(3, 1), np.asarray(tvec, np.float64).reshape(3, 1), rvec_rt, T)
        px_r, jac_r = _projection(obj, rvec_r, tvec_r, K2, D2)
        d_pose = np.empty((6, 6))  # d(right pose)/d(left pose)
        d_pose[:3, :3], d_pose[:3, 3:], d_pose[3:, :3], d_pose[3:, 3:] = dr3dr1, dr3dt1, dt3dr1, dt3dt1
        d_rt = np.empty((6, 6))  # d(right pose)/d(rvec, T)
        d_rt[:3, :3], d_rt[:3, 3:], d_rt[3:, :3], d_rt[3:, 3:] = dr3dr2, dr3dt2, dt3dr2, dt3dt2
        m_l, m_r = len(px_l), len(px_r)
        J_global = np.zeros((m_l + m_r, P))
        J_global[:m_l, :nl] = jac_l[:, cols_l]
        J_global[m_l:, nl:nl + nr] = jac_r[:, cols_r]
        J_global[m_l:, nl + nr:] = jac_r[:, :6] @ d_rt
        J_pose = np.empty((m_l + m_r, 6))
        J_pose[:m_l], J_pose[m_l:] = jac_l[:, :6], jac_r[:, :6] @ d_pose
        J_external = None
        if E:
            J_external = np.zeros((m_l + m_r, E))
            J_external[:m_l, :len(ext_l)] = jac_l[:, ext_l]
            J_external[m_l:, len(ext_l):] = jac_r[:, ext_r]
        views.append(_View(
            key=((index, "left"), (index, "right")), sizes=(m_l, m_r), J_global=J_global,
            J_pose=J_pose, J_external=J_external,
            residual=np.concatenate([px_l - np.asarray(left, np.float64).reshape(-1),
                                     px_r - np.asarray(right, np.float64).reshape(-1)]),
            observed=np.concatenate([np.asarray(left, np.float64).reshape(-1),
                                     np.asarray(right, np.float64).reshape(-1)]),
        ))
    return views


def stereo_covariance(
    object_points: Sequence[np.ndarray], left_points: Sequence[np.ndarray], right_points: Sequence[np.ndarray],
    K1: np.ndarray, D1: np.ndarray, K2: np.ndarray, D2: np.ndarray, R: np.ndarray, T: np.ndarray,
    rvecs: Sequence[np.ndarray], tvecs: Sequence[np.ndarray], *, flags: int,
    intrinsics_covariance: CalibrationCovariance | None = None,
    intrinsics_from: tuple[MonoLinearisation, MonoLinearisation] | str | None = None,
    view_indices: Sequence[int] | None = None, sigma_px: float | None = None,
    image_size: tuple[int, int] | None = None,
) -> CalibrationCovariance:
    """Covariance of both cameras' intrinsics and R (rotation vector), T after cv2.stereoCalibrate.

    Args:
        object_points, left_points, right_points: per view the corners the solver used (mm, px, px).
        K1, D1, K2, D2, R, T: the solution; rvecs, tvecs: per view the LEFT camera's board pose.
        flags: the stereo solver's flags. With ``CALIB_FIX_INTRINSIC`` the intrinsics were inputs,
            and their uncertainty must come from elsewhere, one of:
        intrinsics_covariance: covariance of the given intrinsics (names ``left.*``/``right.*``) from
            a calibration independent of these views (e.g. an intrinsics.yml written with one);
        intrinsics_from: (left, right) :func:`mono_linearisation` of mono calibrations of these same
            views (keyed by ``view_indices``), whose noise is shared with the stereo fit: propagated
            jointly, the correlation included. ``"these views"``: the mono calibrations used exactly
            these views (with ``flags`` without CALIB_FIX_INTRINSIC, the mono flags): their
            linearisations are taken from this fit's projections (the poses differ from the mono
            fits' at noise level only; a right pose reached through the left one spans the same
            directions), which saves projecting every view twice more.
        view_indices: the views' keys for ``intrinsics_from`` (default 0..n-1).
        sigma_px: the corner noise per coordinate to scale by; default the fit's residual sigma.
            Given, it predicts a planned calibration's covariance from noise-free projections
            (``dof`` is then 0: assumed, not estimated).
        image_size: (width, height) px: with it, each camera's residuals are binned over the image
            (:class:`ResidualMap`, ``residual_map``).

    Returns: names ``left.* right.* rvec.* T.*`` (intrinsics: those estimated here or given).

    Raises:
        CovarianceUnavailable: intrinsics fixed with neither source of their uncertainty; unsupported flags.
    """
    n_dist1, n_dist2 = np.asarray(D1).size, np.asarray(D2).size
    free_l, free_r = free_intrinsics(flags, n_dist1), free_intrinsics(flags, n_dist2)
    fixed = not free_l and not free_r
    if fixed and intrinsics_covariance is None and intrinsics_from is None:
        raise CovarianceUnavailable("the intrinsics were fixed and came without a covariance: "
                                    "the calibration's uncertainty is unknown")
    ext_l: tuple[str, ...] = ()
    ext_r: tuple[str, ...] = ()
    mono_flags = flags & ~cv2.CALIB_FIX_INTRINSIC
    if fixed and isinstance(intrinsics_from, str):
        if intrinsics_from != "these views":
            raise ValueError(f"intrinsics_from: two MonoLinearisations or 'these views', not {intrinsics_from!r}")
        ext_l, ext_r = free_intrinsics(mono_flags, n_dist1), free_intrinsics(mono_flags, n_dist2)
    elif fixed and intrinsics_from is not None:
        ext_l, ext_r = intrinsics_from[0].names, intrinsics_from[1].names
    elif fixed:
        ext_l = tuple(n[5:] for n in intrinsics_covariance.with_prefix("left."))
        ext_r = tuple(n[6:] for n in intrinsics_covariance.with_prefix("right."))
    views = _stereo_views(object_points, left_points, right_points, K1, D1, K2, D2, R, T, rvecs, tvecs,
                          free_l, free_r, ext_l, ext_r, view_indices)
    solution = _solve(views, locking=sigma_px is None, jhat=fixed, image_size=image_size,
                      leave_out=sigma_px is None and not fixed)
    if sigma_px is not None:
        solution = replace(solution, assumed_sigma_px=float(sigma_px))
    sigma2 = solution.sigma_px**2
    names = tuple("left." + n for n in free_l) + tuple("right." + n for n in free_r) + EXTRINSIC_NAMES
    if not fixed:
        return CalibrationCovariance(names, sigma2 * solution.S_inv, solution.sigma_px, solution.dof,
                                     solution.pixel_locking_px, solution.residual_map, solution.view_deltas)

    ext_names = tuple("left." + n for n in ext_l) + tuple("right." + n for n in ext_r)
    # The intrinsics held fixed move the stereo solution: d(rvec, T) = S^-1 Jhat^T (dq - J_ext d(intrinsics)).
    G = solution.S_inv @ sum(Jh.T @ v.J_external for Jh, v in zip(solution.Jhat, views, strict=True))  # (6, E)
    if intrinsics_from is None:
        C_e = intrinsics_covariance.subset(ext_names).matrix
        cov_rt = sigma2 * solution.S_inv + G @ C_e @ G.T
        cross = -G @ C_e  # Cov(rvec T, intrinsics)
        matrix = np.block([[C_e, cross.T], [cross, cov_rt]])
        return CalibrationCovariance(ext_names + EXTRINSIC_NAMES, matrix, solution.sigma_px, solution.dof,
                                     solution.pixel_locking_px, solution.residual_map)

    # Same data. Every estimate is linear in the observed corners q (independent, variance sigma^2):
    # intrinsics e = M q with M = S_m^-1 Jhat_m^T (per camera), the stereo fit a = D q - G e with
    # D = S^-1 Jhat^T. Then sum M M^T = S_m^-1, sum D D^T = S^-1, and only X = sum D M^T needs the
    # views that both fits used.
    if isinstance(intrinsics_from, str):
        intrinsics_from = _mono_linearisations_from(views, ext_l, ext_r)
    left_lin, right_lin = intrinsics_from
    n_el, n_e = len(ext_l), len(ext_l) + len(ext_r)
    B = np.zeros((n_e, n_e))
    B[:n_el, :n_el], B[n_el:, n_el:] = left_lin.S_inv, right_lin.S_inv
    X = np.zeros((6, n_e))
    for view, Jh in zip(views, solution.Jhat, strict=True):
        start = 0
        for key, size in zip(view.key, view.sizes, strict=True):
            rows = Jh[start:start + size]
            start += size
            for lin, columns in ((left_lin, slice(0, n_el)), (right_lin, slice(n_el, n_e))):
                if key in lin.jhat:
                    X[:, columns] += rows.T @ lin.jhat[key] @ lin.S_inv
    X = solution.S_inv @ X
    cov_rt = solution.S_inv - G @ X.T - X @ G.T + G @ B @ G.T
    cross = X - G @ B  # Cov(rvec T, intrinsics) / sigma^2
    matrix = sigma2 * np.block([[B, cross.T], [cross, cov_rt]])
    return CalibrationCovariance(ext_names + EXTRINSIC_NAMES, matrix, solution.sigma_px, solution.dof,
                                 solution.pixel_locking_px, solution.residual_map)


def _mono_linearisations_from(views: list[_View], names_left: tuple[str, ...], names_right: tuple[str, ...],
                              ) -> tuple[MonoLinearisation, MonoLinearisation]:
    """Each camera's mono linearisation from a fixed-intrinsics stereo fit's rows: its intrinsics' columns
    (held in ``J_external``) and its own pose columns."""
    n_l = len(names_left)
    out = []
    for side, names, columns in (("left", names_left, slice(0, n_l)), ("right", names_right, slice(n_l, None))):
        mono_views = []
        for view in views:
            rows = slice(0, view.sizes[0]) if side == "left" else slice(view.sizes[0], None)
            key = view.key[0] if side == "left" else view.key[1]
            mono_views.append(_View(key=(key,), sizes=(view.sizes[0 if side == "left" else 1],),
                                    J_global=view.J_external[rows, columns], J_pose=view.J_pose[rows],
                                    J_external=None, residual=view.residual[rows], observed=view.observed[rows]))
        solution = _solve(mono_views, locking=False, jhat=True)
        out.append(MonoLinearisation(names=names, S_inv=solution.S_inv,
                                     jhat={v.key[0]: Jh for v, Jh in zip(mono_views, solution.Jhat, strict=True)}))
    return out[0], out[1]


def extrinsic_sigmas(R: np.ndarray, T: np.ndarray, covariance: CalibrationCovariance) -> dict:
    """Standard uncertainties of the stereo extrinsics in the units an operator reads.

    ``baseline_mm``: of abs(T); ``T_mm`` (3,); ``rvec_deg`` (3,): of the rotation vector's components;
    ``rotation_deg``: of the total rotation angle abs(rvec) (a small-angle rig has rvec near 0, where
    the angle's first-order sigma is meaningless: then the largest component's sigma is given).
    """
    T = np.asarray(T, float).reshape(3)
    C_r = covariance.subset(EXTRINSIC_NAMES[:3]).matrix
    u = T / np.linalg.norm(T)
    rvec = cv2.Rodrigues(np.asarray(R, np.float64))[0].reshape(3)
    angle = float(np.linalg.norm(rvec))
    if angle > 1e-3:
        axis = rvec / angle
        rotation = float(np.sqrt(axis @ C_r @ axis))
    else:
        rotation = float(np.sqrt(np.max(np.diag(C_r))))
    return {
        "baseline_mm": float(np.sqrt(covariance.variance_of(u, EXTRINSIC_NAMES[3:])[0])),
        "T_mm": [covariance.sigma(n) for n in EXTRINSIC_NAMES[3:]],
        "rvec_deg": np.degrees(np.sqrt(np.diag(C_r))).tolist(), "rotation_deg": float(np.degrees(rotation)),
    }
