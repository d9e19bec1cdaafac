"""How long a campaign still takes: the plan's time model (:mod:`stereo_bench.campaign.plan.duration`) corrected
by what the run has measured so far, the operator's time included.

The plan predicts each configuration's machine time (the move to it, then settle, flush and exposures) and how
many prompts it puts to the operator; it leaves out computation (rendering, detection, calibration) and assumes
30 s per prompt (5 s per calibration view by hand), or nothing where the scene is simulated. A run corrects both
from what it measured (:func:`remaining_s`, a pure function):

- *machine*: the time not spent waiting for an operator, per configuration: what the plan predicted plus ``c``,
  the mean unmodelled time per configuration so far (computation, a slower rig); additive, since what the plan
  leaves out costs about the same at every configuration while the moves it does model differ;
- *operator*: the seconds waited per predicted prompt so far (a slow operator, a quick one, a terminal on the
  simulated bench that the plan counts as instant), times the prompts still to come; the time waited on a
  prompt still pending counts as it passes.

::

    forecast = forecast_groups(config, plan.steps)            # per configuration (and visit), in plan order
    tracker = EtaTracker(forecast)                            # fed the run's documents and a clock
    tracker.moved(config_id, now_s); tracker.prompt_answered(waited_s); tracker.remaining(now_s)
    tracker.shown(now_s)                                      # what the progress line shows (noise held back)

A configuration's *marker* is its ``move`` event (the motors have arrived): at a marker the move of that
configuration is behind, its rest (settle, capture) and its prompts ahead.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan.duration import homing_estimate_s
from stereo_bench.campaign.plan.steps import CaptureCalibration, PromptManual, PromptTarget, Step
from stereo_bench.campaign.plan.timing import DurationModel


@dataclass(frozen=True)
class GroupForecast:
    """The plan's prediction for one configuration or visit (a group of steps): ``move_s`` the move to it,
    ``rest_s`` the rest of its machine time (settle, flush, exposures), ``prompts`` the operator prompts it puts
    (manual quantities, calibration views by hand), ``operator_s`` the time the plan assumes for them (s)."""

    config_id: str
    move_s: float
    rest_s: float
    prompts: int
    operator_s: float

    @property
    def runs(self) -> bool:
        """Whether anything is done there (a configuration the plan skips has no move and no prompt)."""
        return self.move_s > 0.0 or self.rest_s > 0.0 or self.prompts > 0


@dataclass(frozen=True)
class Forecast:
    """The plan's time model per group, in plan order, and the homing before the first move (s)."""

    groups: tuple[GroupForecast, ...]
    homing_s: float = 0.0

    def index(self, config_id: str) -> int | None:
        for i, group in enumerate(self.groups):
            if group.config_id == config_id:
                return i
        return None

    @property
    def prior_s_per_prompt(self) -> float:
        """The plan's operator time per prompt (0 where the plan counts none: a simulated scene)."""
        prompts = sum(g.prompts for g in self.groups)
        return sum(g.operator_s for g in self.groups) / prompts if prompts else 0.0


def forecast_groups(config: CampaignConfig, steps: Sequence[Step]) -> Forecast:
    """The plan's time model (:class:`DurationModel`, each step's own ``estimate``) split per group of steps."""
    from stereo_bench.campaign.runner import group_steps

    model = DurationModel.of(config)
    groups = []
    for config_id, group in group_steps(list(steps)):
        move = rest = operator = 0.0
        prompts = 0
        for step in group:
            before = (model.motion_s, model.settle_s + model.flush_s + model.capture_s, model.operator_s)
            step.estimate(model)
            move += model.motion_s - before[0]
            rest += model.settle_s + model.flush_s + model.capture_s - before[1]
            operator += model.operator_s - before[2]
            if isinstance(step, PromptTarget | PromptManual):
                prompts += 1  # asked whoever does it: the terminal on the simulated bench too
            elif isinstance(step, CaptureCalibration) and model.real_scene:
                prompts += step.n_views  # one presentation of the board per view
        groups.append(GroupForecast(config_id, move, rest, prompts, operator))
    homing = 0.0
    travel = model.rig_config.machine_travel()
    if config.rig.homing and travel:
        homing = homing_estimate_s(travel, simulated=config.rig.kind == "simulated") / model.speed_factor
    return Forecast(tuple(groups), homing)


@dataclass(frozen=True)
class Measured:
    """What a run has measured so far, on one clock (s).

    ``group``: the index of the group whose marker (its move) came last, None before the first; ``first``: the
    group this run's first marker was (a resume starts later); ``machine_s``: time so far not spent waiting for an
    operator; ``machine_at_first_s`` / ``machine_at_group_s``: the same at the first marker and the last one;
    ``operator_done_s``: seconds waited on prompts in the groups ``first`` .. ``group - 1``; ``operator_group_s``:
    seconds waited in group ``group`` so far, a pending prompt's wait included (before the first marker: the
    prompts before it); ``second`` / ``machine_at_second_s``: the marker after the first, and the machine time then.
    """

    group: int | None
    machine_s: float
    first: int = 0
    machine_at_first_s: float = 0.0
    machine_at_group_s: float = 0.0
    operator_done_s: float = 0.0
    operator_group_s: float = 0.0
    second: int | None = None
    machine_at_second_s: float = 0.0


def remaining_s(forecast: Forecast, measured: Measured) -> float:
    """Seconds the run still takes: the plan's model corrected by ``measured`` (the module docstring says how).

    Pure: the same forecast and measurements give the same answer, whatever the clock.
    """
    groups = forecast.groups
    if measured.group is None:  # nothing has arrived yet: the plan as it is, homing and the first move under way
        q = forecast.prior_s_per_prompt
        ahead = max(forecast.homing_s + (groups[0].move_s if groups else 0.0) - measured.machine_s, 0.0)
        rest = sum(g.rest_s + g.prompts * q for g in groups[:1])
        later = sum(g.move_s + g.rest_s + g.prompts * q for g in groups[1:])
        return ahead + max(rest - measured.operator_group_s, 0.0) + later
    k, first = measured.group, measured.first
    # The first configuration carries what is done once (the bench's first renders, caches warming up): once a
    # configuration after the second marker is done, the unmodelled time is counted from the second marker.
    base, base_s = first, measured.machine_at_first_s
    if measured.second is not None and k > measured.second:
        base, base_s = measured.second, measured.machine_at_second_s
    done = [g for g in groups[base:k] if g.runs]
    # Predicted between the base marker and this one: the rests of the groups done and the moves since the base.
    predicted = sum(g.rest_s for g in groups[base:k]) + sum(g.move_s for g in groups[base + 1:k + 1])
    c = (measured.machine_at_group_s - base_s - predicted) / len(done) if done else 0.0
    prompts_done = sum(g.prompts for g in groups[first:k])
    q = measured.operator_done_s / prompts_done if prompts_done else forecast.prior_s_per_prompt
    current = groups[k]
    machine_here = max(current.rest_s + c - (measured.machine_s - measured.machine_at_group_s), 0.0)
    operator_here = max(current.prompts * q - measured.operator_group_s, 0.0)
    later = sum(max(g.move_s + g.rest_s + c, 0.0) + g.prompts * q for g in groups[k + 1:] if g.runs)
    return machine_here + operator_here + later


#: A new estimate above the shown ETA's countdown by less than this (relative) is noise: the countdown stays shown.
RISE_BAND = 0.25


def shown_eta_s(estimate_s: float, countdown_s: float | None, *, band: float = RISE_BAND) -> float:
    """The ETA to show: ``estimate_s`` (:func:`remaining_s`) unless it rises above ``countdown_s`` (the ETA shown
    last, less the machine time since) by less than ``band``: then the countdown, so that noise in the measured
    times does not make the ETA climb; a larger rise (an operator away, a slower rig) is shown at once."""
    if countdown_s is None or estimate_s <= countdown_s or estimate_s > countdown_s * (1.0 + band):
        return estimate_s
    return countdown_s


class EtaTracker:
    """:func:`remaining_s` kept up to date from a run's events, on the clock the caller passes (the CLI: the wall
    clock; a test: the bench's). Not thread-safe: one caller (the progress display) feeds it."""

    def __init__(self, forecast: Forecast, *, start_s: float = 0.0):
        self.forecast = forecast
        self._start_s = start_s
        self._operator_s = 0.0  # answered prompts, all groups
        self._pending_since: float | None = None
        self._group: int | None = None
        self._first = 0
        self._at_first = self._at_group = 0.0
        self._operator_at_group = 0.0  # self._operator_s at the last marker
        self._operator_at_first = 0.0
        self._second: int | None = None
        self._at_second = 0.0
        self._shown: tuple[float, float] | None = None  # (ETA shown, machine time then)

    def _machine(self, now_s: float) -> float:
        return now_s - self._start_s - self._operator_s - self._pending(now_s)

    def _pending(self, now_s: float) -> float:
        return 0.0 if self._pending_since is None else max(now_s - self._pending_since, 0.0)

    def moved(self, config_id: str | None, now_s: float) -> None:
        """The marker of ``config_id``: its move event (approach moves and unknown ids are not markers)."""
        index = None if config_id is None else self.forecast.index(config_id)
        if index is None or index == self._group:
            return
        if self._group is None:
            self._first, self._at_first, self._operator_at_first = index, self._machine(now_s), self._operator_s
        elif self._second is None:
            self._second, self._at_second = index, self._machine(now_s)
        self._group, self._at_group, self._operator_at_group = index, self._machine(now_s), self._operator_s

    def prompt_shown(self, now_s: float) -> None:
        """A prompt is shown to the operator: its wait counts as operator time as it passes."""
        self._pending_since = now_s

    def prompt_ended(self) -> None:
        """The prompt shown is no longer pending (its wait is counted by :meth:`prompt_answered`)."""
        self._pending_since = None

    def prompt_answered(self, waited_s: float) -> None:
        """A prompt was answered after ``waited_s`` (the recorded ``prompt`` event's)."""
        self._operator_s += waited_s

    def measured(self, now_s: float) -> Measured:
        pending = self._pending(now_s)
        return Measured(group=self._group, machine_s=self._machine(now_s), first=self._first,
                        machine_at_first_s=self._at_first, machine_at_group_s=self._at_group,
                        operator_done_s=self._operator_at_group - self._operator_at_first,
                        operator_group_s=self._operator_s - self._operator_at_group + pending,
                        second=self._second, machine_at_second_s=self._at_second)

    def remaining(self, now_s: float) -> float:
        return remaining_s(self.forecast, self.measured(now_s))

    def shown(self, now_s: float) -> float:
        """The ETA to show now (:func:`shown_eta_s`); the countdown runs on machine time: it stands still while
        the operator is waited for, as the run does."""
        machine = self._machine(now_s)
        countdown = None if self._shown is None else max(self._shown[0] - (machine - self._shown[1]), 0.0)
        eta = shown_eta_s(self.remaining(now_s), countdown)
        self._shown = (eta, machine)
        return eta
