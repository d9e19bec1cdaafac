"""The runner: executes every step of a campaign on a :class:`~stereo_bench.campaign.bench.Bench` and
publishes what happens as documents.

One runner owns execution (STYLE.md, bluesky's RunEngine): it homes the rig before the first move,
moves it (only the quantities the controller drives), asks the operators for every manual step
(target distance, calibration board, measured target: each recorded as a ``prompt`` document),
waits for the rig to settle, flushes stale frames, has the presenter put boards in front of the
cameras, captures and records every frame as it comes, and hands each configuration's frames to an
analysis thread, so the calibration and measurement of one configuration overlap the motion to the
next. Results are published in plan order, each one only when its configuration is complete: that
is the checkpoint a resume starts from.

Everything it records goes through one :class:`~stereo_bench.campaign.stream.DocumentBus` (on an
ordered recorder thread): the session writer, a progress display, a ``--json`` line stream or a
test collector are its subscribers. Nothing else watches the runner.

Faults: a configuration that fails (board not found after retries, calibration impossible, an
alarm) is recorded as failed with its reason and the campaign goes on; after a rig fault the rig is
soft-reset and homed again first, and if that fails too the run ends as failed (resumable), with the
fault and the failed recovery step as its reason. :meth:`CampaignRunner.request_stop` (Ctrl-C,
SIGTERM, SIGHUP, a live page's Stop) feeds-hold the rig, cuts a settle or an operator prompt short,
finishes nothing new, records what is complete and leaves the session resumable. A KeyboardInterrupt
(a second Ctrl-C) stops at once: analyses still running are dropped (their configurations run again
on resume).
:meth:`request_pause` holds the run at the next step boundary until :meth:`request_resume`; a move in
progress is feed-held and continues on resume (both recorded as ``run_control`` events). While the
runner waits for the operator or is paused it lends the cameras to a preview (``bench.camera_gate``).
At the bench the operator can discard the last calibration view and take it again (an answer to the
view's prompt, recorded as ``calibration_view_discarded``; its frames stay in the session).
"""

from __future__ import annotations

import functools
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from stereo_bench.campaign.analysis import (
    AnalysisError,
    ConfigurationAnalysis,
    calibrate_configuration,
    measure_configuration,
)
from stereo_bench.campaign.approach import approach_moves, move_sequence
from stereo_bench.campaign.documents import (
    AnalysisEvent,
    ApproachEvent,
    CalibrationDetectionsEvent,
    CalibrationEvent,
    CalibrationExclusionsEvent,
    CalibrationFiles,
    CalibrationSelectionEvent,
    CalibrationViewDiscardedEvent,
    CalibrationViewEvent,
    DetectionRecord,
    Draft,
    HomeEvent,
    MeasurementFrameEvent,
    MoveEvent,
    PresentationTimeEvent,
    PromptEvent,
    ResultDocument,
    RigPositionTrustedEvent,
    RigRecoveredEvent,
    RigUnrecoverableEvent,
    RunControlEvent,
    StructureEvent,
    TargetNotFoundEvent,
    TruthEvent,
)
from stereo_bench.campaign.extrinsics import extrinsics_source
from stereo_bench.campaign.operator import (
    CONTINUE,
    DISCARD_LAST_VIEW,
    Answer,
    OperatorDesk,
    Prompt,
    StopRequested,
    manual_prompt,
)
from stereo_bench.campaign.plan import (
    CaptureCalibration,
    CaptureMeasurement,
    Checkpoint,
    Configuration,
    Flush,
    Move,
    PlaceBoard,
    PrepareExtrinsics,
    PromptManual,
    PromptTarget,
    Settle,
    Visit,
    VisitDone,
    is_prepare_id,
)
from stereo_bench.campaign.presenters import CalibrationPlacementError
from stereo_bench.campaign.sources import ApproachTracker, reported_axes
from stereo_bench.executors import background_threads
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.detect import AmbiguousViewError, detect
from stereo_bench.vision.uncertainty import BoardScale

__all__ = ["CampaignRunner", "ConfigurationFailed", "RigUnrecoverable", "RunnerOptions", "StopRequested", "group_steps"]


#: Views taken automatically: grabs in a row that find no pair within the skew limit before the stream gives up (the
#: cameras' clocks or bus, not a pair now and then, are wrong: the error is then the run's, as for a single view).
MAX_UNPAIRED_IN_A_ROW = 30


class ConfigurationFailed(Exception):
    """The configuration cannot be completed; the message is the reason recorded with it."""


class RigUnrecoverable(Exception):
    """The rig failed and could not be recovered (soft reset, then homing): the run ends as failed, resumable once
    the rig is fixed. The message names the fault (``GRBL ALARM:1: Hard limit triggered ...``) and the recovery step
    that failed."""


@dataclass
class Captured:
    """What was captured at one configuration (images stay in memory until the analysis is done)."""

    configuration: Configuration | Visit | None
    calibration_pairs: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    calibration_detections: list[tuple[Future, Future]] = field(default_factory=list)  # detect(), made ahead
    measurement_pairs: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    measurement_detections: list[tuple] = field(default_factory=list)  # (left, right) Detection | None
    # Per-config extrinsics: the calibration, started on the analysis pool once the views are taken, so that
    # it runs while the measurement frames are captured rather than after them.
    calibration: Future | None = None
    axes: dict | None = None  # the kinematic axes the rig reported after the move
    approach: dict | None = None  # per axis the direction the move came from
    truth: dict | None = None  # simulated benches: the truth at the measurement (never used by it)
    # Views left out of the calibration beyond its outlier rule (index -> why) and the per-view RMS threshold (px):
    # [calibration]'s, the operator's review, or (a replay) what the recording's review chose. None: [calibration]'s.
    exclude: dict[int, str] | None = None
    max_view_rms_px: float | None = None

    def detections(self) -> list[tuple]:
        """Per calibration view the (left, right) Detection or None made while capturing (waited for here).
        AnalysisError if a detection failed (as it would have inside the calibration)."""
        try:
            return [(left.result(), right.result()) for left, right in self.calibration_detections]
        except (ValueError, np.linalg.LinAlgError) as error:
            raise AnalysisError(str(error)) from None


@dataclass
class RunnerOptions:
    board_retries: int = 3
    intrinsics_mode: str = "joint"
    intrinsics: tuple | None = None  # (K1, D1, K2, D2) to start from / keep fixed
    intrinsics_covariance: object | None = None  # CalibrationCovariance of ``intrinsics``, when stored with them
    fixed_calibration: StereoCalibration | None = None  # extrinsics mode "fixed"
    calibration_board: str = ""  # how calibrations name their board, e.g. 'checkerboard 11x8 square 25 mm'
    extrinsics_mode: str = "per-config"
    # Extrinsics sources prepared before the run (campaign/extrinsics_run.py): a kinematic model (kinematic
    # mode from a file or a recording; a comparison in the other modes) and the intrinsics nominal uses.
    kinematic_model: object | None = None
    nominal_intrinsics: StereoCalibration | None = None
    # A fixed-board design's lens calibration a resume read back (its intrinsics visit is not visited again).
    lens_calibration: StereoCalibration | None = None
    visits: list[Visit] = field(default_factory=list)
    board_scale: BoardScale = field(default_factory=BoardScale)
    tolerances: dict = field(default_factory=dict)
    repeatability: tuple[float, float] = (0.0, 0.0)  # slide mm, pan heads deg
    # Configurations analysed at once (threads; results are still published in plan order). A live run
    # analyses one while the rig moves on; a replay, which waits for nothing, uses more.
    analysis_workers: int = 1
    # Work that can wait (detecting calibration views ahead of their analysis) runs at a lower priority,
    # so that the capture comes first; a replay, where that work is the critical path, sets False.
    background_nice: bool = True


def result_fields(configuration: Configuration, *, status: str, reason: str | None = None,
                  measured: dict | None = None) -> dict:
    """One result row (a :class:`~stereo_bench.campaign.documents.ResultRow`; the recorder adds attempt, time)."""
    row = {
        "config_id": configuration.config_id, "baseline_mm": configuration.baseline_mm,
        "distance_mm": configuration.distance_mm, "alpha_deg": configuration.alpha_deg,
        "toe_in_deg": configuration.toe_in_deg, "tilt_deg": configuration.tilt_deg,
        "fraction_in_both": configuration.fraction_in_both, "status": status, "reason": reason,
        "square_mean_mm": None, "square_std_mm": None, "n_squares": 0, "error_mm": None, "sigma_mm": None,
        "rms_px": None, "epipolar_rms_px": None,
    }
    row.update(measured or {})
    return row


class CampaignRunner:
    """Runs ``steps`` (from :func:`stereo_bench.campaign.plan.plan_steps`) on ``bench``, publishing to ``bus``."""

    def __init__(self, config, configurations: list[Configuration], steps: list, *, bench, bus,
                 options: RunnerOptions):
        self.config = config
        self.configurations = {c.config_id: c for c in configurations}
        self.steps = steps
        self.bench = bench
        self.bus = bus
        self.options = options
        self.desk = OperatorDesk(bench.operators)
        self.calibration_board = config.calibration_board.build()
        self.target = config.target.build()
        quantities = config.rig.rig_config().quantities
        self._manual_quantities = {q for q, mapping in quantities.items() if mapping.axis == "manual"}
        self._motor_limits = {q: (mapping.min, mapping.max) for q, mapping in quantities.items()
                              if mapping.driven and q not in self._manual_quantities}
        # The tilts the rig drives (grblHAL's A/B): part of every reported position the kinematic model reads.
        self._driven_tilts = tuple(q for q in ("tilt_left_deg", "tilt_right_deg") if q in self._motor_limits)
        self._homed = not bench.homes
        # The plan's moves in order (all of them, also those a resume skips) and where this run stands in them:
        # a move that does not follow the previous one of the plan is approached as the plan's was (approach.py).
        self._sequence = move_sequence(steps)
        self._sequence_index = {entry.config_id: i for i, entry in enumerate(self._sequence)}
        self._last_index: int | None = None  # of the last move made; -1: at home; None: not known (not homed)
        self._start: dict[str, float] | None = None  # where the plan's moves start from (homing leaves the rig)
        self._trusted = False  # [rig] homing = false: the position was taken as right (once, at the first move)
        self._stop = threading.Event()
        self._running = threading.Event()  # cleared while paused
        self._running.set()
        self._control_lock = threading.Lock()  # request_pause vs. the start and end of a move
        self._moving = False
        self._feed_held = False  # a pause feed-held the rig: resume it before anything else moves
        self.stop_reason: str | None = None
        self._analysis = ThreadPoolExecutor(max_workers=max(1, options.analysis_workers), thread_name_prefix="analysis")
        # Calibration views are detected as they come (in the background: the analysis needs them later,
        # the capture must not wait), a measurement frame's two views side by side (the capture waits).
        self._detector = (background_threads(2, "detect") if options.background_nice
                          else ThreadPoolExecutor(max_workers=2, thread_name_prefix="detect"))
        self._side_detector = ThreadPoolExecutor(max_workers=1, thread_name_prefix="detect-side")
        # Every document goes through one recorder thread, in submission order: PNG encoding (on the
        # recorder's encoder pool) and fsync then overlap the next capture instead of delaying it.
        self._recorder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="recorder")
        self._recording: list[Future] = []
        self._pending: list[tuple[Captured, Future]] = []
        self.visits = {visit.config_id: visit for visit in options.visits}
        self._approach = ApproachTracker()
        self._visit_captures: list[Captured] = []
        self._prepared: Future | None = None  # the extrinsics source prepared from the visits
        self._extrinsics = extrinsics_source(options.extrinsics_mode)  # its strategy object
        self.kinematic_model = options.kinematic_model  # after the run: the model used (fitted or given)

    # -- control (thread- and signal-safe) ----------------------------------------------------------------------

    def request_stop(self, reason: str = "stopped by the operator") -> None:
        """Stop at the next safe point; a move in progress is feed-held, a settle or a prompt cut short."""
        if self.stop_reason is None:
            self.stop_reason = reason
        self._stop.set()
        self._running.set()
        try:
            self.bench.rig.stop()
        except Exception:  # noqa: BLE001 - the rig may be mid-reply; the runner re-reads it at the safe point
            pass

    def request_pause(self) -> None:
        """Hold the run at the next step boundary; a move in progress is feed-held (and continued on resume)."""
        with self._control_lock:
            self._running.clear()
            if self._moving and not self._feed_held:
                self._feed_held = True
                try:
                    self.bench.rig.stop()
                except Exception:  # noqa: BLE001 - as in request_stop: the move's own error says what happened
                    pass

    def request_resume(self) -> None:
        self._running.set()

    @property
    def paused(self) -> bool:
        return not self._running.is_set()

    def _between_steps(self) -> None:
        if not self._running.is_set():
            self._hold_until_resumed()
        if self._stop.is_set():
            raise StopRequested()

    def _hold_until_resumed(self) -> None:
        """Paused: wait (cameras lent to a preview) until resumed or stopped; a feed hold is released after."""
        self._publish(Draft(RunControlEvent, data={"action": "pause", "feed_hold": self._feed_held}))
        with self.bench.camera_gate.lent():
            while not self._running.wait(0.1):
                pass
        if self._stop.is_set():
            raise StopRequested()
        if self._feed_held:
            self.bench.rig.resume()  # GrblRig: '~' once the hold is complete; the held move is then queued again
            self._feed_held = False
        self._publish(Draft(RunControlEvent, data={"action": "resume"}))

    # -- recording ----------------------------------------------------------------------------------------------

    def _publish(self, draft: Draft) -> None:
        """Queue a document; a failure to record an earlier one surfaces here (or at the next sync)."""
        # The recorder starts on it at once (frames are encoded on its pool, in parallel); the recorder
        # thread then writes each document in turn, a frame file before the line that references it.
        self._enqueue(self.bus.publish, self.bus.prepare(draft))

    def _enqueue(self, job, *args) -> None:
        """Run ``job(*args)`` on the recorder thread after everything queued before it."""
        self._recording.append(self._recorder.submit(job, *args))
        if len(self._recording) > 64:  # at most a few configurations' frames wait in memory
            self._sync_recording(keep=32)
        else:
            self._reap_recording()

    def _sync_recording(self, keep: int = 0) -> None:
        """Wait until all but ``keep`` queued documents are recorded; re-raise the first failure."""
        while len(self._recording) > keep:
            self._recording.pop(0).result()

    def _reap_recording(self) -> None:
        """Forget the documents already recorded, re-raising the first failure; never waits."""
        while self._recording and self._recording[0].done():
            self._recording.pop(0).result()

    # -- execution -----------------------------------------------------------------------------------------------

    def run(self, *, skip: set[str] = frozenset()) -> str:
        """Execute the steps of every configuration not in ``skip``; returns the exit status."""
        abandon = False
        captured = None
        self.bench.presenter.begin_run(self._sequence)
        try:
            try:
                for config_id, group in group_steps(self.steps):
                    if config_id in skip:
                        continue
                    configuration = self._configuration_of(config_id)
                    captured, failed = Captured(configuration), None
                    if configuration is not None:
                        self.bench.presenter.begin_configuration(configuration)
                    for step in group:
                        self._between_steps()
                        # After a failure only the step that closes the group runs (it records the failure).
                        if failed is None or step.closes_group:
                            try:
                                self._execute(step, captured, failed)
                            except ConfigurationFailed as error:
                                failed = str(error)
                        self._collect(block=False)
                self._collect(block=True)
                return "success"
            except (StopRequested, RigUnrecoverable) as stopped:
                if captured is not None and captured.calibration is not None:
                    captured.calibration.cancel()  # the configuration stopped before it was measured
                self._collect(block=True)  # what is complete is recorded
                if isinstance(stopped, RigUnrecoverable):  # its configuration has no result: it runs on resume
                    self.stop_reason = str(stopped)
                    return "failed"
                return "interrupted"
        except KeyboardInterrupt:  # a second Ctrl-C, even while the first one is being honoured: stop at once
            abandon = True
            self.stop_reason = "stopped at once (second interrupt): analyses in progress were not recorded"
            return "interrupted"
        finally:
            self._analysis.shutdown(wait=not abandon, cancel_futures=abandon)
            self._side_detector.shutdown(wait=True)
            # Detections still queued are of configurations that will not be analysed; their documents
            # (keep_frames) still wait for them, unless the run stops at once.
            self._detector.shutdown(wait=not abandon, cancel_futures=abandon)
            try:
                self._sync_recording()
            finally:
                self._recorder.shutdown(wait=True)

    def _configuration_of(self, config_id: str) -> Configuration | Visit | None:
        """The configuration (or visit) a group of steps belongs to; None for the extrinsics preparation."""
        if is_prepare_id(config_id):
            return None
        return self.configurations.get(config_id) or self.visits[config_id]

    # One handler per step kind (plan.Step): a new kind is its class in plan/steps.py and one handler here.
    # ``failed`` is the reason its configuration failed so far (only steps that close a group see one).

    @functools.singledispatchmethod
    def _execute(self, step, captured: Captured, failed: str | None) -> None:
        raise TypeError(f"unknown step {step!r}")

    @_execute.register
    def _(self, step: Move, captured: Captured, failed: str | None) -> None:
        captured.axes, captured.approach = self._move(captured.configuration)

    @_execute.register
    def _(self, step: PromptTarget, captured: Captured, failed: str | None) -> None:
        self._set_by_hand(captured.configuration, "target_distance_mm", step.distance_mm)

    @_execute.register
    def _(self, step: PromptManual, captured: Captured, failed: str | None) -> None:
        self._set_by_hand(captured.configuration, step.quantity, step.value)

    @_execute.register
    def _(self, step: PlaceBoard, captured: Captured, failed: str | None) -> None:
        prompt = self.bench.presenter.place_board(np.array(step.T_rig_board, float).reshape(4, 4))
        if prompt is not None:
            self._ask(prompt)

    @_execute.register
    def _(self, step: Settle, captured: Captured, failed: str | None) -> None:
        self.bench.clock.wait(step.seconds, self._stop)

    @_execute.register
    def _(self, step: Flush, captured: Captured, failed: str | None) -> None:
        self.bench.cameras.flush()

    @_execute.register
    def _(self, step: CaptureCalibration, captured: Captured, failed: str | None) -> None:
        self._capture_calibration(step.n_views, captured)

    @_execute.register
    def _(self, step: CaptureMeasurement, captured: Captured, failed: str | None) -> None:
        self._capture_measurement(step.n_frames, captured)
        self._record_truth(captured)

    @_execute.register
    def _(self, step: Checkpoint, captured: Captured, failed: str | None) -> None:
        self._checkpoint(captured.configuration, captured, failed)

    @_execute.register(VisitDone)
    @_execute.register(PrepareExtrinsics)
    def _(self, step, captured: Captured, failed: str | None) -> None:
        self._prepare_step(step, captured, failed)

    def _ask(self, prompt: Prompt) -> Answer:
        """Put an operator step to the operators (first answer wins) and record who did it, and how.

        The cameras are lent to a preview meanwhile: nothing is captured while the operator works. Results
        finished meanwhile are published (the operator sees the last configuration's result while setting
        up the next).
        """
        with self.bench.camera_gate.lent():
            answer = self.desk.ask(prompt, stop=self._stop, while_waiting=lambda: self._collect(block=False))
        self._publish(Draft(PromptEvent, config_id=prompt.config_id, data={
            "prompt": prompt.kind, "message": prompt.message, "quantity": prompt.quantity, "value": prompt.value,
            "index": prompt.index, "answered_by": answer.operator, "waited_s": answer.waited_s,
            **({"action": answer.action} if answer.action != CONTINUE else {}),
            **({"action_value": answer.value} if answer.value is not None else {})}))
        return answer

    def _set_by_hand(self, configuration: Configuration, quantity: str, value: float) -> None:
        self._ask(manual_prompt(quantity, value, config_id=configuration.config_id))

    def _trust_position(self) -> None:
        """``[rig] homing = false``: the user states the rig stands where its controller counts, as ``rig unlock
        --trust-position`` does; recorded, since every move of the run rests on it. A rig that cannot be told
        (a replay) has nothing to trust."""
        self._trusted = True
        if not self.bench.rig.capabilities.trust_position:
            return
        reading = self.bench.rig.trust_position()
        self._publish(Draft(RigPositionTrustedEvent, data={
            "rig": reading.to_dict(), "reason": "[rig] homing = false: the position the controller reports is taken "
                                                "as right without homing"}))

    def _home(self) -> None:
        reading = self.bench.rig.home()
        self._homed_at(reading)
        self._publish(Draft(HomeEvent, data={"rig": reading.to_dict()}))

    def _move(self, configuration: Configuration | Visit) -> tuple[dict, dict]:
        """Move to ``configuration``; returns the kinematic axes the rig reported and the approach directions."""
        from drivers.rig.config import RigError

        # The motors only: the operator sets the manual quantities in the prompt steps that follow.
        request = {quantity: None if quantity in self._manual_quantities else value
                   for quantity, value in configuration.move_request().items()}
        while True:
            try:
                if not self._homed:  # the first move homes first, so nothing moves when nothing is left to run
                    self._home()
                elif not self.bench.homes and not self._trusted:
                    self._trust_position()
                self._approach_as_planned(configuration)
                reading = self._move_once(request)
                break
            except RigError as error:
                if self._stop.is_set():  # a feed hold for Ctrl-C surfaces here as a move error
                    raise StopRequested() from None
                if self._feed_held:  # paused mid-move: hold, release the hold, and finish the move
                    self._hold_until_resumed()
                    continue
                self._recover_rig(error, configuration)
                raise ConfigurationFailed(f"rig: {error}") from None
        self._last_index = self._sequence_index.get(configuration.config_id)
        request = configuration.move_request()
        axes = reported_axes(reading, request, self._driven_tilts)
        recorded = self.bench.recorded_approach
        # A replay serves the directions the recording's moves came from (homes of earlier attempts included).
        approach = recorded(configuration.config_id) if recorded is not None else self._approach.reached(axes)
        self._publish(Draft(MoveEvent, config_id=configuration.config_id,
                            data={"rig": reading.to_dict(), "approach": approach}))
        return axes, approach

    def _homed_at(self, reading) -> None:
        """Homing left the rig at ``reading``: where the plan's moves start from, and each axis' approach there."""
        self._homed = True
        # The cycle's last move pulls each axis off its switch: the direction the homed position was reached from.
        self._approach.homed(reported_axes(reading, dict.fromkeys(("baseline_mm", "toe_in_left_deg",
                                                                   "toe_in_right_deg", *self._driven_tilts), 0.0),
                                           self._driven_tilts),
                             self.bench.rig.homing_approach())
        self._last_index = -1
        self._start = self._start or self._motor_position(reading, {})

    def _motor_position(self, reading, fallback: dict) -> dict[str, float]:
        """The motor-driven quantities a reading reports (a quantity it does not report: ``fallback``'s)."""
        position = {}
        for quantity in self._motor_limits:
            value = getattr(reading, quantity, None)
            value = fallback.get(quantity) if value is None else value
            if value is not None:
                position[quantity] = float(value)
        return position

    def _approach_as_planned(self, configuration: Configuration | Visit) -> None:
        """Before a move that does not follow the plan's previous one (a resume: after homing), go where the plan's
        rig came from, each axis from the side it arrived from, and rest (:func:`approach.approach_moves`): the
        move to ``configuration`` is then the uninterrupted run's, and so is what backlash and ringing do to it.
        Each approach move is recorded as an ``approach`` event (a replay serves only the ``move`` events)."""
        index = self._sequence_index.get(configuration.config_id)
        if not self.bench.approaches or not index or self._last_index == index - 1:
            return  # the plan's first move comes from where the run starts, as this one does
        commanded = [{q: v for q, v in entry.move_request().items() if q in self._motor_limits}
                     for entry in self._sequence]
        here = self._motor_position(self.bench.rig.read(), commanded[index])
        self._start = self._start or here  # never homed: the plan's moves start where the rig stands
        moves = approach_moves(commanded, index, here, start=self._start, limits=self._motor_limits)
        for target in moves:
            reading = self._move_once({q: target.get(q) for q in commanded[index]})
            self._approach.reached(reported_axes(reading, {**commanded[index], **target}, self._driven_tilts))
            self._publish(Draft(ApproachEvent, config_id=configuration.config_id,
                                data={"rig": reading.to_dict(), "target": target}))
        if moves:  # rest as at the configuration the plan's rig came from: settled, no longer ringing
            self.bench.clock.wait(self.config.capture.settle_s + self.bench.approach_rest_s, self._stop)
            if self._stop.is_set():
                raise StopRequested()

    def _move_once(self, request: dict):
        """One move, waited on through its status; a pause requested meanwhile feed-holds it (the status then fails
        and :meth:`_move` holds, resumes and queues the move again; see :meth:`request_pause`)."""
        with self._control_lock:
            self._moving = True
        try:
            return self.bench.rig.move_to(**request).wait()
        finally:
            with self._control_lock:
                self._moving = False

    def _recover_rig(self, error: Exception, configuration: Configuration | Visit) -> None:
        """After an alarm or a failed move: a soft reset, then homing, so the next configuration starts from a known
        state. The reset comes first: a controller halted by ALARM:1/2 answers nothing else, not even '?' (homing
        alone was refused), and it discards whatever was still queued; homing then finds the position the alarm (or
        the reset, if the axes were moving) lost. A rig that cannot be recovered ends the run as failed
        (:class:`RigUnrecoverable`): every later configuration would need it."""
        rig = self.bench.rig
        resets = rig.capabilities.reset  # GrblRig.reset(); a rig without one (a replay's) is only homed
        steps = (["soft reset"] if resets else []) + ["homing"]
        step = steps[0]
        try:
            if resets:
                rig.reset()
            step = "homing"
            reading = rig.home()
        except Exception as failure:  # noqa: BLE001 - the campaign cannot go on without a working rig
            self._publish(Draft(RigUnrecoverableEvent, data={"error": f"{step}: {failure}"}))
            same = str(failure) == str(error)  # e.g. a vanished port: the reset fails as the move did
            raise RigUnrecoverable(
                f"rig: {error} (at {configuration.config_id}); recovery ({', then '.join(steps)}) failed at the "
                f"{step}" + ("" if same else f": {failure}")) from failure
        self._homed_at(reading)
        self._publish(Draft(RigRecoveredEvent, data={
            "action": f"{'soft reset, then ' if resets else ''}homed after a failed move"}))

    def _keeps_frames(self, model) -> bool:
        """Whether captures of this kind write their frames to the session (``[capture] keep_frames``)."""
        keep = self.config.capture.keep_frames
        return keep == "all" or (keep == "measurement" and model is MeasurementFrameEvent)

    def _capture(self, model, index: int, configuration: Configuration, **extra) -> tuple[np.ndarray, np.ndarray]:
        return self._record_pair(model, index, configuration, self.bench.cameras.capture_pair(), **extra)

    def _record_pair(self, model, index: int, configuration: Configuration, pair, **extra) -> tuple[np.ndarray,
                                                                                                   np.ndarray]:
        self._publish(Draft(
            model, config_id=configuration.config_id,
            data={"index": index, "dt_s": pair.dt_s, "left": pair.left.describe(), "right": pair.right.describe(),
                  **extra},
            frames={"left": pair.left.image, "right": pair.right.image} if self._keeps_frames(model) else None,
        ))
        return pair.left.image, pair.right.image

    def _publish_detections(self, config_id: str, index: int, found: tuple[Future, Future]) -> None:
        """Record a calibration view's detections (kept instead of its frames) once made, next in the stream."""
        def publish() -> list:
            # A detection that failed is the analysis' to report (one dropped by a stop at once: nobody's).
            sides = [_record_or_none(future) for future in found]
            return self.bus.publish(Draft(CalibrationDetectionsEvent, config_id=config_id, data={
                "index": index, **{side: None if record is None else record.model_dump()
                                   for side, record in zip(("left", "right"), sides, strict=True)}}))

        self._enqueue(publish)

    def _capture_calibration(self, n_views: int, captured: Captured) -> None:
        if self.options.fixed_calibration is not None:
            return
        presenter = self.bench.presenter
        # A fixed-board visit captures the board placed once: nothing is presented, so nothing streams or is timed.
        fixed = bool(getattr(captured.configuration, "board_fixed", False))
        streams = getattr(presenter, "streams", False) and not fixed
        if (not streams and not fixed and self.config.calibration_capture == "auto"
                and self.bench.recorded_views is not None):
            # A replay of views taken automatically: the views the recording kept, as many as it kept.
            n_views = self.bench.recorded_views(captured.configuration.config_id) or n_views
        try:
            prompt = presenter.prepare_calibration(n_views)
        except CalibrationPlacementError as error:
            raise ConfigurationFailed(str(error)) from None
        if prompt is not None:
            self._ask(prompt)
        timed = getattr(presenter, "presents_by_hand", False) and self.bench.now is not None and not fixed
        started_s = self.bench.now() if timed else None
        if streams:
            self._stream_calibration(n_views, captured, started_s)
        else:
            self._take_calibration_views(n_views, captured, started_s)
        if self.bench.recorded_capture is not None:
            # A replay decides nothing and times no operator: it carries over how the recording took its views.
            for event in self.bench.recorded_capture(captured.configuration.config_id):
                self._publish(Draft(type(event), config_id=event.config_id, data=event.data.model_dump()))

    def _presented(self, captured: Captured, started_s: float | None, views: int, seconds: float | None = None) -> None:
        """Record how long the board's presentations took (the next plan's estimate reads it: campaign/presentation.py):
        from the first view asked for to the last one taken, on the bench's clock."""
        if started_s is None or views <= 0:
            return
        if seconds is None:
            seconds = max(self.bench.now() - started_s, 0.0)
        self._publish(Draft(PresentationTimeEvent, config_id=captured.configuration.config_id, data={
            "views": views, "seconds": seconds, "capture": self.config.calibration_capture,
            "clock": "bench" if self.bench.kind in ("simulated", "bring-up") else "wall"}))

    def _stream_calibration(self, n_views: int, captured: Captured, started_s: float | None) -> None:
        """Views taken automatically: pair after pair of the cameras' stream offered to a
        :class:`~stereo_bench.campaign.autocapture.ViewSelector`, which keeps the still, new, whole ones, until the
        coverage gate opens (at least ``n_views``), the operator ends it (Enter) or the presenter has nothing more
        to show. Kept views are recorded as calibration views (``data.auto``: when and why); every pair's decision
        goes into one ``calibration_selection`` event. Pairs not kept are not recorded (their decisions are)."""
        from drivers.camera.stereo import StereoSkewError
        from stereo_bench.campaign.autocapture import AutoCaptureRule, ViewSelector

        presenter = self.bench.presenter
        capture = self.config.capture
        rule = AutoCaptureRule(gate=capture.coverage_gate, min_views=n_views,
                               max_views=max(capture.max_calibration_views, n_views))
        configuration = captured.configuration
        as_detections = not self._keeps_frames(CalibrationViewEvent)
        selector: ViewSelector | None = None
        ticket = None
        prompt_shown_s = None
        offered = unpaired = in_a_row = 0
        ended_by = "the coverage gate"
        first_s = last_s = None
        try:
            while True:
                self._between_steps()
                if selector is not None and selector.gate_open()[0]:
                    break
                if ticket is not None and ticket.done:
                    ended_by = f"the operator ({ticket.answered_by})" if ticket.answered_by else "the operator"
                    break
                if not presenter.next_stream_frame(offered):
                    ended_by = "the presenter (every pose presented)"
                    break
                try:
                    pair = self.bench.cameras.capture_pair()
                except StereoSkewError:  # no pair within [cameras] max_skew_s: the stream goes on without it
                    unpaired += 1
                    in_a_row += 1
                    if in_a_row > MAX_UNPAIRED_IN_A_ROW:
                        raise
                    continue
                in_a_row = 0
                left_image, right_image = pair.left.image, pair.right.image
                if selector is None:
                    height, width = left_image.shape[:2]
                    selector = ViewSelector(rule, self.calibration_board, (width, height))
                left_found = self._side_detector.submit(_detect_or_none_quiet, left_image, self.calibration_board,
                                                        as_detections)
                right = _detect_or_none_quiet(right_image, self.calibration_board, as_detections)
                left = left_found.result()
                time_s = float(pair.left.timestamp_s)
                first_s = time_s if first_s is None else first_s
                last_s = time_s
                decision = selector.offer(time_s, left, right)
                if decision.kept:
                    index = selector.n_kept - 1
                    self._record_pair(CalibrationViewEvent, index, configuration, pair, auto={
                        "time_s": time_s, "offered": offered, "speed_px_s": decision.speed_px_s,
                        "novelty": None if decision.novelty is None or not np.isfinite(decision.novelty)
                        else decision.novelty})
                    found = (_done(left), _done(right))
                    if as_detections:
                        self._publish_detections(configuration.config_id, index, found)
                    if presenter.wants_detections:
                        presenter.calibration_view_captured(index, left, right)
                    captured.calibration_pairs.append((left_image, right_image))
                    captured.calibration_detections.append(found)
                if offered == 0:  # what the operator is told meanwhile (a background prompt: Enter ends it)
                    prompt = presenter.stream_prompt(selector.n_kept, selector.gate_open()[1])
                    if prompt is not None:
                        prompt_shown_s = _wall()
                        ticket = self.desk.open(prompt)
                offered += 1
                self._collect(block=False)
        finally:
            if ticket is not None:
                self.desk.close(ticket, reason=f"done: {ended_by} ended the collection"
                                if not ticket.done else None)
        if ticket is not None:
            self._publish(Draft(PromptEvent, config_id=configuration.config_id, data={
                "prompt": ticket.prompt.kind, "message": ticket.prompt.message, "index": None,
                "answered_by": ticket.answered_by or "coverage gate", "waited_s": max(_wall() - prompt_shown_s, 0.0)}))
        n_kept = 0 if selector is None else selector.n_kept
        collect_s = 0.0 if first_s is None else last_s - first_s
        simulated = self.bench.kind in ("simulated", "bring-up")
        self._publish(Draft(CalibrationSelectionEvent, config_id=configuration.config_id, data={
            "rule": dict(rule.__dict__), "offered": offered, "kept": n_kept, "unpaired": unpaired,
            "tally": {} if selector is None else selector.tally(), "ended_by": ended_by,
            "gate": "nothing offered" if selector is None else selector.gate_open()[1],
            "started_s": first_s, "ended_s": last_s, "collect_s": collect_s,
            "clock": "bench" if simulated else "cameras",
            "decisions": [] if selector is None else [
                (d.time_s, d.reason, d.speed_px_s, None if d.novelty is None or not np.isfinite(d.novelty)
                 else d.novelty) for d in selector.decisions],
            "coverage": None if selector is None else {side: [bar.as_dict() for bar in selector.coverage.bars(side)]
                                                       for side in ("left", "right")}}))
        self._presented(captured, started_s, n_kept)
        self._start_calibration(captured)

    def _take_calibration_views(self, n_views: int, captured: Captured, started_s: float | None) -> None:
        """One view per ``present_calibration_view`` (Enter at the bench; the simulator's next pose; a replay's next
        recorded view), then the review, then the calibration starts."""
        presenter = self.bench.presenter
        as_detections = not self._keeps_frames(CalibrationViewEvent)  # recorded instead of the frames
        index = 0
        presented_s = None
        while True:
            self._between_steps()
            reviewing = index >= n_views  # at the bench: one look at the views before calibrating
            prompt = presenter.review_calibration() if reviewing else presenter.present_calibration_view(index)
            if prompt is not None:
                answer = self._ask(prompt)
                if answer.action == DISCARD_LAST_VIEW and captured.calibration_pairs:
                    index -= 1
                    self._discard_calibration_view(index, captured, answer)
                    continue
            if reviewing:
                self._presented(captured, started_s, len(captured.calibration_pairs), seconds=presented_s)
                self._start_calibration(captured)
                return
            left, right = self._capture(CalibrationViewEvent, index, captured.configuration)
            # Detected once, while the next views are captured; the analysis calibrates from these. A replay
            # of a session that kept the detections instead of the frames serves the recorded ones.
            recorded = presenter.recorded_detections(index)
            if recorded is not None:
                found = (_done(recorded[0]), _done(recorded[1]))
            else:
                # The corner noise of a calibration view is read only where its detections are recorded.
                found = (self._detector.submit(detect, left, self.calibration_board, noise=as_detections),
                         self._detector.submit(detect, right, self.calibration_board, noise=as_detections))
            if as_detections:
                self._publish_detections(captured.configuration.config_id, index, found)
            if presenter.wants_detections:  # coverage feedback for an operator
                presenter.calibration_view_captured(index, found[0].result(), found[1].result())
            captured.calibration_pairs.append((left, right))
            captured.calibration_detections.append(found)
            index += 1
            if started_s is not None and index >= n_views:  # the last view is taken: its review is not presenting
                presented_s = max(self.bench.now() - started_s, 0.0)

    def _start_calibration(self, captured: Captured) -> None:
        """Per-config extrinsics: calibrate from the views just taken while the measurement frames are captured.

        The same computation :meth:`_analyse` would otherwise start after the measurement frames (so the same
        numbers); queued on the analysis pool before that configuration's ``_analyse``, which waits for it.
        The pool takes tasks in order, so a waiting ``_analyse`` never holds up the calibration it waits for.
        """
        if not isinstance(captured.configuration, Configuration):
            return
        calibration = self.config.calibration
        captured.exclude = {i: "excluded by [calibration] exclude_views" for i in calibration.exclude_views
                            if i < len(captured.calibration_pairs)}
        captured.max_view_rms_px = calibration.max_view_rms_px
        recorded = self.bench.recorded_exclusions
        if recorded is not None:  # a replay: what the operator's review chose when it was recorded
            chosen = recorded(captured.configuration.config_id)
            if chosen is not None:
                captured.exclude, captured.max_view_rms_px = dict(chosen[0]), chosen[1]
        elif (calibration.review_for(self.config.cameras.kind) and self._extrinsics.calibrates_each_configuration
              and captured.calibration_pairs):
            self._review_calibration(captured)
            return
        self._extrinsics.after_calibration_views(
            captured, lambda: self._analysis.submit(self._calibrate, captured))

    def _calibrate(self, captured: Captured) -> ConfigurationAnalysis:
        options = self.options
        calibration = self.config.calibration
        exclude = captured.exclude
        if exclude is None:
            exclude = {i: "excluded by [calibration] exclude_views" for i in calibration.exclude_views}
        threshold = captured.max_view_rms_px if captured.exclude is not None else calibration.max_view_rms_px
        return calibrate_configuration(captured.calibration_pairs, self.calibration_board,
                                       intrinsics=options.intrinsics, mode=options.intrinsics_mode,
                                       intrinsics_covariance=options.intrinsics_covariance,
                                       detections=captured.detections(),
                                       lens_model=self.config.extrinsics.lens_model_for(self.config.cameras.kind),
                                       exclude=exclude, max_view_rms_px=threshold)

    def _review_calibration(self, captured: Captured) -> None:
        """The operator's review of a configuration's per-view errors before it is measured (``[calibration]
        review``): a one-screen summary (:func:`stereo_bench.campaign.review.review_message`) whose answers set the
        threshold (``t PX``), exclude or include a view (``x N``), recalibrate (``r``) or accept (Enter). The
        calibration accepted is the one measured with (a failed one fails the configuration); what it left out is
        recorded (``calibration_exclusions``), and a replay leaves out the same."""
        from stereo_bench.campaign.review import ReviewState, review_prompt

        config_id = captured.configuration.config_id
        state = ReviewState(n_views=len(captured.calibration_pairs), exclude=dict(captured.exclude or {}),
                            threshold=captured.max_view_rms_px)
        recalibrations = 0
        while True:
            captured.exclude, captured.max_view_rms_px = dict(state.exclude), state.threshold
            calibrated: Future = self._analysis.submit(self._calibrate, captured)
            try:
                state.shown(calibrated.result(), None)
            except AnalysisError as error:
                state.shown(None, str(error))
            while True:
                answer = self._ask(review_prompt(config_id, state))
                if answer.action == CONTINUE or state.answer(answer.action, answer.value):
                    break  # accepted, or recalibrate
            if answer.action == CONTINUE:
                break
            recalibrations += 1
        captured.exclude, captured.max_view_rms_px = state.applied_exclude, state.applied_threshold
        captured.calibration = calibrated  # the one shown and accepted: measured with, or failing the configuration
        self._publish(Draft(CalibrationExclusionsEvent, config_id=config_id, data={
            "excluded": [[index, why] for index, why in sorted(state.applied_exclude.items())],
            "max_view_rms_px": state.applied_threshold, "recalibrations": recalibrations,
            "answered_by": answer.operator}))

    def _discard_calibration_view(self, index: int, captured: Captured, answer: Answer) -> None:
        """Drop kept view ``index`` (the last one) so that it is taken again; its frames stay recorded."""
        captured.calibration_pairs.pop()
        captured.calibration_detections.pop()
        self.bench.presenter.calibration_view_discarded(index)
        self._publish(Draft(CalibrationViewDiscardedEvent, config_id=captured.configuration.config_id,
                            data={"index": index, "answered_by": answer.operator}))

    def _capture_measurement(self, n_frames: int, captured: Captured) -> None:
        """Capture ``n_frames`` frames of the target; a frame without the target is captured again.

        Up to ``board_retries`` re-captures per frame (every capture is recorded, with its ``retry``
        number and whether the target was found); the detections travel on to the analysis, so
        nothing is detected twice. A frame that never shows the target is kept: the analysis then
        records why the configuration failed.
        """
        configuration = captured.configuration
        partial = configuration.fraction_in_both < 1.0
        for index in range(n_frames):
            for retry in range(self.options.board_retries + 1):
                self._between_steps()
                prompt = self.bench.presenter.present_target(index)
                if prompt is not None:
                    self._ask(prompt)
                left, right = self._capture(MeasurementFrameEvent, index, configuration, retry=retry)
                left_found = self._side_detector.submit(_detect_or_none, left, self.target, partial)
                right_found = _detect_or_none(right, self.target, partial)
                found = (left_found.result(), right_found)
                if all(d is not None for d in found):
                    break
                ambiguous = any(d is _AMBIGUOUS for d in found)
                self._publish(Draft(TargetNotFoundEvent, config_id=configuration.config_id, data={
                    "index": index, "retry": retry, "ambiguous": ambiguous,
                    "missing": [side for side, d in zip(("left", "right"), found, strict=True)
                                if d is None or d is _AMBIGUOUS]}))
            captured.measurement_pairs.append((left, right))
            # An ambiguous partial view is left to the analysis to detect again, so its reason is kept.
            captured.measurement_detections.append(None if _AMBIGUOUS in found else found)

    def _record_truth(self, captured: Captured) -> None:
        """Simulated benches: the truth at the measurement, recorded beside it (the measurement never sees it)."""
        truth = self.bench.truth
        if truth is None:
            return
        captured.truth = truth(captured.configuration.config_id)
        if captured.truth is not None:
            self._publish(Draft(TruthEvent, config_id=captured.configuration.config_id, data=captured.truth))

    # -- the extrinsics source: visits, then one preparation (campaign/extrinsics_run.py) ------------------------

    def _prepare_step(self, step, captured: Captured, failed: str | None) -> None:
        if isinstance(step, VisitDone):
            if not step.skipped:
                self._visit_captures.append(captured if failed is None else Captured(captured.configuration))
            return
        captures, self._visit_captures = self._visit_captures, []
        # A stage prepared before (a fixed-board design's lens calibration) is the next one's input: on the
        # analysis thread, after it (submitted first); a resume that skipped it has it in the options.
        earlier = self._prepared
        self._prepared = self._analysis.submit(self._prepare, step.purpose, captures, earlier)
        self._pending.append((Captured(None), self._prepared))

    def _prepare(self, purpose: str, captures: list[Captured], earlier: Future | None):
        """Runs on the analysis thread: the extrinsics source's preparation from ``captures``."""
        return self._extrinsics.prepare(captures, self.config, self.options, purpose=purpose,
                                        earlier=earlier.result() if earlier is not None else self._given())

    def _given(self):
        """What the run was given before any visit (or a resume read back): a model, intrinsics, a lens calibration."""
        from stereo_bench.campaign.extrinsics_run import Prepared

        return Prepared(kinematic_model=self.options.kinematic_model,
                        nominal_intrinsics=self.options.nominal_intrinsics, lens=self.options.lens_calibration)

    def _source(self):
        """The prepared extrinsics source (analysis thread): a fitted model, or the intrinsics for nominal."""
        if self._prepared is None:
            return self._given()
        return self._prepared.result()

    # -- analysis and results ------------------------------------------------------------------------------------

    def _checkpoint(self, configuration: Configuration, captured: Captured, failed: str | None) -> None:
        if captured.calibration is not None and (failed is not None or not captured.measurement_pairs):
            captured.calibration.cancel()  # not analysed: a calibration not yet started need not run
        if not configuration.runnable:
            status = "infeasible" if not configuration.feasible else "limit"
            self._pending.append((Captured(configuration), _done(result_fields(
                configuration, status=status, reason=configuration.skip_reason))))
        elif failed is not None or not captured.measurement_pairs:
            self._pending.append((Captured(configuration), _done(result_fields(
                configuration, status="failed", reason=failed or "nothing captured"))))
        else:
            self._pending.append((captured, self._analysis.submit(self._analyse, captured)))

    def _analyse(self, captured: Captured) -> dict:
        """Runs on the analysis thread: no recording here, only computation."""
        configuration = captured.configuration
        options = self.options
        try:
            analysis, source = self._extrinsics.analyse(options, self._source(), captured,
                                                        calibrate=lambda: self._calibrate(captured))
            measure_configuration(analysis, captured.measurement_pairs, self.target,
                                  partial=configuration.fraction_in_both < 1.0,
                                  detections=captured.measurement_detections)
        except AnalysisError as error:
            return result_fields(configuration, status="failed", reason=str(error))
        row = result_fields(configuration, status="measured", measured=analysis.row())
        comparison = self._extrinsics.compare(options, self._source(), configuration, captured, analysis,
                                              self.target, used=source)
        row.update(comparison.columns)
        row["_analysis"] = analysis
        row["_structure"] = comparison.data
        return row

    def _collect(self, *, block: bool) -> None:
        """Publish finished analyses in plan order (a result only after all earlier ones)."""
        while self._pending:
            captured, future = self._pending[0]
            if not block and not future.done():
                return
            row = future.result()
            self._pending.pop(0)
            if captured.configuration is None:  # the extrinsics source was prepared: record it
                self._record_prepared(row)
                continue
            analysis = row.pop("_analysis", None)
            structure = row.pop("_structure", None)
            config_id = captured.configuration.config_id
            if analysis is not None:
                if analysis.calibrated and self._extrinsics.calibrates_each_configuration:
                    self._publish(Draft(CalibrationEvent, config_id=config_id, calibration=CalibrationFiles(
                        analysis.calib, analysis.rect, board=self.options.calibration_board)))
                self._publish(Draft(AnalysisEvent, config_id=config_id, data=analysis.details()))
            if structure is not None:
                self._publish(Draft(StructureEvent, config_id=config_id, data=structure))
            # A result is the checkpoint: everything of its configuration is on disk before it, since the
            # recorder writes in order. The capture goes on meanwhile (a crash before the line is written
            # runs the configuration again on resume); the run ends only once everything is recorded.
            self._publish(Draft(ResultDocument, config_id=config_id, row=row))


    def _record_prepared(self, prepared) -> None:
        """Record what the visits prepared: the kinematic model (with its TOML) or the intrinsics' calibration."""
        if prepared.kinematic_model is not None:
            self.kinematic_model = prepared.kinematic_model
        for draft in prepared.drafts(self.options.calibration_board):
            self._publish(draft)
        self._sync_recording()


_AMBIGUOUS = object()  # a partial view whose corner ids cannot be proven


def _detect_or_none(image: np.ndarray, target, partial: bool):
    """The target's detection, None when it is absent, _AMBIGUOUS when its corner ids cannot be proven."""
    try:
        return detect(image, target, partial=partial)
    except AmbiguousViewError:
        return _AMBIGUOUS


def _detect_or_none_quiet(image: np.ndarray, board, noise: bool):
    """A streamed pair's detection of the calibration board, None when it is absent or cannot be read."""
    try:
        return detect(image, board, noise=noise)
    except (ValueError, AmbiguousViewError, np.linalg.LinAlgError):
        return None


def _wall() -> float:
    """Monotonic wall seconds: how long a prompt waited for the operator (as the operator desk measures it)."""
    import time

    return time.monotonic()


def _record_or_none(future: Future):
    """A detection's record, or None if it failed or was cancelled (also while this waits for it: a stop at once
    cancels what is queued, so checking ``cancelled()`` first and then waiting would race)."""
    try:
        detection = future.result()
    except Exception:  # noqa: BLE001 - cancelled (CancelledError is one), or failed: the analysis' to report
        return None
    return DetectionRecord.of(detection)


def _done(value) -> Future:
    future: Future = Future()
    future.set_result(value)
    return future


def step_config_id(step) -> str | None:
    """The configuration a step names, if it names one (moves and checkpoints do): its ``StepKind.config_id``."""
    return step.config_id


def group_steps(steps: list) -> list[tuple[str, list]]:
    """[(config_id, steps)]: a step that names no configuration belongs to the one before it."""
    groups: list[tuple[str, list]] = []
    for step in steps:
        config_id = step_config_id(step)
        if config_id is not None and (not groups or groups[-1][0] != config_id):
            groups.append((config_id, []))
        if not groups:
            raise ValueError(f"plan starts with {step!r}, which names no configuration")
        groups[-1][1].append(step)
    return groups
