"""The campaign's ETA (issue 24): the plan's time model corrected by what was measured, operator time included;
from the third configuration on it never rises and stays within 25 % of the time actually left.

The pure function is driven by synthetic timelines (seeded), the progress display by a simulated run on the bench
clock (the frames' time stamps), never by the wall clock.
"""

from __future__ import annotations

import numpy as np
import pytest

from stereo_bench.campaign.documents import CalibrationViewEvent, MeasurementFrameEvent
from stereo_bench.campaign.eta import (
    EtaTracker,
    Forecast,
    GroupForecast,
    Measured,
    forecast_groups,
    remaining_s,
    shown_eta_s,
    unmodelled_s,
)
from stereo_bench.campaign.execute import CampaignPlan, run_campaign
from tests.campaigns import small_config

TOLERANCE = 0.25  # the band, relative to the time actually left


def _timeline(forecast: Forecast, *, machine_s, operator_s) -> tuple[list[tuple[float, float]], float]:
    """Run ``forecast``'s groups on a synthetic clock: group i takes ``machine_s[i]`` on the machine (its move as
    modelled first, then the rest) and ``operator_s[i]`` s per prompt. Returns [(t, ETA)] at every marker and the
    end."""
    tracker, t, etas = EtaTracker(forecast), 0.0, []
    t += forecast.homing_s
    for i, group in enumerate(forecast.groups):
        t += group.move_s  # the move, as modelled (the motion model is the emulator's)
        tracker.moved(group.config_id, t)
        etas.append((t, tracker.remaining(t)))
        for _ in range(group.prompts):
            tracker.prompt_shown(t)
            t += operator_s[i]
            tracker.prompt_ended()
            tracker.prompt_answered(operator_s[i])
        t += machine_s[i] - group.move_s  # the rest: settle, captures, and what the plan does not model
    return etas, t


def _forecast(n: int, rng: np.random.Generator, prompts: int) -> Forecast:
    moves = rng.uniform(0.5, 6.0, n)  # the plan's moves differ (a new row of the grid: a long one)
    return Forecast(tuple(GroupForecast(f"c{i}", float(moves[i]), 0.6, prompts, 30.0 * prompts) for i in range(n)),
                    homing_s=2.0)


def _check(etas: list[tuple[float, float]], end_s: float) -> list[float]:
    """From the third configuration on: never rising, and within TOLERANCE of the time left. The errors."""
    errors = []
    for j, (t, eta) in enumerate(etas[2:], start=2):
        left = end_s - t
        errors.append((eta - left) / left)
        assert abs(eta - left) <= TOLERANCE * left, (j, eta, left)
        assert eta <= etas[j - 1][1] + 1e-9, (j, eta, etas[j - 1][1])
    return errors


@pytest.mark.parametrize("operator_s", [30.0, 150.0, 8.0], ids=["as-planned", "slow-operator", "quick-operator"])
def test_eta_converges_whatever_the_operator(operator_s):
    rng = np.random.default_rng(24)
    forecast = _forecast(25, rng, prompts=1)
    # Reality: the modelled time plus 2.5 s of computation per configuration (+-10 %), the operator +-10 %.
    machine = [g.move_s + g.rest_s + 2.5 * rng.uniform(0.9, 1.1) for g in forecast.groups]
    operator = list(operator_s * rng.uniform(0.9, 1.1, 25))
    etas, end = _timeline(forecast, machine_s=machine, operator_s=operator)
    errors = _check(etas, end)
    assert max(abs(e) for e in errors) < TOLERANCE
    # The plan alone (no correction) is off by what it does not model: the ETA's correction is what helps.
    plan_only = remaining_s(forecast, Measured(group=None, machine_s=0.0))
    assert abs(plan_only - end) / end > (0.3 if operator_s != 30.0 else 0.05)


def test_an_operator_who_takes_long_raises_the_eta_at_once():
    """The plan assumes 30 s per prompt; the operator takes 5 min on the first one: the ETA counts the wait as it
    passes and, once it is answered, expects as much for every prompt to come."""
    forecast = Forecast(tuple(GroupForecast(f"c{i}", 1.0, 1.0, 1, 30.0) for i in range(5)))
    tracker = EtaTracker(forecast)
    tracker.moved("c0", 1.0)
    before = tracker.remaining(1.0)
    assert before == pytest.approx(1.0 + 30.0 + 4 * (2.0 + 30.0))
    tracker.prompt_shown(1.0)
    assert tracker.remaining(31.0) == pytest.approx(1.0 + 4 * 32.0)  # the 30 s assumed are used up
    assert tracker.remaining(301.0) == pytest.approx(1.0 + 4 * 32.0)  # waiting longer: the rest as planned
    tracker.prompt_ended()
    tracker.prompt_answered(300.0)
    tracker.moved("c1", 303.0)  # c0's rest, c1's move: 2 s as planned
    # Group c0 is done: 300 s per prompt from now on, the machine as the plan says (it was exact).
    assert tracker.remaining(303.0) == pytest.approx(1.0 + 300.0 + 3 * (2.0 + 300.0))


def test_a_resume_corrects_from_its_own_configurations():
    forecast = Forecast(tuple(GroupForecast(f"c{i}", 1.0, 1.0, 0, 0.0) for i in range(6)))
    # Resumed at c3: the first marker seen is c3's, at 10 s (homing, its move); c4 at 10 + 5 s.
    measured = Measured(group=4, machine_s=15.0, marks=((3, 10.0), (4, 15.0)))
    # predicted c3's rest + c4's move = 2 s, measured 5 s: 3 s unmodelled per configuration.
    assert remaining_s(forecast, measured) == pytest.approx((1.0 + 3.0) + (2.0 + 3.0))


def test_skipped_configurations_cost_nothing():
    groups = (GroupForecast("a", 1.0, 1.0, 0, 0.0), GroupForecast("skipped", 0.0, 0.0, 0, 0.0),
              GroupForecast("b", 1.0, 1.0, 0, 0.0), GroupForecast("c", 1.0, 1.0, 0, 0.0))
    measured = Measured(group=2, machine_s=6.0, marks=((0, 0.0), (2, 6.0)))
    # a's rest + b's move predicted 2 s, took 6 s: 4 s more over one configuration that ran (not two).
    assert remaining_s(Forecast(groups), measured) == pytest.approx((1.0 + 4.0) + (2.0 + 4.0))


@pytest.mark.slow
@pytest.mark.parametrize("capture", ["enter", "auto"])
def test_a_simulated_run_gives_an_eta_that_only_falls(tmp_path, capture):
    """The progress display's ETAs over a simulated run, on the bench clock (each group's first frame time); also
    with views taken automatically while the simulated hand presents the board (its time is not in the plan's model
    of a simulated scene: the measured correction carries it)."""
    config = small_config(plan={"baseline_mm": [100, 150], "distance_mm": [400, 450, 500], "alpha_deg": [90]},
                          # the count gate: the bars may never fill with the hand's poses (then all 40 are shown)
                          capture={"calibration_capture": capture, "coverage_gate": "count"},
                          # 3 frames a second: the hand still holds each pose over several (stillness is judged
                          # across them), and 255 frames to render and detect instead of 5 fps' 421
                          sim={"hand_fps": 3.0} if capture == "auto" else {})
    plan = CampaignPlan.of(config)
    # The bench clock counts the rig's own seconds (time_scale only paces it against the wall): the plan's model
    # of the same campaign at time_scale 1 is its prediction.
    at_bench_pace = config.model_copy(update={"rig": config.rig.model_copy(update={"time_scale": 1.0})})
    tracker, etas = EtaTracker(forecast_groups(at_bench_pace, plan.steps)), []
    clock = {"t": 0.0}
    first_frames: list[tuple[str, float]] = []

    def on_bench_clock(document) -> None:
        if isinstance(document, CalibrationViewEvent | MeasurementFrameEvent):
            clock["t"] = max(clock["t"], document.data.left.timestamp_s)
            if not first_frames or first_frames[-1][0] != document.config_id:
                # A frame is stamped as its exposure starts; the move ended one settle before the first one.
                arrived = clock["t"] - config.capture.settle_s
                first_frames.append((document.config_id, arrived))
                tracker.moved(document.config_id, arrived)
                etas.append((arrived, tracker.remaining(arrived)))

    summary = run_campaign(config, tmp_path / "s", yes=True, plan=plan, subscribers=[on_bench_clock])
    assert summary.exit_status == "success"
    assert [cid for cid, _ in first_frames] == [c.config_id for c in plan.configurations]
    end = clock["t"] + config.cameras.optics.exposure_s  # the last exposure's end
    errors = _check(etas, end)
    assert len(errors) == 4
    assert forecast_groups(config, plan.steps).homing_s > 0


def test_the_shown_eta_holds_back_small_rises_only():
    assert shown_eta_s(90.0, None) == 90.0  # nothing shown yet
    assert shown_eta_s(80.0, 100.0) == 80.0  # a fall is shown
    assert shown_eta_s(110.0, 100.0) == 100.0  # a rise within 25 %: noise, the countdown stays
    assert shown_eta_s(130.0, 100.0) == 130.0  # beyond it: something changed (an operator away), shown at once


def test_the_shown_eta_stands_still_while_the_operator_is_waited_for():
    forecast = Forecast(tuple(GroupForecast(f"c{i}", 1.0, 1.0, 1, 30.0) for i in range(3)))
    tracker = EtaTracker(forecast)
    tracker.moved("c0", 1.0)
    first = tracker.shown(1.0)
    tracker.prompt_shown(1.0)
    assert tracker.shown(20.0) == pytest.approx(first - 19.0)  # the prompt's 30 s are counted down as they pass
    assert tracker.shown(200.0) == pytest.approx(first - 30.0)  # then it waits with the run, not below


def test_the_unmodelled_time_leaves_out_the_first_configuration_and_follows_a_drift():
    forecast = Forecast(tuple(GroupForecast(f"c{i}", 1.0, 1.0, 0, 0.0) for i in range(6)))
    # Intervals of 2 s predicted: 12 (start-up), then 5, 5, 3 s measured.
    marks = ((0, 0.0), (1, 12.0), (2, 17.0), (3, 22.0), (4, 25.0))
    assert unmodelled_s(forecast, marks[:2]) == pytest.approx(10.0)  # only the first interval: it is all there is
    assert unmodelled_s(forecast, marks[:3]) == pytest.approx(3.0)  # then the start-up is left out
    assert unmodelled_s(forecast, marks, weight=0.3) == pytest.approx(3.0 + 0.3 * (3.0 - 3.0) + 0.3 * (1.0 - 3.0))


def test_eta_follows_computation_that_drifts():
    """paper-exp1 on the simulated bench: the configurations go faster as the board gets smaller in the images."""
    rng = np.random.default_rng(7)
    forecast = _forecast(25, rng, prompts=0)
    machine = [g.move_s + g.rest_s + np.interp(i, [0, 24], [5.0, 3.0]) for i, g in enumerate(forecast.groups)]
    machine[0] += 8.0  # the bench's first renders
    etas, end = _timeline(forecast, machine_s=machine, operator_s=[0.0] * 25)
    assert max(abs(e) for e in _check(etas, end)) < TOLERANCE
