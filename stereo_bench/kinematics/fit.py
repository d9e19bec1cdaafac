"""The kinematic fit: one joint bundle adjustment of every calibration view of a design of configurations.

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
design of configurations (:func:`stereo_bench.kinematics.design.kinematic_design`), as mrcal and Kalibr
calibrate multi-camera rigs: unknowns are the kinematic parameters, one board pose per view, optionally the
intrinsics, and per configuration the random landing error of each axis (a prior of the rig's repeatability),
so the parameters' covariance, from the Jacobian, accounts for moves that do not land twice alike.

OpenCV for PnP and the initial intrinsics, scipy for least squares.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from stereo_bench.geometry import rotation_deg
from stereo_bench.kinematics.model import (
    _INDEX,
    AXES,
    PARAMETERS,
    TILT_AXES,
    FitSummary,
    KinematicModel,
    ParameterValue,
    ResidualMapRecord,
    _effective,
    _effective_tilts,
    _rotation_matrices,
    _rotation_vector_matrix,
    _rvec,
    chain,
    model_axes,
    nominal_parameters,
    parameter_specs,
    vector_specs,
)


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


def axes_of(configurations: Sequence[ConfigurationViews]) -> tuple[str, ...]:
    """The model axes of a design: AXES, and the tilts every visit reports (a rig that drives them)."""
    return model_axes([a for a in TILT_AXES if configurations and all(a in c.axes for c in configurations)])


def _identifiable(configurations: Sequence[ConfigurationViews]) -> tuple[set[str], dict[str, str]]:
    """(parameter groups the design identifies, reason per group it does not)."""
    free, notes = {"right_pose"}, {}
    groups = {"baseline_mm": ("slide", "slide_backlash"), "toe_in_left_deg": ("left_axis", "left_backlash"),
              "toe_in_right_deg": ("right_axis", "right_backlash")}
    axes = axes_of(configurations)
    for tilt in TILT_AXES:
        side = tilt.split("_")[1]
        if tilt in axes:
            groups[tilt] = (f"{side}_tilt", f"{side}_tilt_backlash")
        elif len(axes) > len(AXES):  # the other camera tilts: this one's joint is in the vector, not in the rig
            notes[f"{side}_tilt"] = notes[f"{side}_tilt_backlash"] = f"not in the model: the rig does not drive {tilt}"
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
    p = nominal_parameters(B_ref, axes_of(configurations))
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
            model = chain(q, B_ref, *_effective(conf.axes, conf.approach, q),
                          *_effective_tilts(conf.axes, conf.approach, q))
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

    def residual_maps(self, x: np.ndarray, image_size: tuple[int, int]) -> dict[str, ResidualMapRecord]:
        """Per camera the residuals at ``x`` binned over the image (as a calibration covariance's residual map)."""
        ordered = self.residuals(x)[: self.m_px] * self.sigma_px  # projected - observed, px, view by view
        raw = np.empty_like(ordered)
        raw[self.order] = ordered
        split = 2 * len(self.obs["left"][0])
        return {side: ResidualMapRecord.of(self.obs[side][2], residual, image_size)
                for side, residual in (("left", raw[:split]), ("right", raw[split:]))}

    def global_covariance(self, lin: dict) -> np.ndarray:
        """Covariance of the global unknowns (board poses marginalised): inverse of the Schur complement."""
        V_inv = np.linalg.inv(lin["V"])
        S = lin["U"] - np.einsum("vgk,vkl,vhl->gh", lin["W"], V_inv, lin["W"])
        return np.linalg.inv(S)

    def minimise(self, x0: np.ndarray) -> tuple[np.ndarray, dict]:
        return _levenberg_marquardt(self.residuals, self.linearize, self.solve, x0)


def assemble_model(
    configurations: Sequence[ConfigurationViews], *, p: np.ndarray, free: np.ndarray, cov_k: np.ndarray,
    held_note, residual_px: np.ndarray, row_view: np.ndarray, view_config: np.ndarray, intr_l: np.ndarray,
    intr_r: np.ndarray, image_size: tuple[int, int], B_ref: float, repeatability: tuple[float, ...],
    sigma_px: float, dof: int, intrinsics: str, intrinsic_names: list[str], cov_i: np.ndarray, cross: np.ndarray,
    locking, residual_maps: dict,
) -> tuple[KinematicModel, np.ndarray]:
    """The model file of a fit (any design: :func:`fit_kinematics`, the fixed-board fit) and its per-view RMS.

    ``p`` every parameter's value, ``free`` which were fitted, ``cov_k`` their covariance (in order); ``held_note``:
    spec -> why a held parameter is not identified; ``residual_px`` (N, 2) the fit's pixel residuals and
    ``row_view`` (N,) the view of each; ``view_config`` per view its configuration. A design whose visits report
    tilts (:func:`axes_of`) gives a model with tilt joints: ``p`` and ``free`` over its vector (:func:`vector_specs`),
    ``repeatability`` then also each driven tilt's.
    """
    axes = axes_of(configurations)
    names = [spec.name for spec in vector_specs(axes)]
    present = {spec.name for spec in parameter_specs(axes)}
    free_index = np.flatnonzero(free)
    sig = np.sqrt(np.clip(np.diag(cov_k), 0.0, None))
    parameters = {}
    for i, spec in enumerate(vector_specs(axes)):
        if spec.name not in present:
            continue
        if free[i]:
            k = int(np.searchsorted(free_index, i))
            parameters[spec.name] = ParameterValue(value=float(p[i]), sigma=float(sig[k]), unit=spec.unit,
                                                   identifiable=True)
        else:
            parameters[spec.name] = ParameterValue(value=float(p[i]), sigma=None, unit=spec.unit, identifiable=False,
                                                   note=held_note(spec) + " (held nominal)")
    n_views = len(view_config)
    per_view = np.array([math.sqrt(float((residual_px[row_view == v] ** 2).sum(axis=1).mean()))
                         for v in range(n_views)])
    per_config_rms = [math.sqrt(float((residual_px[view_config[row_view] == c] ** 2).sum(axis=1).mean()))
                      for c in range(len(configurations))]
    K1, D1 = _K_D(intr_l)
    K2, D2 = _K_D(intr_r)
    span = {axis: [float(min(c.axes[axis] for c in configurations)), float(max(c.axes[axis] for c in configurations))]
            for axis in axes}
    tilted = {}  # a model with tilt joints: its axes and (repeatability[3:], left then right) its tilts' landings
    if len(axes) > len(AXES):
        tilt_sigma = dict(zip(TILT_AXES, repeatability[3:], strict=False))
        tilted = {"axes": list(axes), "repeatability_tilt_left_deg": tilt_sigma.get("tilt_left_deg", 0.0),
                  "repeatability_tilt_right_deg": tilt_sigma.get("tilt_right_deg", 0.0)}
    model = KinematicModel(
        reference_baseline_mm=B_ref, repeatability_mm=repeatability[0],
        repeatability_left_deg=repeatability[1], repeatability_right_deg=repeatability[2], **tilted,
        span=span, parameters=parameters, covariance_names=[names[i] for i in free_index],
        covariance=cov_k.tolist(), image_size=[int(image_size[0]), int(image_size[1])],
        K1=K1.tolist(), D1=D1.ravel().tolist(), K2=K2.tolist(), D2=D2.ravel().tolist(),
        fit=FitSummary(
            rms_px=float(math.sqrt((residual_px**2).sum(axis=1).mean())), pixel_sigma_px=sigma_px,
            n_configurations=len(configurations), n_views=n_views, n_observations=len(residual_px),
            intrinsics=intrinsics, design=[{a: float(c.axes[a]) for a in axes} for c in configurations],
            per_configuration_rms_px=per_config_rms, dof=int(dof),
        ),
        intrinsics_covariance_names=intrinsic_names, intrinsics_covariance=cov_i.tolist(),
        cross_covariance=cross.tolist(),
        pixel_locking_px=None if locking is None else [float(locking[0]), float(locking[1])],
        residual_maps=residual_maps,
    )
    return model, per_view


def fit_kinematics(
    configurations: Sequence[ConfigurationViews], object_points: np.ndarray, image_size: tuple[int, int], *,
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None, refine_intrinsics: bool = True,
    repeatability_mm: float = 0.0, repeatability_left_deg: float = 0.0, repeatability_right_deg: float = 0.0,
    reference_baseline_mm: float | None = None, min_corners: int = 6, pixel_sigma_px: float | None = None,
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
        pixel_sigma_px: the corners' noise per coordinate, when known (a planned fit to exact pixels:
            :func:`stereo_bench.errormodel.rigorous.planned_kinematic_model`); None: what the residuals show,
            found by refitting.

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
    tilts = axes_of(configurations)[len(AXES):]
    if tilts:
        raise ValueError(f"the presented design's fit has no tilt joints and the design reports {', '.join(tilts)}: "
                         "fit a tilting rig with the fixed-board design (stereo_bench.kinematics.fixed_board)")
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
    sigma_px = max(math.sqrt(squares / max(dof, 1)), 1e-3) if pixel_sigma_px is None else float(pixel_sigma_px)
    if not sigma_px > 0:
        raise ValueError(f"pixel_sigma_px must be > 0, not {pixel_sigma_px}")
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
        converged = pixel_sigma_px is not None or abs(estimate / sigma_px - 1.0) < 0.05
        # The pixel weight sets the balance against the landing priors: fit again with the sigma the
        # residuals show, until it agrees with the one assumed.
        sigma_px = sigma_px if pixel_sigma_px is not None else estimate
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
    residual = (r[: bundle.m_px] * sigma_px).reshape(-1, 2)  # view by view (u, v) pairs
    view_of_row = np.repeat(np.arange(bundle.V), [(sl.stop - sl.start) // 2 for sl in bundle.view_slices])
    model, per_view = assemble_model(
        configurations, p=p, free=free, cov_k=cov_k, held_note=lambda spec: notes.get(spec.group, ""),
        residual_px=residual, row_view=view_of_row, view_config=bundle.view_config, intr_l=intr_l, intr_r=intr_r,
        image_size=image_size, B_ref=B_ref,
        repeatability=(repeatability_mm, repeatability_left_deg, repeatability_right_deg), sigma_px=sigma_px,
        dof=dof, intrinsics="refined jointly" if refine_intrinsics else "fixed", intrinsic_names=intrinsic_names,
        cov_i=cov_i, cross=cross, locking=bundle.pixel_locking(x),
        residual_maps=bundle.residual_maps(x, (int(image_size[0]), int(image_size[1]))))
    return KinematicFit(model=model, T_left_board=[_pose_matrix(pose) for pose in poses], view_rms_px=per_view,
                        view_configuration=bundle.view_config.copy(), views_dropped=dropped, landing=landing)
