"""How long a campaign still takes: the plan's time model (:mod:`stereo_bench.campaign.plan.duration`) corrected
by what the run has measured so far, the operator's time included.

The plan predicts each configuration's machine time (the move to it, then settle, flush and exposures) and how
many prompts it puts to the operator; it leaves out computation (rendering, detection, calibration) and assumes
30 s per prompt (5 s per calibration view by hand, or what an earlier run measured: campaign/presentation.py),
or nothing where the scene is simulated. A run corrects both
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
from stereo_bench.campaign.plan.steps import CaptureCalibration, PlaceBoard, PromptManual, PromptTarget, Step
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


def forecast_groups(config: CampaignConfig, steps: Sequence[Step], *, presentation=None) -> Forecast:
    """The plan's time model (:class:`DurationModel`, each step's own ``estimate``) split per group of steps;
    ``presentation``: the seconds per calibration view an earlier run measured
    (:class:`~stereo_bench.campaign.presentation.PresentationTime`; None: the plan's assumed 5 s)."""
    from stereo_bench.campaign.runner import group_steps

    model = DurationModel.of(config, presentation)
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
            elif isinstance(step, PlaceBoard) and model.real_scene:
                prompts += 1  # the fixed-board design's one placement
            elif isinstance(step, CaptureCalibration) and model.real_scene:
                prompts += step.presentations  # one presentation of the board per view (none: a fixed board)
        groups.append(GroupForecast(config_id, move, rest, prompts, operator))
    homing = 0.0
    travel = model.rig_config.machine_travel()
    if config.rig.homing and travel:
        homing = homing_estimate_s(travel, simulated=config.rig.kind == "simulated") / model.speed_factor
    return Forecast(tuple(groups), homing)


#: Weight of the latest configuration in the unmodelled time per configuration (an exponential average): the
#: computation's cost drifts over a campaign (on paper-exp1 the configurations at larger Z, whose boards are
#: smaller in the images, go faster), which a plain mean would follow only late.
RECENT_WEIGHT = 0.3


@dataclass(frozen=True)
class Measured:
    """What a run has measured so far, on one clock (s).

    ``group``: the index of the group whose marker (its move) came last, None before the first; ``machine_s``: time
    so far not spent waiting for an operator; ``marks``: (group index, ``machine_s`` then) at every marker of this
    run, in order (a resume starts at a later group); ``operator_done_s``: seconds waited on prompts in the groups
    from the first marker's up to ``group``'s (excluded); ``operator_group_s``: seconds waited in group ``group`` so
    far, a pending prompt's wait included (before the first marker: the prompts before it).
    """

    group: int | None
    machine_s: float
    marks: tuple[tuple[int, float], ...] = ()
    operator_done_s: float = 0.0
    operator_group_s: float = 0.0


def unmodelled_s(forecast: Forecast, marks: Sequence[tuple[int, float]], *, weight: float = RECENT_WEIGHT) -> float:
    """The machine time per configuration the plan does not model (s; negative where the rig is faster than
    modelled), from the intervals between ``marks``: each interval's measured time less the plan's (the rest of the
    groups it closes, the moves of the groups it opens) per configuration that ran in it. The first interval carries
    what is done once (the bench's first renders, caches warming up) and counts only while it is the only one; the
    later ones are averaged with ``weight`` on the newest."""
    groups = forecast.groups
    per_interval = []
    for (a, at_a), (b, at_b) in zip(marks, marks[1:], strict=False):
        ran = [g for g in groups[a:b] if g.runs]
        if ran:
            predicted = sum(g.rest_s for g in groups[a:b]) + sum(g.move_s for g in groups[a + 1:b + 1])
            per_interval.append((at_b - at_a - predicted) / len(ran))
    if not per_interval:
        return 0.0
    if len(per_interval) == 1:
        return per_interval[0]
    c = per_interval[1]
    for u in per_interval[2:]:
        c = weight * u + (1.0 - weight) * c
    return c


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
    k = measured.group
    marks = measured.marks or ((k, measured.machine_s),)
    first, at_group = marks[0][0], marks[-1][1]
    c = unmodelled_s(forecast, marks)
    prompts_done = sum(g.prompts for g in groups[first:k])
    q = measured.operator_done_s / prompts_done if prompts_done else forecast.prior_s_per_prompt
    current = groups[k]
    machine_here = max(current.rest_s + c - (measured.machine_s - at_group), 0.0)
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
        self._marks: list[tuple[int, float]] = []
        self._operator_at_group = 0.0  # self._operator_s at the last marker
        self._operator_at_first = 0.0
        self._shown: tuple[float, float] | None = None  # (ETA shown, machine time then)

    def _machine(self, now_s: float) -> float:
        return now_s - self._start_s - self._operator_s - self._pending(now_s)

    def _pending(self, now_s: float) -> float:
        return 0.0 if self._pending_since is None else max(now_s - self._pending_since, 0.0)

    def moved(self, config_id: str | None, now_s: float) -> None:
        """The marker of ``config_id``: its move event (approach moves and unknown ids are not markers)."""
        index = None if config_id is None else self.forecast.index(config_id)
        if index is None or (self._marks and index == self._marks[-1][0]):
            return
        if not self._marks:
            self._operator_at_first = self._operator_s
        self._marks.append((index, self._machine(now_s)))
        self._operator_at_group = self._operator_s

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
        return Measured(group=self._marks[-1][0] if self._marks else None, machine_s=self._machine(now_s),
                        marks=tuple(self._marks), operator_done_s=self._operator_at_group - self._operator_at_first,
                        operator_group_s=self._operator_s - self._operator_at_group + self._pending(now_s))

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
