"""The step kinds a runner executes (:class:`StepKind` and its subclasses, the :data:`Step` union) and
:func:`plan_steps`, which lays them out for the configurations and visits of a campaign."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from drivers.rig.codec import vector_feed
from drivers.rig.config import QUANTITIES, to_machine
from drivers.rig.motion import move_time_s
from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan.configurations import VISIT_PURPOSES, Configuration, Visit, plan_visits
from stereo_bench.campaign.plan.timing import OPERATOR_S_PER_PROMPT, DurationModel


class StepKind:
    """What every step kind declares, so that nothing outside it lists the kinds (issue 21): the configuration it
    names (``config_id``, None for one that names none: it belongs to the group before it), whether it still runs
    once its configuration failed (``closes_group``: the checkpoints), its time under a :class:`DurationModel`
    (``estimate``, each kind its own) and the calibration boards it needs presented (``present``). The runner
    executes a step through one handler per kind (``CampaignRunner._execute``)."""

    config_id: ClassVar[str | None] = None
    closes_group: ClassVar[bool] = False

    def estimate(self, model: DurationModel) -> None:
        """Add this step's time to ``model`` (every kind says its own; see :func:`estimate_duration`)."""
        raise NotImplementedError(f"{type(self).__name__} does not say how long it takes")

    def present(self, tally: Presentations) -> None:
        """Count the calibration board presentations this step needs (none by default)."""
        return None


@dataclass(frozen=True)
class Move(StepKind):
    """Move the rig to a configuration (the motors; the manual quantities are the prompt steps that follow)."""

    configuration: Configuration
    kind: ClassVar[str] = "move"

    def as_dict(self) -> dict[str, Any]:
        c = self.configuration
        return {"step": self.kind, "config_id": c.config_id, "index": c.index, "request": c.move_request()}

    @property
    def config_id(self) -> str:
        return self.configuration.config_id

    def estimate(self, model: DurationModel) -> None:
        """One straight GRBL move from where the previous one left the axes (see :func:`estimate_duration`)."""
        request = self.configuration.move_request()
        driven = {q: v for q, v in request.items() if model.rig_config.quantities[q].driven}
        targets = to_machine(model.rig_config, driven)
        deltas = {a: targets[a] - model.position[a] for a in targets}
        feed = vector_feed(deltas, model.feeds)
        model.motion_s += move_time_s(deltas, max_rate_per_min=model.rates, acceleration=model.accels,
                                      feed_per_min=feed) / model.speed_factor
        model.position.update(targets)

    def present(self, tally: Presentations) -> None:
        tally.in_visit = isinstance(self.configuration, Visit)


@dataclass(frozen=True)
class PromptTarget(StepKind):
    """The operator moves the target to ``distance_mm`` (the target distance is manual and changes here)."""

    distance_mm: float
    kind: ClassVar[str] = "prompt_target"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "distance_mm": self.distance_mm}

    def estimate(self, model: DurationModel) -> None:
        model.operator_s += model.s_per_target_move if model.real_scene else 0.0


@dataclass(frozen=True)
class PromptManual(StepKind):
    """The operator sets another manual quantity (e.g. the baseline on a rig without a motorised slide)."""

    quantity: str
    value: float
    kind: ClassVar[str] = "prompt_manual"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "quantity": self.quantity, "value": self.value}

    def estimate(self, model: DurationModel) -> None:
        model.operator_s += OPERATOR_S_PER_PROMPT if model.real_rig else 0.0


@dataclass(frozen=True)
class PlaceBoard(StepKind):
    """The operator places the calibration board once, where the fixed-board design asks (``T_rig_board``, 16
    numbers row-major), and leaves it while the rig moves in front of it (issue 25)."""

    T_rig_board: tuple[float, ...]
    kind: ClassVar[str] = "place_board"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "T_rig_board": list(self.T_rig_board)}

    def estimate(self, model: DurationModel) -> None:
        model.operator_s += model.s_per_placement if model.real_scene else 0.0

    def present(self, tally: Presentations) -> None:
        tally.counts["placements"] += 1


@dataclass(frozen=True)
class Settle(StepKind):
    """Wait for the rig (and the operator's hands) to be still."""

    seconds: float
    kind: ClassVar[str] = "settle"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "seconds": self.seconds}

    def estimate(self, model: DurationModel) -> None:
        model.settle_s += self.seconds


@dataclass(frozen=True)
class Flush(StepKind):
    """Discard the frames the cameras queued before and during the move."""

    kind: ClassVar[str] = "flush"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind}

    def estimate(self, model: DurationModel) -> None:
        model.flush_s += model.flush_frames * model.frame_s


@dataclass(frozen=True)
class CaptureCalibration(StepKind):
    """Capture ``n_views`` stereo views of the calibration board (R, T are estimated from them)."""

    n_views: int
    fixed_board: bool = False  # the board stands where it was placed (PlaceBoard): captured, not presented
    kind: ClassVar[str] = "capture_calibration"

    def as_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"step": self.kind, "n_views": self.n_views}
        if self.fixed_board:
            data["fixed_board"] = True
        return data

    def estimate(self, model: DurationModel) -> None:
        model.capture_s += self.n_views * model.frame_s
        if not self.fixed_board:
            model.operator_s += self.n_views * model.s_per_calibration_view if model.real_scene else 0.0

    @property
    def presentations(self) -> int:
        """Board presentations by hand this capture needs."""
        return 0 if self.fixed_board else self.n_views

    def present(self, tally: Presentations) -> None:
        tally.add(self.presentations)


@dataclass(frozen=True)
class CaptureMeasurement(StepKind):
    """Capture ``n_frames`` stereo frames of the target and measure the square."""

    n_frames: int
    kind: ClassVar[str] = "capture_measurement"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "n_frames": self.n_frames}

    def estimate(self, model: DurationModel) -> None:
        model.capture_s += self.n_frames * model.frame_s


@dataclass(frozen=True)
class Checkpoint(StepKind):
    """End of a configuration: everything before it is recorded, and a resumed run starts after it.

    ``skipped``: the configuration is not run (infeasible or outside the limits); ``reason`` says why.
    """

    config_id: str
    skipped: bool = False
    reason: str | None = None
    kind: ClassVar[str] = "checkpoint"
    closes_group: ClassVar[bool] = True

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "config_id": self.config_id, "skipped": self.skipped, "reason": self.reason}

    def estimate(self, model: DurationModel) -> None:
        return None  # bookkeeping: no time


@dataclass(frozen=True)
class VisitDone(StepKind):
    """End of a visit (:class:`Visit`): its calibration views are kept for :class:`PrepareExtrinsics`.

    ``skipped``: the visit is not run (the board does not fit, or outside the soft limits); ``reason`` says why.
    """

    config_id: str
    skipped: bool = False
    reason: str | None = None
    kind: ClassVar[str] = "visit_done"
    closes_group: ClassVar[bool] = True

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "config_id": self.config_id, "skipped": self.skipped, "reason": self.reason}

    def estimate(self, model: DurationModel) -> None:
        return None  # bookkeeping: no time


#: The config_id of the PrepareExtrinsics step's group (not a configuration: nothing is measured there).
PREPARE_ID = "extrinsics-source"


def stage_id(purpose: str) -> str:
    """The config_id of a PrepareExtrinsics step that prepares a stage before the last (``extrinsics-intrinsics``:
    a fixed-board design's lens calibration); the last one's is :data:`PREPARE_ID`."""
    return f"extrinsics-{purpose}"


def is_prepare_id(config_id: str) -> bool:
    """Whether ``config_id`` names a PrepareExtrinsics step's group (no configuration, no visit)."""
    return config_id == PREPARE_ID or config_id in {stage_id(purpose) for purpose in VISIT_PURPOSES}


@dataclass(frozen=True)
class PrepareExtrinsics(StepKind):
    """Fit the kinematic rig model to the design's views (``kinematic``), or calibrate the intrinsics
    (``intrinsics``), before the first measured configuration; recorded, and read back by a resume."""

    purpose: str
    config_id: str = PREPARE_ID
    kind: ClassVar[str] = "prepare_extrinsics"
    closes_group: ClassVar[bool] = True

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "config_id": self.config_id, "purpose": self.purpose}

    def estimate(self, model: DurationModel) -> None:
        return None  # computation (the fit, the calibration) is not counted


Step = (Move | PromptTarget | PromptManual | PlaceBoard | Settle | Flush | CaptureCalibration | CaptureMeasurement
        | Checkpoint | VisitDone | PrepareExtrinsics)


def move_sequence(steps: Sequence) -> list[Configuration | Visit]:
    """The configurations and visits the plan's Move steps go to, in order (a configuration that is not run, e.g.
    infeasible, has no Move)."""
    return [step.configuration for step in steps if isinstance(step, Move)]


def plan_steps(config: CampaignConfig, configurations: Sequence[Configuration],
               visits: Sequence[Visit] | None = None) -> list[Step]:
    """The steps of a campaign, in order.

    First the visits (``visits``, default :func:`plan_visits`): Move, Settle, Flush, CaptureCalibration,
    VisitDone each (a visit that is not runnable: only ``VisitDone(skipped=True)``), then one
    PrepareExtrinsics (and one after each earlier stage of visits of another purpose: a fixed-board design's lens
    calibration, :func:`stage_id`). Then per runnable configuration: Move; a prompt for each manual quantity whose
    value changes (PromptTarget for the target distance, PromptManual for any other); Settle; Flush;
    CaptureCalibration (per-config extrinsics only); CaptureMeasurement; Checkpoint. A configuration
    that is not runnable gets only ``Checkpoint(skipped=True, reason=...)``.
    """
    rig_config = config.rig.rig_config()
    manual = [q for q in QUANTITIES if rig_config.quantities[q].axis == "manual"]
    last_manual: dict[str, float] = {}
    calibrates_each_configuration = config.extrinsics.source().calibrates_each_configuration
    steps: list[Step] = []
    visits = plan_visits(config, configurations) if visits is None else visits
    placed = False
    for k, visit in enumerate(visits):
        if k and visit.purpose != visits[k - 1].purpose:
            # A stage before this one (a fixed-board design's lens calibration): prepared, and recorded, before the
            # next stage's visits (a resume after it does not ask for its presentations again).
            steps.append(PrepareExtrinsics(visits[k - 1].purpose, config_id=stage_id(visits[k - 1].purpose)))
        if not visit.runnable:
            steps.append(VisitDone(visit.config_id, skipped=True, reason=visit.skip_reason))
            continue
        # The calibration board is shown by hand or by the simulator: no prompt for the target distance.
        steps.append(Move(visit))
        if visit.board_fixed:
            # Placed once, at the first visit run (the live page shows both views there), then left standing.
            if not placed:
                steps.append(PlaceBoard(visit.fixed_board_pose))
                placed = True
            capture = CaptureCalibration(config.extrinsics.fixed_board_views, fixed_board=True)
        else:
            capture = CaptureCalibration(config.capture.calibration_views)
        steps += [Settle(config.capture.settle_s), Flush(), capture, VisitDone(visit.config_id)]
    if visits:
        steps.append(PrepareExtrinsics(visits[-1].purpose))
    for configuration in configurations:
        if not configuration.runnable:
            steps.append(Checkpoint(configuration.config_id, skipped=True, reason=configuration.skip_reason))
            continue
        steps.append(Move(configuration))
        request = configuration.move_request()
        for quantity in manual:
            value = request[quantity]
            if last_manual.get(quantity) != value:
                steps.append(PromptTarget(value) if quantity == "target_distance_mm" else PromptManual(quantity, value))
                last_manual[quantity] = value
        steps.append(Settle(config.capture.settle_s))
        steps.append(Flush())
        if calibrates_each_configuration:
            steps.append(CaptureCalibration(config.capture.calibration_views))
        steps.append(CaptureMeasurement(config.capture.frames_per_config))
        steps.append(Checkpoint(configuration.config_id))
    return steps


@dataclass
class Presentations:
    """Board presentations counted so far (``StepKind.present``): at visits, or at measured configurations."""

    in_visit: bool = False  # the last move went to a visit
    counts: dict[str, int] = field(default_factory=lambda: {"visits": 0, "configurations": 0, "placements": 0})

    def add(self, n_views: int) -> None:
        self.counts["visits" if self.in_visit else "configurations"] += n_views
