"""What one configuration's frames measure: calibrate from the calibration views, measure the square.

Pure with respect to I/O: image pairs and settings in, a result out. The live runner and the replay
call the very same function, which is what makes a replay reproduce a recording to the last digit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from stereo_bench.targets import Target
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.covariance import CalibrationCovariance
from stereo_bench.vision.detect import AmbiguousViewError, Detection
from stereo_bench.vision.pipeline import (
    BoardNotFoundError,
    ImplausibleMeasurement,
    PairMeasurement,
    calibrate_from_images,
    measure_pair,
)
from stereo_bench.vision.rectify import Rectification


class AnalysisError(RuntimeError):
    """The configuration could not be measured; the message is the reason recorded with it."""


@dataclass
class ConfigurationAnalysis:
    """Everything measured at one configuration (the result row is :meth:`row`)."""

    calib: StereoCalibration | None = None
    rect: Rectification | None = None
    calibration_epipolar_rms_px: float = float("nan")
    calibration_views_used: list[int] = field(default_factory=list)
    calibration_views_rejected: list[dict] = field(default_factory=list)
    frames: list[PairMeasurement] = field(default_factory=list)
    frames_failed: list[dict] = field(default_factory=list)
    calibrated: bool = True  # R, T calibrated from this configuration's views (False: kinematic, nominal, fixed)
    calibration_gates: dict | None = None  # the quality gates' measurements (vision.gates.GateReport.as_dict)

    def row(self) -> dict:
        """The result columns of this configuration (status 'measured')."""
        means = np.array([f.square.mean_mm for f in self.frames])
        sigmas = np.array([f.square.sigma_mean_mm for f in self.frames])
        lengths = np.concatenate([f.square.lengths_mm for f in self.frames])
        nominal = self.frames[0].square.nominal_mm
        mean = float(means.mean())
        return {
            "status": "measured",
            "square_mean_mm": mean,
            "square_std_mm": float(lengths.std(ddof=1)) if len(lengths) > 1 else float("nan"),
            "n_squares": int(len(lengths)),
            "n_frames": len(self.frames),
            "error_mm": mean - nominal,
            # The frames' noise is independent, so the mean of n frame means has sigma / sqrt(n).
            "sigma_mm": float(np.sqrt(np.sum(sigmas**2)) / len(sigmas)),
            "frame_scatter_mm": float(means.std(ddof=1)) if len(means) > 1 else float("nan"),
            "rms_px": float(self.calib.rms_px),
            "epipolar_rms_px": float(np.mean([f.epipolar_rms_px for f in self.frames])),
            "calibration_epipolar_rms_px": self.calibration_epipolar_rms_px,
            "depth_mm": float(np.mean([f.square.depth_mm for f in self.frames])),
            "fraction_in_both_measured": float(np.mean([f.fraction_in_both for f in self.frames])),
            "baseline_estimated_mm": float(self.calib.baseline_mm) if self.calibrated else None,
            "calib_views_used": len(self.calibration_views_used),
            "calib_views_rejected": len(self.calibration_views_rejected),
        }

    def details(self) -> dict:
        """Per-view and per-frame figures for the event stream (JSON-ready)."""
        return {
            "calibration": {
                "rms_px": None if self.calib is None else self.calib.rms_px,
                "per_view_rms_px": None if self.calib is None else self.calib.per_view_rms_px.tolist(),
                "views_used": self.calibration_views_used, "views_rejected": self.calibration_views_rejected,
                "epipolar_rms_px": self.calibration_epipolar_rms_px,
                "T_mm": None if self.calib is None else self.calib.T.tolist(),
                "gates": self.calibration_gates,
            },
            "frames": [
                {**f.as_dict(), "lengths_mm": f.square.lengths_mm.tolist(), "pairs": f.square.pairs.tolist()}
                for f in self.frames
            ],
            "frames_failed": self.frames_failed,
        }


def calibrate_configuration(
    calibration_pairs: Sequence[tuple[np.ndarray, np.ndarray]], board: Target, *,
    intrinsics: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None, mode: str = "joint",
    intrinsics_covariance: CalibrationCovariance | None = None,
    detections: Sequence[tuple[Detection | None, Detection | None]] | None = None, lens_model: str | None = None,
    exclude: Mapping[int, str] | None = None, max_view_rms_px: float | None = None,
) -> ConfigurationAnalysis:
    """Stereo calibration of one (B, alpha) from its calibration views; raises AnalysisError if it can't.

    ``exclude``: views (index -> why) left out, e.g. by the operator; ``max_view_rms_px``: after the calibration, the
    views it used whose RMS (the worse camera's) exceeds this are left out too and it is calibrated again without
    them (once). Both are listed among ``calibration_views_rejected`` with their reason; indices stay the views'.

    ``lens_model``: as :func:`~stereo_bench.vision.pipeline.calibrate_from_images` takes it.

    A calibration the quality gates refuse (:mod:`stereo_bench.vision.gates`) fails the configuration with the
    gate's line as its reason, as a physically impossible one does: nothing is measured with it.

    ``intrinsics_covariance``: of given ``intrinsics`` held fixed (without it the covariance is unknown).
    ``detections``: per view, the (left, right) detections already made while capturing (None: detect here).
    """
    left_out = dict(exclude or {})

    def fit():
        kept = [i for i in range(len(calibration_pairs)) if i not in left_out]
        if not kept:
            raise AnalysisError(f"every calibration view is excluded ({len(left_out)} of {len(calibration_pairs)})")
        try:
            result = calibrate_from_images([calibration_pairs[i][0] for i in kept],
                                           [calibration_pairs[i][1] for i in kept], board, intrinsics=intrinsics,
                                           mode="fixed" if mode == "fixed" else "joint", thorough=False,
                                           intrinsics_covariance=intrinsics_covariance,
                                           detections=None if detections is None else [detections[i] for i in kept],
                                           lens_model=lens_model)
        except (ValueError, np.linalg.LinAlgError) as error:
            raise AnalysisError(str(error) + (f" ({len(left_out)} view(s) excluded)" if left_out else "")) from None
        return kept, result

    kept, result = fit()
    if max_view_rms_px is not None:
        worst = np.max(np.asarray(result.calib.per_view_rms_px, float).reshape(len(result.views_used), -1), axis=1)
        over = {kept[used]: float(rms) for used, rms in zip(result.views_used, worst, strict=True)
                if rms > max_view_rms_px}
        if over:
            left_out.update({index: f"per-view RMS {rms:.3f} px over the threshold {max_view_rms_px:g} px"
                             for index, rms in over.items()})
            kept, result = fit()
    rejected = [{**r.as_dict(), "index": kept[r.index]} for r in result.views_rejected]
    rejected += [{"index": index, "reason": why} for index, why in sorted(left_out.items())]
    return ConfigurationAnalysis(
        calib=result.calib, rect=result.rect, calibration_epipolar_rms_px=result.epipolar_rms_px,
        calibration_views_used=[kept[i] for i in result.views_used],
        calibration_views_rejected=sorted(rejected, key=lambda r: r["index"]),
        calibration_gates=None if result.gates is None else result.gates.as_dict(),
    )


def measure_configuration(
    analysis: ConfigurationAnalysis, measurement_pairs: Sequence[tuple[np.ndarray, np.ndarray]], target: Target, *,
    partial: bool, detections: Sequence[tuple[Detection | None, Detection | None] | None] | None = None,
) -> ConfigurationAnalysis:
    """Measure the square in every measurement frame; raises AnalysisError when no frame measures.

    ``detections``: per frame, the (left, right) detections already made while capturing (None: detect here).
    """
    for i, (left_image, right_image) in enumerate(measurement_pairs):
        try:
            analysis.frames.append(measure_pair(left_image, right_image, analysis.calib, target,
                                                rect=analysis.rect, partial=partial,
                                                detections=None if detections is None else detections[i]))
        except (BoardNotFoundError, AmbiguousViewError, ImplausibleMeasurement) as error:
            analysis.frames_failed.append({"index": i, "reason": str(error)})
    if not analysis.frames:
        reasons = sorted({f["reason"] for f in analysis.frames_failed})
        raise AnalysisError(f"target not measured in any of {len(measurement_pairs)} frames: {'; '.join(reasons)}")
    return analysis
