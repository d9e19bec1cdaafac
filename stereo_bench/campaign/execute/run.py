"""Running (or resuming) a campaign into a session directory: :func:`run_campaign` and what only it uses."""

from __future__ import annotations

import contextlib
import platform
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from pydantic import ValidationError

from stereo_bench import __version__, paths
from stereo_bench.campaign.bench import Bench, open_bench
from stereo_bench.campaign.config import CampaignConfig, ConfigError
from stereo_bench.campaign.documents import ControllerEvent, Draft, StartDocument, StopDocument
from stereo_bench.campaign.environment import numeric_environment
from stereo_bench.campaign.execute.control import RunControl
from stereo_bench.campaign.execute.options import runner_options
from stereo_bench.campaign.execute.planned import CampaignPlan, plan_drift
from stereo_bench.campaign.operator import Operator, PromptDisplay, SimulatedOperator, TerminalOperator
from stereo_bench.campaign.plan import PREPARE_ID, Visit, design_problem, stage_id
from stereo_bench.campaign.preflight import Preflight
from stereo_bench.campaign.recorded import RecordedStart
from stereo_bench.campaign.runner import CampaignRunner, RunnerOptions
from stereo_bench.campaign.session import SessionError, SessionReader, SessionWriter
from stereo_bench.campaign.stream import Collector, DocumentBus, FrameSubscriber, Subscriber


def software_versions() -> dict:
    return {"stereo_bench": __version__, "opencv": cv2.__version__, "numpy": np.__version__,
            "python": platform.python_version()}


@dataclass
class RunSummary:
    session: Path
    exit_status: str
    rows: list[dict] = field(default_factory=list)
    skipped: int = 0
    plan_drift: str | None = None
    reason: str | None = None
    # The presentation time this run measured (campaign/presentation.py) and where it was written (None: nothing
    # presented by hand, or the directory beside the session cannot be written: ``presentation_note`` says why).
    presentation: object | None = None
    presentation_file: Path | None = None
    presentation_note: str | None = None

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for row in self.rows:
            counts[row["status"]] = counts.get(row["status"], 0) + 1
        return counts


def resume_sources(options: RunnerOptions, writer: SessionWriter, config: CampaignConfig,
                   visits: Sequence[Visit]) -> set[str]:
    """A resume's extrinsics source from the earlier attempts (the fitted model, nominal's calibrated intrinsics):
    the visits and the preparation to skip (all of them when it is recorded, none when it is not). A fixed-board
    design's lens calibration recorded before its fit was: its intrinsics visit and stage are skipped (the operator
    is not asked for its presentations again) and the fit takes the recorded calibration; the design is visited
    again (docs/EXTRINSICS.md)."""
    from stereo_bench.campaign.extrinsics_run import recorded_sources

    if not visits or writer.recorded_start is None:
        return set()
    optics = config.cameras.optics
    lens_visits = [v.config_id for v in visits if v.purpose == "intrinsics"]
    recorded = recorded_sources(writer.reader(), sources=("design",), image_size=(optics.width_px, optics.height_px),
                                intrinsics_visits=lens_visits)
    if not config.extrinsics.source().is_prepared(recorded):
        if recorded.lens is None or len(lens_visits) == len(visits):
            return set()
        options.lens_calibration = recorded.lens
        return set(lens_visits) | {stage_id("intrinsics")}
    options.kinematic_model = recorded.kinematic_model or options.kinematic_model
    options.nominal_intrinsics = recorded.nominal_intrinsics or options.nominal_intrinsics
    return {visit.config_id for visit in visits} | {PREPARE_ID}


def default_operators(config: CampaignConfig, *, yes: bool, display: PromptDisplay | None = None) -> list[Operator]:
    """``--yes`` on simulated cameras: the simulator does the manual steps; else the terminal (its prompts shown by
    ``display``: the CLI's progress line, which they suspend)."""
    if yes and config.cameras.kind == "simulated":
        return [SimulatedOperator()]
    return [TerminalOperator(display=display)]


def run_campaign(
    config: CampaignConfig, out_dir: str | Path, *, resume: bool = False, yes: bool = False,
    operators: Sequence[Operator] | None = None, subscribers: Iterable[Subscriber] = (),
    control: RunControl | None = None, plan: CampaignPlan | None = None, resume_command: str | None = None,
    bench_factory: Callable[..., Bench] = open_bench, frame_subscribers: Iterable[FrameSubscriber] = (),
    preflight: Preflight | None = None,
) -> RunSummary:
    """Run (or resume) ``config`` into the session directory ``out_dir``.

    A resume runs the *recorded* plan and records where today's planner differs (``plan_drift``).
    ``subscribers`` get every document as recorded (``frame_subscribers`` also the recorded frames' pixels:
    a live page's previews); ``control`` stops or pauses the run from outside.
    ``bench_factory(config, operators=..., transcript=...)`` opens the bench (default: the config's).
    ``preflight``: ``config`` checked and its input files read (:func:`stereo_bench.campaign.preflight.preflight`,
    which the CLI runs once); without it, the run checks and reads them itself.
    """
    from stereo_bench.campaign.preflight import preflight as check

    # what `campaign plan` checks: before the session is written or anything moves
    checked = preflight if preflight is not None else check(config)
    control = control or RunControl()
    operators = list(operators) if operators is not None else default_operators(config, yes=yes)
    summary = RunSummary(session=Path(out_dir), exit_status="failed")
    if resume:
        finished = _finished(Path(out_dir))
        if finished is not None:  # nothing to do: the session is left as it is, and the bench is not opened
            summary.exit_status, summary.skipped = "success", finished
            return summary
    writer = SessionWriter(out_dir, resume=resume)
    opened = False  # the bench: until it is open nothing has moved, and nothing but the start is recorded
    try:
        with writer:
            recorded = writer.recorded_start
            if recorded is not None:
                campaign = CampaignPlan.recorded(config, recorded)
                summary.plan_drift = plan_drift(config, recorded.plan)
            else:
                campaign = plan or CampaignPlan.of(config)
                problem = design_problem(config, campaign.configurations, campaign.visits)
                if problem:  # before anything moves: every configuration would fail on its extrinsics
                    raise ConfigError(f"campaign config: {problem}")
            bus = DocumentBus(writer)
            collector = Collector()
            bus.subscribe(collector)
            for subscriber in subscribers:
                bus.subscribe(subscriber)
            for frame_subscriber in frame_subscribers:
                bus.subscribe_frames(frame_subscriber)
            transcript = writer.transcript_path()  # registered first, so its event follows the start
            bus.publish(Draft(StartDocument, config=config.model_dump(mode="json"),
                              plan=[c.as_dict() for c in campaign.configurations], software=software_versions(),
                              extra={}, bench=config.bench_kind, numeric_environment=numeric_environment(),
                              **({"plan_drift": summary.plan_drift} if summary.plan_drift else {}),
                              **({"design": [v.as_dict() for v in campaign.visits]} if campaign.visits else {})))
            done = writer.completed_config_ids()
            summary.skipped = len(done)
            status, reason = "failed", None
            try:
                options = runner_options(config, visits=campaign.visits, preflight=checked)
                skip = set(done) | resume_sources(options, writer, config, campaign.visits)
                if campaign.visits and all(c.config_id in done for c in campaign.configurations if c.runnable) and done:
                    # nothing left to measure
                    skip |= {visit.config_id for visit in campaign.visits} | {PREPARE_ID, stage_id("intrinsics")}
                with bench_factory(config, operators=operators, transcript=transcript) as bench:
                    opened = True
                    runner = CampaignRunner(config, campaign.configurations, campaign.steps, bench=bench, bus=bus,
                                            options=options)
                    _record_connect(bus, bench, config)
                    for draft in config.extrinsics.source().start_drafts(options, config.extrinsics):
                        bus.publish(draft)  # fixed: the calibration used goes into the session
                    for draft in checked.sources:  # a model file, calib_dir's intrinsics: copied in
                        bus.publish(draft)
                    control.attach(runner)
                    status = runner.run(skip=skip)
                    reason = runner.stop_reason if status != "success" else None  # a stop, or the rig unrecoverable
            except KeyboardInterrupt:  # a second Ctrl-C while the bench opened or closed
                status, reason = "interrupted", "stopped at once (second interrupt)"
            except BaseException as error:
                with contextlib.suppress(Exception):  # the original error is the one to report
                    bus.publish(Draft(StopDocument, exit_status="failed", reason=f"{type(error).__name__}: {error}",
                                      **({"resume_command": resume_command} if opened and resume_command else {})))
                raise
            finally:
                control.detach()
            bus.publish(Draft(StopDocument, exit_status=status, reason=reason,
                              **({"resume_command": resume_command} if status != "success" and resume_command
                                 else {})))
    except BaseException:
        if not opened and not resume:
            # Refused before anything moved (a port that is not there, a controller that never answers): --out is
            # left as it was, so the corrected command is accepted (a new session is never written over).
            with contextlib.suppress(SessionError, OSError):  # not begun by this run (e.g. --out exists): kept
                writer.discard()
        raise
    summary.exit_status, summary.reason = status, reason
    summary.rows = collector.rows
    _write_presentation_time(summary, collector, real_scene=config.cameras.kind != "simulated")
    return summary


def _finished(out_dir: Path) -> int | None:
    """The number of configurations of a session whose last attempt ended in success with every runnable
    configuration of its recorded plan measured (a resume has nothing to do: it neither appends an attempt nor
    opens the bench, whose controller a connection would reset); None otherwise, or when the session cannot be read
    (the resume then says why)."""
    try:
        reader = SessionReader(out_dir)
        if reader.status() != "success":
            return None
        done = reader.completed_config_ids()
        planned = RecordedStart.of(reader.start()).configurations  # the recorded plan as recorded: no steps planned
        # a resume refuses a session with a symlink leaving it, with the reason (SessionWriter): not a no-op then.
        # Scanned only here, for a finished session: an unfinished one is scanned once, by the writer.
        if paths.symlinks_leaving(out_dir):
            return None
    except (SessionError, OSError, ValueError):
        return None
    if all(c.config_id in done for c in planned if c.runnable):
        return len(done)
    return None


def _write_presentation_time(summary: RunSummary, collector: Collector, *, real_scene: bool) -> None:
    """The seconds per board presentation (and, with real cameras, per target move and fixed-board placement) this
    run measured, beside its session: the next plan's estimate."""
    from stereo_bench.campaign.documents import PresentationTimeEvent, PromptEvent
    from stereo_bench.campaign.presentation import PresentationTime, write_beside

    measured = PresentationTime.of_events(collector.of(PresentationTimeEvent), session=summary.session.name,
                                          prompts=collector.of(PromptEvent), real_scene=real_scene)
    if measured is None:
        return
    summary.presentation = measured
    try:
        summary.presentation_file = write_beside(summary.session, measured)
    except OSError as error:  # the measurement is in the session's events all the same
        summary.presentation_note = f"presentation time not written beside {summary.session}: {error}"


def recorded_config(session_dir: str | Path) -> CampaignConfig:
    """The campaign config the session in ``session_dir`` recorded in its start document: what ``campaign run
    --resume`` continues with when no campaign file is given (SessionError, one line, if it cannot be read)."""
    reader = SessionReader(session_dir)
    try:
        return RecordedStart.of(reader.start()).campaign
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first.get("loc", ())) or "config"
        raise SessionError(f"{reader.documents_path} line 1: the recorded campaign config does not validate "
                           f"({where}: {first.get('msg')})") from None


def _record_connect(bus: DocumentBus, bench: Bench, config: CampaignConfig) -> None:
    """The rig controller as read at connect (build, settings, startup lines, warnings): part of the recording."""
    if not bench.rig.capabilities.controller:  # a replay's: no controller behind it
        return
    port = config.rig.port if config.rig.kind == "grbl" else "simulated (GRBL emulator on a pty)"
    bus.publish(Draft(ControllerEvent, config_id=None, data={"port": port, "info": bench.rig.controller_info(),
                                                             "warnings": list(bench.rig.warnings)}))
