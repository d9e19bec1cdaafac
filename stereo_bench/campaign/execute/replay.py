"""Replaying a recorded session through the same runner: :func:`replay_session`, its reproducibility verdict and
the replay-only helpers (:func:`replay_job` for ``stereo-bench replay``'s worker processes)."""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from stereo_bench import atomic, paths
from stereo_bench.campaign.bench import replay_bench
from stereo_bench.campaign.documents import (
    CalibrationDetectionsEvent,
    CalibrationViewEvent,
    Draft,
    EventDocument,
    KinematicModelEvent,
    MeasurementFrameEvent,
    NumericEnvironment,
    ResultDocument,
    ResultRow,
    StartDocument,
    StopDocument,
    json_safe,
)
from stereo_bench.campaign.environment import environment_differences, numeric_environment
from stereo_bench.campaign.execute.options import _recorded_copy, runner_options
from stereo_bench.campaign.execute.planned import CampaignPlan, plan_drift
from stereo_bench.campaign.execute.run import software_versions
from stereo_bench.campaign.extrinsics_run import RIG_CONFIG_FILE, RIG_CONFIG_KIND
from stereo_bench.campaign.plan import PREPARE_ID, stage_id
from stereo_bench.campaign.recorded import RecordedStart
from stereo_bench.campaign.reproduce import (
    SCALE_TOLERANCE,
    UNCERTAINTY_TOLERANCE,
    Deviation,
    RecordedContext,
    compare_models,
    compare_rows,
    largest,
    verdict,
)
from stereo_bench.campaign.runner import CampaignRunner, group_steps
from stereo_bench.campaign.session import SessionError, SessionReader, SessionWriter
from stereo_bench.campaign.stream import Collector, DocumentBus, MemoryRecorder, Subscriber
from stereo_bench.frames import keep_freed_frame_memory
from stereo_bench.vision.calibrate import single_threaded_opencv


@dataclass
class ReplaySummary:
    """What a replay found (docs/REPLAY.md): per measured configuration identical, reproduced within tolerance
    or differing (``differences``: only what is beyond the tolerance, one line per configuration)."""

    compared: int
    identical: int
    differences: list[str]
    rows: list[dict]
    carried_over: int
    out: Path | None
    measured: int = 0  # replayed configurations measured again
    reproduced: int = 0  # configurations whose every number is within the tolerance, not all bit-equal
    largest: Deviation | None = None  # the number nearest its tolerance (None: everything bit-identical)
    deviations: list[Deviation] = field(default_factory=list)  # every number compared
    kinematic_model: str | None = None  # the model fitted again: identical | reproduced | differs (None: none)
    fit_resolution: float | None = None  # its r: the tolerance of its numbers and of those measured with it
    # The recording's numeric environment (None: recorded before it was kept), today's, and where they differ.
    recorded_environment: dict | None = None
    environment: dict = field(default_factory=dict)
    environment_differences: list[tuple[str, Any, Any]] = field(default_factory=list)
    plan_drift: str | None = None
    # Measured configurations the session kept too little of to replay ([capture] keep_frames), with why.
    not_reproducible: dict[str, str] = field(default_factory=dict)
    from_detections: list[str] = field(default_factory=list)  # calibrated from recorded detections, not frames
    warnings: list[str] = field(default_factory=list)  # what of the recording was not replayed (a torn stream)


def check_replay_out(session_dir: str | Path, out_dir: str | Path) -> Path:
    """Refuse a replay's --out that is, holds or lies inside the session replayed, or that is anything but a
    new (or empty) directory; before anything is read or written."""
    out, source = Path(out_dir), Path(session_dir)
    resolved_out, resolved_source = out.resolve(), source.resolve()
    if paths.is_inside(resolved_source, resolved_out):
        raise SessionError(f"--out {out}: is or lies inside the session {source} being replayed: a recording is never "
                           "written to; choose a directory outside it")
    if paths.is_inside(resolved_out, resolved_source):
        raise SessionError(f"--out {out}: holds the session {source} being replayed; choose another directory")
    if out.is_symlink() or (out.exists() and (not out.is_dir() or any(out.iterdir()))):
        raise SessionError(f"--out {out}: exists; a replay records a new session: choose a new directory")
    return out


@contextlib.contextmanager
def _replay_out(session_dir: str | Path, out_dir: str | Path | None):
    """Where a replay records: a temporary directory beside --out, renamed to --out only when the replay ran to
    its end; a replay that fails (a recording that cannot be replayed, Ctrl-C) leaves no --out behind that
    would look like a good session (its temporary directory is removed: the source recording holds it all)."""
    if out_dir is None:
        yield None
        return
    out = check_replay_out(session_dir, out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    work = atomic.make_temp_dir(out.parent, prefix=f".{out.name}.")
    try:
        yield work
        if out.is_dir():  # an empty --out given (checked above): a directory renames over an empty one
            out.rmdir()
        work.rename(out)
        atomic.fsync_dir(out.parent)
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)


def reproducibility(reader: SessionReader, config_ids: Iterable[str]) -> tuple[dict[str, str], list[str]]:
    """({config_id: why it cannot be replayed}, [config_ids calibrated from recorded detections]).

    A configuration replays from its measurement frames and, for its calibration, from each
    calibration view's frames or, where those were not kept, its recorded detections.
    """
    config_ids = set(config_ids)
    keep = RecordedStart.of(reader.start()).campaign.capture.keep_frames
    detected = {(e.config_id, e.data.index) for e in reader.events(kind=CalibrationDetectionsEvent)}
    reasons: dict[str, str] = {}
    from_detections: set[str] = set()
    for event in reader.events(kind=CalibrationViewEvent | MeasurementFrameEvent):
        config_id = event.config_id
        if config_id not in config_ids or config_id in reasons:
            continue
        if "left" in event.frames and "right" in event.frames:
            continue
        if isinstance(event, MeasurementFrameEvent):
            reasons[config_id] = f"measurement frames not kept ([capture] keep_frames = \"{keep}\")"
        elif (config_id, event.data.index) in detected:
            from_detections.add(config_id)
        else:
            reasons[config_id] = "a calibration view kept neither as frames nor as detections"
    return reasons, sorted(from_detections - set(reasons))


def replay_session(session_dir: str | Path, out_dir: str | Path | None = None, *,
                   pipeline: dict | None = None, subscribers: Iterable[Subscriber] = ()) -> ReplaySummary:
    """Run a recorded session's frames and telemetry through the runner again.

    The configurations are the *recorded* plan's (never today's re-planning; where today's planner
    differs is reported as ``plan_drift``). Without ``out_dir`` nothing is written and the results are
    compared with the recorded ones; with it, a new session is recorded there (frames copied, so it
    stands alone). ``pipeline`` overrides pipeline settings (e.g. ``{"extrinsics": {"intrinsics":
    "fixed"}}``) for a re-analysis.

    A session recorded with ``[capture] keep_frames`` other than "all" replays what it kept: a
    configuration whose calibration views were kept as detections is calibrated from those (listed
    in ``from_detections``); one whose measurement frames were not kept cannot be replayed (listed in
    ``not_reproducible`` with the reason; a new session under ``out_dir`` leaves it out).
    """
    if out_dir is not None:
        check_replay_out(session_dir, out_dir)
    keep_freed_frame_memory()  # before the decoding threads start: they reuse each other's freed frames
    reader = SessionReader(session_dir)
    start = reader.start()
    recorded_start = RecordedStart.of(start)
    rig_copy = _recorded_copy(reader, RIG_CONFIG_KIND, RIG_CONFIG_FILE)
    try:
        overrides: dict[str, dict] = {"rig": {"config_file": str(rig_copy)}} if rig_copy is not None else {}
        for section, values in (pipeline or {}).items():  # the copy, not where the file was; then the pipeline's
            overrides[section] = {**overrides.get(section, {}), **values}
        config = recorded_start.campaign_with(overrides) if overrides else recorded_start.campaign
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first.get("loc", ())) or "config"
        raise SessionError(f"{reader.documents_path} line 1: the recorded campaign config does not validate "
                           f"({where}: {first.get('msg')})") from None
    campaign = CampaignPlan.recorded(config, start)
    configurations = campaign.configurations
    # Re-planning takes ~20 ms a configuration: while the frames replay, unless the new session's start needs it.
    drifting = ThreadPoolExecutor(max_workers=1, thread_name_prefix="plan-drift")
    drift_future = drifting.submit(plan_drift, config, start.plan)
    drifting.shutdown(wait=False)
    drift = drift_future.result() if out_dir is not None else None
    recorded_rows = {row.config_id: row for row in reader.results()}
    all_measured = {cid for cid, row in recorded_rows.items() if row.status == "measured"}
    not_reproducible, from_detections = reproducibility(reader, all_measured)
    measured = all_measured - set(not_reproducible)  # what is replayed
    # The visits run again (their recorded views fitted again) when the recording made its source from them.
    viewed = {event.config_id for event in reader.events(kind=CalibrationViewEvent)}  # one pass over the stream
    visited = {v.config_id for v in campaign.visits if v.config_id in viewed}
    if visited:
        visited |= {PREPARE_ID, stage_id("intrinsics")}  # the last stage, and a fixed-board design's lens calibration
    steps = [s for cid, group in group_steps(campaign.steps) if cid in measured | visited for s in group]
    if not all_measured and not visited:  # "0 of 0 reproduced" would pass a recording holding nothing to check
        torn = f"; {reader.warnings[0]}" if reader.torn is not None else ""
        raise SessionError(f"{reader.documents_path}: nothing to replay: no measured configuration is recorded "
                           f"({len(recorded_rows)} result(s), none measured){torn}")

    with contextlib.ExitStack() as stack:
        work = stack.enter_context(_replay_out(session_dir, out_dir))
        writer = stack.enter_context(SessionWriter(work) if work is not None
                                     else contextlib.nullcontext(MemoryRecorder()))
        bus = DocumentBus(writer)
        collector = Collector()
        bus.subscribe(collector)
        for subscriber in subscribers:
            bus.subscribe(subscriber)
        if out_dir is not None:
            bus.publish(Draft(StartDocument, config=config.model_dump(mode="json"), plan=start.plan,
                              software=software_versions(), bench="replay",
                              numeric_environment=numeric_environment(),
                              extra={"replay_of": str(Path(session_dir).resolve()),
                                     **({"plan_drift": drift} if drift else {})},
                              **({"design": start.design} if start.design else {})))
        options = runner_options(config, reader=reader, visits=campaign.visits)
        # Nothing waits for hardware here: analyse two configurations at once (OpenCV's solvers run
        # single-threaded either way, so the numbers are those of one at a time).
        options.analysis_workers = 2
        options.background_nice = False  # the detections are the critical path here, not something that can wait
        # Decoding, detection and analysis pools keep every core busy: OpenCV's own threads would only
        # add hand-over cost, and its solvers then run side by side instead of queueing for one thread.
        with single_threaded_opencv(), replay_bench(reader, measured | visited) as bench:
            runner = CampaignRunner(config, configurations, steps, bench=bench, bus=bus, options=options)
            if out_dir is not None:
                for draft in _recorded_session_sources(reader):
                    bus.publish(draft)
            status = runner.run()
        if status == "interrupted":  # Ctrl-C (a replay has no other stop): no --out, no comparison of a part
            raise KeyboardInterrupt
        if out_dir is not None:
            for cid, row in recorded_rows.items():  # failed and infeasible configurations: as recorded
                if cid not in all_measured:
                    bus.publish(Draft(ResultDocument, config_id=cid,
                                      row={k: v for k, v in row.stored().items() if not k.startswith("_")}))
            bus.publish(Draft(StopDocument, exit_status=status))
    drift = drift_future.result()
    new_rows = {row["config_id"]: row for row in collector.rows}
    differences, counts, deviations = [], {"identical": 0, "reproduced": 0}, []
    model_verdict, recorded_model = None, None
    if PREPARE_ID in visited:
        model_deviations, problem, recorded_model = _model_deviations(reader, runner.kinematic_model)
        if problem:
            differences.append(problem)
        elif model_deviations:
            deviations += model_deviations
            model_verdict = verdict(model_deviations)
            beyond = [d.difference() for d in model_deviations if d.verdict == "differs"]
            if beyond:
                differences.append("kinematic model: the model fitted again from the recorded views differs from the "
                                   "recorded one: " + ", ".join(beyond))
    context = RecordedContext.of(config, reader, refitted_model=recorded_model)
    for cid in sorted(measured):
        new = new_rows.get(cid)
        if new is None:
            differences.append(f"{cid}: not reproduced")
            continue
        compared = compare_rows(recorded_rows[cid].stored(), new, context)  # both rows as stored
        deviations += compared
        outcome = verdict(compared)
        if outcome == "differs":
            differences.append(f"{cid}: " + ", ".join(d.difference() for d in compared if d.verdict == "differs"))
        else:
            counts[outcome] += 1
    recorded_environment = _recorded_environment(reader, [recorded_rows[cid] for cid in measured])
    today = numeric_environment()
    return ReplaySummary(compared=len(measured), identical=counts["identical"], differences=differences,
                         rows=list(new_rows.values()), carried_over=len(recorded_rows) - len(all_measured),
                         out=None if out_dir is None else Path(out_dir),
                         measured=sum(new_rows.get(cid, {}).get("status") == "measured" for cid in measured),
                         reproduced=counts["reproduced"], largest=largest(deviations), deviations=deviations,
                         kinematic_model=model_verdict, fit_resolution=context.fit_resolution,
                         recorded_environment=recorded_environment, environment=today,
                         environment_differences=[] if recorded_environment is None else
                         environment_differences(recorded_environment, today),
                         plan_drift=drift, not_reproducible=not_reproducible, from_detections=from_detections,
                         warnings=_partial_recording(reader))


def _recorded_environment(reader: SessionReader, rows: Sequence[ResultRow]) -> dict | None:
    """The numeric environment of the attempt that recorded most of ``rows`` (start: attempt 1, a resume: its
    own), as recorded (JSON, compared with today's :func:`numeric_environment`); None when that attempt recorded
    none (sessions recorded before it was kept)."""
    by_attempt: dict[int, NumericEnvironment | None] = {1: reader.start().numeric_environment}
    for resume in reader.resumes():
        by_attempt[resume.attempt] = resume.numeric_environment
    attempts = [row.attempt or 1 for row in rows]
    attempt = max(set(attempts), key=attempts.count) if attempts else 1
    environment = by_attempt.get(attempt)
    return None if environment is None else json_safe(environment)


def _partial_recording(reader: SessionReader) -> list[str]:
    """What a replay of an interrupted or torn recording leaves out: only its completed configurations replay."""
    notes = list(reader.warnings)
    if reader.status() == "incomplete":
        notes.append(f"{reader.documents_path}: the recording has no 'stop' document (interrupted): only its "
                     "completed configurations were replayed")
    return notes


def _model_deviations(reader: SessionReader, model) -> tuple[list[Deviation], str | None, object]:
    """The kinematic model fitted again from the recorded design views against the one the recording holds:
    (every compared number, docs/REPLAY.md; or a line saying why they cannot be compared; the recorded model)."""
    from stereo_bench.campaign.extrinsics_run import MODEL_FILE
    from stereo_bench.kinematics import KinematicFileError, model_from_toml

    recorded = [e for e in reader.events(kind=KinematicModelEvent, attempt=None) if e.data.source == "design"]
    if not recorded:
        return [], None, None
    relative = recorded[-1].files.get(MODEL_FILE)
    if model is None:
        return [], (f"kinematic model: not fitted again ({recorded[-1].data.error or 'no model'})"
                    if relative else None), None
    if relative is None:
        return [], "kinematic model: fitted again, but the recording holds no model file to compare it with", None
    try:
        recorded_model = model_from_toml(reader.read_bytes(relative).decode("utf-8"), relative)
    except (KinematicFileError, UnicodeDecodeError) as error:
        return [], f"kinematic model: the recorded model cannot be read ({error})", None
    return compare_models(recorded_model, model), None, recorded_model


def _recorded_session_sources(reader: SessionReader) -> list[Draft]:
    """A model file's, calib_dir's and the rig config file's copies in the recording, recorded again into a
    replay's new session."""
    from stereo_bench.campaign.documents import IntrinsicsEvent, KinematicModelEvent

    drafts = []
    for kind, model in (("kinematic_model", KinematicModelEvent), ("intrinsics", IntrinsicsEvent),
                        (RIG_CONFIG_KIND, EventDocument)):
        for event in reader.events(kind=kind, attempt=None):
            if isinstance(event, KinematicModelEvent) and event.data.source != "file":
                continue
            files = {name: reader.read_bytes(relative) for name, relative in event.files.items()}
            drafts.append(Draft(model, config_id=None, data=event.data, files=files,
                                **({"kind": kind} if model is EventDocument else {})))
    return drafts


def replay_job(job: tuple[str, str | None, dict]) -> dict:
    """One replay as a picklable job for an executor: (session, out or None, pipeline) -> JSON-ready summary.

    Errors come back as data (``error``) so one bad session does not sink a batch.
    """
    from drivers.replay import ReplayMismatch
    from stereo_bench.vision.calibio import CalibrationFileError

    session, out, pipeline = job
    try:
        summary = replay_session(session, out, pipeline=pipeline)
    except (SessionError, KeyError, OSError, ReplayMismatch, CalibrationFileError, UnicodeDecodeError) as error:
        text = " ".join(str(error).strip("'\"").split())
        if isinstance(error, OSError) and error.filename is not None and error.strerror:
            text = f"{error.filename}: {error.strerror}"
        elif isinstance(error, ReplayMismatch):
            text = f"the recording cannot be replayed: {text}"
        return {"session": session, "out": out, "error": text}
    return {"session": session, "out": out, "compared": summary.compared, "identical": summary.identical,
            "reproduced": summary.reproduced, "measured": summary.measured, "differences": summary.differences,
            "largest_deviation": None if summary.largest is None else summary.largest.as_dict(),
            "tolerance": {"relative_to_scale": SCALE_TOLERANCE, "relative_to_u": UNCERTAINTY_TOLERANCE,
                          "kinematic_fit": summary.fit_resolution},
            "kinematic_model": summary.kinematic_model,
            "numeric_environment": {
                "recorded": summary.recorded_environment, "today": summary.environment,
                "differences": [{"field": label, "recorded": old, "today": new}
                                for label, old, new in summary.environment_differences]},
            "carried_over": summary.carried_over, "pipeline": pipeline, "plan_drift": summary.plan_drift,
            "not_reproducible": summary.not_reproducible, "from_detections": summary.from_detections,
            "warnings": summary.warnings}
