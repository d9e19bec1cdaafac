"""Everything ``stereo-bench campaign plan`` reports (:func:`plan_summary`) and the board presentations the steps
need (:func:`calibration_presentations`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan.configurations import design_ranges, expand_plan, plan_visits
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


def plan_summary(config: CampaignConfig, *, margin_px: float = FEASIBILITY_MARGIN_PX,
                 presentation=None) -> dict[str, Any]:
    """Everything ``stereo-bench campaign plan`` reports, as one JSON-able object; ``presentation``: a measured
    :class:`~stereo_bench.campaign.presentation.PresentationTime` for the operator's presentations (None: assumed)."""
    configurations = expand_plan(config, margin_px=margin_px)
    visits = plan_visits(config, configurations)
    steps = plan_steps(config, configurations, visits)
    estimate = estimate_duration(config, configurations, steps, presentation=presentation)
    return {
        "extrinsics_mode": config.extrinsics.mode,
        "design": [v.as_dict() for v in visits],
        "design_ranges": design_ranges(configurations) if visits else None,
        "calibration_presentations": calibration_presentations(steps),
        "name": config.name,
        "configurations": [c.as_dict() for c in configurations],
        "predicted_duration_s": estimate.total_s,
        "presentation_time": {"s_per_calibration_view": (presentation.seconds_per_view if presentation is not None
                                                         else OPERATOR_S_PER_CALIBRATION_VIEW),
                              "source": "measured" if presentation is not None else "assumed",
                              "measured": None if presentation is None else presentation.model_dump()},
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
    }
