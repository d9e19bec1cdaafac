"""The measurement pipeline at one glance: detect -> calibrate -> rectify -> triangulate -> measure."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stereo_bench.targets import Target
from stereo_bench.vision.calibrate import MIN_VIEWS, RejectedView, StereoCalibration, StereoMode, calibrate_stereo
from stereo_bench.vision.covariance import CalibrationCovariance
from stereo_bench.vision.detect import Detection, common_corners, common_sigmas, detect
from stereo_bench.vision.measure import SquareMeasurement, measure_square, planar_fit_rms_px
from stereo_bench.vision.rectify import Rectification, epipolar_errors_px, rectify, rms

MIN_COMMON_CORNERS = 6


class BoardNotFoundError(ValueError):
    """The target is not (or not enough of it is) visible; the message says in which image."""


@dataclass(frozen=True)
class CalibrationResult:
    calib: StereoCalibration
    rect: Rectification
    epipolar_rms_px: float
    views_rejected: list[RejectedView]  # detection failures and calibration outliers, by pair index
    views_used: list[int]  # pair indices


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


def calibrate_from_images(
    left_images: Sequence[np.ndarray], right_images: Sequence[np.ndarray], target: Target, *,
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None, mode: StereoMode = "joint",
    thorough: bool = True, intrinsics_covariance: CalibrationCovariance | None = None,
    detections: Sequence[tuple[Detection | None, Detection | None]] | None = None,
) -> CalibrationResult:
    """Stereo calibration from image pairs of a calibration target (pairs in matching order).

    ``thorough`` retries a missed board with the slower detectors (right for stored images; a live
    campaign, whose views are known to hold the board, passes False). ``intrinsics_covariance``: of
    the given ``intrinsics`` (see :func:`~stereo_bench.vision.calibio.read_intrinsics_covariance`);
    fixed intrinsics without it leave the calibration's covariance unknown. ``detections``: per pair,
    the (left, right) detections of these images (``detect(image, target, thorough=thorough)``), when
    the caller made them already (a campaign detects each view while the next ones are captured).

    Raises:
        ValueError: fewer than ``MIN_VIEWS`` pairs show the board in both images, or the solver fails.
    """
    if len(left_images) != len(right_images):
        raise ValueError(f"{len(left_images)} left images but {len(right_images)} right images")
    if detections is not None and len(detections) != len(left_images):
        raise ValueError(f"{len(detections)} detections for {len(left_images)} image pairs")
    image_size = left_images[0].shape[1::-1]
    rejected: list[RejectedView] = []
    pair_index, objects, lefts, rights = [], [], [], []
    for index, (left_image, right_image) in enumerate(zip(left_images, right_images, strict=True)):
        if detections is not None:
            left, right = detections[index]
        else:
            left = detect(left_image, target, thorough=thorough)
            right = detect(right_image, target, thorough=thorough)
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
    if len(objects) < MIN_VIEWS:
        raise ValueError(f"calibration board found in only {len(objects)} of {len(left_images)} view pairs "
                         f"(need {MIN_VIEWS})")
    calib = calibrate_stereo(objects, lefts, rights, tuple(image_size), intrinsics=intrinsics, mode=mode,
                             intrinsics_covariance=intrinsics_covariance)
    rejected += [RejectedView(pair_index[r.index], r.reason) for r in calib.views_rejected]
    used = [pair_index[i] for i in calib.views_used]
    rect = rectify(calib)
    epipolar = np.concatenate([
        epipolar_errors_px(calib, rect, lefts[i], rights[i]) for i in calib.views_used
    ])
    return CalibrationResult(
        calib=calib, rect=rect, epipolar_rms_px=rms(epipolar),
        views_rejected=sorted(rejected, key=lambda r: r.index), views_used=used,
    )


def measure_pair(
    left_image: np.ndarray, right_image: np.ndarray, calib: StereoCalibration, target: Target, *,
    rect: Rectification | None = None, pixel_sigma_px: float | None = None, thorough: bool = False,
    partial: bool = False, detections: tuple[Detection | None, Detection | None] | None = None,
) -> PairMeasurement:
    """Measure the target's square in one stereo pair with a known calibration.

    ``thorough``: retry a missed board with the slower detector (stored images, not live capture).
    ``detections``: the (left, right) detections of these images, when the caller already has them.
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
    rect = rect or rectify(calib)
    sigma = pixel_sigma_px if pixel_sigma_px is not None else common_sigmas(left, right)
    square = measure_square(calib, target, ids, left_px, right_px, pixel_sigma_px=sigma)
    fit = (planar_fit_rms_px(target.object_points[ids], left_px, calib.K1, calib.D1),
           planar_fit_rms_px(target.object_points[ids], right_px, calib.K2, calib.D2))
    return PairMeasurement(
        square=square, epipolar_rms_px=rms(epipolar_errors_px(calib, rect, left_px, right_px)),
        left=left, right=right, fraction_in_both=len(ids) / target.n_corners, planar_fit_rms_px=fit,
    )
