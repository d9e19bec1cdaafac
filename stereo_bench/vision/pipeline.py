"""The measurement pipeline at one glance: detect -> calibrate -> rectify -> triangulate -> measure."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import cv2
import numpy as np

from stereo_bench.targets import CharucoTarget, Checkerboard, Target
from stereo_bench.vision.calibrate import (
    DEFAULT_FLAGS,
    MIN_VIEWS,
    ImplausibleCalibration,
    RejectedView,
    StereoCalibration,
    StereoMode,
    calibrate_stereo,
    calibrate_stereo_lens,
    calibration_problems,
    camera_problems,
    single_threaded_opencv,
)
from stereo_bench.vision.covariance import CalibrationCovariance
from stereo_bench.vision.detect import AnyBoardSearch, Detection, common_corners, common_sigmas, detect
from stereo_bench.vision.gates import (
    CalibrationRefused,
    GateReport,
    GateView,
    PoseCache,
    gate_board_fit,
    gate_consistent_views,
    image_blur,
    run_gates,
)
from stereo_bench.vision.lensmodels import MODELS
from stereo_bench.vision.measure import SquareMeasurement, measure_square, planar_fit_rms_px
from stereo_bench.vision.rectify import Rectification, epipolar_errors_px, rectify, rms
from stereo_bench.vision.triangulate import camera_depths_mm, parallax_px
from stereo_bench.vision.uncertainty import scale_outlier, with_adequacy

MIN_COMMON_CORNERS = 6

# Physical sanity of a measurement (check_measurement, check_epipolar).
# Under one pixel of parallax a corner cannot be told from one at infinity (triangulate.parallax_px).
MIN_PARALLAX_PX = 1.0
# "Far beyond the calibration's" epipolar error: the calibration's own views leave an epipolar RMS of about
# sqrt(2) x the corner noise; a pair of the same rig leaves about the same. The factor is the calibration's
# outlier rule's (calibrate.OUTLIER_FACTOR, 3x the median view), and the floor covers the corner noise of real
# images (0.1-0.3 px, so 0.15-0.45 px epipolar) with room to spare. Beyond both, the cameras moved since the
# calibration or the files belong to another rig, and the square is biased by an unknown amount.
EPIPOLAR_FACTOR = 3.0
EPIPOLAR_FLOOR_PX = 1.0


class BoardNotFoundError(ValueError):
    """The target is not (or not enough of it is) visible; the message says in which image."""


class ImplausibleMeasurement(ValueError):
    """A result no real stereo pair can produce: the message says what and the likely cause."""


def check_measurement(calib: StereoCalibration, points_mm: np.ndarray) -> None:
    """Raise :class:`ImplausibleMeasurement` unless every triangulated corner is finite, in front of both
    cameras and seen with at least :data:`MIN_PARALLAX_PX` of parallax."""
    points = np.asarray(points_mm, float).reshape(-1, 3)
    if not np.all(np.isfinite(points)):
        raise ImplausibleMeasurement("triangulation gave non-finite corners: the calibration does not fit these "
                                     "images")
    depth_left, depth_right = camera_depths_mm(calib, points)
    behind = (depth_left <= 0) | (depth_right <= 0)
    if np.any(behind):
        raise ImplausibleMeasurement(
            f"{int(behind.sum())} of {len(points)} triangulated corners lie behind the cameras (median depth "
            f"{np.median(depth_left):.1f} mm): are the left and right images swapped?")
    parallax = parallax_px(calib, points)
    if np.median(parallax) < MIN_PARALLAX_PX:
        raise ImplausibleMeasurement(
            f"the two views see the board with {np.median(parallax):.3g} px of parallax (need "
            f"{MIN_PARALLAX_PX:g}): the same image as left and right, or a board too far for this baseline")


def epipolar_limit_px(calibration_epipolar_rms_px: float | None) -> float:
    """The largest epipolar RMS a measurement may show with a calibration that left this much on its own views."""
    reference = calibration_epipolar_rms_px if calibration_epipolar_rms_px and calibration_epipolar_rms_px > 0 else 0
    return max(EPIPOLAR_FACTOR * reference, EPIPOLAR_FLOOR_PX)


def check_epipolar(measured_rms_px: float, calibration_epipolar_rms_px: float | None) -> None:
    """Raise :class:`ImplausibleMeasurement` when a pair's epipolar RMS is far beyond the calibration's
    (:data:`EPIPOLAR_FACTOR` times it, and over :data:`EPIPOLAR_FLOOR_PX`)."""
    limit = epipolar_limit_px(calibration_epipolar_rms_px)
    if not measured_rms_px <= limit:
        reference = ("" if not calibration_epipolar_rms_px else
                     f"{measured_rms_px / calibration_epipolar_rms_px:.0f}x the calibration's "
                     f"{calibration_epipolar_rms_px:.3f} px, ")
        raise ImplausibleMeasurement(
            f"epipolar RMS {measured_rms_px:.3f} px is {reference}over the {limit:.3f} px limit: the cameras moved "
            "since the calibration, or it is another rig's")


@dataclass(frozen=True)
class CalibrationResult:
    calib: StereoCalibration
    rect: Rectification
    epipolar_rms_px: float
    views_rejected: list[RejectedView]  # detection failures and calibration outliers, by pair index
    views_used: list[int]  # pair indices
    gates: GateReport | None = None  # the quality gates' measurements (None: not run)
    # Per view used (calib.views_used' order): (board points (N, 3) mm, left (N, 2) px, right (N, 2) px), the corners
    # the fit saw (a cross-check fits them again: stereo_bench.vision.mrcal_bridge).
    corners: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...] = ()


@dataclass(frozen=True)
class PairMeasurement:
    square: SquareMeasurement
    epipolar_rms_px: float
    left: Detection
    right: Detection
    fraction_in_both: float  # of the target's corners
    planar_fit_rms_px: tuple[float, float]  # (left, right): random + systematic corner error

    def as_dict(self) -> dict:
        return {
            "square_mm": self.square.summary(), "nominal_mm": self.square.nominal_mm, "error_mm": self.square.error_mm,
            "depth_mm": self.square.depth_mm, "epipolar_rms_px": self.epipolar_rms_px,
            "pixel_sigma_px": list(self.square.pixel_sigma_px), "planar_fit_rms_px": list(self.planar_fit_rms_px),
            "corners_in_both": int(len(self.square.ids)),
            "fraction_in_both": self.fraction_in_both,
            "detection_order": {"left": self.left.order, "right": self.right.order},
        }


#: Threads detecting calibration views (at most the cores there are).
DETECTION_THREADS = 4


def _detect_all(left_images: Sequence[np.ndarray], right_images: Sequence[np.ndarray], target: Target, *,
                thorough: bool, any_board: AnyBoardSearch | None = None,
                ) -> list[tuple[Detection | None, Detection | None]]:
    """Per pair the (left, right) detections, without corner-noise estimates, on a few threads. ``any_board``: the
    any-size board searches, kept for the board-size gate (:class:`~stereo_bench.vision.detect.AnyBoardSearch`)."""
    images = [image for pair in zip(left_images, right_images, strict=True) for image in pair]
    workers = max(1, min(DETECTION_THREADS, os.cpu_count() or 1, len(images)))

    def one(image: np.ndarray) -> Detection | None:
        return detect(image, target, thorough=thorough, noise=False, any_board=any_board)

    # OpenCV on one thread inside each detection: the images are already spread over the cores, and OpenCV's own
    # workers would only add hand-over and spinning (~10 % of the detections' CPU on the real sets); the corners
    # are the same bits either way.
    with single_threaded_opencv():
        if workers == 1:
            found = [one(image) for image in images]
        else:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                found = list(pool.map(one, images))
    return list(zip(found[0::2], found[1::2], strict=True))


def _whole_grids(detections: Sequence[tuple[Detection | None, Detection | None]],
                 target: Target) -> list[np.ndarray | None]:
    """Per image (left and right of each pair in turn) the found (rows, cols, 2) corner grid of a whole checkerboard,
    else None (the board-size search's hint: :func:`~stereo_bench.vision.gates.gate_board_fit`)."""
    if not isinstance(target, Checkerboard):
        return [None] * (2 * len(detections))
    return [d.corners_px.reshape(target.rows, target.cols, 2) if d is not None and d.n == target.n_corners else None
            for pair in detections for d in pair]


def calibrate_from_images(
    left_images: Sequence[np.ndarray], right_images: Sequence[np.ndarray], target: Target, *,
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None, mode: StereoMode = "joint",
    thorough: bool = True, intrinsics_covariance: CalibrationCovariance | None = None,
    detections: Sequence[tuple[Detection | None, Detection | None]] | None = None, lens_model: str | None = None,
    gates: bool = True, accept_poor: bool = False, view_names: Sequence[str] | None = None,
) -> CalibrationResult:
    """Stereo calibration from image pairs of a calibration target (pairs in matching order).

    ``thorough`` retries a missed board with the slower detectors (right for stored images; a live
    campaign, whose views are known to hold the board, passes False). ``intrinsics_covariance``: of
    the given ``intrinsics`` (see :func:`~stereo_bench.vision.calibio.read_intrinsics_covariance`);
    fixed intrinsics without it leave the calibration's covariance unknown. ``detections``: per pair,
    the (left, right) detections of these images (``detect(image, target, thorough=thorough)``), when
    the caller made them already (a campaign detects each view while the next ones are captured).
    ``lens_model``: "auto" or a :data:`~stereo_bench.vision.lensmodels.MODELS` name
    (:func:`~stereo_bench.vision.calibrate.calibrate_stereo_lens`); None fits the default flags without a
    comparison, as before lens models were chosen.

    Detection here skips the corner-noise estimate (``detect(..., noise=False)``: the fit takes the noise from
    its own residuals) and runs on :data:`DETECTION_THREADS` threads (OpenCV's detectors release the GIL; the
    corners do not depend on the thread).
    ``gates``: run the quality gates (:mod:`stereo_bench.vision.gates`) and refuse a calibration they fail,
    unless ``accept_poor``; ``view_names`` (per pair, e.g. the file names) go into their lines.

    Raises:
        CalibrationRefused (an ImplausibleCalibration): a quality gate failed (its line names the cause).
        ValueError: fewer than ``MIN_VIEWS`` pairs show the board in both images, or the solver fails.
        ImplausibleCalibration (a ValueError): given intrinsics that do not fit the images, or a result no
            stereo pair can have (:func:`~stereo_bench.vision.calibrate.calibration_problems`).
    """
    if len(left_images) != len(right_images):
        raise ValueError(f"{len(left_images)} left images but {len(right_images)} right images")
    if detections is not None and len(detections) != len(left_images):
        raise ValueError(f"{len(detections)} detections for {len(left_images)} image pairs")
    image_size = left_images[0].shape[1::-1]
    if intrinsics is not None:
        given = camera_problems(intrinsics[0], intrinsics[1], image_size, "left camera")
        given += camera_problems(intrinsics[2], intrinsics[3], image_size, "right camera")
        if given:
            raise ImplausibleCalibration(f"the given intrinsics do not fit these images: {given[0]}")
    rejected: list[RejectedView] = []
    pair_index, objects, lefts, rights = [], [], [], []
    any_board = AnyBoardSearch()
    if detections is None:
        detections = _detect_all(left_images, right_images, target, thorough=thorough, any_board=any_board)
    found: list[bool] = []  # per image, left and right of each pair in turn
    for index in range(len(left_images)):
        left, right = detections[index]
        found += [left is not None, right is not None]
        missing = [side for side, d in (("left", left), ("right", right)) if d is None]
        if missing:
            rejected.append(RejectedView(index, f"board not found in the {' and '.join(missing)} image"))
            continue
        ids, left_px, right_px = common_corners(left, right)
        if len(ids) < MIN_COMMON_CORNERS:
            rejected.append(RejectedView(index, f"only {len(ids)} corners seen in both images"))
            continue
        pair_index.append(index)
        objects.append(target.object_points[ids])
        lefts.append(left_px)
        rights.append(right_px)
    with single_threaded_opencv(), ThreadPoolExecutor(max_workers=2) as pool:
        # Work that does not wait for the fit runs beside it on the other core (each OpenCV call on one thread:
        # the same numbers as one after the other): the board-size search beside the calibration, the quality
        # gates beside the leave-one-view-out check. A refusal by a gate still comes before any other failure.
        report = None
        board_search = None
        blurs: dict = {}

        def measure_blur() -> None:
            # The sharpness gate's measurement needs no calibration: on the pool while the joint fit runs on one
            # thread (started with the mono fits, it took the cores from the two of them).
            if gates and not blurs:
                blurs.update({(index, side): pool.submit(image_blur, image, px, target)
                              for k, index in enumerate(pair_index)
                              for side, image, px in (("left", left_images[index], lefts[k]),
                                                      ("right", right_images[index], rights[k]))})

        if gates:
            images = [image for pair in zip(left_images, right_images, strict=True) for image in pair]
            board_search = pool.submit(gate_board_fit, target, found, images, grids=_whole_grids(detections, target),
                                       any_board=any_board)

        def board_report() -> GateReport | None:
            if board_search is None:
                return None
            board = board_search.result()
            if board.verdict == "fail" and (not accept_poor or len(objects) < MIN_VIEWS):
                raise CalibrationRefused(GateReport((board,)))
            return GateReport((board,), accept_poor)

        if len(objects) < MIN_VIEWS:
            board_report()
            inverted = isinstance(target, CharucoTarget) and not target.inverted and not any(found)
            raise ValueError(f"calibration board found in only {len(objects)} of {len(left_images)} view pairs "
                             f"(need {MIN_VIEWS})" + ("; in none of the images: a ChArUco board printed white on "
                                                      "black needs --inverted" if inverted else ""))
        def fit(objects: list, lefts: list, rights: list, after_mono=None) -> StereoCalibration:
            if lens_model is None:
                return calibrate_stereo(objects, lefts, rights, tuple(image_size), intrinsics=intrinsics, mode=mode,
                                        intrinsics_covariance=intrinsics_covariance, after_mono=after_mono)
            return calibrate_stereo_lens(objects, lefts, rights, tuple(image_size), lens_model=lens_model,
                                         intrinsics=intrinsics, mode=mode,
                                         intrinsics_covariance=intrinsics_covariance, after_mono=after_mono)

        try:
            calib = fit(objects, lefts, rights, measure_blur)
        except Exception:
            board_report()
            raise
        measure_blur()  # started by the fit; here only if it did not
        report = board_report()
        n_paired = len(pair_index)  # the pairs with the board in both images, the gates' views

        def fit_dropped() -> list[tuple[int, str]]:
            # (pair index, reason) of the views the fit's outlier rule dropped, with what the gates found in them.
            diagnoses = report.view_diagnoses if report is not None else {}
            return [(pair_index[r.index], f"{r.reason}: {diagnoses[pair_index[r.index]]}"
                     if pair_index[r.index] in diagnoses else r.reason) for r in calib.views_rejected]

        dropped = fit_dropped()
        # The held-out check of the budget (docs/UNCERTAINTY.md).
        adequacy = pool.submit(with_adequacy, calib, objects, lefts, rights)
        if report is not None:
            views = [GateView(index, objects[k], lefts[k], rights[k], left_images[index], right_images[index])
                     for k, index in enumerate(pair_index)]
            report = report.merged(run_gates(calib, views, target, dropped=dropped, names=view_names,
                                             accept_poor=accept_poor,
                                             blur_of={key: blur.result() for key, blur in blurs.items()},
                                             poses=PoseCache.of_fit(calib, views)))
            if report.refused:
                raise CalibrationRefused(report)
            dropped = fit_dropped()
        calib = adequacy.result()
        # A fixed-mode fit of its own mono intrinsics fits those again without the view.
        refit = fit if mode == "fixed" and intrinsics is None else \
            refit_from(calib, tuple(image_size), mode=mode, intrinsics_covariance=intrinsics_covariance)
        calib, kept, dropped_by_scale = drop_scale_outliers(
            calib, refit, objects, lefts, rights, most=n_paired // 4)
        if dropped_by_scale:
            dropped_by_scale = [(pair_index[position], why) for position, why in dropped_by_scale]
            pair_index, objects, lefts, rights = ([seq[i] for i in kept]
                                                  for seq in (pair_index, objects, lefts, rights))
            dropped = sorted(fit_dropped() + dropped_by_scale)
            if report is not None:
                report = report.replaced(gate_consistent_views(n_paired, dropped, view_names))
                if report.refused:
                    raise CalibrationRefused(report)
    problems = calibration_problems(calib)
    if problems:
        if report is not None and report.failed:  # kept with --accept-poor: the gates name the cause
            raise ImplausibleCalibration(f"the calibration is not physically possible ({problems[0]}), because: "
                                         f"{report.refusal_line()}")
        raise ImplausibleCalibration(f"the calibration is not physically possible: {problems[0]}")
    rejected += [RejectedView(index, why) for index, why in dropped]
    used = [pair_index[i] for i in calib.views_used]
    rect = rectify(calib)
    epipolar = np.concatenate([
        epipolar_errors_px(calib, rect, lefts[i], rights[i]) for i in calib.views_used
    ])
    return CalibrationResult(
        calib=calib, rect=rect, epipolar_rms_px=rms(epipolar),
        views_rejected=sorted(rejected, key=lambda r: r.index), views_used=used, gates=report,
        corners=tuple((objects[i], lefts[i], rights[i]) for i in calib.views_used),
    )


def refit_from(first: StereoCalibration, image_size: tuple[int, int], *, mode: StereoMode = "joint",
               intrinsics_covariance: CalibrationCovariance | None = None,
               ) -> Callable[[list, list, list], StereoCalibration]:
    """A fit of other views (objects, lefts, rights) started from ``first``'s intrinsics, in its lens model, for
    :func:`drop_scale_outliers`: the same minimum as a fit from scratch (opencv_sample without pair 7: abs(T), fx
    and sigma(abs T) to 1e-4) in 0.02 s, where auto's comparison made again took 0.6 s. The result keeps
    ``first``'s lens choice: the comparison of the views with the dropped one."""
    flags = MODELS[first.lens_model].flags if first.lens_model else DEFAULT_FLAGS

    def refit(objects: list, lefts: list, rights: list) -> StereoCalibration:
        start = (first.K1, first.D1, first.K2, first.D2)
        calib = calibrate_stereo(objects, lefts, rights, image_size, intrinsics=start, mode=mode, flags=flags,
                                 intrinsics_covariance=intrinsics_covariance)
        return replace(calib, lens_model=first.lens_model, lens_choice=first.lens_choice)

    return refit


def drop_scale_outliers(calib: StereoCalibration, fit: Callable[[list, list, list], StereoCalibration],
                        object_points: Sequence[np.ndarray], left_points: Sequence[np.ndarray],
                        right_points: Sequence[np.ndarray], *, most: int,
                        ) -> tuple[StereoCalibration, list[int], list[tuple[int, str]]]:
    """``calib`` (fitted to these views, with its adequacy) fitted again by ``fit(objects, lefts, rights)`` without
    each view whose held-out squares disagree with every other view's (:func:`~stereo_bench.vision.uncertainty.
    scale_outlier`), one at a time, at most ``most`` views and never below ``MIN_VIEWS``.

    Counted as the model's inadequacy instead, one view's fault widens every measurement's U: opencv_sample's
    pair 7 (docs/UNCERTAINTY.md). Returns (the calibration, with its adequacy; the positions of the views it was
    fitted from, its ``views_used`` indexing them in turn; (position, reason) of each view dropped).
    """
    kept, dropped = list(range(len(object_points))), []
    while len(dropped) < most and len(calib.views_used) > MIN_VIEWS:
        outlier = scale_outlier(calib.adequacy)
        if outlier is None:
            break
        position = kept[calib.views_used[outlier.position]]
        fewer = [i for i in kept if i != position]
        views = [[seq[i] for i in fewer] for seq in (object_points, left_points, right_points)]
        try:
            refitted = fit(*views)
        except (ValueError, cv2.error):
            break  # the views left do not fit alone: the calibration keeps the view (and its excess in u_rel)
        calib, kept = with_adequacy(refitted, *views), fewer
        dropped.append((position, outlier.reason()))
    return calib, kept, dropped


def measure_pair(
    left_image: np.ndarray, right_image: np.ndarray, calib: StereoCalibration, target: Target, *,
    rect: Rectification | None = None, pixel_sigma_px: float | None = None, thorough: bool = False,
    partial: bool = False, detections: tuple[Detection | None, Detection | None] | None = None,
) -> PairMeasurement:
    """Measure the target's square in one stereo pair with a known calibration.

    ``thorough``: retry a missed board with the slower detector (stored images, not live capture).
    ``detections``: the (left, right) detections of these images, when the caller already has them.

    Raises:
        BoardNotFoundError: the target is not in both images.
        ImplausibleMeasurement: corners behind the cameras or without parallax (:func:`check_measurement`).
    """
    if detections is None:
        detections = (detect(left_image, target, thorough=thorough, partial=partial),
                      detect(right_image, target, thorough=thorough, partial=partial))
    left, right = detections
    for side, found in (("left", left), ("right", right)):
        if found is None:
            raise BoardNotFoundError(f"{target.kind} {target.cols}x{target.rows} not found in the {side} image")
    ids, left_px, right_px = common_corners(left, right)
    if len(ids) < MIN_COMMON_CORNERS:
        raise BoardNotFoundError(f"only {len(ids)} corners are seen in both images (need {MIN_COMMON_CORNERS})")
    if pixel_sigma_px is not None and not (np.isfinite(pixel_sigma_px) and pixel_sigma_px >= 0):
        raise ValueError(f"pixel_sigma_px must be a finite number >= 0, not {pixel_sigma_px}")
    rect = rect or rectify(calib)
    sigma = pixel_sigma_px if pixel_sigma_px is not None else common_sigmas(left, right)
    square = measure_square(calib, target, ids, left_px, right_px, pixel_sigma_px=sigma)
    check_measurement(calib, square.points_mm)
    fit = (planar_fit_rms_px(target.object_points[ids], left_px, calib.K1, calib.D1),
           planar_fit_rms_px(target.object_points[ids], right_px, calib.K2, calib.D2))
    return PairMeasurement(
        square=square, epipolar_rms_px=rms(epipolar_errors_px(calib, rect, left_px, right_px)),
        left=left, right=right, fraction_in_both=len(ids) / target.n_corners, planar_fit_rms_px=fit,
    )
