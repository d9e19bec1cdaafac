"""What the rig and the boards add to a prediction: the structure and target terms of the campaign's budget.

A prediction that stops at image noise and the calibration's own error answers a question nobody measures:
the bench's square is wrong by the board's print scale in every mode, and by the rig's geometry wherever
R, T do not come from a calibration at the configuration itself. :class:`RigErrors` says where R, T come
from (the campaign's ``[extrinsics] mode``) and what the rig and boards state about themselves; the
functions here turn that into the same terms the campaign's uncertainty budget
(:func:`stereo_bench.vision.uncertainty.configuration_budget`) reports, at a predicted configuration:

- ``structure``: the (6, 6) covariance of (rvec [rad], T [mm]) of the source R, T pushed through the
  measurement. ``per-config``: none beyond the calibration (its own error is the calibration term);
  ``nominal``: the rig's stated tolerances (:func:`stereo_bench.kinematics.nominal_covariance`);
  ``kinematic``: a fitted model's prediction covariance (:func:`stereo_bench.kinematics.predict`) when a model
  is given, else the axes' landing repeatability alone (a lower bound: the parameters' own covariance needs
  the fit);
- ``target``: the measured board's relative scale uncertainty (a print) and, where R, T come from a
  calibration, the calibration board's (T scales with it): ``square_mm * sqrt(u_target^2 + u_board^2)``;
- ``calibration``: where R, T do not come from the calibration, the intrinsics' part of it only.

Lengths mm, angles deg, relative uncertainties 1.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from stereo_bench.kinematics import (
    TOLERANCE_NAMES,
    DesignConfiguration,
    KinematicModel,
    kinematic_design,
    nominal_covariance,
)
from stereo_bench.kinematics import predict as predict_kinematic
from stereo_bench.vision.uncertainty import DEFAULT_BOARD_SCALE_U_REL, PRINTED_TARGET_SCALE_U_REL

RigMode = Literal["per-config", "nominal", "kinematic"]
RIG_MODES: tuple[str, ...] = ("per-config", "nominal", "kinematic")


@dataclass(frozen=True)
class RigErrors:
    """Where R, T come from and what the rig and boards state (see the module docstring).

    ``tolerances``: each of :data:`stereo_bench.kinematics.TOLERANCE_NAMES` (nominal mode needs them);
    ``repeatability_mm`` / ``repeatability_deg``: the slide's and each head's landing std per move;
    ``kinematic_model``: a fitted model (kinematic mode), else the repeatability alone;
    ``target_scale_u_rel`` / ``calibration_board_scale_u_rel``: the boards' relative scale uncertainties;
    ``source``: where these came from, for the message (a config file, the defaults).
    """

    mode: RigMode = "per-config"
    tolerances: Mapping[str, float] = field(default_factory=dict)
    repeatability_mm: float = 0.003
    repeatability_deg: float = 0.002
    kinematic_model: KinematicModel | None = None
    target_scale_u_rel: float = PRINTED_TARGET_SCALE_U_REL
    calibration_board_scale_u_rel: float = DEFAULT_BOARD_SCALE_U_REL
    source: str = "the campaign's defaults"
    # How many configurations' calibration views the intrinsics rest on: the kinematic fit refines them from
    # every design visit's views (the presented design visits 3 baselines x 3 toe-in pairs); 1 elsewhere.
    intrinsics_visits: int = 1
    # Kinematic mode without a model file: the design the campaign would visit and where its board stands, so
    # that a prediction fits the design's planned views (errormodel.rigorous.planned_kinematic_model) and carries
    # the joint covariance of intrinsics and R, T the campaign's budget carries. None: the intrinsics of one
    # configuration's views scaled by 1/sqrt(intrinsics_visits), and R, T apart (an over-prediction).
    design: tuple[DesignConfiguration, ...] | None = None
    design_distance_mm: float | None = None

    def __post_init__(self):
        if self.mode not in RIG_MODES:
            raise ValueError(f"mode must be one of {', '.join(RIG_MODES)}, not {self.mode!r}")
        if self.mode == "nominal":
            missing = [name for name in TOLERANCE_NAMES if name not in self.tolerances]
            if missing:
                raise ValueError(f"nominal mode needs the rig's tolerances: missing {', '.join(missing)}")
        if self.design is not None and not (self.design_distance_mm is not None and self.design_distance_mm > 0):
            raise ValueError(f"a design needs design_distance_mm > 0, not {self.design_distance_mm}")
        if self.intrinsics_visits < 1:
            raise ValueError(f"intrinsics_visits must be >= 1, not {self.intrinsics_visits}")
        for name in ("repeatability_mm", "repeatability_deg", "target_scale_u_rel", "calibration_board_scale_u_rel"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, not {value}")
        for name, value in self.tolerances.items():
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"tolerances.{name} must be finite and >= 0, not {value}")

    @property
    def intrinsics_scale(self) -> float:
        """The factor on one configuration's predicted intrinsics error: 1 / sqrt(visits), as N times the views
        of the same kind divide a covariance by N."""
        return 1.0 / math.sqrt(self.intrinsics_visits)

    @property
    def extrinsics_from_calibration(self) -> bool:
        """R, T are the configuration's own calibration's (per-config): its error holds them."""
        return self.mode == "per-config"

    def describe(self) -> str:
        what = {"per-config": "R, T calibrated at every configuration",
                "nominal": "R, T from the rig's ideal geometry (its stated tolerances)",
                "kinematic": ("R, T predicted by the kinematic model (where a calibration is predicted "
                              "too, the fit's own error goes, joint with the intrinsics', in its term and the "
                              "structure term is the landing repeatability)"
                              if self.kinematic_model is not None or self.design is not None else
                              "R, T predicted by a kinematic model (its landing repeatability only: the fit's "
                              "own uncertainty needs a model file or a campaign's design)")}[self.mode]
        return f"{what}; {self.source}"


#: How many configurations the presented kinematic design visits (3 baselines x 3 toe-in pairs), each with its
#: calibration views: what the kinematic fit refines the intrinsics from.
PRESENTED_DESIGN_VISITS = len(kinematic_design((1.0, 2.0), (0.0, 1.0)))


def rig_errors_of(extrinsics, target, calibration_board, *, mode: str | None = None,
                  kinematic_model: KinematicModel | None = None, target_scale_u_rel: float | None = None,
                  design: Sequence[DesignConfiguration] | None = None, design_distance_mm: float | None = None,
                  source: str) -> RigErrors:
    """The :class:`RigErrors` a campaign's sections state: ``extrinsics`` (its ``[extrinsics]``: mode, tolerances,
    repeatability), ``target`` and ``calibration_board`` (their scale uncertainties). ``mode``,
    ``target_scale_u_rel``: instead of the sections' (None: theirs). ``design``, ``design_distance_mm``: the
    kinematic design the campaign's plan visits (:func:`stereo_bench.kinematics.campaign_design`), kinematic mode
    only."""
    mode = mode or extrinsics.mode
    if mode != "kinematic":
        design = design_distance_mm = None
    return RigErrors(mode=mode, tolerances=extrinsics.tolerances.sigmas(), repeatability_mm=extrinsics.repeatability_mm,
                     repeatability_deg=extrinsics.repeatability_deg, kinematic_model=kinematic_model,
                     target_scale_u_rel=(target.scale_u("target") if target_scale_u_rel is None
                                         else target_scale_u_rel),
                     calibration_board_scale_u_rel=calibration_board.scale_u("calibration_board"), source=source,
                     intrinsics_visits=PRESENTED_DESIGN_VISITS if mode == "kinematic" else 1,
                     design=None if design is None else tuple(design), design_distance_mm=design_distance_mm)



def _repeatability_tolerances(errors: RigErrors) -> dict[str, float]:
    """The as-built chain's deviations a move adds when the chain itself is known: the slide's landing (a
    separation error) and each head's (its pan landing)."""
    tolerances = dict.fromkeys(TOLERANCE_NAMES, 0.0)
    tolerances["baseline_zero_mm"] = errors.repeatability_mm
    tolerances["pan_repeat_deg"] = errors.repeatability_deg
    return tolerances


def structure_covariance(errors: RigErrors, baseline_mm: float, alpha_left_deg: float, alpha_right_deg: float,
                         tilt_deg: float = 0.0) -> np.ndarray | None:
    """(6, 6) covariance of (rvec [rad], T [mm]) of the source R, T at a configuration; None in per-config mode
    (the calibration's own covariance holds it)."""
    if errors.mode == "per-config":
        return None
    if errors.mode == "nominal":
        return nominal_covariance(baseline_mm, alpha_left_deg, alpha_right_deg, tolerances=errors.tolerances,
                                  tilt_left_deg=tilt_deg, tilt_right_deg=tilt_deg)
    if errors.kinematic_model is not None:
        axes = {"baseline_mm": baseline_mm, "toe_in_left_deg": 90.0 - alpha_left_deg,
                "toe_in_right_deg": 90.0 - alpha_right_deg}
        # A campaign approaches every axis from a known side (the plan's moves): no backlash term.
        return predict_kinematic(errors.kinematic_model, axes, dict.fromkeys(axes, 1)).covariance
    return nominal_covariance(baseline_mm, alpha_left_deg, alpha_right_deg,
                              tolerances=_repeatability_tolerances(errors), tilt_left_deg=tilt_deg,
                              tilt_right_deg=tilt_deg)


def target_sigma_mm(errors: RigErrors, square_mm: float, depth_mm: float | None = None) -> tuple[float, float | None]:
    """(σ of the square, σ of the centre depth) from the boards' scales, mm.

    The measured board's print scales the true square against its nominal; a calibration board's scale
    scales T, and with it every length and depth, where R, T come from that calibration.
    """
    board = errors.calibration_board_scale_u_rel if errors.extrinsics_from_calibration else 0.0
    square = square_mm * math.hypot(errors.target_scale_u_rel, board)
    return square, None if depth_mm is None else abs(depth_mm) * board


#: The terms a combined prediction adds in quadrature, in the order they are listed.
TERM_NAMES = ("noise", "bias", "calibration", "structure", "target", "given")


def dominant_term(terms: Mapping[str, float | None]) -> str | None:
    """The name of the largest known term; None when none is known."""
    known = {name: value for name, value in terms.items() if value is not None}
    return max(known, key=lambda name: abs(known[name])) if known else None


def combined(terms: Mapping[str, float | None]) -> float | None:
    """The terms in quadrature; None when any is unknown."""
    if any(value is None for value in terms.values()):
        return None
    return math.sqrt(sum(value * value for value in terms.values()))
