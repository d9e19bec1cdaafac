"""Mono and stereo calibration with a stated outlier rule.

Outlier rule (both stages): a view whose RMS reprojection error exceeds
``max(OUTLIER_FACTOR x median per-view RMS, OUTLIER_FLOOR_PX)`` is dropped and the calibration is
repeated, up to ``max_rounds`` times, never leaving fewer than ``min_views`` views. The rule is
for gross failures (a mis-ordered grid, motion blur, a board that moved between exposures); the
floor keeps a set of uniformly excellent views (synthetic, ~0.05 px) from losing members to noise,
and a real view at 3x the median but under 1 px (opencv_sample pair 5: 0.64 px) still carries
more information than error.

Stereo modes:
- ``"joint"``: start from the mono intrinsics and refine intrinsics and extrinsics together
  (``CALIB_USE_INTRINSIC_GUESS``).
- ``"fixed"``: keep the mono intrinsics (``CALIB_FIX_INTRINSIC``), estimate R, T only.
The default is ``"joint"``, by measurement (scripts/bench_extrinsics_mode.py and the real-image
tests): on 12 rendered 20-view calibrations RMS abs(T) error 0.001 mm joint vs 0.002 mm fixed (square
error 0.0019 mm RMS either way); on opencv_sample abs(T) = 99.842 mm joint vs 99.916 mm fixed
(Bouguet: 99.81); on present_cjn 49.313 vs 49.304 mm (published 49.30). Joint refinement is never
much worse and guards against the scale bias a slightly wrong focal length puts into abs(T).
Fixed mode is right when the intrinsics come from a better, separate calibration (``--intrinsics``).

Every calibration carries the covariance of what it estimated (:mod:`stereo_bench.vision.covariance`):
mono, the camera's intrinsics; stereo, both cameras' intrinsics and R (rotation vector), T. In fixed
mode the intrinsics' own uncertainty is propagated into R, T: from the mono calibrations of the same
views (jointly, their shared noise included) or from the covariance given with the intrinsics;
intrinsics given without one leave the covariance unknown (None, with the reason in
``covariance_note``), never zero.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np

from stereo_bench.vision.covariance import (
    CalibrationCovariance,
    CovarianceUnavailable,
    mono_covariance,
    mono_linearisation,
    stereo_covariance,
)

MIN_VIEWS = 5  # fewer views of a flat board leave the intrinsics and R, T poorly determined
OUTLIER_FACTOR = 3.0
OUTLIER_FLOOR_PX = 1.0
DEFAULT_FLAGS = cv2.CALIB_FIX_K3  # k3 is poorly constrained by a dozen views of a flat board
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-9)
# The other lens models' joint fits in an auto comparison, warm-started from the default model's solution. The
# rational model crawls along its numerator/denominator degeneracy for all 200 iterations (1.6 s of CPU on
# smiler488_box, against 0.23 s for 30, |T| 1.6 um apart); on the real sets 30 iterations left |T| within 2 um
# and every held-out figure within 1e-4 of 200 iterations' (the linearised leave-one-out's gradient term takes
# an unfinished step into account). A chosen candidate is the calibration as fitted here.
CANDIDATE_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-7)

#: The candidates whose joint fits are slowest (stereoCalibrate's LM over more distortion terms), started first.
_SLOW_CANDIDATES = ("thin-prism", "rational")

StereoMode = Literal["joint", "fixed"]

# Physical sanity of a stereo calibration (calibration_problems). Two cameras' optical centres cannot be closer
# than their housings allow (even board cameras are ~8 mm wide): |T| under 1 mm means both images were taken
# from one viewpoint (the same images given as left and right), and every depth measured with it is noise.
MIN_BASELINE_MM = 1.0
# R is stored to 16 digits by OpenCV's YAML writer; 1e-4 also admits files typed in by hand from a paper.
ROTATION_TOLERANCE = 1e-4


class ImplausibleCalibration(ValueError):
    """A calibration no real stereo pair can have (the message says what and the likely cause)."""


@dataclass(frozen=True)
class RejectedView:
    index: int
    reason: str

    def as_dict(self) -> dict:
        return {"index": self.index, "reason": self.reason}


@dataclass(frozen=True)
class MonoCalibration:
    """One camera: ``K`` (3, 3) px, ``dist`` (1, k), RMS and per-view RMS (px), parameter standard deviations."""

    K: np.ndarray
    dist: np.ndarray
    image_size: tuple[int, int]
    rms_px: float
    per_view_rms_px: np.ndarray  # (n_used,)
    std_intrinsics: dict[str, float]  # fx, fy, cx, cy, k1, k2, p1, p2, k3 (px / unitless)
    views_used: list[int]
    views_rejected: list[RejectedView] = field(default_factory=list)
    rvecs: list[np.ndarray] = field(default_factory=list)  # per used view: board pose (rad), as the solver found it
    tvecs: list[np.ndarray] = field(default_factory=list)  # (mm)
    covariance: CalibrationCovariance | None = None  # of fx fy cx cy and the free distortion coefficients
    covariance_note: str = ""  # why the covariance is None

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])


@dataclass(frozen=True)
class StereoCalibration:
    """Both cameras and X_right = R @ X_left + T (T (3,) in the board's length unit, mm here)."""

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]
    rms_px: float = float("nan")
    per_view_rms_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (n_used, 2): left, right
    views_used: list[int] = field(default_factory=list)
    views_rejected: list[RejectedView] = field(default_factory=list)
    mode: str = "given"
    E: np.ndarray | None = None
    F: np.ndarray | None = None
    # Of left.* right.* intrinsics, rvec.* (rad, rotation vector of R) and T.* (mm); None = unknown.
    covariance: CalibrationCovariance | None = None
    covariance_note: str = ""  # why the covariance is None
    # The leave-one-view-out check on the calibration's own board (uncertainty.ModelAdequacy, set by
    # uncertainty.with_adequacy, which pipeline.calibrate_from_images applies); None: not computed.
    adequacy: object | None = None
    lens_model: str = ""  # the lens model fitted (stereo_bench.vision.lensmodels); "" = not recorded
    lens_choice: object | None = None  # lensmodels.Choice: how it was chosen and the held-out comparison
    # Each camera calibrated alone from the same views, when the fit did that first (the quality gates compare
    # each view's residual with them: stereo_bench.vision.gates); None for given intrinsics or a loaded file.
    mono: tuple[MonoCalibration, MonoCalibration] | None = None
    # Per used view (views_used' order): the left camera's board pose (rvec (3,) rad, tvec (3,) mm) as the stereo
    # fit found it (the quality gates start each view's stereo residual there); () when not known (a loaded file).
    board_poses: tuple[tuple[np.ndarray, np.ndarray], ...] = ()

    @property
    def baseline_mm(self) -> float:
        return float(np.linalg.norm(self.T))


_SINGLE_THREAD = threading.Lock()
_pinned = 0  # nesting depth of single_threaded_opencv(): while > 0 OpenCV runs on one thread throughout
_unpinned_threads = 0  # OpenCV's thread count before the outermost single_threaded_opencv()


@contextmanager
def _deterministic():
    """Run OpenCV's solver on one thread.

    With several threads its sums come out in a varying order and the result changes in the 14th
    digit from run to run; a replayed session must reproduce the recorded numbers exactly. The
    setting is process-wide, so other OpenCV work runs single-threaded for these few 100 ms, and
    solves wait for each other, unless :func:`single_threaded_opencv` already holds OpenCV on one
    thread (then solves on several Python threads run side by side, each single-threaded).
    """
    if _pinned:
        yield
        return
    with _SINGLE_THREAD:
        previous = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            yield
        finally:
            cv2.setNumThreads(previous)


def opencv_threads() -> int:
    """OpenCV's thread count as this process has it set: ``cv2.getNumThreads()`` outside the windows in which this
    module holds OpenCV on one thread (a solve, :func:`single_threaded_opencv`). Read inside one of those, from
    another thread, the setting is 1 for the moment only: a session's numeric environment recorded so, and its
    replay read outside (or the other way round), said "OpenCV threads 2 -> 1" of the same process."""
    with _SINGLE_THREAD:  # a solve holding OpenCV on one thread ends first (a few 100 ms)
        return int(_unpinned_threads if _pinned else cv2.getNumThreads())


@contextmanager
def single_threaded_opencv():
    """OpenCV on one thread (process-wide) for the duration; the previous thread count is restored after.

    For work that runs its own pool of Python threads on every core (a replay): OpenCV's worker
    threads then only add hand-over and spinning (~1.4 ms of CPU per 1080p detection on 2 cores), and
    calibration solves need no lock to be deterministic. Nothing may still run OpenCV from inside
    the block once it ends (join the pools first); nested uses keep the outermost setting.
    """
    global _pinned, _unpinned_threads
    with _SINGLE_THREAD:
        if not _pinned:
            _unpinned_threads = cv2.getNumThreads()
            cv2.setNumThreads(1)
        _pinned += 1
    try:
        yield
    finally:
        with _SINGLE_THREAD:
            _pinned -= 1
            if not _pinned:
                cv2.setNumThreads(_unpinned_threads)


def camera_problems(K: np.ndarray, D: np.ndarray, image_size: tuple[int, int] | None, name: str) -> list[str]:
    """What makes one camera's intrinsics physically impossible for images of ``image_size`` (empty when none).

    The principal point is where the optical axis meets the sensor, so it lies inside the image: intrinsics
    of a 1920x1080 camera (cx ~ 960) used for 640x480 images put it outside.
    """
    K, D = np.asarray(K, float), np.asarray(D, float)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D))):
        return [f"{name}: intrinsics have non-finite entries (NaN or infinity)"]
    problems = []
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        problems.append(f"{name}: focal lengths fx = {K[0, 0]:g}, fy = {K[1, 1]:g} px must be positive")
    if image_size is not None:
        width, height = image_size
        if not (0 <= K[0, 2] <= width and 0 <= K[1, 2] <= height):
            problems.append(f"{name}: principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) px lies outside the "
                            f"{width}x{height} image: intrinsics of another camera or image size")
    return problems


def calibration_problems(calib: StereoCalibration) -> list[str]:
    """What makes a stereo calibration physically impossible (empty when nothing does).

    Non-finite entries, non-positive focal lengths, a principal point outside the image, an R that is not
    a rotation, and a degenerate baseline (|T| < :data:`MIN_BASELINE_MM`).
    """
    problems = camera_problems(calib.K1, calib.D1, calib.image_size, "left camera")
    problems += camera_problems(calib.K2, calib.D2, calib.image_size, "right camera")
    R, T = np.asarray(calib.R, float), np.asarray(calib.T, float).reshape(-1)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(T))):
        return problems + ["R, T have non-finite entries (NaN or infinity)"]
    if np.max(np.abs(R.T @ R - np.eye(3))) > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
        problems.append("R is not a rotation matrix (R^T R != I or det(R) <= 0)")
    baseline = float(np.linalg.norm(T))
    if baseline < MIN_BASELINE_MM:
        problems.append(f"baseline |T| = {baseline:.4f} mm is below {MIN_BASELINE_MM:g} mm: both views come from one "
                        "viewpoint (the same images as left and right?)")
    return problems


def model_length(flags: int) -> int:
    """Length of the distortion vector the solver's ``flags`` estimate (OpenCV may return 14 coefficients, the
    unused ones zero, which would read as free parameters of a richer model)."""
    if flags & cv2.CALIB_TILTED_MODEL:
        return 14
    if flags & cv2.CALIB_THIN_PRISM_MODEL:
        return 12
    return 8 if flags & cv2.CALIB_RATIONAL_MODEL else 5


def _model_vector(D: np.ndarray, flags: int) -> np.ndarray:
    """D as (1, k), cut to :func:`model_length` when the coefficients beyond it are all zero (given intrinsics of a
    richer model keep theirs)."""
    D = np.asarray(D, float).reshape(1, -1)
    n = model_length(flags)
    return D[:, :n] if D.shape[1] > n and not np.any(D[0, n:]) else D


def covariance_flags(flags: int) -> int:
    """The flags the covariance is computed for: fx = fy (CALIB_FIX_ASPECT_RATIO) is linearised as fx and fy free,
    a model that contains the coupled one, so its covariance is a little larger (conservative), never smaller."""
    return flags & ~cv2.CALIB_FIX_ASPECT_RATIO


def _rejection_threshold(per_view_rms_px: np.ndarray) -> float:
    return max(OUTLIER_FACTOR * float(np.median(per_view_rms_px)), OUTLIER_FLOOR_PX)


def _views_to_drop(per_view_rms_px: np.ndarray, n_keep_min: int) -> list[int]:
    """Positions (into the current list) of the worst views over the threshold, worst first."""
    threshold = _rejection_threshold(per_view_rms_px)
    over = [i for i in np.argsort(per_view_rms_px)[::-1] if per_view_rms_px[i] > threshold]
    return over[: max(0, len(per_view_rms_px) - n_keep_min)]


def calibrate_mono(
    object_points: list[np.ndarray], image_points: list[np.ndarray], image_size: tuple[int, int], *,
    flags: int = DEFAULT_FLAGS, min_views: int = MIN_VIEWS, max_rounds: int = 3, covariance: bool = True,
) -> MonoCalibration:
    """Calibrate one camera from views of a planar target.

    Args:
        object_points: per view (N_i, 3) float32 board coordinates (mm).
        image_points: per view (N_i, 2) pixel coordinates.
        image_size: (width, height) px.
        covariance: compute the intrinsics' covariance (a few % of the calibration's time).
    """
    if len(object_points) < min_views:
        raise ValueError(f"mono calibration needs at least {min_views} views with the board, got {len(object_points)}")
    used = list(range(len(object_points)))
    rejected: list[RejectedView] = []
    # CALIB_FIX_ASPECT_RATIO keeps the ratio fx/fy of the matrix given: 1 (square pixels).
    K_start = np.eye(3) if flags & cv2.CALIB_FIX_ASPECT_RATIO else None
    for _ in range(max_rounds + 1):
        with _deterministic():
            rms, K, dist, rvecs, tvecs, std_int, _, per_view = cv2.calibrateCameraExtended(
                [np.asarray(object_points[i], np.float32).reshape(-1, 1, 3) for i in used],
                [np.asarray(image_points[i], np.float32).reshape(-1, 1, 2) for i in used],
                image_size, None if K_start is None else K_start.copy(), None, flags=flags, criteria=CRITERIA,
            )
        per_view = np.asarray(per_view, float).reshape(-1)
        drop = _views_to_drop(per_view, min_views)
        if not drop:
            break
        threshold = _rejection_threshold(per_view)
        for position in drop:
            rejected.append(RejectedView(
                used[position], f"reprojection RMS {per_view[position]:.3f} px > {threshold:.3f} px"
            ))
        used = [index for position, index in enumerate(used) if position not in set(drop)]
    std = np.asarray(std_int, float).reshape(-1)
    names = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx",
             "ty"][:4 + np.asarray(dist).size]
    dist = _model_vector(dist, flags)
    rvecs, tvecs = [np.asarray(r, float).reshape(3) for r in rvecs], [np.asarray(t, float).reshape(3) for t in tvecs]
    cov, note = None, "not computed"
    if covariance:
        try:
            cov, note = mono_covariance([object_points[i] for i in used], [image_points[i] for i in used], K, dist,
                                        rvecs, tvecs, flags=covariance_flags(flags)), ""
        except CovarianceUnavailable as error:
            note = str(error)
    return MonoCalibration(
        K=K, dist=dist, image_size=tuple(image_size), rms_px=float(rms),
        per_view_rms_px=per_view, std_intrinsics={n: float(s) for n, s in zip(names, std, strict=False)},
        views_used=used, views_rejected=rejected, rvecs=rvecs, tvecs=tvecs, covariance=cov, covariance_note=note,
    )


def calibrate_stereo(
    object_points: list[np.ndarray], left_points: list[np.ndarray], right_points: list[np.ndarray],
    image_size: tuple[int, int], *, intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
    mode: StereoMode = "joint", flags: int = DEFAULT_FLAGS, min_views: int = MIN_VIEWS, max_rounds: int = 3,
    intrinsics_covariance: CalibrationCovariance | None = None, covariance: bool = True,
    after_mono: Callable[[], object] | None = None,
) -> StereoCalibration:
    """Stereo calibration from views seen by both cameras.

    Args:
        object_points: per view (N_i, 3) board coordinates (mm) of the corners seen in BOTH views.
        left_points, right_points: per view (N_i, 2) pixels, same corner order as ``object_points``.
        intrinsics: (K1, D1, K2, D2) to start from; when None each camera is first calibrated alone.
        mode: "joint" refines the intrinsics with R, T; "fixed" keeps them.
        intrinsics_covariance: of the given ``intrinsics`` (names ``left.*``, ``right.*``), from a
            calibration independent of these views; fixed mode propagates it into R, T.
        covariance: compute the parameters' covariance (~2 % of a 12-view calibration's time,
            scripts/bench_covariance.py); False leaves it None ("not computed").
        after_mono: called once, when the cameras' mono fits are done and the joint fit begins (at once with
            given intrinsics): for a caller's work that should run beside the joint fit, which is one thread,
            rather than compete with the two mono fits for the cores. It does not change the calibration.
    """
    return _calibrate_stereo(object_points, left_points, right_points, image_size, intrinsics=intrinsics, mode=mode,
                             flags=flags, min_views=min_views, max_rounds=max_rounds,
                             intrinsics_covariance=intrinsics_covariance, covariance=covariance,
                             after_mono=after_mono)[0]


def _calibrate_stereo(
    object_points: list[np.ndarray], left_points: list[np.ndarray], right_points: list[np.ndarray],
    image_size: tuple[int, int], *, intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
    mode: StereoMode = "joint", flags: int = DEFAULT_FLAGS, min_views: int = MIN_VIEWS, max_rounds: int = 3,
    intrinsics_covariance: CalibrationCovariance | None = None, covariance: bool = True, criteria=CRITERIA,
    after_mono: Callable[[], object] | None = None,
) -> tuple[StereoCalibration, list, list]:
    """`calibrate_stereo`, and the left camera's board pose per used view (rvecs (3,) rad, tvecs (3,) mm)."""
    if not len(object_points) == len(left_points) == len(right_points):
        raise ValueError("object, left and right point lists must have one entry per view")
    if len(object_points) < min_views:
        raise ValueError(f"stereo calibration needs at least {min_views} views seen by both cameras, "
                         f"got {len(object_points)}")
    rejected: list[RejectedView] = []
    if intrinsics is None:
        # The two cameras side by side, each solve on one OpenCV thread (the numbers of one after the other).
        def mono(points: list[np.ndarray]) -> MonoCalibration:
            return calibrate_mono(object_points, points, image_size, flags=flags, min_views=min_views,
                                  covariance=False)

        with single_threaded_opencv(), ThreadPoolExecutor(max_workers=min(2, os.cpu_count() or 1)) as pool:
            left, right = pool.map(mono, (left_points, right_points))
        K1, D1, K2, D2 = left.K, left.dist, right.K, right.dist
        bad = {r.index: f"left {r.reason}" for r in left.views_rejected}
        bad.update({r.index: f"right {r.reason}" for r in right.views_rejected if r.index not in bad})
        rejected.extend(RejectedView(i, reason) for i, reason in sorted(bad.items()))
        used = [i for i in range(len(object_points)) if i not in bad]
    else:
        left = right = None
        K1, D1, K2, D2 = (np.asarray(a, float) for a in intrinsics)
        used = list(range(len(object_points)))
    if after_mono is not None:
        after_mono()

    stereo_flags = flags | (cv2.CALIB_FIX_INTRINSIC if mode == "fixed" else cv2.CALIB_USE_INTRINSIC_GUESS)
    for round_ in range(max_rounds + 1):
        with _deterministic():
            rms, K1n, D1n, K2n, D2n, R, T, E, F, rvecs, tvecs, per_view = cv2.stereoCalibrateExtended(
                [np.asarray(object_points[i], np.float32).reshape(-1, 1, 3) for i in used],
                [np.asarray(left_points[i], np.float32).reshape(-1, 1, 2) for i in used],
                [np.asarray(right_points[i], np.float32).reshape(-1, 1, 2) for i in used],
                K1.copy(), D1.copy(), K2.copy(), D2.copy(), image_size, None, None,
                flags=stereo_flags, criteria=criteria,
            )
        per_view = np.asarray(per_view, float).reshape(-1, 2)
        worst = per_view.max(axis=1)
        # No round left to refit without them: the solution stays that of these views (dropping them anyway
        # paired this solution's poses with fewer views, which the covariance refused with a crash).
        drop = _views_to_drop(worst, min_views) if round_ < max_rounds else []
        if not drop:
            break
        threshold = _rejection_threshold(worst)
        for position in drop:
            rejected.append(RejectedView(used[position], f"stereo reprojection RMS {worst[position]:.3f} px > "
                                                         f"{threshold:.3f} px"))
        used = [index for position, index in enumerate(used) if position not in set(drop)]
    D1n, D2n = _model_vector(D1n, flags), _model_vector(D2n, flags)
    T = np.asarray(T, float).reshape(3)
    cov, note = None, "not computed"
    if covariance:
        cov, note = _fit_covariance(object_points, left_points, right_points, used, K1n, D1n, K2n, D2n, R, T, rvecs,
                                    tvecs, flags=flags, stereo_flags=stereo_flags, mode=mode, mono=(left, right),
                                    intrinsics_covariance=intrinsics_covariance, image_size=image_size)
    rvecs, tvecs = [np.asarray(r, float).reshape(3) for r in rvecs], [np.asarray(t, float).reshape(3) for t in tvecs]
    calib = StereoCalibration(
        K1=K1n, D1=D1n, K2=K2n, D2=D2n, R=R, T=T, image_size=tuple(image_size), rms_px=float(rms),
        per_view_rms_px=per_view, views_used=used, views_rejected=sorted(rejected, key=lambda r: r.index),
        mode=mode, E=E, F=F, covariance=cov, covariance_note=note, lens_model=model_of_flags(flags),
        mono=None if left is None else (left, right), board_poses=tuple(zip(rvecs, tvecs, strict=True)),
    )
    return calib, rvecs, tvecs


def _fit_covariance(object_points, left_points, right_points, used: list[int], K1, D1, K2, D2, R, T, rvecs, tvecs, *,
                    flags: int, stereo_flags: int, mode: StereoMode, mono: tuple, intrinsics_covariance,
                    image_size) -> tuple[CalibrationCovariance | None, str]:
    """(covariance, note) of a stereo fit of :func:`_calibrate_stereo` (its views ``used``, solution, board poses,
    mono fits ``mono`` (left, right) or (None, None)); (None, why) when it is not available."""
    left, right = mono
    try:
        intrinsics_from = None
        if mode == "fixed" and left is not None and left.views_used == right.views_used == used:
            intrinsics_from = "these views"  # the usual case: the linearisations come from the stereo fit's rows
        elif mode == "fixed" and left is not None:
            intrinsics_from = tuple(
                mono_linearisation([object_points[i] for i in fit.views_used], [points[i] for i in fit.views_used],
                                   fit.K, fit.dist, fit.rvecs, fit.tvecs, flags=covariance_flags(flags),
                                   view_indices=fit.views_used, side=side)
                for fit, points, side in ((left, left_points, "left"), (right, right_points, "right"))
            )
        return stereo_covariance(
            [object_points[i] for i in used], [left_points[i] for i in used], [right_points[i] for i in used],
            K1, D1, K2, D2, R, T, rvecs, tvecs, flags=covariance_flags(stereo_flags), view_indices=used,
            intrinsics_covariance=intrinsics_covariance, intrinsics_from=intrinsics_from, image_size=tuple(image_size),
        ), ""
    except CovarianceUnavailable as error:
        return None, str(error)


def model_of_flags(flags: int) -> str:
    """The lens model (:mod:`stereo_bench.vision.lensmodels`) whose flags ``flags`` are, or "" for none."""
    from stereo_bench.vision.lensmodels import MODELS

    return next((m.name for m in MODELS.values() if m.flags == flags), "")


def _start(K: np.ndarray, D: np.ndarray, model) -> tuple[np.ndarray, np.ndarray]:
    """A warm start for ``model`` from another model's K (3, 3), D (1, k): D zero-padded or cut to the model's
    length, the terms it holds fixed 0, fx = fy at their geometric mean for square pixels."""
    out = np.zeros((1, model_length(model.flags)))
    D = np.asarray(D, float).reshape(-1)[:out.size]
    out[0, :D.size] = D
    for flag, index in ((cv2.CALIB_FIX_K3, 4), (cv2.CALIB_FIX_K4, 5), (cv2.CALIB_FIX_K5, 6), (cv2.CALIB_FIX_K6, 7)):
        if model.flags & flag and index < out.size:
            out[0, index] = 0.0
    K = np.array(K, float)
    if model.square_pixels:
        K[0, 0] = K[1, 1] = float(np.sqrt(K[0, 0] * K[1, 1]))
    return K, out


def calibrate_stereo_lens(
    object_points: list[np.ndarray], left_points: list[np.ndarray], right_points: list[np.ndarray],
    image_size: tuple[int, int], *, lens_model: str = "auto",
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None, mode: StereoMode = "joint",
    intrinsics_covariance: CalibrationCovariance | None = None, covariance: bool = True,
    candidates: tuple[str, ...] | None = None, after_mono: Callable[[], object] | None = None,
) -> StereoCalibration:
    """:func:`calibrate_stereo` with the lens model ``lens_model`` (a :data:`~stereo_bench.vision.lensmodels.MODELS`
    name) or, for "auto", the one the held-out views choose (:func:`~stereo_bench.vision.lensmodels.choose`).

    Auto: the default model (:data:`~stereo_bench.vision.lensmodels.DEFAULT_MODEL`) is calibrated in full (views
    dropped by the outlier rule); every other candidate is fitted jointly on the views it kept, warm-started from
    its solution; each fit's held-out estimate is its linearised leave-one-view-out. Intrinsics given
    (``intrinsics``) keep their model: auto then fits the default flags, as before lens models were chosen.
    The result records ``lens_model`` and ``lens_choice`` (the comparison). ``after_mono``: as
    :func:`calibrate_stereo` takes it, for the default model's fit (the candidates' start from its solution).
    """
    from stereo_bench.vision.lensmodels import (
        AUTO,
        DEFAULT_MODEL,
        MODELS,
        Choice,
        HeldOut,
        adjacency,
        choose,
        diagonal_fov_deg,
        held_out,
    )

    if lens_model != AUTO and lens_model not in MODELS:
        raise ValueError(f"unknown lens model {lens_model!r}: one of {AUTO}, {', '.join(MODELS)}")
    first = MODELS[DEFAULT_MODEL if lens_model == AUTO else lens_model]
    comparing = lens_model == AUTO and intrinsics is None
    # Compared, the default model's covariance is computed only once it is chosen (another model's replaces it).
    base, rvecs, tvecs = _calibrate_stereo(object_points, left_points, right_points, image_size,
                                           intrinsics=intrinsics, mode=mode, flags=first.flags,
                                           intrinsics_covariance=intrinsics_covariance,
                                           covariance=covariance and not comparing, after_mono=after_mono)
    if intrinsics is not None and lens_model == AUTO:
        return replace(base, lens_model=DEFAULT_MODEL if base.lens_model else "")
    if lens_model != AUTO:
        return replace(base, lens_model=first.name,
                       lens_choice=Choice(first.name, lens_model, (), "named by the caller"))
    used = base.views_used
    objs = [object_points[i] for i in used]
    lefts, rights = [left_points[i] for i in used], [right_points[i] for i in used]
    pairs = adjacency(objs)

    def estimate(model, calib, rv, tv) -> HeldOut:
        try:
            return held_out(model, objs, lefts, rights, calib.K1, calib.D1, calib.K2, calib.D2, calib.R, calib.T,
                            rv, tv, calib.rms_px, pairs)
        except (CovarianceUnavailable, np.linalg.LinAlgError) as error:
            return HeldOut(model.name, model.n_free(np.asarray(calib.D1).size), calib.rms_px, np.array([np.nan]),
                           np.array([np.nan]), f"no held-out estimate: {error}")

    def candidate(name: str):
        model = MODELS[name]
        if name == first.name:
            return name, (base, rvecs, tvecs), estimate(model, base, rvecs, tvecs)
        (K1, D1), (K2, D2) = _start(base.K1, base.D1, model), _start(base.K2, base.D2, model)
        try:
            fit = _calibrate_stereo(objs, lefts, rights, image_size, intrinsics=(K1, D1, K2, D2), mode="joint",
                                    flags=model.flags, max_rounds=0, covariance=False, criteria=CANDIDATE_CRITERIA)
        except (ValueError, cv2.error):
            return name, None, None  # a model the solver cannot fit here is no candidate
        return name, fit, estimate(model, *fit)

    names = [first.name] + [n for n in (candidates or tuple(MODELS)) if n != first.name]
    # Each solve on one OpenCV thread (deterministic), the candidates side by side on the cores, the slowest
    # fits first (the thin-prism and rational solves take 3-5x the others' on the real sets: started last, one
    # of them would run alone on one core at the end). The results do not depend on the order.
    names.sort(key=lambda name: 0 if name in _SLOW_CANDIDATES else 2 if name == first.name else 1)
    with single_threaded_opencv(), ThreadPoolExecutor(max_workers=max(1, min(len(names), os.cpu_count() or 1))) as pool:
        done = list(pool.map(candidate, names))
    fits = {name: fit for name, fit, _ in done if fit is not None}
    results = sorted((r for _, fit, r in done if fit is not None),
                     key=lambda r: (r.n_free, list(MODELS).index(r.model)))
    chosen, reason = choose(results)
    final = base
    if chosen == first.name and covariance:
        stereo_flags = first.flags | (cv2.CALIB_FIX_INTRINSIC if mode == "fixed" else cv2.CALIB_USE_INTRINSIC_GUESS)
        cov, note = _fit_covariance(object_points, left_points, right_points, base.views_used, base.K1, base.D1,
                                    base.K2, base.D2, base.R, base.T, rvecs, tvecs, flags=first.flags,
                                    stereo_flags=stereo_flags, mode=mode, mono=base.mono or (None, None),
                                    intrinsics_covariance=intrinsics_covariance, image_size=image_size)
        final = replace(base, covariance=cov, covariance_note=note)
    if chosen != first.name:
        model = MODELS[chosen]
        fit, rv, tv = fits[chosen]
        if mode == "fixed":  # the comparison was of joint fits; the calibration keeps the mode asked for
            final = calibrate_stereo(objs, lefts, rights, image_size, mode="fixed", flags=model.flags,
                                     covariance=covariance, max_rounds=0)
        else:
            final = replace(fit, covariance=None, covariance_note="not computed")
            if covariance:
                try:
                    final = replace(final, covariance_note="", covariance=stereo_covariance(
                        objs, lefts, rights, fit.K1, fit.D1, fit.K2, fit.D2, fit.R, fit.T, rv, tv,
                        flags=covariance_flags(model.flags | cv2.CALIB_USE_INTRINSIC_GUESS),
                        view_indices=list(range(len(objs))), image_size=tuple(image_size)))
                except CovarianceUnavailable as error:
                    final = replace(final, covariance_note=str(error))
        # Indices into the caller's views, as base's; the mono fits (the gates' reference) are base's, of those views.
        final = replace(final, views_used=[used[i] for i in final.views_used], views_rejected=base.views_rejected,
                        mono=base.mono)
    fov = max(diagonal_fov_deg(final.K1, image_size), diagonal_fov_deg(final.K2, image_size))
    choice = Choice(chosen, lens_model, tuple(results), reason, diagonal_fov_deg=fov)
    return replace(final, lens_model=chosen, lens_choice=choice)
