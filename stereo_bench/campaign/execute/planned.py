"""The plan a run follows (:class:`CampaignPlan`: configurations, visits and steps, expanded once, or as a session
recorded them) and where today's planner differs from a recorded plan (:func:`plan_drift`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.documents import StartDocument
from stereo_bench.campaign.plan import Configuration, Step, Visit, expand_plan, plan_steps, plan_visits
from stereo_bench.campaign.recorded import RecordedStart
from stereo_bench.campaign.runner import group_steps
from stereo_bench.campaign.session import first_difference


@dataclass(frozen=True)
class CampaignPlan:
    """A config's configurations, the visits its extrinsics source needs first, and the steps, expanded once."""

    configurations: list[Configuration]
    steps: list[Step]
    visits: list[Visit] = field(default_factory=list)

    @classmethod
    def of(cls, config: CampaignConfig, configurations: Sequence[Configuration] | None = None,
           visits: Sequence[Visit] | None = None) -> CampaignPlan:
        configurations = list(configurations) if configurations is not None else expand_plan(config)
        visits = list(visits) if visits is not None else plan_visits(config, configurations)
        return cls(configurations, plan_steps(config, configurations, visits), visits)

    @classmethod
    def design_only(cls, plan: CampaignPlan) -> CampaignPlan:
        """Only the visits and the preparation of ``plan`` (``rig calibrate-kinematics``): nothing is measured."""
        steps = [step for cid, group in group_steps(plan.steps) if cid not in {c.config_id for c in plan.configurations}
                 for step in group]
        return cls([], steps, list(plan.visits))

    @classmethod
    def recorded(cls, config: CampaignConfig, start: StartDocument) -> CampaignPlan:
        """The plan a session's start document recorded (its configurations and visits), never today's re-planning."""
        recorded = RecordedStart.of(start)
        return cls.of(config, recorded.configurations, recorded.visits)


def plan_drift(config: CampaignConfig, recorded_plan: list[dict]) -> str | None:
    """Where today's planner differs from a recorded plan (None if it does not); the recorded plan is what runs."""
    try:
        today = [c.as_dict() for c in expand_plan(config)]
    except Exception as error:  # noqa: BLE001 - e.g. a rig config file that is not on this machine
        return f"not recomputed: {error}"
    difference = first_difference(recorded_plan, today, "plan")
    return None if difference is None else f"today's planner differs from the recorded plan: {difference}"
