"""What the live page shows, folded from the campaign's own document stream (a bus subscriber).

Everything comes from documents as they are recorded (plan and config from ``start``, rig positions
from ``home``/``move``, captures, prompts answered, calibrations, analyses, results, ``stop``), plus
three things a recording holds elsewhere: the serial transcript (a session file the ``transcript``
event names), the pending prompt (offered to the page as an operator) and the previews/coverage
(the recorded frames, see preview.py). :meth:`LiveState.snapshot` is the JSON the page renders; every
browser tab gets the same one. ``version`` counts the changes of everything but the preview, which
has a version of its own (``preview["version"]``): the server sends the two as separate events.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path

from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.coverage import Coverage
from stereo_bench.campaign.documents import (
    AnalysisEvent,
    ApproachEvent,
    CalibrationEvent,
    CalibrationViewDiscardedEvent,
    CalibrationViewEvent,
    Document,
    HomeEvent,
    MeasurementFrameEvent,
    MoveEvent,
    PromptEvent,
    ResultDocument,
    ResumeDocument,
    RigRecoveredEvent,
    RigUnrecoverableEvent,
    RunControlEvent,
    StartDocument,
    StopDocument,
    TargetNotFoundEvent,
    TranscriptEvent,
)
from stereo_bench.campaign.plan import Configuration
from stereo_bench.campaign.recorded import RecordedStart
from stereo_bench.campaign.router import DocumentRouter, handles
from stereo_bench.live.transcript import TranscriptTail

#: Result columns the page shows (the uncertainty columns when a row has them).
RESULT_KEYS = ("config_id", "baseline_mm", "distance_mm", "alpha_deg", "tilt_deg", "status", "reason",
               "square_mean_mm", "error_mm", "sigma_mm", "u_combined_mm", "U_expanded_mm", "rms_px",
               "epipolar_rms_px", "n_squares", "calib_views_used", "calib_views_rejected")
PLAN_QUANTITIES = ("baseline_mm", "distance_mm", "alpha_deg", "tilt_deg")
FINAL = ("measured", "failed", "infeasible", "limit")


def varying_quantities(configurations: Sequence[Configuration]) -> list[str]:
    """The plan's quantities that take more than one value, most values first (the plot's x, then series)."""
    counts = {q: len({getattr(c, q) for c in configurations}) for q in PLAN_QUANTITIES}
    return [q for q in sorted(counts, key=lambda q: -counts[q]) if counts[q] > 1]


def configuration_estimates_s(config: CampaignConfig, configurations: list[Configuration]) -> dict[str, float]:
    """The plan's predicted duration per configuration (motion, settle, frames, operator; no computation)."""
    from stereo_bench.campaign.plan import estimate_duration, plan_steps
    from stereo_bench.campaign.runner import group_steps

    steps = plan_steps(config, configurations)
    return {config_id: estimate_duration(config, configurations, group).total_s
            for config_id, group in group_steps(steps)}


class LiveState(DocumentRouter):
    """The page's state; call it with every document (a DocumentBus subscriber, a router). Thread-safe."""

    def __init__(self, *, session_dir: Path | None = None, rig_config=None, boards: dict | None = None,
                 image_size: tuple[int, int] | None = None, name: str = "", on_change: Callable[[], None] = None,
                 clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.session_dir = None if session_dir is None else Path(session_dir)
        self.boards = boards or {}
        self.image_size = image_size
        self.on_change = on_change or (lambda: None)
        self.clock = clock
        self.transcript = TranscriptTail(rig_config)
        self._lock = threading.RLock()
        self.version = 0
        self.run = {"name": name, "session": None if session_dir is None else str(session_dir), "bench": None,
                    "status": "starting", "reason": None, "resume_command": None, "attempt": None}
        self.plan: list[dict] = []
        self.varying: list[str] = []
        self.estimates_s: dict[str, float] = {}
        self.eta_tracker = None  # campaign.eta.EtaTracker once the plan is known
        self.status: dict[str, str] = {}
        self.reasons: dict[str, str] = {}
        self.results: dict[str, dict] = {}
        self._arrivals = 0
        self.on_calibration = None  # (config_id, StereoCalibration): the previews' rectification (LivePage)
        self.current: str | None = None
        self.step = "starting"
        self.rig: dict = {"position": {}, "source": None}
        self.rig_events: list[str] = []
        self.manual: dict[str, float] = {}  # quantities set by hand, as the operator confirmed them
        self.views_expected = 0
        self.coverage: Coverage | None = None
        self.coverage_config: str | None = None
        self.views_taken: list[int] = []
        self.calibration: dict | None = None
        self.prompt: dict | None = None
        self.preview: dict | None = None
        self.paused = False
        self.log: deque[dict] = deque(maxlen=30)
        self._attempt_started: float | None = None
        self._finished_this_attempt = 0
        self._first_move_at: float | None = None

    # -- the document stream ---------------------------------------------------------------------------------

    def __call__(self, document: Document) -> None:
        with self._lock:
            super().__call__(document)
            self.version += 1
        self.on_change()

    @handles(StartDocument)
    def _start(self, doc: StartDocument) -> None:
        self.run.update(bench=doc.bench, status="running", attempt=doc.attempt)
        self._started(doc)
        self._attempt_started = self.clock()

    @handles(ResumeDocument)
    def _resume(self, doc: ResumeDocument) -> None:
        """A resumed session: the plan and the earlier results are in the session (not re-sent on the bus)."""
        self.run.update(status="running", attempt=doc.attempt)
        self._attempt_started = self.clock()
        if doc.config is not None and doc.plan is not None:  # the resume carries what the page shows
            self.run.update(bench=doc.bench)
            self._started_with(RecordedStart.of_resume(doc))
            rows = doc.results or []
        elif self.session_dir is not None:  # a resume recorded before it carried them: the session on disk
            from stereo_bench.campaign.session import SessionReader

            reader = SessionReader(self.session_dir)
            start = reader.start()
            self.run.update(bench=start.bench)
            self._started(start)
            rows = reader.results()
        else:
            return
        for row in rows:
            self._result_row(row.stored())
        self._note(f"resumed (attempt {doc.attempt}): {len(doc.completed)} configurations already complete")

    def _started(self, start: StartDocument) -> None:
        self._started_with(RecordedStart.of(start))

    def _started_with(self, recorded: RecordedStart) -> None:
        """The recorded config and plan: the run's name, the plan, the calibration views to expect."""
        try:
            config = recorded.campaign
        except ValueError:  # a config this version does not validate: no name, no views count, no ETA
            config = None
        if config is not None and config.name:
            self.run["name"] = config.name
        try:
            configurations = recorded.configurations
        except (KeyError, TypeError, ValueError):  # a plan this version does not read: no plan, no ETA
            configurations = []
        try:
            visits = recorded.visits
        except (KeyError, TypeError, ValueError):
            visits = []
        self._set_plan(config, configurations, visits)
        self.views_expected = int(config.capture.calibration_views or 0) if config is not None else 0

    def _set_plan(self, config: CampaignConfig | None, configurations: list[Configuration],
                  visits: Sequence = ()) -> None:
        self.plan = [{key: getattr(c, key) for key in ("config_id", *PLAN_QUANTITIES, "toe_in_deg", "runnable",
                                                       "feasible", "reason", "status")} for c in configurations]
        self.varying = varying_quantities(configurations)
        self.status = {c.config_id: "pending" for c in configurations}
        try:
            self.estimates_s = configuration_estimates_s(config, configurations) if config is not None else {}
        except Exception:  # noqa: BLE001 - e.g. a rig config file missing on this machine: no plan-based ETA
            self.estimates_s = {}
        # The terminal's ETA (campaign/eta.py): the plan's time model corrected by what was measured so far,
        # operator waits included; fed the same events, so the page and the status line agree.
        self.eta_tracker = None
        if config is not None and self.estimates_s:
            from stereo_bench.campaign.eta import EtaTracker, forecast_groups
            from stereo_bench.campaign.plan import plan_steps

            try:
                steps = plan_steps(config, configurations, list(visits))
                self.eta_tracker = EtaTracker(forecast_groups(config, steps), start_s=self.clock())
            except Exception:  # noqa: BLE001 - a plan this version cannot step through: the rate-based ETA
                self.eta_tracker = None

    @handles(TranscriptEvent)
    def _transcript(self, doc: TranscriptEvent) -> None:
        relative = doc.files.get(doc.data.name)
        if relative is None or self.session_dir is None:
            return
        from stereo_bench.campaign.session import SessionError, SessionReader

        try:
            self.transcript.follow(SessionReader(self.session_dir).path(relative))
        except SessionError:
            pass  # a path outside the session is never followed

    def _rig_reading(self, doc, what: str) -> None:
        rig = doc.data.rig
        self.rig = {"position": {q: getattr(rig, q) for q in ("baseline_mm", "toe_in_left_deg", "toe_in_right_deg",
                                                               "tilt_left_deg", "tilt_right_deg",
                                                               "target_distance_mm")},
                    "alpha_left_deg": rig.alpha_left_deg, "alpha_right_deg": rig.alpha_right_deg,
                    "state": rig.state, "source": f"{what} event", "sources": rig.sources}
        if doc.config_id is not None:
            self._running(doc.config_id)
            self.step = f"{doc.config_id}: at position"
            if self._first_move_at is None:
                self._first_move_at = self.clock()
        else:
            self.step = "homed"

    @handles(HomeEvent)
    def _home(self, doc: HomeEvent) -> None:
        self._rig_reading(doc, "home")

    @handles(MoveEvent)
    def _move(self, doc: MoveEvent) -> None:
        self._rig_reading(doc, "move")
        if self.eta_tracker is not None:
            self.eta_tracker.moved(doc.config_id, self.clock())

    @handles(ApproachEvent)
    def _approach(self, doc: ApproachEvent) -> None:
        self._rig_reading(doc, "approach")
        self.step = f"{doc.config_id}: approaching as the plan did (backlash)"

    def _running(self, config_id: str) -> None:
        previous = self.current
        if previous is not None and previous != config_id and self.status.get(previous) == "running":
            self.status[previous] = "analysing"  # captured; its result follows when the analysis is done
        self.current = config_id
        if self.status.get(config_id) == "pending":
            self.status[config_id] = "running"

    @handles(CalibrationViewEvent)
    def _calibration_view(self, doc: CalibrationViewEvent) -> None:
        config_id, index = doc.config_id, doc.data.index
        self._running(config_id)
        if self.coverage_config != config_id:
            self._new_coverage(config_id)
        self.views_taken.append(index)
        self.step = f"{config_id}: calibration view {index + 1}/{self.views_expected or '?'}"

    def _new_coverage(self, config_id: str) -> None:
        self.coverage_config = config_id
        self.views_taken = []
        board = self.boards.get("calibration")
        self.coverage = Coverage(self.image_size, board) if board is not None and self.image_size else None

    @handles(CalibrationViewDiscardedEvent)
    def _discarded(self, doc: CalibrationViewDiscardedEvent) -> None:
        index = doc.data.index
        if self.coverage_config == doc.config_id:
            if self.coverage is not None:
                self.coverage.discard(index)
            if index in self.views_taken:
                self.views_taken.reverse()
                self.views_taken.remove(index)
                self.views_taken.reverse()
        self._note(f"{doc.config_id}: calibration view {index + 1} discarded by {doc.data.answered_by}")

    @handles(MeasurementFrameEvent)
    def _measurement_frame(self, doc: MeasurementFrameEvent) -> None:
        self._running(doc.config_id)
        retry = f" (again, {doc.data.retry})" if doc.data.retry else ""
        self.step = f"{doc.config_id}: measurement frame {doc.data.index + 1}{retry}"

    @handles(TargetNotFoundEvent)
    def _target_not_found(self, doc: TargetNotFoundEvent) -> None:
        self._note(f"{doc.config_id}: target not found in {' and '.join(doc.data.missing)} "
                   f"(frame {doc.data.index + 1}, capture {doc.data.retry + 1})", level="warn")

    @handles(PromptEvent)
    def _prompt_answered(self, doc: PromptEvent) -> None:
        data = doc.data
        if data.quantity is not None and data.value is not None:  # set by hand: what the operator confirmed
            self.manual[data.quantity] = data.value
        if self.eta_tracker is not None and data.waited_s is not None:
            self.eta_tracker.prompt_answered(data.waited_s)
        how = f" ({data.action.replace('_', ' ')})" if data.action else ""
        if data.answered_by != "simulator":
            self._note(f"{data.prompt.replace('_', ' ')} done by {data.answered_by}{how} after {data.waited_s:.1f} s")

    @handles(CalibrationEvent)
    def _calibrated(self, doc: CalibrationEvent) -> None:
        if doc.config_id is None:
            return
        if self.on_calibration is not None and self.session_dir is not None and "intrinsics" in doc.files:
            # The rectified preview: the files are written before the event reaches a subscriber.
            from stereo_bench.vision.calibio import read_calibration

            try:
                where = Path(self.session_dir) / Path(doc.files["intrinsics"]).parent
                self.on_calibration(doc.config_id, read_calibration(where))
            except Exception as error:  # noqa: BLE001 - a preview must never take the campaign down
                self._note(f"rectified preview unavailable: {error}", level="warn")
        self.calibration = {"config_id": doc.config_id, "rms_px": doc.data.rms_px,
                            "baseline_mm": doc.data.baseline_mm, "views_used": doc.data.views_used,
                            "per_view": [], "rejected": []}

    @handles(AnalysisEvent)
    def _analysis(self, doc: AnalysisEvent) -> None:
        calibration = doc.data.calibration
        used = calibration.get("views_used") or []
        per_view = calibration.get("per_view_rms_px") or []
        entry = self.calibration if self.calibration and self.calibration["config_id"] == doc.config_id else None
        if entry is None:
            entry = self.calibration = {"config_id": doc.config_id, "rms_px": calibration.get("rms_px"),
                                        "views_used": used}
        entry["per_view"] = [{"index": i, "left_px": _side(e, 0), "right_px": _side(e, 1)}
                             for i, e in zip(used, per_view, strict=False)]
        entry["rejected"] = list(calibration.get("views_rejected") or [])
        entry["epipolar_rms_px"] = calibration.get("epipolar_rms_px")

    @handles(ResultDocument)
    def _result(self, doc: ResultDocument) -> None:
        row = doc.row.stored()
        self._result_row(row)
        if row.get("status") in ("measured", "failed") and doc.attempt == self.run.get("attempt"):
            self._finished_this_attempt += 1
        if row.get("status") == "failed":
            self._note(f"{doc.config_id} failed: {row.get('reason')}", level="warn")

    def _result_row(self, row: dict) -> None:
        config_id = row["config_id"]
        self.results[config_id] = {key: row.get(key) for key in RESULT_KEYS if row.get(key) is not None}
        self._arrivals += 1
        self.results[config_id]["arrival"] = self._arrivals  # the page lists the newest first
        self.status[config_id] = row.get("status") or "failed"
        if row.get("reason"):
            self.reasons[config_id] = row["reason"]

    @handles(RunControlEvent)
    def _run_control(self, doc: RunControlEvent) -> None:
        self.paused = doc.data.action == "pause"
        self.run["status"] = "paused" if self.paused else "running"
        held = " (the move in progress feed-held)" if doc.data.feed_hold else ""
        self._note(f"{'paused' + held if self.paused else 'resumed'}")

    @handles(RigRecoveredEvent, RigUnrecoverableEvent)
    def _rig_note(self, doc) -> None:
        text = doc.data.action if isinstance(doc, RigRecoveredEvent) else f"rig unrecoverable: {doc.data.error}"
        self.rig_events.append(text)
        self._note(text, level="warn" if isinstance(doc, RigRecoveredEvent) else "error")

    @handles(StopDocument)
    def _stop(self, doc: StopDocument) -> None:
        self.run.update(status=doc.exit_status, reason=doc.reason, resume_command=doc.resume_command)
        self.paused = False
        self.step = f"campaign {doc.exit_status}" + (f": {doc.reason}" if doc.reason else "")
        self.prompt = None

    # -- the other inputs ------------------------------------------------------------------------------------

    def set_prompt(self, prompt: dict | None) -> None:
        with self._lock:
            if self.eta_tracker is not None:
                if prompt is not None and self.prompt is None:
                    self.eta_tracker.prompt_shown(self.clock())
                elif prompt is None:
                    self.eta_tracker.prompt_ended()
            self.prompt = prompt
            self.version += 1
        self.on_change()

    def set_preview(self, meta: dict) -> None:
        """The newest preview (its own ``version``): not a change of the state's version, so that the live
        previews (6 a second while idle) reach the page as small ``preview`` events, not whole snapshots."""
        with self._lock:
            self.preview = meta
        self.on_change()

    def calibration_view_detected(self, config_id: str, index: int, detections: dict) -> None:
        """Full-resolution detections of a recorded calibration view (from the preview worker)."""
        with self._lock:
            if self.coverage_config != config_id or self.coverage is None or index not in self.views_taken:
                return
            for side, detection in detections.items():
                if detection is not None:
                    self.coverage.add(side, index, detection)
            self.version += 1
        self.on_change()

    def requested(self, text: str) -> None:
        """A control the page sent (pause, stop, ...): shown in the log until the run records it."""
        with self._lock:
            self._note(text)
            self.version += 1
        self.on_change()

    def poll_transcript(self) -> bool:
        changed = self.transcript.poll()
        if changed:
            with self._lock:
                self.version += 1
        return changed

    def _note(self, text: str, *, level: str = "info") -> None:
        self.log.appendleft({"time": time.time(), "text": text, "level": level})

    # -- the snapshot ------------------------------------------------------------------------------------------

    def _counts(self) -> dict:
        values = list(self.status.values())
        return {"total": len(values), "measured": values.count("measured"), "failed": values.count("failed"),
                "infeasible": values.count("infeasible") + values.count("limit"),
                "remaining": sum(v not in FINAL for v in values)}

    def _eta(self) -> dict:
        remaining = [entry["config_id"] for entry in self.plan
                     if self.status.get(entry["config_id"]) not in FINAL and entry.get("runnable", True)]
        if not remaining:
            return {"eta_s": 0.0, "basis": "nothing left to run"}
        if self.eta_tracker is not None:
            return {"eta_s": self.eta_tracker.shown(self.clock()),
                    "basis": "the plan's time model corrected by what was measured so far (operator waits "
                             "included; computation not modelled), as the terminal's"}
        if self._finished_this_attempt and self._first_move_at is not None:
            rate = (self.clock() - self._first_move_at) / self._finished_this_attempt
            return {"eta_s": rate * len(remaining),
                    "basis": f"{rate:.0f} s per configuration so far ({self._finished_this_attempt} done)"}
        if self.estimates_s:
            return {"eta_s": sum(self.estimates_s.get(c, 0.0) for c in remaining),
                    "basis": "the plan's estimate (motion, settle, frames, operator; computation not included)"}
        return {"eta_s": None, "basis": "no estimate yet"}

    def current_step(self) -> str:
        if self.prompt is not None:
            return f"waiting for the operator: {self.prompt['message']}"
        if self.paused:
            return "paused"
        state = self.transcript.state or ""
        if state.startswith(("Run", "Jog")) and self.run["status"] == "running":
            return "moving the rig"
        if state.startswith("Home"):
            return "homing"
        return self.step

    def snapshot(self) -> dict:
        """The JSON the page renders (see the module docstring)."""
        with self._lock:
            transcript = self.transcript.snapshot()
            coverage = None
            if self.coverage is not None:
                coverage = {"config_id": self.coverage_config, "views_expected": self.views_expected,
                            "views_taken": len(self.views_taken), **self.coverage.as_dict()}
            plan = [{**entry, "status": self.status.get(entry["config_id"], "pending"),
                     "reason": self.reasons.get(entry["config_id"]) or entry.get("reason")} for entry in self.plan]
            live_position = transcript["position"]
            rig = {**self.rig, "state": transcript["state"] or self.rig.get("state"),
                   "alarms": transcript["alarms"] + self.rig_events[-5:], "transcript": transcript["lines"]}
            if live_position:  # the controller's latest report, converted like the driver does
                rig["position"] = {**rig.get("position", {}), **live_position}
                rig["source"] = "status report"
            for quantity, value in self.manual.items():
                if rig.get("position", {}).get(quantity) is None:
                    rig.setdefault("position", {})[quantity] = value
                    rig.setdefault("manual", []).append(quantity)
            return {
                "version": self.version,
                "run": {**self.run, "paused": self.paused,
                        "elapsed_s": None if self._attempt_started is None else self.clock() - self._attempt_started},
                "plan": {"configs": plan, "varying": self.varying, "counts": self._counts(), "current": self.current,
                         "step": self.current_step(), **self._eta()},
                "rig": rig,
                "coverage": coverage,
                "calibration": self.calibration,
                "results": [self.results[e["config_id"]] for e in self.plan if e["config_id"] in self.results],
                "prompt": self.prompt,
                "preview": self.preview,
                "log": list(self.log),
            }


def _side(error, side: int) -> float | None:
    """One camera's RMS of a per-view entry ([left, right] px; a single number is both)."""
    if isinstance(error, list | tuple):
        return error[side] if len(error) > side else None
    return error


