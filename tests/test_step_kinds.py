"""Every step kind of a plan (plan.Step) declares what the plan's readers need and has one runner handler (issue 21):
adding a kind is its class in plan/steps.py and one handler in runner.py, no isinstance chain elsewhere."""

from __future__ import annotations

import typing

import pytest

from stereo_bench.campaign.plan import Step, StepKind
from stereo_bench.campaign.runner import CampaignRunner

KINDS = typing.get_args(Step)
DISPATCHER = vars(CampaignRunner)["_execute"].dispatcher  # the runner's one table: step kind -> handler


def test_the_union_lists_every_step_kind_once():
    # plan/steps.py's own kinds: a test's throw-away subclass (below) may still stand in __subclasses__()
    declared = [kind for kind in StepKind.__subclasses__() if kind.__module__ == StepKind.__module__]
    assert len(KINDS) == len(set(KINDS)) == len(declared)
    assert set(KINDS) == set(declared)


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.__name__)
def test_every_step_kind_has_a_handler_and_an_estimate(kind):
    assert DISPATCHER.dispatch(kind) is not DISPATCHER.dispatch(object), f"no runner handler for {kind.__name__}"
    assert "estimate" in vars(kind), f"{kind.__name__} does not say how long it takes"
    assert isinstance(kind.kind, str) and kind.kind


def test_a_step_kind_without_an_estimate_is_refused():
    class Unknown(StepKind):
        pass

    with pytest.raises(NotImplementedError, match="Unknown"):
        Unknown().estimate(None)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="unknown step"):
        DISPATCHER.dispatch(Unknown)(None, Unknown(), None, None)
