"""How a run that does not come from the plan's previous configuration re-approaches it (campaign/approach.py)."""

from __future__ import annotations

import pytest

from stereo_bench.campaign.approach import approach_moves, arrivals, move_sequence, placements
from stereo_bench.campaign.execute import CampaignPlan
from tests.campaigns import lab_config, small_config

HOME = {"B": 349.0, "L": 1.0}


def _sign(x: float) -> int:
    return (x > 0) - (x < 0)


def _arrival_sides(path: list[dict], start: dict) -> dict[str, int]:
    """Per axis the direction of the last move that changed it, along ``path`` from ``start``."""
    sides, here = {}, dict(start)
    for target in path:
        for axis, value in target.items():
            if value != here[axis]:
                sides[axis] = _sign(value - here[axis])
                here[axis] = value
    return sides


PLAN = [{"B": 100.0, "L": 0.0}, {"B": 100.0, "L": 3.0}, {"B": 150.0, "L": 3.0}, {"B": 150.0, "L": 0.0},
        {"B": 150.0, "L": 5.0}, {"B": 60.0, "L": 5.0}]


@pytest.mark.parametrize("index", range(len(PLAN)))
def test_after_homing_the_last_move_and_every_side_are_the_uninterrupted_runs(index):
    moves = approach_moves(PLAN, index, HOME, start=HOME)
    resumed = [*moves, PLAN[index]]
    uninterrupted = PLAN[: index + 1]
    # The move to the configuration starts where the plan's did, and every axis arrived from the same side.
    before = {**HOME, **(PLAN[index - 1] if index else {})}
    assert {**HOME, **(resumed[-2] if len(resumed) > 1 else {})} == before
    assert _arrival_sides(resumed, HOME) == _arrival_sides(uninterrupted, HOME)
    assert len(moves) <= 2 and (index > 0 or moves == [])


def test_only_what_comes_from_the_wrong_side_goes_round():
    # B = 150 was reached from below (100); from home (349) it would come from above: B goes to 100 first. L = 3
    # was reached from below (0); from home (1) it comes from below anyway: L goes straight.
    assert approach_moves(PLAN, 3, HOME, start=HOME) == [{"B": 100.0}, {"B": 150.0, "L": 3.0}]
    # An axis whose target is where it stands is moved round too: from where it stands its side is unknown.
    assert approach_moves(PLAN, 3, PLAN[2], start=HOME) == [{"B": 100.0}, {"B": 150.0, "L": 3.0}]
    assert approach_moves(PLAN, 2, {"B": 349.0, "L": 3.0}, start=HOME) == [{"L": 0.0}, {"B": 100.0, "L": 3.0}]


def test_a_side_outside_the_soft_limits_is_not_gone_round_to():
    limits = {"B": (120.0, 350.0), "L": (0.0, 90.0)}
    assert approach_moves(PLAN, 3, HOME, start=HOME, limits=limits) == [{"B": 150.0, "L": 3.0}]


def test_arrivals_name_the_configuration_that_moved_an_axis_to_its_value():
    plan = CampaignPlan.of(lab_config())
    sequence = move_sequence(plan.steps)
    assert [c.config_id for c in sequence] == ["B100_Z450_A90", "B100_Z450_A87", "B150_Z450_A87", "B150_Z450_A90"]
    found = arrivals(sequence)
    assert found["B150_Z450_A90"]["baseline_mm"] == "B150_Z450_A87"
    assert found["B150_Z450_A90"]["toe_in_left_deg"] == "B150_Z450_A90"
    assert found["B100_Z450_A87"]["baseline_mm"] == "B100_Z450_A90"
    assert found["B150_Z450_A87"]["toe_in_right_deg"] == "B100_Z450_A87"
    # One target distance: one placement, named after the first configuration that shows the target.
    assert set(placements(sequence).values()) == {"B100_Z450_A90"}


def test_placements_follow_the_distance_and_skip_what_is_not_run():
    plan = CampaignPlan.of(small_config(plan={"baseline_mm": [100], "distance_mm": [450, 500], "alpha_deg": [90]}))
    sequence = move_sequence(plan.steps)
    named = placements(sequence)
    assert len(sequence) == 2 and len(set(named.values())) == 2
    assert all(named[c.config_id] == c.config_id for c in sequence)
    # infeasible configurations have no move: the sequence holds only what is run
    small = move_sequence(CampaignPlan.of(small_config()).steps)
    assert [c.config_id for c in small] == ["B100_Z450_A90", "B150_Z450_A90"]
