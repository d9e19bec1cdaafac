"""The bench a campaign runs on: rig, cameras, presenter, operators and clock, from exactly three factories.

    bench = open_bench(config, operators=[TerminalOperator()], transcript=path)   # by config.bench_kind
    with bench:
        runner = CampaignRunner(config, configurations, steps, bench=bench, bus=bus, options=options)

- :func:`simulated_bench`: simulated cameras rendering a simulated scene. The rig is the GRBL emulator
  on a pty (``rig.kind = "simulated"``), or the real controller on ``rig.port`` (``"grbl"``: bring-up
  mode, the cameras render from the positions the controller *reports*).
- :func:`hardware_bench`: the real controller and two V4L2 cameras; the operator presents the boards.
- :func:`replay_bench`: a recorded session's telemetry and frames behind the same protocols.

Which combination is allowed is decided once, by the config (``CampaignConfig.bench_kind``). This
is the only module of ``stereo_bench`` outside the CLI that imports the simulators (``drivers.sim``).
"""

from __future__ import annotations

import contextlib
import functools
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stereo_bench.campaign.camera_gate import CameraGate
from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.operator import Operator, Prompt
from stereo_bench.campaign.plan import Configuration, Visit
from stereo_bench.campaign.presenters import CalibrationPlacementError, OperatorPresenter, Presenter, scene_seed
from stereo_bench.geometry import RigPose, alpha_from_toe_in
from stereo_bench.targets import Target
from stereo_bench.vision.detect import Detection

# (width_px or None) -> (left, right, dt_s): a live preview pair (Bench.grab_preview)
PreviewGrab = Callable[[int | None], tuple[np.ndarray, np.ndarray, float]]


class Clock:
    """The bench's waits (settle times): divided by ``time_scale``, and cut short by a stop request.

    ``advance(seconds)``: a simulated bench's clock, moved on by each wait at once (drivers/sim/clock.py):
    the time the simulation sees pass is the wait's, however long it really took; the real wait only paces.
    """

    def __init__(self, time_scale: float = 1.0, advance: Callable[[float], object] | None = None):
        self.time_scale = time_scale
        self._advance = advance

    def wait(self, seconds: float, stop: threading.Event) -> None:
        if self._advance is not None:
            self._advance(seconds)
        real = seconds / self.time_scale if self.time_scale != math.inf else 0.0
        if real > 0:
            stop.wait(real)


@dataclass
class Bench:
    """What a campaign runs on; :meth:`close` (or the context manager) closes everything the factory opened.

    ``rig`` implements ``drivers.rig.rig.Rig``; ``cameras`` a stereo camera (``capture_pair()``,
    ``flush()``); ``presenter`` a :class:`Presenter`; ``operators`` answer the operator steps;
    ``camera_gate`` lends the cameras to a preview while the runner waits (see camera_gate.py).
    ``truth(config_id)``: a simulated bench's ground truth now (JSON-ready; a replay serves the recorded one),
    recorded beside the measurement and never used by it; None on real hardware.
    ``recorded_approach(config_id)``: a replay serves the directions the recorded moves came from (the
    runner infers them from the positions reported since homing, which a replay does not see).
    ``approaches``: the runner re-approaches a configuration it did not come to from the plan's previous one (a
    resume; ``campaign/approach.py``); a replay serves the recorded moves only. ``approach_rest_s``: how long the
    rig rests after such an approach beyond the settle (a simulated bench: until its heads stop ringing).
    """

    kind: str  # "simulated", "bring-up", "hardware" or "replay"
    rig: Any
    cameras: Any
    presenter: Presenter
    operators: list[Operator]
    clock: Clock
    homes: bool = True  # run the homing cycle before the first move
    camera_gate: CameraGate = field(default_factory=CameraGate)
    preview: PreviewGrab | None = None  # see grab_preview()
    _stack: contextlib.ExitStack = field(default_factory=contextlib.ExitStack, repr=False)
    truth: Callable[[str], dict | None] | None = None
    recorded_approach: Callable[[str], dict] | None = None
    approaches: bool = True
    approach_rest_s: float = 0.0
    # The clock the operator's presentation time is measured on (s): the bench clock of a simulated bench, the
    # wall clock at a real one; None (a replay): not measured.
    now: Callable[[], float] | None = None
    # A replay: the calibration views recorded at a configuration (views taken automatically vary in number).
    recorded_views: Callable[[str], int] | None = None
    # A replay: what the operator's review left out of a configuration's calibration, ({index: why}, threshold px),
    # or None where it recorded no review.
    recorded_exclusions: Callable[[str], tuple[dict[int, str], float | None] | None] | None = None
    # A replay: how a configuration's calibration views were taken, as recorded (its last ``calibration_selection``
    # and ``presentation_time`` events: the replay copies them, as it takes no decision and measures no operator).
    recorded_capture: Callable[[str], list] | None = None

    def grab_preview(self, width_px: int | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(left, right, dt_s) for a live preview; only with the cameras borrowed (``camera_gate.borrowed()``).

        Real cameras grab a pair at their capture size (the runner flushes before it captures); the
        simulated bench renders the scene without counting the frames, so previews never change what a
        capture renders, and at most ``width_px`` wide when given (the preview's size: a render is
        the sensor's stand-in, and a full-size one would only be shrunk).
        """
        if self.preview is not None:
            return self.preview(width_px)
        pair = self.cameras.capture_pair()
        return pair.left.image, pair.right.image, pair.dt_s

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> Bench:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_bench(config: CampaignConfig, *, operators: Sequence[Operator], transcript: Path | None = None) -> Bench:
    """The bench ``config`` asks for (simulated, bring-up or hardware), opened."""
    if config.cameras.kind == "simulated":
        return simulated_bench(config, operators=operators, transcript=transcript)
    return hardware_bench(config, operators=operators, transcript=transcript)


def _open_rig(stack: contextlib.ExitStack, rig):
    """Open ``rig`` with its close on ``stack`` first: a failed open still closes what it opened (the spy log)."""
    stack.callback(rig.close)
    return rig.open()


# -- simulated (and bring-up) ----------------------------------------------------------------------


def pose_from_reading(reading) -> RigPose:
    """The rig pose a ``RigReading`` reports (a quantity it cannot say, e.g. an unmapped tilt, is 0)."""
    return RigPose(baseline_mm=float(reading.baseline_mm or 0.0),
                   alpha_left_deg=alpha_from_toe_in(float(reading.toe_in_left_deg or 0.0)),
                   alpha_right_deg=alpha_from_toe_in(float(reading.toe_in_right_deg or 0.0)),
                   tilt_left_deg=float(reading.tilt_left_deg or 0.0),
                   tilt_right_deg=float(reading.tilt_right_deg or 0.0))


def simulated_bench(config: CampaignConfig, *, operators: Sequence[Operator],
                    transcript: Path | None = None, render_ahead: bool = True) -> Bench:
    """Simulated cameras and scene; the rig is the emulator on a pty, or (bring-up) the real controller.

    ``render_ahead``: the presenter stages each configuration's scenes so that the simulator renders
    them while the rig settles (the frames are the same either way; see drivers/sim/bench.py).
    """
    from drivers.camera.stereo import StereoCamera
    from drivers.rig.rig import GrblRig
    from drivers.sim.bench import BenchSimulator
    from drivers.sim.render import Optics

    rig_config = config.rig.rig_config()
    optics = config.cameras.optics
    bring_up = config.rig.kind == "grbl"
    stack = contextlib.ExitStack()
    try:
        rig_holder: list = []
        sim = stack.enter_context(BenchSimulator(
            rig_config=rig_config, left=optics.camera_model("left"), right=optics.camera_model("right"),
            optics=Optics(noise_sigma_dn=optics.noise_dn, blur_sigma_px=optics.blur_px),
            time_scale=1.0 if bring_up else config.rig.time_scale, exposure_s=optics.exposure_s,
            homing_enabled=config.rig.homing, profile=config.sim.resolve(), seed=config.seed,
            # Bring-up: render from where the real controller says the axes are, read at each grab.
            pose_source=(lambda: pose_from_reading(rig_holder[0].read())) if bring_up else None,
        ))
        port = config.rig.port if bring_up else sim.tty_path
        # The runner does the manual steps (no prompt here): it moves only what the controller drives.
        rig = _open_rig(stack, GrblRig(port, rig_config, spy_log=transcript))
        rig_holder.append(rig)
        cameras = stack.enter_context(StereoCamera(*sim.cameras(), max_skew_s=config.cameras.max_skew_s))
        stage_ahead = functools.partial(planned_captures, config) if render_ahead else None
        if config.sim_presenter == "hand":
            presenter = HandPresenter(sim, config.calibration_board.build(), config.target.build(), seed=config.seed,
                                      stage_ahead=stage_ahead, streams=config.calibration_capture == "auto",
                                      fps=config.sim.hand_fps,
                                      max_views=max(config.capture.max_calibration_views,
                                                    config.capture.calibration_views))
        else:
            presenter = SimulatedPresenter(sim, config.calibration_board.build(), config.target.build(),
                                           seed=config.seed, stage_ahead=stage_ahead)
        stack.callback(presenter.close)
    except BaseException:
        stack.close()
        raise
    # Settles pass on the bench clock (the emulator's, the cameras'): the simulation is a function of the plan.
    clock = Clock(sim.time_scale, advance=sim.clock.advance)
    return Bench(kind="bring-up" if bring_up else "simulated", rig=rig, cameras=cameras, presenter=presenter,
                 operators=list(operators), clock=clock, homes=config.rig.homing,
                 preview=_simulated_preview(sim, stack), _stack=stack, truth=lambda config_id: sim.truth(),
                 approach_rest_s=sim.ringing_s, now=sim.clock.now)


def _simulated_preview(sim, stack: contextlib.ExitStack) -> PreviewGrab:
    """Both simulated views of the scene now (at most ``width_px`` wide), rendered side by side."""
    from concurrent.futures import ThreadPoolExecutor

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-preview")
    stack.callback(pool.shutdown)

    def preview(width_px: int | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        right = pool.submit(sim.preview, "right", width_px)
        return sim.preview("left", width_px), right.result(), 0.0  # one trigger: no skew

    return preview


def planned_captures(config: CampaignConfig, configuration: Configuration | Visit) -> tuple[int, int]:
    """(calibration views, measurement frames) that :func:`~stereo_bench.campaign.plan.plan_steps` has a runnable
    configuration or design visit capture: a visit shows the calibration board only; a configuration its
    calibration views (per-config extrinsics) and its measurement frames."""
    if isinstance(configuration, Visit):
        return (config.extrinsics.fixed_board_views if configuration.board_fixed
                else config.capture.calibration_views), 0
    views = config.capture.calibration_views if config.extrinsics.source().calibrates_each_configuration else 0
    return views, config.capture.frames_per_config


class SimulatedPresenter:
    """Places boards in a :class:`drivers.sim.bench.BenchSimulator` scene.

    ``stage_ahead``: given a configuration or design visit, the (calibration views, measurement frames) it
    will capture (:func:`planned_captures`). At the start of each (before the rig moves) the presenter then
    draws the calibration board's poses on a background thread and stages every scene it will show with the bench
    (:meth:`~drivers.sim.bench.BenchSimulator.stage`), which renders them ahead once the rig rests
    there; the frames are exactly those a render at the trigger gives. None: nothing ahead.
    """

    wants_detections = False
    streams = False  # one still board per view (HandPresenter: the board carried by hand, streamed)
    presents_by_hand = False

    def __init__(self, bench, calibration_board: Target, target: Target, *, seed: int = 0,
                 calibration_distance_mm: Callable[[float], tuple[float, float]] | None = None,
                 stage_ahead: Callable[[Configuration | Visit], tuple[int, int]] | None = None):
        self.bench = bench
        self.calibration_board = calibration_board
        self.target = target
        self.seed = seed
        # Where an operator would hold the calibration board, around the target distance.
        self.calibration_distance_mm = calibration_distance_mm or (lambda z: (max(250.0, 0.6 * z), 1.3 * z))
        self.stage_ahead = stage_ahead
        self._poses: list[np.ndarray] = []
        self._configuration: Configuration | None = None
        self._target_requests: Counter = Counter()
        self._planned: Future | None = None  # (n_views, poses or the error) of the current configuration
        self._planner = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-presenter") if stage_ahead else None
        # The plan's order (begin_run): where its rig arrived at each value, which placement each target sees.
        self._arrivals: dict[str, dict[str, str]] = {}
        self._placements: dict[str, str] = {}
        self._fixed_board: np.ndarray | None = None  # where the simulated operator stood the fixed board
        bench.warm_up(calibration_board, target)

    def close(self) -> None:
        if self._planner is not None:
            self._planner.shutdown(wait=True, cancel_futures=True)

    def begin_run(self, sequence: Sequence[Configuration | Visit]) -> None:
        from stereo_bench.campaign.approach import arrivals, placements

        self._arrivals, self._placements = arrivals(sequence), placements(sequence)
        # A fixed-board design: the operator stands the board once, off the requested pose by a placement error
        # drawn from the campaign seed (the same draw in a resumed run, which places it again: the design starts
        # over).
        fixed = next((v for v in sequence if isinstance(v, Visit) and v.board_fixed), None)
        if fixed is not None:
            from drivers.sim.hand import placed_board_pose

            centre = np.array([*self.calibration_board.grid_size_mm, 0.0]) / 2.0
            self._fixed_board = placed_board_pose(fixed.fixed_board_matrix(), centre_board=centre,
                                                  seed=scene_seed(self.seed, "fixed-board", "placement", 0))

    def place_board(self, T_rig_board: np.ndarray) -> None:
        assert self._fixed_board is not None, "begin_run() with a fixed-board visit first"
        config_id = self._configuration.config_id if self._configuration is not None else "fixed-board"
        self.bench.show(self.calibration_board, self._fixed_board,
                        seed=scene_seed(self.seed, config_id, "fixed-board", 0))
        return None

    def _placement(self, configuration: Configuration) -> str | None:
        return self._placements.get(configuration.config_id)

    def begin_configuration(self, configuration: Configuration) -> None:
        # The bench keys its landing draws by the configuration the plan's rig arrived at each value for.
        self.bench.begin_configuration(configuration.config_id, targets=configuration.move_request(),
                                       arrivals=self._arrivals.get(configuration.config_id, {}))
        self._configuration = configuration
        self._target_requests = Counter()
        self._poses = []
        self._planned = None
        if self._planner is not None:
            self._planned = self._planner.submit(self._stage, configuration, *self.stage_ahead(configuration))

    def _stage(self, configuration: Configuration, n_views: int, n_frames: int) -> tuple[int, list | Exception]:
        """Draws the calibration poses and stages the configuration's scenes (on the presenter's thread)."""
        try:
            poses: list | Exception = self._calibration_poses(configuration, n_views) if n_views else []
        except CalibrationPlacementError as error:
            poses = error
        scenes = [] if isinstance(poses, Exception) else [
            ("board", self.calibration_board, pose,
             scene_seed(self.seed, configuration.config_id, "calibration", index)) for index, pose in enumerate(poses)]
        scenes += [("target", self.target, configuration.distance_mm,
                    scene_seed(self.seed, configuration.config_id, "target", index), self._placement(configuration))
                   for index in range(n_frames)]
        self.bench.stage(scenes, at=configuration.rig_pose(), ahead=len(scenes))
        return n_views, poses

    def _calibration_poses(self, configuration: Configuration, n_views: int) -> list[np.ndarray]:
        from drivers.sim.render import calibration_board_poses

        if isinstance(configuration, Visit) and configuration.board_fixed:
            assert self._fixed_board is not None, "begin_run() with the fixed-board visits first"
            return [self._fixed_board] * n_views  # it stands where it was placed; each view a new exposure
        near, far = self.calibration_distance_mm(configuration.distance_mm)
        fits = configuration.calibration_range_mm
        if fits:  # where the plan found the board fits both views
            near, far = max(near, fits[0]), min(far, fits[1])
            if near > far:
                near, far = fits
        rng = np.random.default_rng(scene_seed(self.seed, configuration.config_id, "calibration-poses", 0))
        try:
            # Usable views by the rule the plan predicted with (geometry.calibration_view_fits).
            return calibration_board_poses(
                configuration.rig_pose(), self.calibration_board, n_views=n_views, rng=rng, distance_mm=(near, far),
                left=self.bench.left_model, right=self.bench.right_model,
            )
        except ValueError as error:
            raise CalibrationPlacementError(f"calibration board cannot be shown to both cameras: {error}") from None

    def prepare_calibration(self, n_views: int) -> None:
        configuration = self._configuration
        assert configuration is not None, "begin_configuration() first"
        planned = self._planned.result() if self._planned is not None else None
        if planned is not None and planned[0] == n_views:  # drawn ahead (the same seeded draw)
            if isinstance(planned[1], Exception):
                raise planned[1]
            self._poses = planned[1]
        else:
            self._poses = self._calibration_poses(configuration, n_views)
        return None

    def present_calibration_view(self, index: int) -> None:
        assert self._configuration is not None
        self.bench.show(self.calibration_board, self._poses[index],
                        seed=scene_seed(self.seed, self._configuration.config_id, "calibration", index))

    def recorded_detections(self, index: int) -> None:
        return None  # the rendered views are detected

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None:
        return None

    def calibration_view_discarded(self, index: int) -> None:
        return None  # the view is shown again at the same pose: the scene has nothing to undo

    def review_calibration(self) -> None:
        return None

    def present_target(self, frame_index: int) -> None:
        configuration = self._configuration
        assert configuration is not None, "begin_configuration() first"
        # Asked again for the same frame (the target was not found): a fresh frame, not the same one.
        retry = self._target_requests[frame_index]
        self._target_requests[frame_index] += 1
        kind = "target" if retry == 0 else f"target-retry{retry}"
        # The simulated operator places the target (the bench draws a placement error per placement).
        self.bench.place_target(self.target, distance_mm=configuration.distance_mm,
                                seed=scene_seed(self.seed, configuration.config_id, kind, frame_index),
                                placement=self._placement(configuration))


def _board_fixed(configuration) -> bool:
    """A fixed-board design's visit: the board placed once stands in the scene (nothing is presented)."""
    return isinstance(configuration, Visit) and configuration.board_fixed


class HandPresenter(SimulatedPresenter):
    """A simulated operator presents the calibration board by hand (:class:`drivers.sim.hand.HandPresentation`):
    carried from pose to pose, held for a while, trembling, sometimes half out of a view first.

    ``streams`` (views taken automatically): the cameras stream at ``fps`` frames per bench second while the hand
    presents up to ``max_views`` poses; :meth:`next_stream_frame` moves the bench clock to the next frame and puts
    the board where the hand holds it then (smeared by its motion during the exposure). Otherwise (Enter): the
    hand presents the view's pose and the simulated operator presses Enter as the hand stops, uniformly from
    ``PRESS_EARLY_S`` before the hold to ``PRESS_LATE_S`` into it (as scripts/bench_autocapture.py's "enter").
    Time is the bench clock's: the stream's frames, the hand's moves and holds pass on it, not on the wall clock.
    """

    PRESS_EARLY_S = 0.3
    PRESS_LATE_S = 0.5
    presents_by_hand = True

    def __init__(self, bench, calibration_board: Target, target: Target, *, seed: int = 0, streams: bool,
                 fps: float = 10.0, max_views: int = 40, **kwargs):
        super().__init__(bench, calibration_board, target, seed=seed, **kwargs)
        self.streams = streams
        self.fps = float(fps)
        self.max_views = int(max_views)
        self.hand = None  # the HandPresentation of the current configuration
        self._t0_s = 0.0  # bench time the hand started

    def _stage(self, configuration: Configuration, n_views: int, n_frames: int) -> tuple[int, list | Exception]:
        if _board_fixed(configuration):
            return super()._stage(configuration, n_views, n_frames)  # the placed board stands still
        return super()._stage(configuration, 0, n_frames)  # the hand's board is never still: the targets only

    def prepare_calibration(self, n_views: int) -> None:
        from drivers.sim.hand import HandPresentation

        configuration = self._configuration
        assert configuration is not None, "begin_configuration() first"
        if _board_fixed(configuration):  # a fixed-board visit: the hand placed the board once, it stands there
            self.hand = None
            return super().prepare_calibration(n_views)
        poses = self._calibration_poses(configuration, max(self.max_views, n_views) if self.streams else n_views)
        self._poses = poses
        self.hand = HandPresentation(poses, seed=scene_seed(self.seed, configuration.config_id, "hand", 0),
                                     board_width_mm=self.calibration_board.grid_size_mm[0])
        self._t0_s = self.bench.clock.now()
        return None

    def _show_at(self, t_s: float, seed: int) -> None:
        """Move the bench clock on to bench time ``t_s`` (never back) and put the board where the hand holds it
        during the exposure that starts then."""
        clock = self.bench.clock
        ahead = t_s - clock.now()
        if ahead > 0:
            clock.advance(ahead)
        start = clock.now() - self._t0_s
        exposure = self.bench.exposure_s
        hand = self.hand
        self.bench.show(self.calibration_board, hand.pose_at(start + exposure / 2.0), seed=seed,
                        moving=(hand.pose_at(start), hand.pose_at(start + exposure)))

    def next_stream_frame(self, offered: int) -> bool:
        """Put the board where the hand holds it at the stream's ``offered``-th frame; False once the hand has
        presented every pose (the collection ends)."""
        assert self.hand is not None and self._configuration is not None, "prepare_calibration() first"
        t_s = offered / self.fps
        if t_s > self.hand.duration_s:
            return False
        self._show_at(self._t0_s + t_s, scene_seed(self.seed, self._configuration.config_id, "calibration-stream",
                                                   offered))
        return True

    def stream_prompt(self, n_kept: int, gate: str) -> Prompt:
        # The hand presents by itself (the simulator answers nothing here); at a terminal Enter still ends it early.
        return Prompt("calibration_stream", "the simulated hand presents the calibration board: views are taken "
                      f"automatically when it is still and new ({gate}); press Enter to calibrate with the views "
                      "kept so far", config_id=self._configuration.config_id, background=True)

    def present_calibration_view(self, index: int) -> None:
        if _board_fixed(self._configuration):
            return super().present_calibration_view(index)
        assert self.hand is not None and self._configuration is not None, "prepare_calibration() first"
        config_id = self._configuration.config_id
        start, _, _ = self.hand.holds[index]
        rng = np.random.default_rng(scene_seed(self.seed, config_id, "press", index))
        press = start + float(rng.uniform(-self.PRESS_EARLY_S, self.PRESS_LATE_S))
        self._show_at(self._t0_s + press, scene_seed(self.seed, config_id, "calibration", index))


# -- the real bench --------------------------------------------------------------------------------


def hardware_bench(config: CampaignConfig, *, operators: Sequence[Operator], transcript: Path | None = None) -> Bench:
    """The real controller on ``rig.port`` and two V4L2 cameras bound by identity."""
    from drivers.camera.base import CameraNotFound
    from drivers.camera.stereo import StereoCamera
    from drivers.camera.usb_identity import resolve_camera
    from drivers.camera.v4l2 import V4L2Camera
    from drivers.rig.rig import GrblRig

    optics = config.cameras.optics
    stack = contextlib.ExitStack()
    try:
        rig = _open_rig(stack, GrblRig(config.rig.port, config.rig.rig_config(), spy_log=transcript))
        settings = config.cameras.camera_settings()
        left_node, right_node = (resolve_camera(spec).capture_node for spec in (config.cameras.left,
                                                                                  config.cameras.right))
        if left_node == right_node:  # two spellings of one camera (by-id: and usb-port:): the plan could not tell
            raise CameraNotFound(f"cameras.left {config.cameras.left} and cameras.right {config.cameras.right} are "
                                 f"one camera ({left_node}): a stereo pair needs two", device=left_node)
        left = V4L2Camera(left_node, settings, name="left")
        right = V4L2Camera(right_node, settings, name="right")
        cameras = stack.enter_context(StereoCamera(left, right, max_skew_s=config.cameras.max_skew_s))
    except BaseException:
        stack.close()
        raise
    presenter = OperatorPresenter(image_size=(optics.width_px, optics.height_px),
                                  target_description=config.target.describe(),
                                  calibration_board=config.calibration_board.build(),
                                  streams=config.calibration_capture == "auto")
    return Bench(kind="hardware", rig=rig, cameras=cameras, presenter=presenter, operators=list(operators),
                 clock=Clock(1.0), homes=config.rig.homing, _stack=stack, now=time.monotonic)


# -- replay ----------------------------------------------------------------------------------------


class ReplayPresenter:
    """Queues the recorded pair the runner is about to capture.

    ``detections``: per ``config_id/index``, the (left, right) detections recorded for calibration
    views whose frames were not kept (``[capture] keep_frames``): the runner uses them instead of
    detecting the placeholder images it is served.
    """

    wants_detections = False
    streams = False  # views taken automatically replay as the views the recording kept
    presents_by_hand = False

    def __init__(self, cameras, detections: dict[str, tuple] | None = None):
        self.cameras = cameras
        self.config_id = ""
        self.retries: Counter = Counter()
        self.detections = detections or {}

    def recorded_detections(self, index: int) -> tuple | None:
        return self.detections.get(f"{self.config_id}/{index}")

    def begin_run(self, sequence: Sequence[Configuration | Visit]) -> None:
        return None

    def begin_configuration(self, configuration: Configuration) -> None:
        self.config_id = configuration.config_id

    def place_board(self, T_rig_board: np.ndarray) -> None:
        return None

    def prepare_calibration(self, n_views: int) -> None:
        return None

    def present_calibration_view(self, index: int) -> None:
        self.cameras.expect(f"{self.config_id}/calibration_view/{index}")

    def calibration_view_captured(self, index, left, right) -> None:
        return None

    def calibration_view_discarded(self, index: int) -> None:
        return None  # a replay runs no operator actions: the recorded view that was kept is served

    def review_calibration(self) -> None:
        return None

    def present_target(self, frame_index: int) -> None:
        # The runner asks again for a frame whose target was not found: serve the recorded retries in turn.
        retry = self.retries[(self.config_id, frame_index)]
        self.retries[(self.config_id, frame_index)] += 1
        self.cameras.expect(f"{self.config_id}/measurement_frame/{frame_index}/{retry}")


class ReplayOperator:
    """Answers the operator steps of a replay at once: what the operator did is in the recorded frames."""

    name = "replay"

    def offer(self, ticket) -> None:
        if not ticket.prompt.background:
            ticket.answer(self.name)

    def withdraw(self, ticket) -> None:
        return None


def replay_bench(reader, config_ids: set[str]) -> Bench:
    """The recorded rig telemetry and frames of ``config_ids`` (a ``SessionReader``'s session), opened.

    A calibration view whose frames were not kept is served as black frames of the recorded size, and
    its recorded detections stand in for what the runner would detect in them.
    """
    from drivers.replay import ReplayRig, ReplayStereoCamera
    from stereo_bench.campaign.documents import (
        CalibrationDetectionsEvent,
        CalibrationExclusionsEvent,
        CalibrationSelectionEvent,
        CalibrationViewEvent,
        MeasurementFrameEvent,
        MoveEvent,
        PresentationTimeEvent,
        TruthEvent,
        json_safe,
    )
    from stereo_bench.campaign.router import DocumentRouter

    # What goes down to drivers/replay.py (which does not import stereo_bench) goes as the JSON it was recorded as.
    frames: dict[str, CalibrationViewEvent | MeasurementFrameEvent] = {}  # key -> event, in recorded order (the
    readings = []                                                         # order the replay will ask for them)
    approaches: dict[str, dict] = {}
    truths: dict[str, dict] = {}
    detections = {}
    views: dict[str, tuple[int, int]] = {}  # config_id -> (attempt, views recorded in it)
    exclusions: dict[str, tuple[dict[int, str], float | None]] = {}
    capture: dict[str, dict[type, object]] = {}  # config_id -> event type -> its last event

    def capture_record(event) -> None:
        capture.setdefault(event.config_id, {})[type(event)] = event

    def move(event: MoveEvent) -> None:
        readings.append(json_safe(event.data.rig))
        approaches[event.config_id] = dict(event.data.approach or {})

    def truth(event: TruthEvent) -> None:
        truths[event.config_id] = json_safe(event.data)

    def calibration_view(event: CalibrationViewEvent) -> None:
        frames[f"{event.config_id}/calibration_view/{event.data.index}"] = event
        # The views of the configuration's last attempt (a resumed one took its views again, as many as it kept).
        attempt, count = views.get(event.config_id, (event.attempt, 0))
        views[event.config_id] = ((event.attempt, max(count, event.data.index + 1)) if event.attempt == attempt
                                  else (event.attempt, event.data.index + 1))

    def measurement_frame(event: MeasurementFrameEvent) -> None:
        frames[f"{event.config_id}/measurement_frame/{event.data.index}/{event.data.retry or 0}"] = event

    def calibration_exclusions(event: CalibrationExclusionsEvent) -> None:
        exclusions[event.config_id] = ({int(index): why for index, why in event.data.excluded},
                                       event.data.max_view_rms_px)

    def calibration_detections(event: CalibrationDetectionsEvent) -> None:
        detections[f"{event.config_id}/{event.data.index}"] = tuple(
            None if side is None else side.detection() for side in (event.data.left, event.data.right))

    router = (DocumentRouter().on(MoveEvent, move).on(TruthEvent, truth).on(CalibrationViewEvent, calibration_view)
              .on(MeasurementFrameEvent, measurement_frame).on(CalibrationDetectionsEvent, calibration_detections)
              .on(CalibrationExclusionsEvent, calibration_exclusions)
              .on(CalibrationSelectionEvent, capture_record).on(PresentationTimeEvent, capture_record))
    router.read(event for event in reader.events() if event.config_id in config_ids)

    def load_pair(key: str):
        event = frames.get(key)
        if event is None:
            raise KeyError(f"{reader.directory}: recording holds no {key}")
        kept, data = event.frames, json_safe(event.data)
        if "left" in kept and "right" in kept:
            return reader.frame(kept["left"]), reader.frame(kept["right"]), data
        if key.split("/")[1] == "calibration_view" and key.replace("/calibration_view", "", 1) in detections:
            return _not_kept(event.data.left), _not_kept(event.data.right), data
        raise KeyError(f"{reader.directory}: the frames of {key} were not kept")

    stack = contextlib.ExitStack()
    rig = stack.enter_context(ReplayRig(readings))
    # Read and decode ~8 pairs ahead on two threads: a pair is ~2 MB and ~20 ms of decoding.
    cameras = stack.enter_context(ReplayStereoCamera(load_pair, order=list(frames), ahead=8, workers=2))
    return Bench(kind="replay", rig=rig, cameras=cameras, presenter=ReplayPresenter(cameras, detections),
                 operators=[ReplayOperator()], clock=Clock(math.inf), homes=False, _stack=stack,
                 truth=truths.get if truths else None, approaches=False,
                 recorded_approach=lambda config_id: approaches.get(config_id, {}),
                 recorded_views=lambda config_id: views.get(config_id, (0, 0))[1], recorded_exclusions=exclusions.get,
                 recorded_capture=lambda config_id: list(capture.get(config_id, {}).values()))


def _not_kept(description) -> np.ndarray:
    """A black frame of the recorded shape and type (a ``FrameRecord``): stands in for a frame that was not kept."""
    return np.zeros(tuple(description.shape or (0, 0)), dtype=np.dtype(description.dtype or "uint8"))


__all__ = [
    "Bench", "CalibrationPlacementError", "Clock", "HandPresenter", "Prompt", "ReplayOperator", "ReplayPresenter",
    "SimulatedPresenter",
    "hardware_bench", "open_bench", "pose_from_reading", "replay_bench", "simulated_bench",
]
