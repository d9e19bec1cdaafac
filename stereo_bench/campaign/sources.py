"""Sources of stereo extrinsics at a configuration, and the square measured with each (issue 11 items 2-3).

A configuration's frames are triangulated with the R, T of one source (``[extrinsics] mode``) and, for
comparison, of every other source available there, on the same detections (cheap: no detection again):

- ``calibrated``: the stereo calibration of the configuration's own views (``per-config``);
- ``kinematic``: the kinematic rig model's prediction at the axis positions the rig *reported* and the
  directions it approached them from (:func:`stereo_bench.kinematics.predict`), with the model's intrinsics
  (its joint fit's);
- ``nominal``: the ideal geometry at the *commanded* B and alphas (:func:`stereo_bench.kinematics.nominal_extrinsics`),
  with intrinsics from a calibration;
- ``fixed``: a calibration read from a file.

Each source carries what its uncertainty budget needs (:func:`stereo_bench.vision.uncertainty.configuration_budget`):
the covariance of the calibration behind it, the structure component (calibrated: zeros, the rig did not
move since its views; kinematic: the prediction's covariance, which holds the rig's repeatability;
nominal: the rig's stated tolerances, :func:`stereo_bench.kinematics.nominal_covariance`; fixed: unknown)
and the boards' scale (the calibration board's scale enters R, T unless they come from the slide).

    used = kinematic_source(model, axes, approach)
    frames = measure_with(used, detections, target)
    budget = budget_of(used, frames, target)

Pure: detections and models in, measurements and JSON-ready records out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from stereo_bench.geometry import stereo_structure
from stereo_bench.kinematics import (
    AXES,
    TILT_AXES,
    KinematicModel,
    approach_directions,
    joint_covariance,
    nominal_covariance,
    nominal_extrinsics,
    predict,
    structure_sigma,
)
from stereo_bench.targets import Target
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.covariance import EXTRINSIC_NAMES, CalibrationCovariance
from stereo_bench.vision.detect import Detection
from stereo_bench.vision.pipeline import PairMeasurement, measure_pair
from stereo_bench.vision.rectify import rectify
from stereo_bench.vision.uncertainty import BoardScale, UncertaintyBudget, configuration_budget

#: The sources (the extrinsics source each ``[extrinsics] mode`` measures with: its strategy object's ``used``,
#: :mod:`stereo_bench.campaign.extrinsics`).
SOURCE_NAMES = ("calibrated", "kinematic", "nominal", "fixed")


# --------------------------------------------------------------------------------------------------
# Where the rig is, and from which side it got there


def reported_axes(reading: Any, commanded: Mapping[str, float], tilts: Sequence[str] = ()) -> dict[str, float]:
    """The kinematic axes a rig reading reports (``baseline_mm``, ``toe_in_left_deg``, ``toe_in_right_deg``, and
    ``tilts``: the tilts the rig drives, grblHAL's A/B); a quantity the rig does not report (set by hand) is the
    commanded value."""
    out = {}
    for axis in (*AXES, *tilts):
        value = getattr(reading, axis, None) if reading is not None else None
        out[axis] = float(commanded[axis] if value is None else value)
    return out


class ApproachTracker:
    """Per axis the direction of the move that reached the current position (+1 increasing, -1 decreasing).

    Fed with every position the rig reported, in order (the homed position first): the kinematic model
    corrects the commanded values for backlash by it. An axis never moved is 0 (unknown).
    """

    def __init__(self):
        self.previous: dict[str, float] | None = None
        self.approach: dict[str, int] = {}

    def homed(self, axes: Mapping[str, float], directions: Mapping[str, int]) -> dict[str, int]:
        """Record that homing left the rig at ``axes``, arriving from ``directions`` (its pull-off:
        ``GrblRig.homing_approach``; an axis missing there keeps what it had)."""
        approach = approach_directions(self.previous, axes, self.approach)
        approach.update({axis: int(directions[axis]) for axis in _tracked(axes) if axis in directions})
        self.approach = approach
        self.previous = {axis: float(axes[axis]) for axis in _tracked(axes)}
        return dict(self.approach)

    def reached(self, axes: Mapping[str, float]) -> dict[str, int]:
        """Record that the rig now stands at ``axes``; returns the directions it approached them from."""
        self.approach = approach_directions(self.previous, axes, self.approach)
        self.previous = {axis: float(axes[axis]) for axis in _tracked(axes)}
        return dict(self.approach)


def _tracked(axes: Mapping[str, float]) -> tuple[str, ...]:
    """The axes an :class:`ApproachTracker` follows: the chain's three, and the tilts where ``axes`` has them."""
    return (*AXES, *(axis for axis in TILT_AXES if axis in axes))


# --------------------------------------------------------------------------------------------------
# Sources


@dataclass(frozen=True)
class Source:
    """The extrinsics of one source at one configuration and what its uncertainty budget rests on.

    ``calib``: the intrinsics and R, T the frames are triangulated with; its ``covariance`` is the
    calibration component's (for kinematic and nominal the intrinsics only). ``structure_covariance``:
    (6, 6) over (rvec rad, T mm), None when unknown. ``structure_sigma``: the optical baseline's, alphas'
    and rotation's standard uncertainties when the source states them.
    """

    name: str
    calib: StereoCalibration
    structure_covariance: np.ndarray | None
    extrinsics_from_calibration: bool
    structure_source: str
    board_scale: BoardScale
    structure_sigma: dict[str, float] | None = None
    note: str | None = None

    @property
    def structure(self) -> dict[str, float]:
        return stereo_structure(self.calib.R, self.calib.T)


def calibrated_source(calib: StereoCalibration, board_scale: BoardScale) -> Source:
    """R, T calibrated from this configuration's own views: the rig has not moved since (structure 0)."""
    return Source("calibrated", calib, np.zeros((6, 6)), True,
                  "calibrated at this configuration: the rig did not move since its views", board_scale)


def fixed_source(calib: StereoCalibration, board_scale: BoardScale) -> Source:
    """R, T read from a calibration file: how far the rig has moved since is not known (structure unknown)."""
    return Source("fixed", calib, None, True, "a calibration file: the rig's change since it is unknown",
                  board_scale)


def model_intrinsics_covariance(model: KinematicModel) -> CalibrationCovariance | None:
    """The model's intrinsics covariance as a calibration covariance (None when the model has none)."""
    matrix = model.intrinsics_covariance_matrix()
    if matrix is None:
        return None
    fit = model.fit
    locking = tuple(model.pixel_locking_px) if model.pixel_locking_px is not None else None
    return CalibrationCovariance(tuple(model.intrinsics_covariance_names), matrix,
                                 sigma_px=float(fit.pixel_sigma_px) if fit is not None else float("nan"),
                                 dof=int(fit.dof or 0) if fit is not None else 0, pixel_locking_px=locking,
                                 residual_map=model.residual_map_objects())


def kinematic_source(model: KinematicModel, axes: Mapping[str, float], approach: Mapping[str, int],
                     board_scale: BoardScale) -> Source:
    """The kinematic model's R, T at reported ``axes`` approached from ``approach``, with the model's intrinsics.

    The design's one fit estimated the intrinsics and the kinematic parameters together, and their errors
    are correlated (a focal length against the right camera's position): the calibration component covers
    both, jointly (the intrinsics and the R, T the parameters predict here, with their cross-covariance), as
    a per-config calibration's covers its intrinsics and R, T. The structure component is what the rig
    adds at this move: its landing repeatability, and the backlash when the approach is unknown. A model
    file without the cross-covariance (older) keeps them apart: the parameters' part in the structure
    component, the intrinsics alone in the calibration component (their correlation then unaccounted).
    """
    prediction = predict(model, axes, approach)
    K1, D1, K2, D2 = model.intrinsics()
    covariance = model_intrinsics_covariance(model)
    both = joint_covariance(model, prediction)
    joint = covariance is not None and both is not None
    if joint:
        covariance = CalibrationCovariance(covariance.names + EXTRINSIC_NAMES, both[0], covariance.sigma_px,
                                           covariance.dof, covariance.pixel_locking_px, covariance.residual_map)
    calib = StereoCalibration(
        K1=K1, D1=D1, K2=K2, D2=D2, R=prediction.R, T=prediction.T,
        image_size=(int(model.image_size[0]), int(model.image_size[1])),
        rms_px=float(model.fit.rms_px) if model.fit is not None else float("nan"), mode="kinematic",
        covariance=covariance,
        covariance_note="" if covariance is not None else "the kinematic model file has no intrinsics covariance")
    note = (f"extrapolated beyond the design's span in {', '.join(prediction.extrapolated)}"
            if prediction.extrapolated else None)
    backlash = "" if all(approach.get(a, 0) for a in AXES) else " and the backlash (approach unknown)"
    if joint:
        return Source("kinematic", calib, prediction.rig_covariance, True,
                      "kinematic rig model: the rig's repeatability since the design" + backlash,
                      board_scale, structure_sigma=dict(prediction.structure_sigma), note=note)
    return Source("kinematic", calib, prediction.covariance, False,
                  "kinematic rig model: the parameters' covariance, the rig's repeatability" + backlash,
                  board_scale, structure_sigma=dict(prediction.structure_sigma), note=note)


def nominal_source(intrinsics: StereoCalibration, *, baseline_mm: float, alpha_left_deg: float,
                   alpha_right_deg: float, tilt_deg: float, tolerances: Mapping[str, float],
                   board_scale: BoardScale) -> Source:
    """The ideal geometry's R, T at the commanded B and alphas, with the intrinsics of ``intrinsics``.

    Its structure component is the rig's stated ``tolerances``; the calibration component the intrinsics'
    covariance only. T comes from the slide, not from a calibration board: the calibration board's scale
    does not enter (``calibration_board_u_rel`` 0); the slide's scale is in the tolerances.
    """
    R, T = nominal_extrinsics(baseline_mm, alpha_left_deg, alpha_right_deg, tilt_left_deg=tilt_deg,
                              tilt_right_deg=tilt_deg)
    covariance = intrinsics.covariance
    if covariance is not None:
        names = [n for n in covariance.names if n.startswith(("left.", "right."))]
        covariance = covariance.subset(names) if names else None
    calib = replace(intrinsics, R=np.asarray(R, float), T=np.asarray(T, float), mode="nominal",
                    covariance=covariance, covariance_note=intrinsics.covariance_note
                    or ("" if covariance is not None else "the intrinsics came without a covariance"))
    structure_covariance = nominal_covariance(baseline_mm, alpha_left_deg, alpha_right_deg, tolerances=tolerances,
                                              tilt_left_deg=tilt_deg, tilt_right_deg=tilt_deg)
    return Source("nominal", calib, structure_covariance, False,
                  "nominal geometry: the rig's stated tolerances",
                  replace(board_scale, calibration_board_u_rel=0.0),
                  structure_sigma=structure_sigma(R, T, structure_covariance))


# --------------------------------------------------------------------------------------------------
# Measuring with a source


def measure_with(source: Source, detections: Sequence[tuple[Detection, Detection]],
                 target: Target) -> list[PairMeasurement]:
    """The square of every frame (its ``(left, right)`` detections) triangulated with ``source``'s calibration."""
    rect = rectify(source.calib)
    return [measure_pair(None, None, source.calib, target, rect=rect, detections=pair) for pair in detections]


def budget_of(source: Source, frames: Sequence[PairMeasurement], target: Target) -> UncertaintyBudget:
    """The uncertainty budget of the square ``frames`` measured with ``source``."""
    return configuration_budget(frames, source.calib, target, structure_covariance=source.structure_covariance,
                                extrinsics_from_calibration=source.extrinsics_from_calibration,
                                structure_source=source.structure_source, board_scale=source.board_scale)


def budget_record(budget: UncertaintyBudget, board_scale: BoardScale) -> dict[str, Any]:
    """The JSON-ready ``uncertainty`` record: ``uncertainty_mm``'s keys (noise, calibration, structure, target,
    combined, expanded, k) and what they rest on.

    ``target_print_mm`` is the measured board's own scale part of ``target`` (nominal x its u_rel): a
    comparison against the board's true printed square (a simulated session's ``square_true_mm``) leaves it
    out, ``combined_vs_true`` = sqrt(combined^2 - target_print^2).
    """
    details = budget.details()
    details.pop("sensitivities", None)
    target_print = 0.0 if board_scale.same_board else float(budget.nominal_mm * board_scale.target_u_rel)
    combined = budget.combined
    return {**budget.as_dict(), **details, "target_print_mm": target_print,
            "combined_vs_true": float(math.sqrt(max(combined**2 - target_print**2, 0.0)))}


@dataclass
class SourceResult:
    """One source's R, T and what it measured at a configuration."""

    source: Source
    frames: list[PairMeasurement]
    budget: UncertaintyBudget | None
    error: str | None = None  # the budget could not be computed: why

    @property
    def square_mm(self) -> float:
        return float(np.mean([f.square.mean_mm for f in self.frames]))

    def record(self, *, square_true_mm: float | None) -> dict[str, Any]:
        """The source's entry of the structure document (:class:`~stereo_bench.campaign.documents.SourceRecord`)."""
        calib = self.source.calib
        nominal = float(self.frames[0].square.nominal_mm)
        square = self.square_mm
        note = "; ".join(n for n in (self.source.note, self.error) if n) or None
        return {
            "R": np.asarray(calib.R, float).tolist(), "T": np.asarray(calib.T, float).reshape(3).tolist(),
            "structure": self.source.structure, "structure_sigma": self.source.structure_sigma,
            "square_mean_mm": square, "error_mm": square - nominal,
            "error_true_mm": None if square_true_mm is None else square - square_true_mm,
            "uncertainty": None if self.budget is None else budget_record(self.budget, self.source.board_scale),
            "note": note,
        }


def assess(source: Source, frames: Sequence[PairMeasurement], target: Target) -> SourceResult:
    """``frames`` (already measured with ``source``) and their budget; a budget that cannot be computed is noted."""
    try:
        budget = budget_of(source, frames, target)
        error = None
    except (ValueError, np.linalg.LinAlgError) as failure:
        budget, error = None, f"no uncertainty budget: {failure}"
    return SourceResult(source, list(frames), budget, error)


def compare(sources: Sequence[Source], detections: Sequence[tuple[Detection, Detection]],
            target: Target) -> dict[str, SourceResult]:
    """Each source's measurement of the same detections (the comparison sources of a configuration)."""
    return {source.name: assess(source, measure_with(source, detections, target), target) for source in sources}


# --------------------------------------------------------------------------------------------------
# The records


def truth_columns(truth: Mapping[str, Any] | None) -> dict[str, float | None]:
    """The result row's ``*_true_*`` columns from a simulated bench's truth (empty without one)."""
    if not truth:
        return {}
    structure = truth.get("structure") or {}
    target = truth.get("target") or {}
    return {"baseline_true_mm": structure.get("baseline_mm"), "alpha_left_true_deg": structure.get("alpha_left_deg"),
            "alpha_right_true_deg": structure.get("alpha_right_deg"),
            "square_true_mm": target.get("square_true_mm") if target.get("kind") == "target" else None}


def result_columns(mode: str, used: SourceResult) -> dict[str, Any]:
    """The result row's columns of the source the measurement used: mode, structure, u_c, U, the budget."""
    structure = used.source.structure
    row: dict[str, Any] = {"extrinsics_mode": mode, "baseline_used_mm": structure["baseline_mm"],
                           "alpha_left_used_deg": structure["alpha_left_deg"],
                           "alpha_right_used_deg": structure["alpha_right_deg"]}
    if used.budget is not None:
        row.update(u_combined_mm=used.budget.combined, U_expanded_mm=used.budget.expanded,
                   uncertainty=budget_record(used.budget, used.source.board_scale))
    return row


def structure_data(mode: str, results: Mapping[str, SourceResult], *, used: str, axes: Mapping[str, float],
                   approach: Mapping[str, int], truth: Mapping[str, Any] | None) -> dict[str, Any]:
    """The ``structure`` event's data: every source side by side with the truth (simulated sessions); ``used``:
    the source ``mode`` measures with."""
    square_true = truth_columns(truth).get("square_true_mm")
    truth_record = None
    if truth:
        truth_record = {"R": truth.get("R"), "T": truth.get("T"), "structure": truth.get("structure"),
                        "square_true_mm": square_true}
    return {"mode": mode, "used": used, "axes": dict(axes), "approach": dict(approach),
            "sources": {name: result.record(square_true_mm=square_true) for name, result in results.items()},
            "truth": truth_record}


@dataclass
class StructureComparison:
    """What a configuration's analysis adds for the extrinsics: the row's columns and the structure event."""

    columns: dict[str, Any] = field(default_factory=dict)
    data: dict[str, Any] | None = None


__all__ = [
    "SOURCE_NAMES", "ApproachTracker", "Source", "SourceResult", "StructureComparison", "assess",
    "budget_of", "budget_record", "calibrated_source", "compare", "fixed_source", "kinematic_source",
    "measure_with", "model_intrinsics_covariance", "nominal_source", "reported_axes", "result_columns",
    "structure_data", "truth_columns",
]
