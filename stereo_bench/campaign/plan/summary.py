"""Everything ``stereo-bench campaign plan`` reports (:func:`plan_summary`) and the board presentations the steps
need (:func:`calibration_presentations`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan.configurations import (
    Configuration,
    design_problem,
    design_ranges,
    design_tilt,
    expand_plan,
    plan_visits_and_lens,
)
from stereo_bench.campaign.plan.duration import estimate_duration
from stereo_bench.campaign.plan.feasibility import FEASIBILITY_MARGIN_PX, MIN_CORNERS_IN_BOTH
from stereo_bench.campaign.plan.steps import Presentations, Step, plan_steps
from stereo_bench.campaign.plan.timing import OPERATOR_S_PER_CALIBRATION_VIEW


def calibration_presentations(steps: Sequence[Step]) -> dict[str, int]:
    """Board presentations the steps need: ``visits`` (design or intrinsics visits), ``configurations``
    (per-config calibration views at the measured configurations) and ``total``."""
    tally = Presentations()
    for step in steps:
        step.present(tally)
    return {**tally.counts, "total": tally.counts["visits"] + tally.counts["configurations"]}


def operator_actions(steps: Sequence[Step]) -> dict[str, int]:
    """What the operator does by hand in the steps: board ``presentations``, board ``placements`` (a fixed-board
    design's one), ``target_moves`` and other ``manual_settings``; ``total``."""
    from stereo_bench.campaign.plan.steps import PromptManual, PromptTarget

    counts = calibration_presentations(steps)
    out = {"presentations": counts["total"], "placements": counts["placements"],
           "target_moves": sum(isinstance(s, PromptTarget) for s in steps),
           "manual_settings": sum(isinstance(s, PromptManual) for s in steps)}
    return {**out, "total": sum(out.values())}


def planned_fixed_board_fit(config: CampaignConfig, visits: Sequence, lens=None) -> tuple[Any, str] | None:
    """A fixed-board design's planned fit before any view (the board projected exactly through the nominal chain at
    every runnable visit; :func:`stereo_bench.kinematics.fixed_board.planned_fit`) and where its intrinsics come from:
    ``calib_dir``'s intrinsics and covariance as the fit will take them when it holds readable ones, or the fit
    ``lens`` (:class:`~stereo_bench.campaign.plan.lens.LensPlan`) decided with: with the predicted prior of the lens
    calibration the plan presents, else from the design's views alone. None for other designs or when fewer than 3
    visits can run."""
    from stereo_bench.campaign.plan.lens import design_table
    from stereo_bench.kinematics.fixed_board import INTRINSIC_NAMES

    runnable = [v for v in visits if v.runnable and v.board_fixed]
    if not config.extrinsics.fixed_board or len(runnable) < 3:
        return None
    label = "from the design's views alone"
    if lens is not None:
        if lens.n_views:
            label = f"a lens calibration of {lens.n_views} presented views as prior (predicted)"
        return lens.fit, label
    intrinsics = covariance = None
    if config.extrinsics.calib_dir is not None:
        from stereo_bench.vision.calibio import CalibrationFileError, read_intrinsics, read_intrinsics_covariance

        try:
            K1, D1, K2, D2 = read_intrinsics(config.extrinsics.calib_dir)[:4]
            stored = read_intrinsics_covariance(config.extrinsics.calib_dir)
        except (CalibrationFileError, OSError):
            stored = None
        if stored is not None and all(name in stored.names for name in INTRINSIC_NAMES):
            intrinsics = (K1, D1, K2, D2)
            index = stored.index(INTRINSIC_NAMES)
            covariance = stored.matrix[index][:, index]
            label = "calib_dir prior"
    return design_table(config, runnable, intrinsics=intrinsics, covariance=covariance), label


def design_identifiability(planned: tuple[Any, str] | None) -> list[dict[str, Any]] | None:
    """The identifiability table of :func:`planned_fixed_board_fit`'s fit (JSON-ready rows); None without one."""
    if planned is None:
        return None
    fit, label = planned
    return [{"name": r.name, "unit": r.unit, "identified": r.identified, "sigma": r.sigma, "note": r.note,
             "intrinsics": label} for r in fit.rows]


def extrinsics_prediction(model, steps: Sequence) -> dict[str, Any] | None:
    """The sigma of the R, T kinematic ``model`` predicts at each measured configuration the ``steps`` move to,
    approached as the steps approach it (:func:`stereo_bench.kinematics.prediction.predict`: the parameters'
    covariance and the rig's landing repeatability, to first order). Per configuration ``sigma_T_mm``:
    sqrt(E|dT|^2); ``sigma_R_deg``: sqrt(E angle(dR)^2); ``structure``: the sigmas of the optical baseline, the
    alphas and the rotation; ``extrapolated``: the axes beyond the model's span. ``held``: the parameters held
    nominal, whose error (the rig's build tolerance) is not counted. None when the steps measure nothing."""
    from stereo_bench.campaign.plan.steps import move_sequence
    from stereo_bench.kinematics.design import approach_directions
    from stereo_bench.kinematics.prediction import predict

    rows, previous, approach = [], None, {}
    for target in move_sequence(steps):
        request = target.move_request()
        axes = {axis: request[axis] for axis in model.axes}
        approach = approach_directions(previous, axes, approach)
        previous = axes
        if not isinstance(target, Configuration):
            continue  # a design or intrinsics visit
        prediction = predict(model, axes, approach)
        C = prediction.covariance
        rows.append({"config_id": target.config_id, "sigma_T_mm": math.sqrt(max(float(np.trace(C[3:, 3:])), 0.0)),
                     "sigma_R_deg": math.degrees(math.sqrt(max(float(np.trace(C[:3, :3])), 0.0))),
                     "structure": prediction.structure_sigma, "extrapolated": prediction.extrapolated})
    if not rows:
        return None
    sT = np.array([r["sigma_T_mm"] for r in rows])
    sR = np.array([r["sigma_R_deg"] for r in rows])
    return {"rms_sigma_T_mm": float(np.sqrt(np.mean(sT**2))), "max_sigma_T_mm": float(sT.max()),
            "rms_sigma_R_deg": float(np.sqrt(np.mean(sR**2))), "max_sigma_R_deg": float(sR.max()),
            "held": [name for name, value in model.parameters.items() if not value.identifiable],
            "configurations": rows}


def predicted_extrinsics(config: CampaignConfig, planned: tuple[Any, str] | None, steps: Sequence,
                         ) -> dict[str, Any] | None:
    """:func:`extrinsics_prediction` of :func:`planned_fixed_board_fit`'s planned model (at the plan's corner noise,
    ``corner_sigma_px``; its ``intrinsics`` label); None without one or a measured configuration."""
    if planned is None:
        return None
    predicted = extrinsics_prediction(planned[0].model, steps)
    if predicted is None:
        return None
    return {"corner_sigma_px": config.extrinsics.plan_corner_sigma_px, "intrinsics": planned[1], **predicted}


def lens_summary(config: CampaignConfig, configurations: Sequence, visits: Sequence, lens) -> dict[str, Any] | None:
    """A fixed-board design's lens calibration: how many presentations (``presentations``), at which visit, and why
    (``reason``); ``gains``: the parameters it identifies that the board alone does not; ``held``: those held
    nominal all the same. None for other designs."""
    if not config.extrinsics.fixed_board or not any(v.board_fixed for v in visits):
        return None
    if config.extrinsics.calib_dir is not None:
        return {"presentations": 0, "visit": None, "gains": [], "held": [],
                "reason": f"calib_dir's lens calibration ({config.extrinsics.calib_dir}) is the fit's prior"}
    if lens is None:
        return None
    visit = next((v.config_id for v in visits if v.purpose == "intrinsics"), None)
    return {"presentations": lens.n_views, "visit": visit, "reason": lens.reason, "gains": list(lens.gains),
            "held": list(lens.held)}


def _presentation_time(presentation) -> dict[str, Any]:
    """The plan's seconds per hand presentation, per target move and per fixed-board placement, and whether each is
    ``measured`` by an earlier run (``presentation``) or ``assumed``."""
    from stereo_bench.campaign.plan.timing import OPERATOR_S_PER_BOARD_PLACEMENT, OPERATOR_S_PER_PROMPT

    def figure(measured: float | None, assumed: float) -> tuple[float, str]:
        return (measured, "measured") if measured is not None else (assumed, "assumed")

    view, source = figure(None if presentation is None else presentation.seconds_per_view,
                          OPERATOR_S_PER_CALIBRATION_VIEW)
    move, move_source = figure(None if presentation is None else presentation.seconds_per_target_move,
                               OPERATOR_S_PER_PROMPT)
    placement, placement_source = figure(None if presentation is None else presentation.seconds_per_placement,
                                         OPERATOR_S_PER_BOARD_PLACEMENT)
    return {"s_per_calibration_view": view, "source": source, "s_per_target_move": move,
            "target_move_source": move_source, "s_per_placement": placement, "placement_source": placement_source,
            "measured": None if presentation is None else presentation.model_dump()}


def plan_summary(config: CampaignConfig, *, margin_px: float = FEASIBILITY_MARGIN_PX,
                 presentation=None) -> dict[str, Any]:
    """Everything ``stereo-bench campaign plan`` reports, as one JSON-able object; ``presentation``: a measured
    :class:`~stereo_bench.campaign.presentation.PresentationTime` for the operator's presentations (None: assumed)."""
    configurations = expand_plan(config, margin_px=margin_px)
    visits, lens = plan_visits_and_lens(config, configurations)
    steps = plan_steps(config, configurations, visits)
    estimate = estimate_duration(config, configurations, steps, presentation=presentation)
    tilt_note = design_tilt(config, configurations).note if visits else None
    planned = planned_fixed_board_fit(config, visits, lens)
    return {
        "extrinsics_mode": config.extrinsics.mode,
        "design": [v.as_dict() for v in visits],
        # Why the visits cannot give the extrinsics source (campaign run refuses it before moving); None: they can.
        "design_problem": design_problem(config, configurations, visits),
        "design_ranges": design_ranges(configurations) if visits else None,
        "calibration_presentations": calibration_presentations(steps),
        "operator_actions": operator_actions(steps),
        "identifiability": design_identifiability(planned),
        # The sigma of the R, T the fixed-board fit will predict at the measured configurations (None: other designs).
        "predicted_extrinsics": predicted_extrinsics(config, planned, steps),
        "lens_calibration": lens_summary(config, configurations, visits, lens),
        "name": config.name,
        "configurations": [c.as_dict() for c in configurations],
        "predicted_duration_s": estimate.total_s,
        "presentation_time": _presentation_time(presentation),
        "duration": estimate.as_dict(),
        "n_steps": len(steps),
        "steps": [s.as_dict() for s in steps],
        "n_configurations": len(configurations),
        "infeasible": sum(not c.feasible for c in configurations),
        "partial": sum(c.status == "partial" for c in configurations),
        "limit_violations": sum(c.limit_violation is not None for c in configurations),
        "runnable": sum(c.runnable for c in configurations),
        "margin_px": margin_px,
        "min_corners_in_both": MIN_CORNERS_IN_BOTH,
        # a rig that drives the tilts: whether the design steps them, and why
        **({"design_tilt": tilt_note} if tilt_note else {}),
    }
