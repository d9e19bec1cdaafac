"""Calibration quality gates: a calibration that the data say is poor is refused, with its cause in one line.

Each gate measures one number on the calibration's own views, compares it with a named threshold and says
what is wrong in words that name the cause (docs/CALIBRATION.md, a section per gate). They run after the
detection and the fit (:func:`run_gates`, called by :func:`stereo_bench.vision.pipeline.calibrate_from_images`
before the physical-sanity checks, so that the cause is named rather than its symptom) and on a failure
raise :class:`CalibrationRefused` unless the caller accepts a poor calibration (``calibrate --accept-poor``).

The gates and what they measure (units in the names):
- ``synchronised``: per view, the stereo residual (one board pose for both cameras, through R, T) over the
  larger of the two mono residuals (each image with its own pose). A board that moved between the left and
  the right exposure fits each image alone but not both at once.
- ``consistent_views``: the share of views the calibration's outlier rule dropped (their reasons recorded).
- ``sharpness``: per image, the blur of the board's edges (Gaussian sigma, px) from the steepest grey-level
  step across the edges between adjacent corners; motion blur is told from defocus by its direction.
- ``flatness``: a bowl-shaped bend of the board (peak-to-valley, relative to the board's diagonal) fitted to
  the mono residuals of all views at once, each view's pose free (a flat board leaves no such pattern).
- ``board_fit``: the board size given against the one the images show (run where the board is missed).
- ``left_right``: the right camera's centre lies on the left camera's +x side (BRIEF section 3).

Pure functions of arrays: no files, no printing.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from stereo_bench.targets import Checkerboard, Target
from stereo_bench.vision.calibrate import ImplausibleCalibration, StereoCalibration
from stereo_bench.vision.detect import THOROUGH_SEARCH_WIDTH_PX, AnyBoardSearch, _search_image

# --- thresholds (docs/CALIBRATION.md says why each has its value) ---
# synchronised: a view fails when its stereo residual exceeds SYNC_RATIO_MAX x the larger mono residual AND
# SYNC_FLOOR_PX. Synchronised real views: ratio 1.0-1.7 (opencv_sample, present_cjn, smiler488_box).
SYNC_RATIO_MAX = 3.0
SYNC_FLOOR_PX = 1.0
# consistent_views: refused when the outlier rule dropped more than this share of the views with the board.
MAX_DROPPED_SHARE = 0.25
# sharpness: refused when an image's board edges are blurred beyond BLUR_MAX_PX (Gaussian sigma) or beyond
# BLUR_MAX_SQUARE_FRACTION of the square's side in that image; the blur counts as motion when the two edge
# directions differ by more than MOTION_ANISOTROPY.
BLUR_MAX_PX = 3.0
BLUR_MAX_SQUARE_FRACTION = 0.15
MOTION_ANISOTROPY = 1.6
# flatness: refused when the fitted bowl's peak-to-valley exceeds FLATNESS_MAX_REL of the board's diagonal
# and FLATNESS_MIN_SIGMAS standard deviations of its own estimate.
FLATNESS_MAX_REL = 0.005
FLATNESS_MIN_SIGMAS = 5.0
# board_fit: fails when at least this many of the searched images agree on a checkerboard of another size
# (whole: at least one square from the image border, so that a board cut by the border is not taken for a small
# one); one image could be a second board in the room.
BOARD_FIT_MIN_OTHER = 2
# ... and a board smaller than the one named counts only when the named one is missing from over half the images.
BOARD_FIT_MIN_FOUND_SHARE = 0.5
# ... and an image where the named board was found is searched only when its grid's checker pattern may go on past
# an edge (a larger board): the four squares meeting one step beyond every edge corner are sampled, and a side ends
# where its two inner squares differ by over BOARD_EDGE_CONTRAST_DN and its two outer squares do not repeat them
# crosswise; a side with fewer than half its points inside the image and contrasted cannot be judged (searched).
BOARD_EDGE_CONTRAST_DN = 20.0
# left_right: judged only for side-by-side cameras (|x| of the right centre over its distance at least this).
SIDE_BY_SIDE_MIN = 0.5

GATE_NAMES = ("board_fit", "synchronised", "consistent_views", "sharpness", "flatness", "left_right")


@dataclass(frozen=True)
class GateResult:
    """One gate: ``value`` measured against ``threshold`` (both in ``unit``); ``verdict`` 'pass', 'fail' or
    'n/a' (does not apply to these views); ``line`` the finding in one line; ``views`` the pairs it names."""

    name: str
    value: float
    threshold: float
    unit: str
    verdict: str
    line: str
    views: tuple[int, ...] = ()

    def as_dict(self) -> dict:
        value = float(self.value) if np.isfinite(self.value) else None  # JSON has no NaN
        return {"name": self.name, "value": value, "threshold": float(self.threshold), "unit": self.unit,
                "verdict": self.verdict, "line": self.line, "views": list(self.views)}


@dataclass(frozen=True)
class GateReport:
    results: tuple[GateResult, ...]
    accept_poor: bool = False
    view_diagnoses: dict[int, str] = field(default_factory=dict)  # pair index -> what is wrong with that view

    @property
    def failed(self) -> list[GateResult]:
        return [r for r in self.results if r.verdict == "fail"]

    @property
    def refused(self) -> bool:
        return bool(self.failed) and not self.accept_poor

    def refusal_line(self) -> str:
        return "; ".join(r.line for r in self.failed)

    def as_dict(self) -> dict:
        return {"gates_run": [r.name for r in self.results], "accept_poor": self.accept_poor,
                "refused": self.refused, "gates": {r.name: r.as_dict() for r in self.results}}

    def file_items(self) -> dict[str, object]:
        """Keys for the calibration files (:func:`~stereo_bench.vision.calibio.write_calibration`'s ``extra``)."""
        items: dict[str, object] = {"gates_run": " ".join(r.name for r in self.results),
                                    "gates_accept_poor": int(self.accept_poor)}
        for r in self.results:
            items.update({f"gate_{r.name}_value": float(r.value) if np.isfinite(r.value) else -1.0,
                          f"gate_{r.name}_threshold": float(r.threshold), f"gate_{r.name}_unit": r.unit,
                          f"gate_{r.name}_verdict": r.verdict, f"gate_{r.name}_line": r.line})
        return items

    def replaced(self, result: GateResult) -> GateReport:
        """This report with the gate of ``result``'s name measured again: ``result`` in its place."""
        return GateReport(tuple(result if r.name == result.name else r for r in self.results), self.accept_poor,
                          self.view_diagnoses)

    def merged(self, other: GateReport) -> GateReport:
        return GateReport(self.results + other.results, self.accept_poor,
                          {**self.view_diagnoses, **other.view_diagnoses})


class CalibrationRefused(ImplausibleCalibration):
    """The quality gates refused the calibration; ``report`` holds every gate's measurement."""

    def __init__(self, report: GateReport):
        # What keeps it anyway is the caller's to say (calibrate: --accept-poor); a campaign has no such option.
        super().__init__(f"calibration refused by the quality gates: {report.refusal_line()}")
        self.report = report


@dataclass(frozen=True)
class GateView:
    """One stereo view: its pair index, ``object_points`` (N, 3) mm of the corners seen in both images,
    ``left_px``/``right_px`` (N, 2), and the grey images (None: the sharpness gate skips the view)."""

    index: int
    object_points: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    left_image: np.ndarray | None = None
    right_image: np.ndarray | None = None


def _name(index: int, names: Sequence[str] | None) -> str:
    return f"pair {index}" + (f" ({names[index]})" if names is not None and index < len(names) else "")


def _names(indices: Sequence[int], names: Sequence[str] | None, most: int = 6) -> str:
    shown = ", ".join(_name(i, names) for i in list(indices)[:most])
    return shown + (f" and {len(indices) - most} more" if len(indices) > most else "")


# --- per-view residuals -------------------------------------------------------------------------------------

def _project(obj: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    return cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, D)[0].reshape(-1, 2)


def _rms(residual: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.square(residual), axis=-1))))


def mono_pose(obj: np.ndarray, px: np.ndarray, K: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(rvec (3,), tvec (3,) mm, RMS px) of the board in one image with the camera's intrinsics fixed."""
    obj = np.asarray(obj, np.float64).reshape(-1, 3)
    px = np.asarray(px, np.float64).reshape(-1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, px, K, D, flags=cv2.SOLVEPNP_IPPE if len(obj) >= 4 else cv2.SOLVEPNP_ITERATIVE)
    rvec, tvec = cv2.solvePnPRefineLM(obj, px, K, D, rvec, tvec)
    rvec, tvec = rvec.reshape(3), tvec.reshape(3)
    return rvec, tvec, _rms(px - _project(obj, rvec, tvec, K, D))


class PoseCache:
    """:func:`mono_pose` of each (board points, pixels, K, D) computed once: the synchronisation gate and the
    flatness gate fit the same images with the same mono intrinsics (and, without mono fits, the synchronisation
    gate fits each image twice with the same ones). Keyed by the arrays' identities, so it serves one
    :func:`run_gates` call, whose views hold the arrays; the same calls on the same numbers: the same bits.

    :meth:`of_fit` fills it with the poses the calibration's own fits found instead (each camera's mono fit, and
    the stereo fit's one pose per view, :meth:`joint`): at a fit's solution each view's pose is the one that view
    alone gives with those intrinsics (the fit's gradient in its pose is zero), so solving it again (solvePnP +
    refine, ~0.5 ms per image) finds the same pose to the solvers' tolerance."""

    def __init__(self) -> None:
        self._poses: dict[tuple[int, int, int, int], tuple[tuple, tuple[np.ndarray, np.ndarray, float]]] = {}
        self._fitted: dict[tuple[int, int, int, int], tuple[tuple, np.ndarray, np.ndarray]] = {}
        self._joint: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    @classmethod
    def of_fit(cls, calib: StereoCalibration, views: Sequence[GateView]) -> PoseCache:
        """The poses ``calib``'s fits found for ``views``, which must be the views it was fitted from in that order
        (``views[k]`` the k-th: ``calib.views_used`` and its mono fits' ``views_used`` index them). A view a fit
        dropped has no pose of that fit: :meth:`pose` solves it, :meth:`joint` is None."""
        cache = cls()
        if calib.mono:
            for fit, side in zip(calib.mono, ("left", "right"), strict=True):
                for k, rvec, tvec in zip(fit.views_used, fit.rvecs, fit.tvecs, strict=True):
                    view = views[k]
                    px = view.left_px if side == "left" else view.right_px
                    key = (id(view.object_points), id(px), id(fit.K), id(fit.dist))
                    cache._fitted[key] = ((view.object_points, px, fit.K, fit.dist), rvec, tvec)
        if len(calib.board_poses) == len(calib.views_used):
            cache._joint = {views[k].index: pose for k, pose in zip(calib.views_used, calib.board_poses, strict=True)}
        return cache

    def pose(self, obj: np.ndarray, px: np.ndarray, K: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                         float]:
        key = (id(obj), id(px), id(K), id(D))
        if key not in self._poses:
            if key in self._fitted:
                _, rvec, tvec = self._fitted[key]
                points = np.asarray(obj, np.float64).reshape(-1, 3)
                result = (rvec, tvec, _rms(np.asarray(px, np.float64).reshape(-1, 2) - _project(points, rvec, tvec,
                                                                                                 K, D)))
            else:
                result = mono_pose(obj, px, K, D)
            # The arrays are kept with their result: their ids stay theirs while the cache lives.
            self._poses[key] = ((obj, px, K, D), result)
        return self._poses[key][1]

    def joint(self, index: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The stereo fit's board pose (rvec, tvec in the left camera's frame) of the view of pair ``index``, or
        None (not filled by :meth:`of_fit`, or a view the fit dropped)."""
        return self._joint.get(index)


def _stereo_residual(calib: StereoCalibration, obj: np.ndarray, observed: np.ndarray, p: np.ndarray,
                     rvec_stereo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(residual (4N,) px, Jacobian (4N, 6)) of one board pose p = (rvec, tvec) in the left camera's frame, seen
    by the left camera and, through (R, T) (``composeRT``'s chain rule), by the right one."""
    T = np.asarray(calib.T, float).reshape(3, 1)
    rvec, tvec = p[:3].reshape(3, 1), p[3:].reshape(3, 1)
    left, jac_left = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, calib.K1, calib.D1)
    rvec_r, tvec_r, dr_dr1, dr_dt1, _, _, dt_dr1, dt_dt1, _, _ = cv2.composeRT(rvec, tvec, rvec_stereo, T)
    right, jac_right = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec_r, tvec_r, calib.K2, calib.D2)
    chain = np.block([[dr_dr1, dr_dt1], [dt_dr1, dt_dt1]])  # d(rvec_r, tvec_r) / d(rvec, tvec)
    J = np.concatenate([jac_left[:, :6], jac_right[:, :6] @ chain])
    residual = observed - np.concatenate([left.reshape(-1, 2), right.reshape(-1, 2)]).reshape(-1)
    return residual, -J


def stereo_view_rms_px(calib: StereoCalibration, obj: np.ndarray, left_px: np.ndarray, right_px: np.ndarray,
                       starts: Sequence[tuple[np.ndarray, np.ndarray]], *, iterations: int = 10) -> float:
    """RMS (px, over both images' corners) of one view with ONE board pose (in the left camera's frame) seen by
    both cameras through the calibration's R, T: Gauss-Newton from the best of ``starts`` (rvec, tvec)."""
    obj = np.asarray(obj, np.float64).reshape(-1, 3)
    observed = np.concatenate([np.asarray(left_px, float).reshape(-1, 2),
                               np.asarray(right_px, float).reshape(-1, 2)]).reshape(-1)
    rvec_stereo = cv2.Rodrigues(np.asarray(calib.R, float))[0]
    best = None
    for rvec, tvec in starts:
        p = np.concatenate([np.asarray(rvec, float).reshape(3), np.asarray(tvec, float).reshape(3)])
        r, J = _stereo_residual(calib, obj, observed, p, rvec_stereo)
        if best is None or r @ r < best[1] @ best[1]:
            best = (p, r, J)
    p, r, J = best
    for _ in range(iterations):
        delta, *_ = np.linalg.lstsq(J, -r, rcond=None)
        r_new, J_new = _stereo_residual(calib, obj, observed, p + delta, rvec_stereo)
        if r_new @ r_new >= r @ r:
            break
        improvement = (r @ r - r_new @ r_new) / max(r @ r, 1e-300)
        p, r, J = p + delta, r_new, J_new
        if improvement < 1e-8:
            break
    return _rms(r.reshape(-1, 2))


@dataclass(frozen=True)
class ViewResiduals:
    index: int
    mono_left_px: float
    mono_right_px: float
    stereo_px: float

    @property
    def ratio(self) -> float:
        return self.stereo_px / max(self.mono_left_px, self.mono_right_px, 1e-9)

    @property
    def not_together(self) -> bool:
        return self.ratio > SYNC_RATIO_MAX and self.stereo_px > SYNC_FLOOR_PX


def _mono_intrinsics(calib: StereoCalibration) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """((K1, D1), (K2, D2)) of each camera calibrated alone when the fit did that, else the calibration's."""
    if calib.mono:
        return (calib.mono[0].K, calib.mono[0].dist), (calib.mono[1].K, calib.mono[1].dist)
    return (calib.K1, calib.D1), (calib.K2, calib.D2)


def view_residuals(calib: StereoCalibration, view: GateView, poses: PoseCache | None = None) -> ViewResiduals:
    """Mono residuals (each image with its own pose) and the stereo residual (one pose for both) of a view.
    ``poses``: a :class:`PoseCache` shared with the other gates of one run."""
    poses = poses or PoseCache()
    pose = poses.pose
    # Each image alone with its camera's own mono calibration where there is one: a joint fit of pairs that
    # were not taken together bends the intrinsics until no view fits, alone or not.
    (K1, D1), (K2, D2) = _mono_intrinsics(calib)
    _, _, mono_left = pose(view.object_points, view.left_px, K1, D1)
    _, _, mono_right = pose(view.object_points, view.right_px, K2, D2)
    fitted = poses.joint(view.index)
    if fitted is not None:
        # The stereo fit's own pose of this view: its solution for these intrinsics and R, T already.
        starts: tuple[tuple[np.ndarray, np.ndarray], ...] = (fitted,)
    else:
        rl, tl, _ = pose(view.object_points, view.left_px, calib.K1, calib.D1)
        rr, tr, _ = pose(view.object_points, view.right_px, calib.K2, calib.D2)
        # Start from each camera's own pose (the right one carried into the left frame) and keep the better fit.
        R, T = np.asarray(calib.R, float), np.asarray(calib.T, float).reshape(3)
        starts = ((rl, tl), (cv2.Rodrigues(R.T @ cv2.Rodrigues(rr)[0])[0].reshape(3), R.T @ (tr - T)))
    stereo = stereo_view_rms_px(calib, view.object_points, view.left_px, view.right_px, starts)
    return ViewResiduals(view.index, mono_left, mono_right, stereo)


# --- gates --------------------------------------------------------------------------------------------------

def misfit_side(view: ViewResiduals, typical_px: float) -> str | None:
    """The image ("left" or "right") of a view whose board does not fit its own camera: its mono residual above
    ``SYNC_RATIO_MAX`` x ``typical_px`` (the views' median mono residual) and ``SYNC_FLOOR_PX``. Its corners are then
    not the board's (a wrong detection, another board), and a large stereo residual is that, not two moments; None
    when both images fit."""
    side, worst = max((("left", view.mono_left_px), ("right", view.mono_right_px)), key=lambda item: item[1])
    return side if worst > SYNC_RATIO_MAX * typical_px and worst > SYNC_FLOOR_PX else None


def _typical_mono_px(residuals: Sequence[ViewResiduals]) -> float:
    return float(np.median([r for v in residuals for r in (v.mono_left_px, v.mono_right_px)]))


def view_diagnosis(view: ViewResiduals, typical_px: float) -> str:
    """Why a view whose stereo residual is far above its mono residuals (``not_together``) fails, in a phrase."""
    side = misfit_side(view, typical_px)
    if side is not None:
        mono = view.mono_left_px if side == "left" else view.mono_right_px
        return (f"the board found in the {side} image does not fit its camera (that image alone {mono:.2f} px, the "
                f"views' median {typical_px:.2f} px): a wrong detection or another board")
    return (f"left and right not taken together (stereo residual {view.stereo_px:.2f} px, each image alone "
            f"{view.mono_left_px:.2f} / {view.mono_right_px:.2f} px)")


def gate_synchronised(residuals: Sequence[ViewResiduals], names: Sequence[str] | None = None) -> GateResult:
    """Fails when a view's stereo residual is far above both of its mono residuals (``SYNC_*``). The line says which
    of those views' images do not fit their own camera (:func:`misfit_side`: not a matter of timing) and which were
    not taken together."""
    if not residuals:
        return GateResult("synchronised", float("nan"), SYNC_RATIO_MAX, "ratio", "n/a", "no views")
    worst = max(residuals, key=lambda v: v.ratio)
    bad = [v for v in residuals if v.not_together]
    if not bad:
        return GateResult("synchronised", worst.ratio, SYNC_RATIO_MAX, "ratio", "pass",
                          f"left and right taken together: worst stereo/mono residual ratio {worst.ratio:.2f} "
                          f"({_name(worst.index, names)})")
    typical = _typical_mono_px(residuals)
    side_of = {v.index: misfit_side(v, typical) for v in bad}
    misfits = [v for v in bad if side_of[v.index] is not None]
    apart = [v for v in bad if side_of[v.index] is None]
    parts = []
    if apart:
        v = max(apart, key=lambda b: b.ratio)
        parts.append(
            f"left and right images not taken at the same moment in {len(apart)} of {len(residuals)} pairs "
            f"({_names([b.index for b in apart], names)}): the board moved between the two exposures, e.g. "
            f"{_name(v.index, names)} fits each image alone to {v.mono_left_px:.2f} / {v.mono_right_px:.2f} px but "
            f"both at once only to {v.stereo_px:.2f} px ({v.ratio:.0f}x, limit {SYNC_RATIO_MAX:g}x and "
            f"{SYNC_FLOOR_PX:g} px); synchronise the cameras or hold the board still for each pair")
    if misfits:
        v = max(misfits, key=lambda b: max(b.mono_left_px, b.mono_right_px))
        worst_mono = max(v.mono_left_px, v.mono_right_px)
        parts.append(
            f"in {len(misfits)} of {len(residuals)} pairs the board found in one image does not fit that camera "
            f"({_names([b.index for b in misfits], names)}): e.g. {_name(v.index, names)}'s {side_of[v.index]} image "
            f"alone fits only to {worst_mono:.2f} px (the views' median {typical:.2f} px), so its corners are not the "
            "board's: a wrong detection or another board; remove those pairs")
    return GateResult("synchronised", worst.ratio, SYNC_RATIO_MAX, "ratio", "fail", "; ".join(parts),
                      tuple(b.index for b in bad))


def gate_consistent_views(n_views: int, dropped: Sequence[tuple[int, str]],
                          names: Sequence[str] | None = None) -> GateResult:
    """Fails when the calibration's outlier rule dropped more than ``MAX_DROPPED_SHARE`` of the views."""
    share = len(dropped) / n_views if n_views else 0.0
    if share <= MAX_DROPPED_SHARE:
        line = ("every view consistent with the rest" if not dropped else
                f"{len(dropped)} of {n_views} views dropped as inconsistent with the rest: "
                + "; ".join(f"{_name(i, names)}: {why}" for i, why in dropped))
        return GateResult("consistent_views", share, MAX_DROPPED_SHARE, "share", "pass", line,
                          tuple(i for i, _ in dropped))
    return GateResult(
        "consistent_views", share, MAX_DROPPED_SHARE, "share", "fail",
        f"views inconsistent with each other: {len(dropped)} of {n_views} views disagree with the rest "
        f"(over {MAX_DROPPED_SHARE:.0%}: {_names([i for i, _ in dropped], names)}), so no one camera model fits "
        "these images: the cameras moved, zoomed or refocused during the capture, or the views are of two rigs",
        tuple(i for i, _ in dropped))


_SQRT_2PI = float(np.sqrt(2 * np.pi))


def edge_blur_px(gray: np.ndarray, grid: np.ndarray) -> tuple[float, float]:
    """(blur along rows, blur along columns): median Gaussian sigma (px) of the board's edges in ``gray``.

    ``grid`` (rows, cols, 2) inner corners. Between two adjacent corners runs the edge between a black and a
    white square; across its middle the grey level steps by the contrast C, and a step blurred by a Gaussian
    of sigma s has the steepest slope C / (s sqrt(2 pi)). The profile (0.25 px samples over +- 0.35 of the
    corner spacing, bilinear) gives C (its ends' difference) and the slope, hence s. The first value is of
    the edges between row-adjacent corners (they blur under motion across them, i.e. along the rows).
    """
    gray = np.asarray(gray, np.float32)
    out = []
    for axis in (1, 0):  # edges between corners adjacent along a row, then along a column
        a = grid[:, :-1] if axis == 1 else grid[:-1, :]
        b = grid[:, 1:] if axis == 1 else grid[1:, :]
        a, b = a.reshape(-1, 2), b.reshape(-1, 2)
        if len(a) == 0:
            out.append(float("nan"))
            continue
        mid, along = 0.5 * (a + b), b - a
        length = np.linalg.norm(along, axis=1, keepdims=True)
        normal = np.stack([-along[:, 1], along[:, 0]], axis=1) / np.maximum(length, 1e-9)
        half = 0.35 * length
        steps = np.linspace(-1.0, 1.0, 2 * int(np.ceil(float(half.max()) / 0.25)) + 1)
        ds = (half * (steps[1] - steps[0])).reshape(-1)  # sample spacing per edge (px)
        points = mid[:, None, :] + normal[:, None, :] * (half[:, :, None] * steps[None, :, None])
        maps = points.astype(np.float32)
        profile = cv2.remap(gray, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        profile = cv2.GaussianBlur(profile, (5, 1), 0)  # against the noise of 0.25 px samples of 8-bit levels
        ends = len(steps) // 6 + 1
        contrast = np.abs(profile[:, -ends:].mean(axis=1) - profile[:, :ends].mean(axis=1))
        slope = np.max(np.abs(np.diff(profile, axis=1)), axis=1) / ds
        ok = (contrast > 20) & (slope > 0)
        sigma = contrast[ok] / (_SQRT_2PI * slope[ok])
        out.append(float(np.median(sigma)) if ok.any() else float("nan"))
    return out[0], out[1]


def gate_sharpness(blurs: Sequence[tuple[int, str, float, float, float]],
                   names: Sequence[str] | None = None) -> GateResult:
    """``blurs``: (pair index, side, blur along rows px, along columns px, square side px) per image."""
    if not blurs:
        return GateResult("sharpness", float("nan"), BLUR_MAX_PX, "px", "n/a", "no images to measure")
    def limit(square_px: float) -> float:
        return min(BLUR_MAX_PX, BLUR_MAX_SQUARE_FRACTION * square_px)
    scored = [(max(r, c) / limit(s), i, side, r, c, s) for i, side, r, c, s in blurs if np.isfinite(max(r, c))]
    if not scored:
        return GateResult("sharpness", float("nan"), BLUR_MAX_PX, "px", "n/a", "no edge with enough contrast")
    worst = max(scored)
    bad = sorted([s for s in scored if s[0] > 1.0], reverse=True)
    value = max(worst[3], worst[4])
    if not bad:
        return GateResult("sharpness", value, limit(worst[5]), "px", "pass",
                          f"board edges sharp: worst blur sigma {value:.2f} px ({_name(worst[1], names)} "
                          f"{worst[2]}, limit {limit(worst[5]):.2f} px)")
    _, i, side, along_rows, along_cols, square = bad[0]
    motion = max(along_rows, along_cols) > MOTION_ANISOTROPY * min(along_rows, along_cols)
    cause = (f"motion blur ({'across the columns' if along_rows > along_cols else 'across the rows'}: edges spread "
             f"{max(along_rows, along_cols):.1f} px one way, {min(along_rows, along_cols):.1f} px the other): the "
             "board or camera moved during the exposure; hold it still or shorten the exposure"
             if motion else
             f"images out of focus (edges spread {along_rows:.1f} / {along_cols:.1f} px both ways): refocus, or keep "
             "the board within the depth of field")
    views = sorted({b[1] for b in bad})
    return GateResult(
        "sharpness", value, limit(square), "px", "fail",
        f"{cause}, in {len(views)} pairs ({_names(views, names)}; worst {_name(i, names)} {side}, blur sigma "
        f"{max(along_rows, along_cols):.1f} px over the {limit(square):.2f} px limit = min({BLUR_MAX_PX:g} px, "
        f"{BLUR_MAX_SQUARE_FRACTION:g} x its {square:.0f} px squares))", tuple(views))


def bowl_basis(object_points: np.ndarray, extent: tuple[float, float, float, float]) -> np.ndarray:
    """(N, 3): x'^2, y'^2, x'y' with x', y' the board coordinates scaled to [-1, 1] over ``extent``
    (xmin, xmax, ymin, ymax mm): the shapes of a bent board no rigid pose can mimic."""
    xmin, xmax, ymin, ymax = extent
    x = (object_points[:, 0] - 0.5 * (xmin + xmax)) / max(0.5 * (xmax - xmin), 1e-9)
    y = (object_points[:, 1] - 0.5 * (ymin + ymax)) / max(0.5 * (ymax - ymin), 1e-9)
    return np.stack([x * x, y * y, x * y], axis=1)


def fit_bowl(images: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
             board_points: np.ndarray, poses: PoseCache | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Fit a bend dz = c . (x'^2, y'^2, x'y') (mm, out of the board's plane) to every image's residuals at once.

    ``images``: per image (object_points (N, 3) mm, pixels (N, 2), K, D); each image keeps its own pose,
    linearised (6 columns from ``projectPoints``) and eliminated, so only a bend no pose change mimics is fitted.
    Returns (c (3,) mm, covariance of c (3, 3) mm^2 scaled by the residual variance, peak-to-valley mm of the
    fitted bend over ``board_points``). ``poses``: a :class:`PoseCache` shared with the other gates of one run.
    """
    pose = (poses or PoseCache()).pose
    extent = (board_points[:, 0].min(), board_points[:, 0].max(), board_points[:, 1].min(), board_points[:, 1].max())
    normal, rhs, sq, dof = np.zeros((3, 3)), np.zeros(3), 0.0, 0
    for obj, px, K, D in images:
        rvec, tvec, _ = pose(obj, px, K, D)
        obj = np.asarray(obj, np.float64).reshape(-1, 3)
        projected, jac = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, D)
        r = (np.asarray(px, float).reshape(-1, 2) - projected.reshape(-1, 2)).reshape(-1)
        J = jac[:, :6]  # (2N, 6): rvec, tvec
        shifted = obj.copy()
        shifted[:, 2] += 1e-3
        dz = (cv2.projectPoints(shifted.reshape(-1, 1, 3), rvec, tvec, K, D)[0].reshape(-1, 2)
              - projected.reshape(-1, 2)) / 1e-3  # (N, 2) px per mm out of the plane
        G = (dz[:, :, None] * bowl_basis(obj, extent)[:, None, :]).reshape(-1, 3)  # (2N, 3)
        Q, _ = np.linalg.qr(J)
        G_perp, r_perp = G - Q @ (Q.T @ G), r - Q @ (Q.T @ r)
        normal += G_perp.T @ G_perp
        rhs += G_perp.T @ r_perp
        sq += float(r_perp @ r_perp)
        dof += len(r) - 6
    c = np.linalg.solve(normal, rhs)
    variance = max(sq - float(c @ rhs), 0.0) / max(dof - 3, 1)
    cov = variance * np.linalg.inv(normal)
    shape = bowl_basis(board_points, extent) @ c
    return c, cov, float(shape.max() - shape.min())


def gate_flatness(calib: StereoCalibration, views: Sequence[GateView], board_points: np.ndarray,
                  poses: PoseCache | None = None) -> GateResult:
    """Fails when a bend of the board (:func:`fit_bowl`) is both large and well measured (``FLATNESS_*``)."""
    if len(views) < 3:
        return GateResult("flatness", float("nan"), FLATNESS_MAX_REL, "of diagonal", "n/a", "too few views")
    (K1, D1), (K2, D2) = _mono_intrinsics(calib)
    images = [(v.object_points, v.left_px, K1, D1) for v in views]
    images += [(v.object_points, v.right_px, K2, D2) for v in views]
    c, cov, pv = fit_bowl(images, board_points, poses)
    extent = (board_points[:, 0].min(), board_points[:, 0].max(), board_points[:, 1].min(), board_points[:, 1].max())
    diagonal = float(np.hypot(extent[1] - extent[0], extent[3] - extent[2]))
    # sigma of the peak-to-valley, linearised: the bend's shape over the board with c's covariance.
    shape = bowl_basis(board_points, extent)
    hi, lo = int(np.argmax(shape @ c)), int(np.argmin(shape @ c))
    g = shape[hi] - shape[lo]
    sigma = float(np.sqrt(max(g @ cov @ g, 0.0)))
    rel = pv / diagonal
    significant = pv > FLATNESS_MIN_SIGMAS * sigma
    verdict = "fail" if rel > FLATNESS_MAX_REL and significant else "pass"
    measured = (f"{pv:.2f} +- {sigma:.2f} mm peak-to-valley over the {diagonal:.0f} mm board diagonal "
                f"({100 * rel:.2f} %, limit {100 * FLATNESS_MAX_REL:g} % at over {FLATNESS_MIN_SIGMAS:g} sigma)")
    line = (f"board flat within the data: bend {measured}" if verdict == "pass" else
            f"board not flat: its corners leave a bowl-shaped residual pattern no flat board produces, a bend of "
            f"{measured}; mount the print on a rigid flat plate (glass, aluminium)")
    return GateResult("flatness", rel, FLATNESS_MAX_REL, "of diagonal", verdict, line)


def gate_left_right(calib: StereoCalibration) -> GateResult:
    """Fails when the right camera's centre lies on the left camera's -x side (left and right swapped)."""
    R, T = np.asarray(calib.R, float), np.asarray(calib.T, float).reshape(3)
    centre = -R.T @ T  # the right camera's optical centre in the left camera's frame (mm)
    side = float(centre[0] / max(np.linalg.norm(centre), 1e-12))
    if abs(side) < SIDE_BY_SIDE_MIN:
        return GateResult("left_right", side, 0.0, "x/|C|", "n/a",
                          f"cameras not side by side (the right centre at {np.round(centre, 1).tolist()} mm): "
                          "left/right not judged")
    if side > 0:
        return GateResult("left_right", side, 0.0, "x/|C|", "pass",
                          f"right camera {centre[0]:.1f} mm to the left camera's right")
    return GateResult("left_right", side, 0.0, "x/|C|", "fail",
                      f"left and right swapped: the 'right' camera sits {-centre[0]:.1f} mm to the LEFT of the 'left' "
                      "one (T_x > 0; this project's rig frame puts the right camera at +x): exchange the left and "
                      "right images (calibrate's --left and --right) or the cameras' bindings ([cameras] left and "
                      "right)")


def found_board_shape(gray: np.ndarray, any_board: AnyBoardSearch | None = None) -> tuple[int, int] | None:
    """(cols, rows) inner corners of the largest checkerboard in ``gray`` (SB with CALIB_CB_LARGER, at <= 960 px), or
    None (none, or one that reaches within a square of the image border: perhaps cut by it). ``any_board``: the
    searches the detection made already (:class:`~stereo_bench.vision.detect.AnyBoardSearch`)."""
    any_board = any_board or AnyBoardSearch()
    for flags in (0, cv2.CALIB_CB_NORMALIZE_IMAGE):
        found, corners, meta = any_board.search(gray, flags)
        if found and meta is not None and corners is not None and meta.size == len(corners):
            rows, cols = meta.shape
            grid = corners.reshape(rows, cols, 2)
            spacing = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2)))
            height, width = _search_image(gray, THOROUGH_SEARCH_WIDTH_PX)[0].shape
            inside = (grid[..., 0].min() > spacing and grid[..., 1].min() > spacing
                      and grid[..., 0].max() < width - 1 - spacing and grid[..., 1].max() < height - 1 - spacing)
            return (cols, rows) if inside else None
    return None


_QUADRANT_OFFSETS = np.array([-0.1, 0.0, 0.1])  # samples across a quadrant, in steps of the grid
_QUADRANT_CENTRE = 0.25  # the quadrants sampled around the point beyond the edge, in steps of the grid


def _side_ends(gray: np.ndarray, edge: np.ndarray, inner: np.ndarray) -> bool | None:
    """Does the checker pattern end at this side of a found grid? ``edge`` (n, 2) its corners, ``inner`` (n, 2) the
    row (or column) next to it. True: it ends (the squares beyond are not the board's); False: it goes on (a larger
    board); None: cannot be judged (too few points inside the image with contrast).

    One step beyond each edge corner (linear extrapolation) four squares meet: the two on the inside are the
    board's outermost, one black one white; on a larger board the two outside repeat them crosswise (an X-corner),
    at a board's edge they are its margin (alike)."""
    outward = edge - inner
    along = np.gradient(edge, axis=0)
    beyond = edge + outward
    quadrants = []
    for su, sv in ((1, 1), (-1, 1), (1, -1), (-1, -1)):
        centre = beyond + _QUADRANT_CENTRE * (su * along + sv * outward)
        points = (centre[:, None, None, :] + _QUADRANT_OFFSETS[None, :, None, None] * along[:, None, None, :]
                  + _QUADRANT_OFFSETS[None, None, :, None] * outward[:, None, None, :]).reshape(len(edge), 9, 2)
        maps = points.astype(np.float32)
        quadrants.append(cv2.remap(gray, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0))
    inside = np.all(np.stack(quadrants) >= 0, axis=(0, 2))
    out_a, out_b, in_c, in_d = (np.median(q, axis=1) for q in quadrants)  # (+along, +out), (-, +), (+, -), (-, -)
    contrast = np.abs(in_d - in_c)
    judged = inside & (contrast > BOARD_EDGE_CONTRAST_DN)
    crosswise = (judged & ((out_a - out_b) * (in_d - in_c) > 0) & (np.abs(out_a - out_b) > 0.5 * contrast)
                 & (np.abs(out_a - in_d) < 0.5 * contrast) & (np.abs(out_b - in_c) < 0.5 * contrast))
    if judged.sum() < 0.5 * len(edge):
        return None
    return bool(crosswise.sum() < 0.5 * judged.sum())


def board_may_be_larger(gray: np.ndarray, grid: np.ndarray) -> bool:
    """False when the checker pattern of a found (rows, cols, 2) corner grid ends at all four sides
    (:func:`_side_ends`): the board is the one found, not a larger one containing it, and the board-size search
    (SB, ~50-100 ms) can only find it again. True when a side goes on or cannot be judged."""
    if grid.shape[0] < 2 or grid.shape[1] < 2:
        return True
    gray = np.asarray(gray, np.float32)
    sides = ((grid[0], grid[1]), (grid[-1], grid[-2]), (grid[:, 0], grid[:, 1]), (grid[:, -1], grid[:, -2]))
    return not all(_side_ends(gray, edge, inner) is True for edge, inner in sides)


def gate_board_fit(target: Target, found: Sequence[bool], images: Sequence[np.ndarray], *,
                   most: int = 4, grids: Sequence[np.ndarray | None] | None = None,
                   any_board: AnyBoardSearch | None = None) -> GateResult:
    """Is the board the user named the one in the images? ``found`` per image; ``images`` the same images.

    Up to ``most`` of the missed images and two of the found ones are searched for the largest checkerboard
    of any size (SB, ~40 ms each); it fails when that is another size than the one given. ``grids``: per image the
    found (rows, cols, 2) corners (None where not found or not whole); a found image whose grid's pattern ends at
    every side (:func:`board_may_be_larger` False) is not searched: only a larger board counts there. ``any_board``:
    the detection's searches of these images (:class:`~stereo_bench.vision.detect.AnyBoardSearch`), not repeated.
    """
    if not isinstance(target, Checkerboard):
        return GateResult("board_fit", float("nan"), BOARD_FIT_MIN_OTHER, "images", "n/a", "not a checkerboard")
    given = (target.cols, target.rows)

    def oriented(shape: tuple[int, int] | None) -> tuple[int, int] | None:
        if shape is None:
            return None
        big, small = max(shape), min(shape)
        return (big, small) if given[0] >= given[1] else (small, big)

    # The missed images, and two where the board was found: a board larger than the one named contains it,
    # and the classic detector then finds the smaller grid inside it in some images (wrong corner ids).
    grids = list(grids) if grids is not None else [None] * len(images)
    found_at = [k for k, ok in enumerate(found) if ok][:2]
    searched = ([im for im, ok in zip(images, found, strict=True) if not ok][:most]
                + [images[k] for k in found_at if grids[k] is None or board_may_be_larger(images[k], grids[k])])
    # Side by side on threads (SB releases the GIL; each search's answer does not depend on the thread).
    with ThreadPoolExecutor(max_workers=max(1, min(len(searched), os.cpu_count() or 1))) as pool:
        any_board = any_board or AnyBoardSearch()
        shapes = [oriented(shape) for shape in pool.map(lambda image: found_board_shape(image, any_board), searched)]
    shapes += [None] * (len(found_at) - (len(shapes) - min(most, len(found) - sum(map(bool, found)))))
    n_missed = min(most, len(found) - sum(map(bool, found)))
    missed, hits = shapes[:n_missed], shapes[n_missed:]
    # A board smaller than the one named is evidence only where the named one is missing from most images: where
    # it is found in most, a smaller grid in a missed image is a part of it (blurred, shaded or cut off).
    found_most = np.mean(found) >= BOARD_FIT_MIN_FOUND_SHARE if len(found) else False
    seen = [s for s in missed + hits if s is not None
            and (s[0] * s[1] > given[0] * given[1] or (not found_most and s in missed))]
    if seen:
        cols, rows = max(set(seen), key=seen.count)
        other = [s for s in seen if sorted(s) != sorted(given)]
        if len(other) >= BOARD_FIT_MIN_OTHER and sorted((cols, rows)) != sorted(given):
            return GateResult(
                "board_fit", len(other), BOARD_FIT_MIN_OTHER, "images", "fail",
                f"board size does not fit: --board {given[0]}x{given[1]} is found in {sum(found)} of {len(found)} "
                f"images, and {seen.count((cols, rows))} of the {len(missed) + len(hits)} images searched show a "
                f"checkerboard of {cols}x{rows} inner corners (count the corners where four squares meet, not the "
                f"squares): use --board {cols}x{rows}")
    return GateResult("board_fit", 0, BOARD_FIT_MIN_OTHER, "images", "pass",
                      f"{given[0]}x{given[1]} board found in {sum(found)} of {len(found)} images; no other board size "
                      "seen in the rest")


def image_blur(image: np.ndarray | None, px: np.ndarray, target: Target) -> tuple[float, float, float] | None:
    """(blur along rows px, along columns px, square side px) of one image's whole checkerboard (the sharpness
    gate's measurement, :func:`edge_blur_px`); None without the image or a whole checkerboard. It needs no
    calibration: a caller may measure it while the fit runs (``run_gates(blur_of=...)``)."""
    if image is None or not isinstance(target, Checkerboard) or len(px) != target.n_corners:
        return None
    grid = np.asarray(px, float).reshape(target.rows, target.cols, 2)
    steps = [np.linalg.norm(np.diff(grid, axis=a), axis=2) for a in (0, 1)]
    square = float(np.median(np.concatenate([s.ravel() for s in steps])))
    along_rows, along_cols = edge_blur_px(image, grid)
    return along_rows, along_cols, square


def run_gates(calib: StereoCalibration, views: Sequence[GateView], target: Target, *,
              dropped: Sequence[tuple[int, str]] = (), names: Sequence[str] | None = None,
              accept_poor: bool = False,
              blur_of: Mapping[tuple[int, str], tuple[float, float, float] | None] | None = None,
              poses: PoseCache | None = None) -> GateReport:
    """Every gate on a finished stereo calibration.

    ``views``: every pair with the board in both images (also those the outlier rule dropped: the
    synchronisation gate names them); ``dropped``: (pair index, reason) of the views the fit dropped.
    ``blur_of``: per (pair index, "left" | "right") the :func:`image_blur` of the views' images, when the caller
    measured it already (the same numbers). ``poses``: the fits' own poses of ``views``
    (:meth:`PoseCache.of_fit`, when ``views`` are the views the calibration was fitted from, in its order); None
    solves every image's pose.
    """
    dropped_set = {i for i, _ in dropped}
    poses = poses or PoseCache()
    residuals = [view_residuals(calib, v, poses) for v in views]
    sync = gate_synchronised(residuals, names)
    typical = _typical_mono_px(residuals) if residuals else float("nan")
    diagnoses = {v.index: view_diagnosis(v, typical) for v in residuals if v.not_together}
    kept = [v for v in views if v.index not in dropped_set]
    blurs = []
    for v in kept:
        for side, image, px in (("left", v.left_image, v.left_px), ("right", v.right_image, v.right_px)):
            blur = blur_of[(v.index, side)] if blur_of is not None else image_blur(image, px, target)
            if blur is not None:
                blurs.append((v.index, side, *blur))
    results = (
        sync,
        gate_consistent_views(len(views), dropped, names),
        gate_sharpness(blurs, names),
        gate_flatness(calib, kept, target.object_points, poses),
        gate_left_right(calib) if sync.verdict != "fail" else GateResult(
            "left_right", float("nan"), 0.0, "x/|C|", "n/a", "not judged: R, T of pairs not taken together"),
    )
    return GateReport(results, accept_poor, diagnoses)
