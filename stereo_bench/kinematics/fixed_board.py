"""The kinematic fit from a board that stays put while the rig moves (hand-eye style, issue 25).

The operator places the calibration board once; the rig moves through a design of slide and pan
positions (:func:`fixed_board_design`) and both cameras capture the board at each. The chain is the
one of :mod:`stereo_bench.kinematics.model`; what is new is that every view sees the SAME board, so
each camera's own motion is observed, not only the pair's relative pose::

    T_L_board = inv(T_S_L(t_L')) @ Trans(share * k_s * (B' - B_ref) * d) @ T_Sref_board
    T_R_board = T_R_L(B', t_L', t_R') @ T_L_board          (T_R_L: model.chain)

with ``T_Sref_board`` the board in the left camera's frame at B_ref and toe-in 0 (the one nuisance pose
shared by every view) and ``share`` the part of a baseline change the left carriage makes (0.5 for two
carriages moving symmetrically, 0 for a fixed left carriage): a nuisance too, since R and T depend only
on the separation. Unknowns: the free kinematic parameters, ``share``, the board pose, one landing
error per axis and visit (the rig's repeatability as prior), and the intrinsics of both cameras
(refined jointly; with a lens calibration given, its values and covariance are a prior).

What the design identifies is not assumed: :func:`identifiability` reads it off the Jacobian (the
information matrix of the kinematic parameters with every nuisance marginalised, scaled by each
parameter's tolerance), and :func:`fit_fixed_board` holds at nominal what it cannot identify, naming
the parameters it is confounded with.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from stereo_bench.geometry import rotation_deg
from stereo_bench.kinematics.design import DesignConfiguration
from stereo_bench.kinematics.fit import (
    _K_D,
    ConfigurationViews,
    _average_transform,
    _identifiable,
    _initial_parameters,
    _intrinsic_vector,
    _levenberg_marquardt,
    _pnp,
    _pose_matrix,
    _project,
    _rotate,
    _solve_dense,
    assemble_model,
    axes_of,
)
from stereo_bench.kinematics.model import (
    _INDEX,
    N_PARAMS,
    PARAMETERS,
    TILT_AXES,
    KinematicModel,
    ParameterSpec,
    ResidualMapRecord,
    _about_line,
    _effective,
    _effective_tilts,
    _pan_line,
    _rotation_matrices,
    _rvec,
    _tilt_joint,
    _tilt_line,
    nominal_parameters,
    vector_specs,
)

INTRINSIC_NAMES = tuple(f"{side}.{name}" for side in ("left", "right")
                        for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"))

#: The scale each parameter is judged on (its unit of "does it matter"): a direction of the parameters the
#: design determines worse than this (sigma > 1 in these units, at the pixel noise) is not identified.
#: Angles 0.3 deg, lengths 1 mm, scales 2e-3: the rig's stated tolerances (docs/EXTRINSICS.md): a parameter the design
#: determines no better than the rig's build is known is not identified by it.
IDENTIFIABILITY_SCALE = {"deg": 0.3, "mm": 1.0, "1": 2e-3}


# --------------------------------------------------------------------------------------------------
# The design


def fixed_board_design(baseline_range_mm: tuple[float, float], toe_in_left_range_deg: tuple[float, float] = (0.0, 0.0),
                       toe_in_right_range_deg: tuple[float, float] | None = None, *, baseline_levels: int = 4,
                       pan_levels: int = 4, min_pan_span_deg: float = 6.0,
                       tilt_ranges_deg: Mapping[str, tuple[float, float]] | None = None, tilt_levels: int = 3,
                       min_tilt_span_deg: float = 10.0) -> list[DesignConfiguration]:
    """Slide and pan positions for the fixed-board fit, in the order to visit them (every axis from both sides).

    ``baseline_levels`` slide positions over the range; at each, the two heads go through
    ``pan_levels`` toe-in pairs over their range (equal toe-ins, then the two heads in opposite
    order, so the heads' scales and axes separate), forward on the way out along the slide and back
    on the way home, so every slide position is reached from both sides and every pan position
    with a reversal of the head. A pan range narrower than ``min_pan_span_deg`` (a campaign at one
    toe-in) is widened about its middle (a toe-in of 0 upward): the heads turning are what shows
    where each pan axis is and what separates the intrinsics from the board pose; a single pan level
    (``pan_levels`` 1) keeps the pan where the campaign needs it.

    ``tilt_ranges_deg``: per tilt the rig drives (``tilt_left_deg``, ``tilt_right_deg``: a rig config that maps it to
    an axis), the range the campaign uses; its ``tilt_levels`` values (a range narrower than ``min_tilt_span_deg``
    widened about its middle) are stepped up and down once per visit, the right tilt half a period behind the left
    (a triangle wave: every inner level reached from both sides), so each tilt meets every slide and pan position.
    """
    if baseline_levels < 1 or pan_levels < 1 or tilt_levels < 1:
        raise ValueError("baseline_levels, pan_levels and tilt_levels must be >= 1")
    unknown = [axis for axis in (tilt_ranges_deg or {}) if axis not in TILT_AXES]
    if unknown:
        raise ValueError(f"tilt_ranges_deg: {', '.join(unknown)} not of {', '.join(TILT_AXES)}")
    toe_in_right_range_deg = toe_in_right_range_deg or toe_in_left_range_deg

    def widen(r: tuple[float, float]) -> tuple[float, float]:
        lo, hi = float(min(r)), float(max(r))
        if pan_levels > 1 and hi - lo < min_pan_span_deg:
            mid = 0.5 * (lo + hi)
            lo, hi = mid - min_pan_span_deg / 2.0, mid + min_pan_span_deg / 2.0
            if lo < 0.0 <= min(r):  # toe-in stays on the side the campaign uses
                lo, hi = 0.0, min_pan_span_deg
        return lo, hi

    lo_b, hi_b = baseline_range_mm
    # Levels to 0.1 mm and 0.1 deg (readable visit names; the fit takes the positions the rig reports anyway).
    bs = [round(float(v), 1) for v in np.linspace(lo_b, hi_b, baseline_levels)] if hi_b > lo_b else [float(lo_b)]
    tl = [round(float(v), 1) for v in np.linspace(*widen(toe_in_left_range_deg), pan_levels)]
    tr = [round(float(v), 1) for v in np.linspace(*widen(toe_in_right_range_deg), pan_levels)]
    n = len(tl)
    # Pan pairs: the two heads together, then crossed (left rising while the right falls).
    together = [(tl[i], tr[i]) for i in range(n)]
    crossed = [(tl[i], tr[n - 1 - i]) for i in range(n)] if n > 1 else []
    design: list[DesignConfiguration] = []
    sweep = list(range(len(bs))) + list(range(len(bs) - 1, -1, -1))  # out and home: both sides of each B
    for k, b in enumerate(sweep):
        pairs = together if k % 2 == 0 else crossed or together
        if k % 2 == 1:
            pairs = pairs[::-1]
        if len(bs) == 1 and k:
            pairs = pairs[::-1]
        for left, right in pairs:
            design.append(DesignConfiguration(bs[b], left, right))
    if tilt_ranges_deg:
        design = _with_tilts(design, tilt_ranges_deg, tilt_levels, min_tilt_span_deg)
    return design


def _with_tilts(design: list[DesignConfiguration], ranges: Mapping[str, tuple[float, float]], levels: int,
                min_span_deg: float) -> list[DesignConfiguration]:
    """``design`` with each driven tilt stepped through its levels, up and down (see :func:`fixed_board_design`)."""
    from dataclasses import replace

    period = max(1, 2 * (levels - 1))
    wave = [k if k < levels else period - k for k in range(period)]  # 0 1 .. n-1 .. 1
    values = {}
    for axis, (a, b) in ranges.items():
        lo, hi = float(min(a, b)), float(max(a, b))
        if levels > 1 and hi - lo < min_span_deg:
            mid = 0.5 * (lo + hi)
            lo, hi = mid - min_span_deg / 2.0, mid + min_span_deg / 2.0
        values[axis] = [round(float(v), 1) for v in np.linspace(lo, hi, levels)] if levels > 1 else [0.5 * (lo + hi)]
    out = []
    for k, visit in enumerate(design):
        tilts = {axis: values[axis][wave[(k + (0 if axis == "tilt_left_deg" else levels - 1)) % period]]
                 for axis in values}
        out.append(replace(visit, **tilts))
    return out


# --------------------------------------------------------------------------------------------------
# The fit


@dataclass(frozen=True)
class IdentifiabilityRow:
    """One parameter of the identifiability table."""

    name: str
    unit: str
    identified: bool
    sigma: float | None  # with every identified parameter free (None: held)
    null_share: float  # 0..1: how much of the parameter lies in directions the design does not determine
    note: str = ""


@dataclass
class FixedBoardFit:
    """A fitted model and what the fit saw: the one board pose, the carriage share, the identifiability table."""

    model: KinematicModel
    T_ref_board: np.ndarray  # 4x4: the board in the left camera's frame at B_ref and toe-in 0
    left_share: float
    identifiability: list[IdentifiabilityRow]
    view_rms_px: np.ndarray
    view_configuration: np.ndarray
    landing: np.ndarray  # (n_configurations, 3), or 5 with tilt joints (mm, deg)
    views_dropped: list[tuple[int, int, str]] = field(default_factory=list)


def _about_lines(direction: np.ndarray, point: np.ndarray, rads: np.ndarray) -> np.ndarray:
    """(C, 4, 4) rigid rotations by each of ``rads`` (C,) about one line (unit ``direction``, ``point``)."""
    x, y, z = direction
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(rads)[:, None, None], np.cos(rads)[:, None, None]
    R = np.eye(3) + s * K + (1.0 - c) * (K @ K)
    T = np.zeros((len(rads), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = point - R @ point
    T[:, 3, 3] = 1.0
    return T


def _chains(p: np.ndarray, reference_baseline_mm: float, b: np.ndarray, tl: np.ndarray, tr: np.ndarray,
            til: np.ndarray | None = None, tir: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(T_S_L, T_R_L), each (C, 4, 4), of :func:`stereo_bench.kinematics.model.chain` at C effective axis values at
    once (the same chain, batched: tests/test_kinematics_fixed_board.py checks they agree); ``til``, ``tir``: the
    effective tilts, for a vector ``p`` with tilt joints."""
    left_dir, left_point = _pan_line(p, "left")
    right_dir, right_point = _pan_line(p, "right")
    T_S_L = _about_lines(left_dir, left_point, np.radians(p[_INDEX["left_angle_scale"]] * tl))
    T_R0_R = _about_lines(right_dir, right_point, -np.radians(p[_INDEX["right_angle_scale"]] * tr))
    if len(p) > N_PARAMS:
        for side, tilt in (("left", til), ("right", tir)):
            direction, point = _tilt_line(p, side)
            turn = _about_lines(direction, point, -np.radians(p[_INDEX[f"{side}_tilt_scale"]] * tilt))
            if side == "left":
                T_S_L = T_S_L @ turn
            else:
                T_R0_R = T_R0_R @ turn
    i = _INDEX["right_rot_x_deg"]
    T_S_R0 = np.eye(4)
    T_S_R0[:3, :3] = _rotation_matrices(np.radians(p[i : i + 3]))[0]
    T_S_R0[:3, 3] = p[i + 3 : i + 6]
    T_S_R = T_S_R0 @ T_R0_R
    T_S_R[:, :3, 3] += (p[_INDEX["slide_scale"]] * (b - reference_baseline_mm))[:, None] * _slide_direction(p)
    R_t = np.transpose(T_S_R[:, :3, :3], (0, 2, 1))
    T_R_S = np.zeros_like(T_S_R)
    T_R_S[:, :3, :3] = R_t
    T_R_S[:, :3, 3] = -np.einsum("cij,cj->ci", R_t, T_S_R[:, :3, 3])
    T_R_S[:, 3, 3] = 1.0
    return T_S_L, T_R_S @ T_S_L


def _invert(T: np.ndarray) -> np.ndarray:
    """(C, 4, 4) inverses of rigid transforms."""
    R_t = np.transpose(T[:, :3, :3], (0, 2, 1))
    out = np.zeros_like(T)
    out[:, :3, :3] = R_t
    out[:, :3, 3] = -np.einsum("cij,cj->ci", R_t, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def _left_in_S(p: np.ndarray, toe_in_left_deg: float, tilt_left_deg: float = 0.0) -> np.ndarray:
    direction, point = _pan_line(p, "left")
    T = _about_line(direction, point, math.radians(p[_INDEX["left_angle_scale"]] * toe_in_left_deg))
    return T @ _tilt_joint(p, "left", tilt_left_deg) if len(p) > N_PARAMS else T


def _slide_direction(p: np.ndarray) -> np.ndarray:
    return (rotation_deg("y", p[_INDEX["slide_yaw_deg"]]) @ rotation_deg("z", p[_INDEX["slide_pitch_deg"]])
            @ np.array([1.0, 0.0, 0.0]))


class _FixedBundle:
    """Dense adjustment. Unknowns: [kinematic (the vector's 22, or 34 with tilt joints; masked), share, board pose (6),
    landings (one per axis and visit: 3 C, or 5 C with tilt joints), intrinsics (16)].

    Residuals: every corner's pixel error / sigma_px (left then right camera), the landing priors, the
    intrinsics prior (whitened by its covariance's Cholesky factor). Held parameters stay at their value
    (their columns are still computed for the identifiability table).
    """

    def __init__(self, p0, B_ref, configurations, views, object_points, intr0, *, sigma_px, landing_sigmas,
                 intrinsics_prior, refine_intrinsics):
        self.p0, self.B_ref, self.configurations = np.asarray(p0, float), B_ref, configurations
        self.C = len(configurations)
        self.sigma_px = sigma_px
        self.landing_sigmas = np.asarray(landing_sigmas, float)
        self.n_axes = len(self.landing_sigmas)  # the chain's axes: 3, or 5 with tilt joints
        self.landing_axes = [a for a in range(self.n_axes) if self.landing_sigmas[a] > 0.0]
        self.refine = refine_intrinsics
        self.intr0 = np.asarray(intr0, float)  # (18,): left 9, right 9 (k3 fixed)
        self.prior = intrinsics_prior  # (mean (16,), whitening (16, 16)) or None
        self.n_k = len(self.p0)
        self.o_share = self.n_k
        self.o_board = self.o_share + 1
        self.o_land = self.o_board + 6
        self.o_intr = self.o_land + self.n_axes * self.C
        self.n = self.o_intr + (16 if refine_intrinsics else 0)
        obs = {"left": ([], [], []), "right": ([], [], [])}
        for v, (_c, ids_l, px_l, ids_r, px_r) in enumerate(views):
            for side, ids, px in (("left", ids_l, px_l), ("right", ids_r, px_r)):
                obs[side][0].append(np.full(len(ids), v))
                obs[side][1].append(object_points[ids])
                obs[side][2].append(px)
        self.obs = {s: tuple(np.concatenate(a) for a in obs[s]) for s in obs}
        self.view_config = np.array([v[0] for v in views])
        self.V = len(views)
        self.m_left = 2 * len(self.obs["left"][0])
        self.m_px = self.m_left + 2 * len(self.obs["right"][0])
        rows_view = np.concatenate([np.repeat(self.obs["left"][0], 2), np.repeat(self.obs["right"][0], 2)])
        self.row_view = rows_view
        self.row_config = self.view_config[rows_view]
        self.row_is_right = np.arange(self.m_px) >= self.m_left

    def intrinsics(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        il, ir = self.intr0[:9].copy(), self.intr0[9:].copy()
        if self.refine:
            il[:8], ir[:8] = x[self.o_intr : self.o_intr + 8], x[self.o_intr + 8 : self.o_intr + 16]
        return il, ir

    def transforms(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(V, 4, 4) T_L_board and T_R_board of every view."""
        p = x[: self.n_k]
        share = x[self.o_share]
        T_ref_board = _pose_matrix(x[self.o_board : self.o_board + 6])
        landing = x[self.o_land : self.o_intr].reshape(self.C, self.n_axes)
        if self.n_axes > 3:
            effective = np.array([(*_effective(conf.axes, conf.approach, p), *_effective_tilts(conf.axes, conf.approach,
                                                                                              p))
                                  for conf in self.configurations]) + landing
            b, tl, tr, til, tir = effective.T
            T_S_L, T_R_L = _chains(p, self.B_ref, b, tl, tr, til, tir)
        else:
            effective = np.array([_effective(conf.axes, conf.approach, p) for conf in self.configurations]) + landing
            b, tl, tr = effective.T
            T_S_L, T_R_L = _chains(p, self.B_ref, b, tl, tr)
        T_S_board = np.repeat(T_ref_board[None], self.C, axis=0)
        T_S_board[:, :3, 3] += (share * p[_INDEX["slide_scale"]] * (b - self.B_ref))[:, None] * _slide_direction(p)
        T_L = _invert(T_S_L) @ T_S_board
        T_R = T_R_L @ T_L
        return T_L[self.view_config], T_R[self.view_config]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        T_L, T_R = self.transforms(x)
        il, ir = self.intrinsics(x)
        out = []
        for side, T, intr in (("left", T_L, il), ("right", T_R, ir)):
            vid, obj, px = self.obs[side]
            X = _rotate(T[vid, :3, :3], obj) + T[vid, :3, 3]
            out.append((_project(X, intr) - px).ravel() / self.sigma_px)
        landing = x[self.o_land : self.o_intr].reshape(self.C, self.n_axes)
        if self.landing_axes:
            out.append((landing[:, self.landing_axes] / self.landing_sigmas[self.landing_axes]).ravel())
        if self.refine and self.prior is not None:
            mean, whitening = self.prior
            out.append(whitening @ (x[self.o_intr : self.o_intr + 16] - mean))
        return np.concatenate(out)

    def jacobian(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(m, n) forward differences; unknowns touching disjoint rows share one evaluation (landings per axis,
        each intrinsic of the left camera with the same one of the right)."""
        J = np.zeros((r.size, self.n))

        def diff(indices: list[int]) -> tuple[np.ndarray, np.ndarray]:
            step = x.copy()
            h = np.array([1e-6 * max(1.0, abs(x[k])) for k in indices])
            step[indices] += h
            return self.residuals(step) - r, h

        for k in range(self.o_land):
            d, h = diff([k])
            J[:, k] = d / h[0]
        m = self.m_px
        n_axes = len(self.landing_axes)
        for a in self.landing_axes:
            columns = [self.o_land + self.n_axes * c + a for c in range(self.C)]
            d, h = diff(columns)
            j = self.landing_axes.index(a)
            for c, column in enumerate(columns):
                J[:m, column] = np.where(self.row_config == c, d[:m], 0.0) / h[c]
                J[m + c * n_axes + j, column] = 1.0 / self.landing_sigmas[a]
        if self.refine:
            for j in range(8):
                cols = [self.o_intr + j, self.o_intr + 8 + j]
                d, h = diff(cols)
                J[:m, cols[0]] = np.where(self.row_is_right, 0.0, d[:m]) / h[0]
                J[:m, cols[1]] = np.where(self.row_is_right, d[:m], 0.0) / h[1]
            if self.prior is not None:
                J[r.size - 16 :, self.o_intr : self.o_intr + 16] = self.prior[1]
        return J


def _normal(J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J^T J, J^T r)."""
    return J.T @ J, J.T @ r


def _information(J: np.ndarray, interest: np.ndarray, nuisance: np.ndarray) -> np.ndarray:
    """J^T J of the ``interest`` columns with the ``nuisance`` columns marginalised (Schur complement)."""
    A = J[:, interest]
    N = J[:, nuisance]
    I_aa = A.T @ A
    if N.shape[1] == 0:
        return I_aa
    I_an = A.T @ N
    I_nn = N.T @ N
    return I_aa - I_an @ np.linalg.solve(I_nn + 1e-12 * np.eye(len(I_nn)) * np.trace(I_nn) / len(I_nn), I_an.T)


def _scales(specs: Sequence[ParameterSpec] = PARAMETERS) -> np.ndarray:
    return np.array([IDENTIFIABILITY_SCALE[spec.unit] for spec in specs])


def identifiability(J: np.ndarray, free: np.ndarray, nuisance: np.ndarray, *, notes: Mapping[str, str] | None = None,
                    held: Mapping[str, str] | None = None,
                    specs: Sequence[ParameterSpec] = PARAMETERS) -> tuple[np.ndarray, list[IdentifiabilityRow]]:
    """Which of the ``free`` kinematic parameters the whitened Jacobian ``J`` determines.

    ``J``'s first ``len(NAMES)`` columns are the kinematic parameters; ``nuisance`` the column indices
    marginalised (board pose, share, landings, intrinsics). The information matrix of the free
    parameters, scaled to :data:`IDENTIFIABILITY_SCALE`, is decomposed; a direction whose sigma exceeds
    1 (the tolerance) is not determined, and the parameter with the largest part in it is held, until
    every remaining direction is determined. ``notes``: why a parameter group is held by rule (the design
    holds its axis at one value...); ``held``: why a parameter was held by an earlier call. Returns (the mask
    of identified parameters, the table). ``specs``: the kinematic columns' parameters (with tilt joints:
    :func:`stereo_bench.kinematics.model.vector_specs`); a tilt joint the rig does not drive has no row.
    """
    notes = dict(notes or {})
    names = [spec.name for spec in specs]
    scales = _scales(specs)
    free = np.array(free, bool).copy()
    held_note: dict[int, str] = {}
    while free.any():
        idx = np.flatnonzero(free)
        info = _information(J * np.concatenate([scales, np.ones(J.shape[1] - len(scales))]), idx, nuisance)
        w, U = np.linalg.eigh(0.5 * (info + info.T))
        if w[0] >= 1.0:
            break
        vec = U[:, 0]
        worst = int(np.argmax(np.abs(vec)))
        partners = [names[idx[k]] for k in np.argsort(-np.abs(vec)) if k != worst and abs(vec[k]) > 0.3]
        what = "not determined by the design" + (f": confounded with {', '.join(partners)}" if partners
                                                else f" (sigma {1.0 / math.sqrt(max(w[0], 1e-300)):.3g} x its "
                                                     "tolerance)")
        held_note[int(idx[worst])] = what
        free[idx[worst]] = False
    rows: list[IdentifiabilityRow] = []
    idx = np.flatnonzero(free)
    sig = np.full(len(names), np.nan)
    null_share = np.zeros(len(names))
    if idx.size:
        info = _information(J, idx, nuisance)
        cov = np.linalg.inv(info)
        sig[idx] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    # The part of each parameter in the directions left undetermined, with all rule-free parameters.
    for i, spec in enumerate(specs):
        if free[i]:
            rows.append(IdentifiabilityRow(spec.name, spec.unit, True, float(sig[i]), float(null_share[i])))
        elif notes.get(spec.group, "").startswith("not in the model"):
            continue  # the joint of a tilt the rig does not drive: in the vector, not in the rig
        else:
            note = held_note.get(i) or (held or {}).get(spec.name) or notes.get(spec.group, "not identifiable")
            rows.append(IdentifiabilityRow(spec.name, spec.unit, False, None, 1.0, note))
    return free, rows


def identifiability_table(rows: Sequence[IdentifiabilityRow]) -> str:
    """The table as text: one line per parameter."""
    lines = [f"{'parameter':26s} {'identified':10s} {'sigma':>12s}  note"]
    for row in rows:
        sigma = f"{row.sigma:.3g} {row.unit}" if row.sigma is not None else "-"
        lines.append(f"{row.name:26s} {'yes' if row.identified else 'no':10s} {sigma:>12s}  {row.note}")
    return "\n".join(lines)


def fit_fixed_board(
    configurations: Sequence[ConfigurationViews], object_points: np.ndarray, image_size: tuple[int, int], *,
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    intrinsics_covariance: np.ndarray | None = None, refine_intrinsics: bool = True,
    repeatability_mm: float = 0.0, repeatability_left_deg: float = 0.0, repeatability_right_deg: float = 0.0,
    repeatability_tilt_left_deg: float = 0.0, repeatability_tilt_right_deg: float = 0.0,
    reference_baseline_mm: float | None = None, left_share: float = 0.5, min_corners: int = 6,
    max_iterations: int = 50,
) -> FixedBoardFit:
    """Fit the kinematic model to views of one board that stayed put while the rig moved.

    Args:
        configurations: one entry per visit (:class:`~stereo_bench.kinematics.fit.ConfigurationViews`); every
            view of every visit shows the same board, which did not move.
        intrinsics: (K1, D1, K2, D2) to start from (a lens calibration: ``calib_dir``'s).
        intrinsics_covariance: (16, 16) covariance of left.fx ... right.p2 (``INTRINSIC_NAMES``) of that lens
            calibration: a prior in the joint refinement. None with ``refine_intrinsics``: refined from
            these views alone (the identifiability table says whether the design determines them).
        left_share: start value of the part of a baseline change the left carriage makes.
        repeatability_*: std of each axis' landing error per move (a prior on one landing error per axis
            and visit).

    Visits whose ``axes`` report tilts (every one of them: a rig that drives ``tilt_left_deg`` / ``tilt_right_deg``)
    give a model with the tilt joints of :mod:`stereo_bench.kinematics.model`, fitted with the rest.

    Raises:
        ValueError: too few usable views.
    """
    from threadpoolctl import threadpool_limits

    # One BLAS thread: every product and solve here is small, and a threaded BLAS spins 10-100x longer on a loaded
    # 2-core machine (the presented fit measured it; here 23 ms per 140x140 solve against ~1 ms).
    with threadpool_limits(1):
        return _fit_fixed_board(configurations, object_points, image_size, intrinsics=intrinsics,
                                intrinsics_covariance=intrinsics_covariance, refine_intrinsics=refine_intrinsics,
                                repeatability_mm=repeatability_mm, repeatability_left_deg=repeatability_left_deg,
                                repeatability_right_deg=repeatability_right_deg,
                                repeatability_tilts=(repeatability_tilt_left_deg, repeatability_tilt_right_deg),
                                reference_baseline_mm=reference_baseline_mm, left_share=left_share,
                                min_corners=min_corners, max_iterations=max_iterations)


def _fit_fixed_board(configurations, object_points, image_size, *, intrinsics, intrinsics_covariance,
                     refine_intrinsics, repeatability_mm, repeatability_left_deg, repeatability_right_deg,
                     repeatability_tilts, reference_baseline_mm, left_share, min_corners,
                     max_iterations) -> FixedBoardFit:
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
    seen = {v[0] for v in views}
    missing = [c for c in range(len(configurations)) if c not in seen]
    if len(views) < 3 or missing:
        raise ValueError(f"the fixed-board fit needs the board seen by both cameras at every visit "
                         f"(visits without: {missing}, views usable: {len(views)})")
    axes = axes_of(configurations)
    tilted = len(axes) > 3
    specs = vector_specs(axes)
    groups, notes = _identifiable(configurations)
    rule_free = np.array([spec.group in groups for spec in specs])
    baselines = [float(c.axes["baseline_mm"]) for c in configurations]
    B_ref = float(reference_baseline_mm if reference_baseline_mm is not None
                  else 0.5 * (min(baselines) + max(baselines)))
    intr_l = np.concatenate([_intrinsic_vector(intrinsics[0], intrinsics[1])])
    intr_r = _intrinsic_vector(intrinsics[2], intrinsics[3])
    K1, D1 = _K_D(intr_l)
    K2, D2 = _K_D(intr_r)

    # Start: the presented fit's start from the per-visit relative poses, then the one board pose.
    T_lb = [_pnp(object_points[v[1]], v[2], K1, D1) for v in views]
    T_rb = [_pnp(object_points[v[3]], v[4], K2, D2) for v in views]
    per_config: list[list[np.ndarray]] = [[] for _ in configurations]
    for v, (tl, tr) in enumerate(zip(T_lb, T_rb, strict=True)):
        per_config[views[v][0]].append(tr @ np.linalg.inv(tl))
    p0 = _initial_parameters(rule_free, B_ref, configurations, [_average_transform(ts) for ts in per_config])
    d0 = _slide_direction(p0)
    boards = []
    for v, T in enumerate(T_lb):
        conf = configurations[views[v][0]]
        b, tl, _ = _effective(conf.axes, conf.approach, p0)
        shift = np.eye(4)
        shift[:3, 3] = -left_share * p0[_INDEX["slide_scale"]] * (b - B_ref) * d0
        boards.append(shift @ _left_in_S(p0, tl, _effective_tilts(conf.axes, conf.approach, p0)[0]) @ T)
    T_board0 = _average_transform(boards)

    prior = None
    if refine_intrinsics and intrinsics_covariance is not None:
        cov = np.asarray(intrinsics_covariance, float).reshape(16, 16)
        prior = (np.concatenate([intr_l[:8], intr_r[:8]]), np.linalg.inv(np.linalg.cholesky(cov)))
    landing_sigmas = (repeatability_mm, repeatability_left_deg, repeatability_right_deg)
    if tilted:  # one landing per tilt and visit; a tilt the rig does not drive lands exactly (held at 0)
        landing_sigmas += tuple(sigma if axis in axes else 0.0
                                for axis, sigma in zip(TILT_AXES, repeatability_tilts, strict=True))

    def build(sigma_px: float, p: np.ndarray) -> _FixedBundle:
        return _FixedBundle(p, B_ref, configurations, views, object_points, np.concatenate([intr_l, intr_r]),
                            sigma_px=sigma_px, landing_sigmas=landing_sigmas, intrinsics_prior=prior,
                            refine_intrinsics=refine_intrinsics)

    sigma_px = 0.1
    bundle = build(sigma_px, p0)
    x = np.concatenate([p0, [left_share], _rvec(T_board0[:3, :3]), T_board0[:3, 3],
                        np.zeros(bundle.n_axes * len(configurations)),
                        np.concatenate([intr_l[:8], intr_r[:8]]) if refine_intrinsics else []])
    # Landing errors of an axis with no stated repeatability are not unknowns (exact landings).
    nuisance = np.array([k for k in range(bundle.n_k, bundle.n)
                         if not (bundle.o_land <= k < bundle.o_intr and (k - bundle.o_land) % bundle.n_axes not in
                                 bundle.landing_axes)], int)
    if len(set(baselines)) < 2:
        nuisance = nuisance[nuisance != bundle.o_share]  # the share needs two baselines: held
    # Which parameters the design determines, at the start (a Jacobian there is as good for the rank).
    J0 = bundle.jacobian(x, bundle.residuals(x))
    free, start_table = identifiability(J0, rule_free, nuisance, notes=notes, specs=specs)
    held = {row.name: row.note for row in start_table if not row.identified}
    nominal = nominal_parameters(B_ref, axes)
    x[: bundle.n_k] = np.where(free, x[: bundle.n_k], nominal)  # what the design cannot identify: held nominal

    active = np.concatenate([np.flatnonzero(free), nuisance]).astype(int)
    converged = False
    for _ in range(3):
        bundle = build(sigma_px, x[: bundle.n_k])

        def residuals(z: np.ndarray, bundle=bundle) -> np.ndarray:
            full = x.copy()
            full[active] = z
            return bundle.residuals(full)

        def normal(z: np.ndarray, r: np.ndarray, bundle=bundle) -> tuple[np.ndarray, np.ndarray]:
            full = x.copy()
            full[active] = z
            J = bundle.jacobian(full, r)[:, active]
            return _normal(J, r)

        z, _ = _levenberg_marquardt(residuals, normal, _solve_dense, x[active], max_iterations=max_iterations)
        x[active] = z
        r = bundle.residuals(x)
        pixel = r[: bundle.m_px] * sigma_px
        dof = max(1, bundle.m_px - (len(active) - bundle.n_axes * len(configurations)))
        estimate = max(math.sqrt(float(pixel @ pixel) / dof), 1e-6)
        converged = abs(estimate / sigma_px - 1.0) < 0.05
        sigma_px = estimate
        if converged:
            break
    bundle = build(sigma_px, x[: bundle.n_k])
    r = bundle.residuals(x)
    J = bundle.jacobian(x, r)
    # The table at the solution (the start's Jacobian chose what to hold; at the solution it says the same
    # unless the start was far off, and then the table tells).
    _, table = identifiability(J, free, nuisance, notes=notes, held=held, specs=specs)
    cov = np.linalg.inv(_normal(J[:, active], r)[0])
    n_free = int(free.sum())
    cov_k = cov[:n_free, :n_free]
    p = x[: bundle.n_k]
    by_name = {row.name: row for row in table}
    intrinsic_names: list[str] = []
    cov_i = cross = np.zeros((0, 0))
    il, ir = bundle.intrinsics(x)
    if refine_intrinsics:
        where = [int(np.flatnonzero(active == bundle.o_intr + j)[0]) for j in range(16)]
        intrinsic_names = list(INTRINSIC_NAMES)
        cov_i = cov[np.ix_(where, where)]
        cross = cov[np.ix_(where, list(range(n_free)))]
    residual = (r[: bundle.m_px] * sigma_px).reshape(-1, 2)
    split = bundle.m_left // 2
    model, per_view = assemble_model(
        configurations, p=p, free=free, cov_k=cov_k,
        held_note=lambda spec: by_name[spec.name].note if spec.name in by_name else notes.get(spec.group, ""),
        residual_px=residual, row_view=bundle.row_view[::2], view_config=bundle.view_config, intr_l=il, intr_r=ir,
        image_size=image_size, B_ref=B_ref,
        repeatability=landing_sigmas, sigma_px=sigma_px,
        dof=dof, intrinsics=("refined jointly, lens calibration as prior" if prior is not None else
                             "refined jointly" if refine_intrinsics else "fixed"),
        intrinsic_names=intrinsic_names, cov_i=cov_i, cross=cross, locking=None,
        # The residuals binned per camera, as the presented fit keeps them: the budget reads the corner error
        # beyond noise from them (docs/UNCERTAINTY.md) instead of bounding it as coherent.
        residual_maps={side: ResidualMapRecord.of(bundle.obs[side][2], pixels, image_size) for side, pixels in
                       (("left", residual[:split]), ("right", residual[split:]))})
    return FixedBoardFit(model=model, T_ref_board=_pose_matrix(x[bundle.o_board : bundle.o_board + 6]),
                         left_share=float(x[bundle.o_share]), identifiability=table, view_rms_px=per_view,
                         view_configuration=bundle.view_config.copy(),
                         landing=x[bundle.o_land : bundle.o_intr].reshape(len(configurations), bundle.n_axes),
                         views_dropped=dropped)


def design_visits(design) -> tuple[list[ConfigurationViews], float]:
    """The visits of ``design`` in order, each with the approach directions that order gives (no views yet), and
    the reference baseline (mm) of a fit to them: the middle of their baselines."""
    from stereo_bench.kinematics.design import approach_directions

    configurations, previous, approach = [], None, {}
    for visit in design:
        approach = approach_directions(previous, visit.axes(), approach)
        previous = visit.axes()
        configurations.append(ConfigurationViews(visit.axes(), dict(approach), []))
    baselines = [c.axes["baseline_mm"] for c in configurations]
    return configurations, 0.5 * (min(baselines) + max(baselines))


@dataclass(frozen=True)
class PlannedFit:
    """What a fixed-board design's fit will know, before any view is taken (:func:`planned_fit`).

    ``rows``: the identifiability table. ``model``: the nominal rig's model with the covariance the design's exact
    views give its identified parameters (every nuisance marginalised: board pose, carriage share, landings,
    intrinsics with their prior); the held ones at nominal without a sigma. Through
    :func:`stereo_bench.kinematics.prediction.predict` it gives the sigma of R, T the fit will predict at any
    configuration, the error of a held parameter (the rig's build tolerance) not counted.
    """

    rows: list[IdentifiabilityRow]
    model: KinematicModel


def design_identifiability(design: Sequence[DesignConfiguration], object_points: np.ndarray, T_rig_board: np.ndarray,
                           intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], **kw,
                           ) -> list[IdentifiabilityRow]:
    """The identifiability table a fixed-board design will have, before any view is taken (:func:`planned_fit`'s
    ``rows``; the same arguments)."""
    return planned_fit(design, object_points, T_rig_board, intrinsics, **kw).rows


def planned_fit(
    design: Sequence[DesignConfiguration], object_points: np.ndarray, T_rig_board: np.ndarray,
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], *, pixel_sigma_px: float = 0.1,
    intrinsics_covariance: np.ndarray | None = None, refine_intrinsics: bool = True, repeatability_mm: float = 0.0,
    repeatability_deg: float = 0.0, repeatability_tilt_deg: float | None = None,
    image_size: tuple[int, int] = (0, 0),
) -> PlannedFit:
    """The identifiability table and the planned model a fixed-board design will have, before any view is taken
    (``campaign plan``).

    The board at ``T_rig_board`` (the rig frame of :class:`stereo_bench.geometry.RigPose`) is projected exactly
    through the nominal chain at every visit of ``design`` (visited in order, approach directions from the
    order); the Jacobian there, whitened by ``pixel_sigma_px``, is what :func:`identifiability` reads. The views
    are the nominal rig's: a built rig differs by its tolerances, which change the table little. A design with
    tilts (:func:`fixed_board_design`'s ``tilt_ranges_deg``) has the tilt joints' rows too; their landings' std is
    ``repeatability_tilt_deg`` (None: ``repeatability_deg``, the heads'). ``image_size`` (w, h px) is only recorded
    in the planned model.
    """
    from stereo_bench.geometry import RigPose

    configurations, B_ref = design_visits(design)
    T_ref_board = np.linalg.inv(RigPose(B_ref, 90.0, 90.0).T_rig_left) @ np.asarray(T_rig_board, float)
    intr = np.concatenate([_intrinsic_vector(intrinsics[0], intrinsics[1]), _intrinsic_vector(intrinsics[2],
                                                                                              intrinsics[3])])
    points = np.asarray(object_points, float).reshape(-1, 3)
    ids = np.arange(len(points))
    axes = axes_of(configurations)
    specs = vector_specs(axes)
    p0 = nominal_parameters(B_ref, axes)
    sigmas = (repeatability_mm, repeatability_deg, repeatability_deg)
    if len(axes) > 3:
        tilt_sigma = repeatability_deg if repeatability_tilt_deg is None else repeatability_tilt_deg
        sigmas += tuple(tilt_sigma if axis in axes else 0.0 for axis in TILT_AXES)
    x = np.concatenate([p0, [0.5], _rvec(T_ref_board[:3, :3]), T_ref_board[:3, 3],
                        np.zeros(len(sigmas) * len(configurations)),
                        intr[[0, 1, 2, 3, 4, 5, 6, 7, 9, 10, 11, 12, 13, 14, 15, 16]] if refine_intrinsics else []])
    placeholder = [(c, ids, np.zeros((len(ids), 2)), ids, np.zeros((len(ids), 2))) for c in range(len(configurations))]
    prior = None
    if refine_intrinsics and intrinsics_covariance is not None:
        cov = np.asarray(intrinsics_covariance, float).reshape(16, 16)
        prior = (x[-16:].copy(), np.linalg.inv(np.linalg.cholesky(cov)))

    def bundle(views):
        return _FixedBundle(p0, B_ref, configurations, views, points, intr, sigma_px=pixel_sigma_px,
                            landing_sigmas=sigmas, intrinsics_prior=prior, refine_intrinsics=refine_intrinsics)

    T_L, T_R = bundle(placeholder).transforms(x)
    il, ir = intr[:9], intr[9:]
    views = [(c, ids, _project(_rotate(np.repeat(T_L[c, None, :3, :3], len(ids), 0), points) + T_L[c, :3, 3], il),
              ids, _project(_rotate(np.repeat(T_R[c, None, :3, :3], len(ids), 0), points) + T_R[c, :3, 3], ir))
             for c in range(len(configurations))]
    exact = bundle(views)
    groups, notes = _identifiable(configurations)
    rule_free = np.array([spec.group in groups for spec in specs])
    nuisance = np.array([k for k in range(exact.n_k, exact.n)
                         if not (exact.o_land <= k < exact.o_intr and (k - exact.o_land) % exact.n_axes not in
                                 exact.landing_axes)], int)
    if len({c.axes["baseline_mm"] for c in configurations}) < 2:
        nuisance = nuisance[nuisance != exact.o_share]
    J = exact.jacobian(x, exact.residuals(x))
    free, rows = identifiability(J, rule_free, nuisance, notes=notes, specs=specs)
    index = np.flatnonzero(free)
    cov_k = np.linalg.inv(_information(J, index, nuisance)) if index.size else np.zeros((0, 0))
    by_name = {row.name: row for row in rows}
    n_corners = exact.m_px // 2
    model, _ = assemble_model(
        configurations, p=p0, free=free, cov_k=cov_k,
        held_note=lambda spec: by_name[spec.name].note if spec.name in by_name else notes.get(spec.group, ""),
        residual_px=np.zeros((n_corners, 2)), row_view=exact.row_view[::2], view_config=exact.view_config,
        intr_l=il, intr_r=ir, image_size=image_size, B_ref=B_ref, repeatability=sigmas, sigma_px=pixel_sigma_px,
        dof=max(1, exact.m_px - int(free.sum())), intrinsics="planned: the design's exact views on the nominal rig",
        intrinsic_names=[], cov_i=np.zeros((0, 0)), cross=np.zeros((0, 0)), locking=None, residual_maps={})
    return PlannedFit(rows, model)
