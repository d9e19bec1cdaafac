"""The runner: executes a campaign's steps on any rig and cameras that implement the drivers' protocols.

One runner owns execution (STYLE.md, bluesky's RunEngine): it moves the rig, waits for it to settle,
flushes stale frames, has the presenter put boards in front of the cameras, captures and records
every frame as it comes, and hands each configuration's frames to an analysis thread, so the
calibration and measurement of one configuration overlap the motion to the next. Results are
written in plan order, each one only when its configuration is complete: that is the checkpoint a
resume starts from.

Faults: a configuration that fails (board not found after retries, calibration impossible, an
alarm) is recorded as failed with its reason and the campaign goes on; an alarm is cleared by
homing again first. Ctrl-C (``request_stop``) feeds-hold the rig, finishes nothing new, records
what is complete, and leaves the session resumable.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stereo_bench.campaign.analysis import AnalysisError, calibrate_configuration, measure_configuration
from stereo_bench.campaign.plan import (
    CaptureCalibration,
    CaptureMeasurement,
    Checkpoint,
    Configuration,
    Flush,
    Move,
    PromptManual,
    PromptTarget,
    Settle,
)
from stereo_bench.campaign.presenters import CalibrationPlacementError, Presenter
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.detect import AmbiguousViewError, detect
from stereo_bench.vision.rectify import rectify


class StopRequested(Exception):
    """Raised inside the runner when the operator asked it to stop."""


class ConfigurationFailed(Exception):
    """The configuration cannot be completed; the message is the reason recorded with it."""


@dataclass
class Captured:
    """What was captured at one configuration (images stay in memory until the analysis is done)."""

    configuration: Configuration
    rig_reading: dict = field(default_factory=dict)
    calibration_pairs: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    measurement_pairs: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    measurement_detections: list[tuple] = field(default_factory=list)  # (left, right) Detection | None


@dataclass
class RunnerOptions:
    settle_s: float = 0.3
    board_retries: int = 3
    time_scale: float = 1.0  # simulated rig only: waits are divided by it
    intrinsics_mode: str = "joint"
    intrinsics: tuple | None = None  # (K1, D1, K2, D2) to start from / keep fixed
    fixed_calibration: StereoCalibration | None = None  # extrinsics mode "fixed"


def result_row(configuration: Configuration, *, status: str, reason: str | None = None,
               measured: dict | None = None, attempt: int = 1) -> dict:
    """One row of the results table."""
    row = {
        "config_id": configuration.config_id, "baseline_mm": configuration.baseline_mm,
        "distance_mm": configuration.distance_mm, "alpha_deg": configuration.alpha_deg,
        "toe_in_deg": configuration.toe_in_deg, "tilt_deg": configuration.tilt_deg,
        "fraction_in_both": configuration.fraction_in_both, "status": status, "reason": reason,
        "square_mean_mm": None, "square_std_mm": None, "n_squares": 0, "error_mm": None, "sigma_mm": None,
        "rms_px": None, "epipolar_rms_px": None, "attempt": attempt,
    }
    row.update(measured or {})
    return row


class CampaignRunner:
    """Runs ``steps`` (from :func:`stereo_bench.campaign.plan.plan_steps`) and records them with ``writer``.

    ``rig`` implements drivers.rig.rig.Rig; ``cameras`` a stereo camera (``capture_pair()``,
    ``flush()``); ``presenter`` a :class:`Presenter`. ``on_result(row)`` is called after each result.
    """

    def __init__(
        self, config, configurations: list[Configuration], steps: list, *, rig, cameras, presenter: Presenter,
        writer, options: RunnerOptions,
        on_result: Callable[[dict], None] | None = None, on_step: Callable[[Any], None] | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ):
        self.config = config
        self.configurations = {c.config_id: c for c in configurations}
        self.steps = steps
        self.rig = rig
        self.cameras = cameras
        self.presenter = presenter
        self.writer = writer
        self.options = options
        self.on_result = on_result or (lambda row: None)
        self.on_step = on_step or (lambda step: None)
        self.sleep = sleep
        self.calibration_board = config.calibration_board.build()
        self.target = config.target.build()
        self._stop = threading.Event()
        self._analysis = ThreadPoolExecutor(max_workers=1, thread_name_prefix="analysis")
        # Every write to the session goes through one recorder thread, in submission order: PNG
        # encoding and fsync then overlap the next capture instead of delaying it.
        self._recorder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="recorder")
        self._recording: list[Future] = []
        self._pending: list[tuple[Captured, Future]] = []

    # -- control -------------------------------------------------------------------------------------------------

    def request_stop(self) -> None:
        """Stop at the next safe point (thread- and signal-safe); a move in progress is feed-held."""
        self._stop.set()
        try:
            self.rig.stop()
        except Exception:  # noqa: BLE001 - the rig may be mid-reply; the runner re-reads it at the safe point
            pass

    def _record(self, method: str, *args, **kwargs) -> None:
        """Queue a session write (``writer.<method>(*args, **kwargs)``); failures surface at the next sync."""
        self._recording.append(self._recorder.submit(getattr(self.writer, method), *args, **kwargs))
        if len(self._recording) > 64:
            self._sync_recording(keep=32)

    def _sync_recording(self, keep: int = 0) -> None:
        """Wait until all but ``keep`` queued writes are on disk; re-raise the first failure."""
        while len(self._recording) > keep:
            self._recording.pop(0).result()

    def _check_stop(self) -> None:
        if self._stop.is_set():
            raise StopRequested()

    # -- execution -----------------------------------------------------------------------------------------------

    def run(self, *, skip: set[str] = frozenset()) -> str:
        """Execute the steps of every configuration not in ``skip``; returns the exit status."""
        try:
            for config_id, group in group_steps(self.steps):
                if config_id in skip:
                    continue
                configuration = self.configurations[config_id]
                captured, failed = Captured(configuration), None
                for step in group:
                    self._check_stop()
                    self.on_step(step)
                    if isinstance(step, Checkpoint):
                        self._checkpoint(configuration, captured, failed)
                    elif failed is None:
                        try:
                            self._execute(step, captured)
                        except ConfigurationFailed as error:
                            failed = str(error)
                    self._collect(block=False)
            self._collect(block=True)
            return "success"
        except (StopRequested, KeyboardInterrupt):
            self._collect(block=True)
            return "interrupted"
        finally:
            self._analysis.shutdown(wait=True)
            try:
                self._sync_recording()
            finally:
                self._recorder.shutdown(wait=True)

    def _execute(self, step, captured: Captured | None) -> None:
        if isinstance(step, Move):
            self._move(step.configuration, captured)
        elif isinstance(step, PromptTarget | PromptManual):
            pass  # GrblRig.move_to asks the operator for manual quantities through its prompt callback
        elif isinstance(step, Settle):
            self.sleep(step.seconds / self.options.time_scale)
        elif isinstance(step, Flush):
            self.cameras.flush()
        elif isinstance(step, CaptureCalibration):
            self._capture_calibration(step.n_views, captured)
        elif isinstance(step, CaptureMeasurement):
            self._capture_measurement(step.n_frames, captured)
        else:
            raise TypeError(f"unknown step {step!r}")

    def _move(self, configuration: Configuration, captured: Captured) -> None:
        from drivers.rig.config import RigError

        try:
            reading = self.rig.move_to(**configuration.move_request())
        except RigError as error:
            self._check_stop()  # a feed hold for Ctrl-C surfaces here as a move error
            self._recover_rig()
            raise ConfigurationFailed(f"rig: {error}") from None
        captured.rig_reading = reading.to_dict()
        self._record("event", "move", config_id=configuration.config_id, data={"rig": captured.rig_reading})

    def _recover_rig(self) -> None:
        """After an alarm or a failed move, home again so the next configuration starts from a known state."""
        try:
            self.rig.home()
            self._record("event", "rig_recovered", data={"action": "homed after a failed move"})
        except Exception as error:  # noqa: BLE001 - the campaign cannot go on without a working rig
            self._record("event", "rig_unrecoverable", data={"error": str(error)})
            raise StopRequested() from error

    def _capture(self, kind: str, index: int, configuration: Configuration, **extra) -> tuple[np.ndarray, np.ndarray]:
        pair = self.cameras.capture_pair()
        self._record(
            "event", kind, config_id=configuration.config_id,
            data={"index": index, "dt_s": pair.dt_s, "left": pair.left.describe(), "right": pair.right.describe(),
                  **extra},
            frames={"left": pair.left.image, "right": pair.right.image},
        )
        return pair.left.image, pair.right.image

    def _capture_calibration(self, n_views: int, captured: Captured) -> None:
        configuration = captured.configuration
        if self.options.fixed_calibration is not None:
            return
        try:
            self.presenter.begin_configuration(configuration.config_id, configuration.rig_pose(),
                                               configuration.distance_mm, n_views,
                                               calibration_range_mm=configuration.calibration_range_mm)
        except CalibrationPlacementError as error:
            raise ConfigurationFailed(str(error)) from None
        for index in range(n_views):
            self._check_stop()
            self.presenter.present_calibration_view(index)
            left, right = self._capture("calibration_view", index, configuration)
            if getattr(self.presenter, "wants_detections", False):  # coverage feedback for an operator
                self.presenter.calibration_view_captured(
                    index, detect(left, self.calibration_board), detect(right, self.calibration_board))
            captured.calibration_pairs.append((left, right))

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
                self._check_stop()
                self.presenter.present_target(index)
                left, right = self._capture("measurement_frame", index, configuration, retry=retry)
                found = tuple(_detect_or_none(image, self.target, partial) for image in (left, right))
                if all(d is not None for d in found):
                    break
                ambiguous = any(d is _AMBIGUOUS for d in found)
                self._record("event", "target_not_found", config_id=configuration.config_id,
                             data={"index": index, "retry": retry,
                                   "missing": [side for side, d in zip(("left", "right"), found, strict=True)
                                               if d is None or d is _AMBIGUOUS],
                                   "ambiguous": ambiguous})
            captured.measurement_pairs.append((left, right))
            # An ambiguous partial view is left to the analysis to detect again, so its reason is kept.
            captured.measurement_detections.append(None if _AMBIGUOUS in found else found)

    # -- analysis and results ------------------------------------------------------------------------------------

    def _checkpoint(self, configuration: Configuration, captured: Captured, failed: str | None) -> None:
        if not configuration.runnable:
            status = "infeasible" if not configuration.feasible else "limit"
            reason = configuration.skip_reason
            self._pending.append((Captured(configuration), _done(result_row(
                configuration, status=status, reason=reason, attempt=self.writer.attempt))))
        elif failed is not None or not captured.measurement_pairs:
            self._pending.append((Captured(configuration), _done(result_row(
                configuration, status="failed", reason=failed or "nothing captured", attempt=self.writer.attempt))))
        else:
            self._pending.append((captured, self._analysis.submit(self._analyse, captured)))

    def _analyse(self, captured: Captured) -> dict:
        """Runs on the analysis thread: no recording here, only computation."""
        configuration = captured.configuration
        options = self.options
        try:
            if options.fixed_calibration is not None:
                from stereo_bench.campaign.analysis import ConfigurationAnalysis

                analysis = ConfigurationAnalysis(calib=options.fixed_calibration,
                                                 rect=rectify(options.fixed_calibration))
            else:
                analysis = calibrate_configuration(captured.calibration_pairs, self.calibration_board,
                                                   intrinsics=options.intrinsics, mode=options.intrinsics_mode)
            measure_configuration(analysis, captured.measurement_pairs, self.target,
                                  partial=configuration.fraction_in_both < 1.0,
                                  detections=captured.measurement_detections)
        except AnalysisError as error:
            return result_row(configuration, status="failed", reason=str(error), attempt=self.writer.attempt)
        row = result_row(configuration, status="measured", measured=analysis.row(), attempt=self.writer.attempt)
        row["_analysis"] = analysis
        return row

    def _collect(self, *, block: bool) -> None:
        """Record finished analyses in plan order (a result is written only after all earlier ones)."""
        while self._pending:
            captured, future = self._pending[0]
            if not block and not future.done():
                return
            row = future.result()
            self._pending.pop(0)
            analysis = row.pop("_analysis", None)
            config_id = captured.configuration.config_id
            if analysis is not None:
                if self.options.fixed_calibration is None:
                    self._record("write_calibration", config_id, analysis.calib, analysis.rect,
                                 board=self.calibration_board_description())
                self._record("event", "analysis", config_id=config_id, data=analysis.details())
            # A result is the checkpoint: everything of its configuration must be on disk first.
            self._record("result", config_id, row)
            self._sync_recording()
            self.on_result(row)

    def calibration_board_description(self) -> str:
        board = self.config.calibration_board
        return f"{board.kind} {board.cols}x{board.rows} square {board.square_mm:g} mm"


_AMBIGUOUS = object()  # a partial view whose corner ids cannot be proven


def _detect_or_none(image: np.ndarray, target, partial: bool):
    """The target's detection, None when it is absent, _AMBIGUOUS when its corner ids cannot be proven."""
    try:
        return detect(image, target, partial=partial)
    except AmbiguousViewError:
        return _AMBIGUOUS


def _done(row: dict) -> Future:
    future: Future = Future()
    future.set_result(row)
    return future


def step_config_id(step) -> str | None:
    """The configuration a step names, if it names one (moves and checkpoints do)."""
    configuration = getattr(step, "configuration", None)
    if configuration is not None:
        return configuration.config_id
    return getattr(step, "config_id", None)


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
