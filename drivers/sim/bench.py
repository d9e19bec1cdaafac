"""The simulated bench: a GRBL emulator on a pseudo-terminal, a scene, and two cameras that render it.

The cameras render whatever the scene holds (the calibration board at some pose, the measured
target at some distance, or nothing) from the rig pose that the emulator's axes are at *at the
moment of the grab*, converted to physical units through the same ``RigConfig`` the real driver
uses. So the runner drives the real serial driver against the emulator, and what the cameras see
follows from where the motors really are — a move that did not finish shows up in the images.

Noise is reproducible per scene: every change of the scene carries a seed, and the n-th frame a
camera renders of that scene uses ``(seed, camera, n)``. A campaign that resumes after a crash
therefore renders the same frames as one that never stopped.

Imperfections come from a :class:`~drivers.sim.profile.SimProfile` (default: the ideal bench, which
renders exactly what this bench rendered before profiles existed). They act downstream of what the
emulator reports: the emulator says what the steppers were told, the cameras stand where the
mechanics (:mod:`drivers.sim.mechanics`) really put them. Backlash, landing errors and the ringing
after a move need the history of the axes: the emulator reports every motion that ends (its
:class:`~drivers.sim.grbl.planner.MotionEvent`: the axes, the direction each arrived in, the exact end
time of the motion model) and the bench keeps them in a :class:`~drivers.sim.mechanics.MoveHistory`.

Time is the bench clock's (:mod:`drivers.sim.clock`), shared with the emulator: it runs only while
the emulator has motion, a homing, a dwell or a boot pending and stops at that activity's exact
end; otherwise it moves only by what the bench does: each trigger's exposure (``exposure_s``, after
which the pair's frames are stamped) and the campaign's settle waits (``clock.advance``). The ringing
a frame sees (the time since the last move ended, at mid-exposure) is therefore a function of the
plan, never of the wall clock: not of ``time_scale``, a slow render, a late driver or a loaded machine.

Random draws are keyed by what they are, not by the order they happen in: a landing error by the
configuration at which the plan's rig arrived at that axis position and the index of that move there
(:meth:`BenchSimulator.begin_configuration`), a manual target placement by the placement it belongs
to (the first configuration of the plan's run of configurations at that distance). A campaign resumed
after a crash therefore draws what an uninterrupted one drew. A bench that is not told (a test, a
render) keys landings by position and visits, placements by distance and placements there.

The mechanics take where the emulator's axes stand (``GrblEmulator.physical_position()``: whole motor
steps, so step quantisation is in; once the controller is homed this is exactly what its step counters,
``machine_position()``, report, and before homing it is where the motors really are, while the counters
restart at 0 wherever the axes stand).

Bring-up (``pose_source``): a real controller moves real motors, no emulator runs, and the cameras
render from the positions the controller reports at each grab. The profile's static imperfections
still apply to that pose (pan axes off the optical centres, scale errors, slide direction, camera
mounts; lenses, JPEG, boards, target placement), so the frames look like the ``lab`` bench's; the
imperfections of *motion* (backlash, landing errors, ringing) do not: they need the axes' history,
which only the emulator's motion events give (a real controller is read once per grab).

Rendering ahead (:meth:`BenchSimulator.stage`): whoever places the boards may say which scenes come
next and where the rig will stand for them. As soon as the emulator has the move there queued, the
bench predicts the pair's state at rest there (the end of the planned move in whole steps; on a
bench with motion errors, the history fed that move: its backlash and landing draws, no ringing)
and renders the scenes' first frames in the background, so the render (~30 ms a view, longer than
an exposure) overlaps the motion and the settle instead of delaying the captures. Once the rig
rests there (idle, ringing stopped dead by friction), the prediction is checked against the real
state and frames rendered for a wrong one are rendered again. A prerendered frame is used only if
the scene shown and the pair's state at the trigger are exactly those it was rendered for, so it is
bit for bit the frame a render at the trigger would give; otherwise the frame is rendered there.

Unsynchronised cameras (``cameras.synchronised = false``): the right frame of each pair is exposed a random
skew after the left one (:func:`board_at_exposure`), while a hand-held calibration board moves; the frames'
truth carries the board as each camera saw it and the skew (``truth.board.capture_skew_s``). Their time
stamps stay the one trigger's (the campaign's left-right time check sees nothing: what a pair of webcams
whose clocks are read by the host at retrieval, not at exposure, reports).

The bench knows the truth at every frame: the true camera poses, R and T of the pair
(X_right = R X_left + T), the board's true pose, scale and bow. ``truth()`` returns it for the
current state; every frame carries it in its metadata (``meta["truth"]``).
"""

from __future__ import annotations

import contextlib
import copy
import math
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from drivers.camera.base import CameraSettings
from drivers.camera.synthetic import SyntheticCamera
from drivers.rig.config import RigConfig, alpha_from_toe_in, to_physical
from drivers.rig.motion import REFERENCE_HOMING
from drivers.sim.clock import BenchClock
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.firmware import AxisSpec, axis_specs_for_travel
from drivers.sim.grbl.planner import MotionEvent, _approach_of
from drivers.sim.mechanics import MOVED, TILTS, MoveHistory, PairState, pair_state, ringing_duration_s
from drivers.sim.profile import IDEAL, BoardErrors, CameraErrors, SimProfile
from drivers.sim.render import BoardShape, Optics, StereoRenderer, _auto_px_per_square
from stereo_bench.geometry import (
    CameraModel,
    RigPose,
    board_pose_facing_rig,
    invert_transform,
    stereo_structure,
)
from stereo_bench.targets import CharucoTarget, Checkerboard

Target = Checkerboard | CharucoTarget
SIDES = ("left", "right")
PREVIEW_FRAME_BASE = 1 << 40  # preview frames' noise streams start here, far from any captured frame's index


# How often (real seconds) the renderer ahead looks whether the rig rests where a staged scene needs it.
REST_POLL_S = 0.005
# How close (mm, deg) the reported axes must be to a staged scene's rig pose to render it ahead (whole
# motor steps put them a few thousandths off the commanded values; the trigger then checks exactly).
REST_TOLERANCE = 0.01


@dataclass
class Scene:
    """What stands in front of the rig: a target at ``T_rig_board`` (4x4, mm), or nothing.

    ``shape``: the print as it really is (None: flat and to scale); ``placement``: the operator's
    error when the target was placed by hand (distance mm, yaw deg), for the truth.
    """

    target: Target | None = None
    T_rig_board: np.ndarray | None = None
    seed: int = 0
    frames_rendered: dict[str, int] = field(default_factory=lambda: {side: 0 for side in SIDES})
    shape: BoardShape | None = None
    measured_target: bool = False
    placement: dict | None = None
    # A board carried by hand: its pose (4x4, mm) at the start and at the end of the exposure; each camera's frame
    # is smeared by the board's image motion between them (and sheared by it in a rolling shutter's readout).
    exposure_poses: tuple[np.ndarray, np.ndarray] | None = None


@dataclass(frozen=True)
class MoveContext:
    """What the rig is being moved for (:meth:`BenchSimulator.begin_configuration`), for the landing draws.

    ``targets``: the configuration's commanded physical values; ``arrivals``: per quantity, the configuration
    at which the plan's rig arrived at that value (the first of the plan's run of configurations that command
    it), whose draw a move ending there repeats.
    """

    config_id: str
    targets: dict[str, float]
    arrivals: dict[str, str]


def _crc(text: str) -> int:
    return zlib.crc32(text.encode())


@dataclass(frozen=True)
class _Snapshot:
    """What one trigger of the pair sees: the reported pose and the true one (for both cameras)."""

    pose: RigPose
    T_rig_cam: dict[str, np.ndarray]
    state: PairState | None = None  # None on a mechanically ideal bench
    smear_px: dict[str, tuple[float, float] | None] = field(default_factory=lambda: {"left": None, "right": None})
    sim_time_s: float = math.nan


def _same_view(a: _Snapshot, b: _Snapshot) -> bool:
    """Whether two triggers see the pair in the same state (everything a frame and its truth are made of)."""
    if a.pose != b.pose or a.smear_px != b.smear_px:
        return False
    if any(not np.array_equal(a.T_rig_cam[side], b.T_rig_cam[side]) for side in SIDES):
        return False
    if (a.state is None) != (b.state is None):
        return False
    return a.state is None or (a.state.ringing_deg == b.state.ringing_deg and a.state.rock_deg == b.state.rock_deg)


def _same_scene(a: Scene, b: Scene) -> bool:
    if a.target != b.target or a.seed != b.seed or a.shape != b.shape or a.measured_target != b.measured_target:
        return False
    if a.placement != b.placement or (a.T_rig_board is None) != (b.T_rig_board is None):
        return False
    if (a.exposure_poses is None) != (b.exposure_poses is None) or (a.exposure_poses is not None and not all(
            np.array_equal(x, y) for x, y in zip(a.exposure_poses, b.exposure_poses, strict=True))):
        return False
    return a.T_rig_board is None or np.array_equal(a.T_rig_board, b.T_rig_board)


@dataclass(eq=False)  # compared by identity: scenes hold arrays
class _Staged:
    """A scene announced ahead (:meth:`BenchSimulator.stage`) and, once rendered, its first frame pair."""

    scene: Scene
    at: RigPose  # where the rig will stand when the scene is captured
    snapshot: _Snapshot | None = None  # the pair's state the frames were rendered for
    frames: dict[str, Future] | None = None
    dropped: bool = False
    checked: bool = False  # rendered for the state the rig was seen to rest in (not only predicted)


def _scaled_camera(camera: CameraModel, scale: float) -> CameraModel:
    """``camera`` seeing the same rays on a sensor ``scale`` times its size (pixel centres: u' = s (u + 0.5) - 0.5)."""
    K = np.array(camera.K, dtype=np.float64)
    K[:2] *= scale
    K[:2, 2] += 0.5 * scale - 0.5
    width, height = camera.image_size
    return CameraModel(K=K, dist=camera.dist, image_size=(round(width * scale), round(height * scale)),
                       name=camera.name)


def true_lens(camera: CameraModel, high_order: float, prism: tuple[float, float, float, float]) -> CameraModel:
    """``camera`` with the profile's lens terms (OpenCV's 12-coefficient model); unchanged when there are none.

    ``high_order`` c adds c r^6 to the numerator (k3) and sets the rational k6 to c: the two cancel
    to leading order and leave the terms from r^8 up. ``prism``: thin-prism s1..s4.
    """
    if high_order == 0.0 and not any(prism):
        return camera
    dist = np.zeros(max(12, camera.dist.size))
    dist[: camera.dist.size] = np.asarray(camera.dist, dtype=float).ravel()
    if high_order != 0.0:
        if dist[5] != 0.0 or dist[6] != 0.0 or dist[7] != 0.0:
            raise ValueError(f"{camera.name}: the configured lens already has rational terms; cannot add more")
        dist[4] += high_order
        dist[7] = high_order
    dist[8:12] += np.asarray(prism, dtype=float)
    return CameraModel(K=camera.K, dist=dist, image_size=camera.image_size, name=camera.name)


def camera_optics(optics: Optics, cams: CameraErrors) -> Optics:
    """``optics`` with the profile's sensor and lens imperfections (unchanged, the same object, when there are none).

    Defocus adds in quadrature to the optics' blur, the gain's extra read noise to its read noise; shot noise,
    corner noise and the rolling shutter's row time are the profile's.
    """
    if not (cams.defocus_sigma_px or cams.extra_read_noise_dn or cams.shot_noise_gain or cams.corner_noise_px
            or cams.line_time_us):
        return optics
    return replace(optics, blur_sigma_px=math.hypot(optics.blur_sigma_px, cams.defocus_sigma_px),
                   noise_sigma_dn=math.hypot(optics.noise_sigma_dn, cams.extra_read_noise_dn),
                   shot_noise_gain=optics.shot_noise_gain + cams.shot_noise_gain, jitter_px=cams.corner_noise_px,
                   jitter_scale_px=cams.corner_noise_scale_px, line_time_s=cams.line_time_us * 1e-6)


def board_at_exposure(profile: SimProfile, T_rig_board: np.ndarray, *, seed: int, index: int, side: str,
                      measured_target: bool = False) -> tuple[np.ndarray, float | None]:
    """(T_rig_board 4x4 mm, skew s) of a board shown at ``T_rig_board`` as the ``side`` camera's ``index``-th
    frame of a scene with noise seed ``seed`` sees it.

    On a synchronised pair (and for the measured target, which stands) the scene's pose, skew None. An
    unsynchronised pair (``cameras.synchronised = false``) exposes the right frame ``skew`` after the left one,
    drawn per frame pair from N(0, ``capture_skew_sigma_ms``) keyed by (seed, frame index); the hand-held
    calibration board moves meanwhile at ``calibration_board.hand_held_speed_mm_s`` in a direction drawn per
    scene (a hand's drift, straight over a few ms). The left frame sees the scene's pose.
    """
    cams, speed = profile.cameras, profile.calibration_board.hand_held_speed_mm_s
    if cams.synchronised or measured_target:
        return T_rig_board, None
    skew = float(np.random.default_rng([seed & 0xFFFFFFFF, 0x5E3, index]).normal(
        0.0, cams.capture_skew_sigma_ms * 1e-3))
    if side == "left" or speed == 0.0:
        return T_rig_board, skew
    direction = np.random.default_rng([seed & 0xFFFFFFFF, 0x4A4D]).normal(size=3)
    moved = np.array(T_rig_board, dtype=np.float64)
    moved[:3, 3] += speed * skew * direction / np.linalg.norm(direction)
    return moved, skew


def board_shape(errors: BoardErrors) -> BoardShape | None:
    """The render shape of a board with these errors (None: flat and to scale)."""
    if errors.flat_and_true:
        return None
    return BoardShape(scale=1.0 + errors.print_scale_error, bow_mm=errors.bow_mm)


class BenchSimulator:
    """Emulator + scene + two rendering cameras; ``start()``/``stop()`` or a context manager.

    Args:
        rig_config: axis mapping shared with the real driver (default: X = B - 350, Y/Z = -toe-ins, Grbl's
            machine space).
        left, right: camera intrinsics (default 1920x1080, f = 4 mm, 3 um pixels); the profile's
            lens terms are added to them (``left_model``/``right_model`` are the true lenses).
        optics: image formation (blur, noise, ...); the profile's cameras are applied on top (``jpeg_quality``,
            and :func:`camera_optics`: defocus, sensor noise and gain, corner noise, rolling shutter).
        time_scale: > 1 runs motion and exposures faster than real time (the bench clock's pace: it changes no
            simulated time, only how long it takes in real time).
        exposure_s: exposure + readout per trigger (bench-clock seconds; ``exposure_s / time_scale`` real).
        profile: the bench's imperfections (default: the ideal bench).
        seed: seed of the profile's random draws (landing errors, target placements).
        pose_source: where the rig is, when a real controller drives it (bring-up: the cameras are not
            mounted yet and render from the positions the controller reports); no emulator is started, and
            the profile's motion errors (backlash, landing, ringing) are left out (module docstring).
    """

    def __init__(
        self, *, rig_config: RigConfig | None = None, left: CameraModel | None = None,
        right: CameraModel | None = None, optics: Optics | None = None, time_scale: float = 1.0,
        exposure_s: float = 0.02, homing_enabled: bool = True, axis_specs: dict[str, AxisSpec] | None = None,
        profile: SimProfile | None = None, seed: int = 0, pose_source: Callable[[], RigPose] | None = None,
        firmware: str | None = None,
    ):
        self.rig_config = rig_config or RigConfig()
        # The tilts a motor drives: through the heads' tilt joints (drivers/sim/mechanics.py); a fixed tilt has none.
        self.tilting = tuple(q for q in TILTS if self.rig_config.quantities[q].driven)
        self._moved = MOVED + self.tilting
        self.profile = profile or IDEAL
        self.seed = int(seed)
        cams = self.profile.cameras
        self.left_model = true_lens(left or CameraModel.from_sensor(name="left"), *cams.lens_terms("left"))
        self.right_model = true_lens(right or CameraModel.from_sensor(name="right"), *cams.lens_terms("right"))
        self.optics = optics or Optics()
        if cams.jpeg_quality is not None:
            self.optics = replace(self.optics, jpeg_quality=cams.jpeg_quality)
        self.optics = camera_optics(self.optics, cams)
        self.time_scale = time_scale
        self.exposure_s = exposure_s
        self.pose_source = pose_source
        self.clock = BenchClock(time_scale)  # the emulator's and the cameras' time (drivers/sim/clock.py)
        # The emulated controller's travel ($13x) comes from the rig config's soft limits, in the machine space
        # a stock Grbl gives (negative from the homing switch); a config with positive machine targets gets
        # the HOMING_FORCE_SET_ORIGIN build that serves them (see docs/RIG.md).
        specs, force_set_origin = axis_specs_for_travel(self.rig_config.machine_travel(),
                                                        margin=REFERENCE_HOMING.pulloff)
        self.emulator = None if pose_source is not None else GrblEmulator(
            axes=self.rig_config.axes, axis_specs=axis_specs or specs, time_scale=time_scale,
            homing_enabled=homing_enabled, force_set_origin=force_set_origin,  # homing: the reference rig's
            clock=self.clock, on_motion=self._on_motion,
            # Grbl 1.1h drives three axes; a rig config that maps A, B or C needs grblHAL's (up to six).
            firmware=firmware or ("grbl" if set(self.rig_config.axes) <= set("XYZ") else "grblhal"),
        )
        self._scene = Scene()
        self._lock = threading.Lock()
        self._renderers: dict[Target, Future] = {}  # a StereoRenderer per target, built once
        self._renderers_lock = threading.Lock()
        self._preview_renderers: dict[tuple[Target, float], StereoRenderer] = {}
        self._trigger_s = 0.0  # bench time the current trigger began
        self._trigger_wall = time.monotonic()  # ... and the real time it began (paces the readout)
        self._trigger_used: set[str] = set(SIDES)  # the first grab starts a trigger
        self._prefetched: dict[str, Future] = {}
        self._previews = 0
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-render")
        # Rendering ahead (stage()): scenes announced, in order; the one the current scene matched.
        self._staged: list[_Staged] = []
        self._staged_now: _Staged | None = None
        self._stage_changed = threading.Condition(self._lock)
        self._ahead_pool: ThreadPoolExecutor | None = None
        self._ahead_thread: threading.Thread | None = None
        self._ahead = 16  # frame pairs rendered ahead at most (stage())
        self._warming: list[threading.Thread] = []  # warm_up()'s builds: joined by stop()
        self.prerendered_used = 0  # frame pairs served from a render ahead (for tests and benchmarks)
        # What the operator would set by hand (the target distance unless it is motorised).
        self.manual_values: dict[str, float] = {}
        # The axes' history (backlash, landing errors, ringing), when the profile needs one and an emulator
        # reports the motions. Its lock is never held while the emulator is called: the emulator calls
        # _on_motion with its own lock held.
        self.history = (MoveHistory(self.profile, self.seed, quantities=self._moved)
                        if self.profile.moves_need_history and self.emulator is not None else None)
        self._history_lock = threading.Lock()
        self._context: MoveContext | None = None
        self._draws: Counter = Counter()  # landing draws made in the current context, per (quantity, kind)
        self._motions_seen = 0  # MotionEvents received (against PlannedMotion.reported)
        self._homings = 0
        self._stopping = threading.Event()
        self._placements: Counter = Counter()
        self._placed: tuple | None = None  # (target, distance) of the current manual placement
        self._placement: dict = {}

    # -- lifecycle ---------------------------------------------------------------------------------------------

    def start(self) -> BenchSimulator:
        self._stopping.clear()
        if self.emulator is not None:
            self.emulator.start()
        return self

    def stop(self) -> None:
        self._stopping.set()
        with self._lock:
            self._drop_staged(self._staged)
            self._staged = []
            self._stage_changed.notify_all()
        if self._ahead_thread is not None:
            self._ahead_thread.join()
            self._ahead_thread = None
        if self._ahead_pool is not None:
            self._ahead_pool.shutdown(wait=True, cancel_futures=True)
            self._ahead_pool = None
        self._pool.shutdown(wait=True)
        # A build still running in OpenCV when the process exits aborts it ("terminate called without an active
        # exception", status 134: the interpreter ends a daemon thread inside C++ code): a run stopped in its
        # first second (Ctrl-C, a closed pipe) waits for them (~1-2 s at most) instead.
        for thread in self._warming:
            thread.join()
        self._warming.clear()
        if self.emulator is not None:
            self.emulator.stop()

    def __enter__(self) -> BenchSimulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def ringing_s(self) -> float:
        """How long (bench s) the heads ring after a move, on a bench that follows the axes' history (else 0)."""
        return ringing_duration_s(self.profile.cameras) if self.history is not None else 0.0

    @property
    def tty_path(self) -> str:
        if self.emulator is None:
            raise RuntimeError("this simulated bench renders from a real controller's positions: it has no emulator")
        return self.emulator.tty_path

    # -- the scene ---------------------------------------------------------------------------------------------

    def show(self, target: Target | None, T_rig_board: np.ndarray | None = None, *, seed: int = 0,
             moving: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Put ``target`` at ``T_rig_board`` in front of the rig (None: an empty scene).

        A board shown this way is the calibration board, as the profile's ``calibration_board`` has
        it; :meth:`place_target` places the measured target. ``moving``: a board carried by hand, its pose at the
        start and at the end of the next exposure (``T_rig_board`` is the one at mid-exposure): the frames are
        smeared by its image motion.
        """
        self._set_scene(Scene(target=target, T_rig_board=None if T_rig_board is None else np.array(T_rig_board),
                              seed=int(seed), shape=board_shape(self.profile.calibration_board),
                              exposure_poses=None if moving is None else (np.array(moving[0]), np.array(moving[1]))))

    def _board_smear_px(self, side: str, scene: Scene, T_rig_cam: np.ndarray) -> tuple[float, float] | None:
        """The image motion (px) of a hand-held board's centre during the exposure, in the ``side`` camera."""
        if scene.exposure_poses is None or scene.target is None:
            return None
        camera = self.left_model if side == "left" else self.right_model
        width_mm, height_mm = scene.target.grid_size_mm
        centre = np.array([width_mm / 2.0, height_mm / 2.0, 0.0, 1.0])
        T_cam_rig = invert_transform(T_rig_cam)
        ends = []
        for T_rig_board in scene.exposure_poses:
            point = (T_cam_rig @ T_rig_board @ centre)[:3]
            ends.append((np.asarray(camera.K) @ (point / point[2]))[:2])
        dx, dy = (float(v) for v in ends[1] - ends[0])
        return dx, dy

    def _set_scene(self, scene: Scene) -> None:
        with self._lock:
            self._scene = scene
            self._prefetched.clear()  # frames of the old scene
            self._trigger_used = set(SIDES)
            # A scene staged ahead: the ones announced before it were skipped and will not be shown.
            match = next((i for i, staged in enumerate(self._staged) if _same_scene(staged.scene, scene)), None)
            self._staged_now = None
            if match is not None:
                self._drop_staged(self._staged[:match])
                self._staged_now = self._staged[match]
                del self._staged[: match + 1]
                self._stage_changed.notify_all()

    def place_target(self, target: Target, *, distance_mm: float, seed: int = 0,
                     placement: str | None = None) -> np.ndarray:
        """The operator places the measured ``target`` facing the rig at ``distance_mm``; returns T_rig_board.

        The nominal pose is :func:`board_pose_facing_rig`'s. When the target distance is set by hand,
        each placement (a new distance, target or ``placement``) stands off by a random distance and yaw
        error (the profile's ``placement_*_sigma``), drawn once per placement: asking again for the same
        one (the next frame, a retry) keeps the target where it stands. ``placement`` names the placement
        and keys its draw (the campaign: the first configuration of the plan's run at this distance); None
        keys it by the distance and the placements made there so far. The target is shown with its print
        scale and bow. ``seed`` is the scene's noise seed, as for :meth:`show`.
        """
        key, placement, where = self._placement_for(target, distance_mm, placement)
        if key != self._placed:
            self._placed, self._placement = key, placement
            if where is not None:
                self._placements[where] += 1
        scene = self._target_scene(target, distance_mm, self._placement, seed)
        self._set_scene(scene)
        return scene.T_rig_board

    def _placement_for(self, target: Target, distance_mm: float,
                       name: str | None = None) -> tuple[tuple, dict, int | None]:
        """(key, placement, where) of placing ``target`` at ``distance_mm`` now, without placing it.

        ``where`` is the placement counter a new placement draws from (None: no count; see :meth:`place_target`).
        """
        errors = self.profile.target
        manual = self.rig_config.quantities["target_distance_mm"].axis == "manual"
        key = (target, float(distance_mm), name)
        if key == self._placed:
            return key, self._placement, None
        placement, where = {"distance_error_mm": 0.0, "yaw_error_deg": 0.0}, None
        if manual and (errors.placement_distance_sigma_mm > 0 or errors.placement_yaw_sigma_deg > 0):
            at = int(round(distance_mm * 1000)) & 0xFFFFFFFF
            if name is None:  # counted: the n-th placement at this distance
                where = at
                words = [self.seed & 0xFFFFFFFF, 0x91ACE, at, self._placements[at]]
            else:  # named: the same placement whenever it is made
                words = [self.seed & 0xFFFFFFFF, 0x91ACE, at, 0x9A3E, _crc(name)]
            rng = np.random.default_rng(words)
            placement = {"distance_error_mm": float(rng.normal(0.0, errors.placement_distance_sigma_mm)),
                         "yaw_error_deg": float(rng.normal(0.0, errors.placement_yaw_sigma_deg))}
        return key, placement, where

    def _target_scene(self, target: Target, distance_mm: float, placement: dict, seed: int) -> Scene:
        if placement["distance_error_mm"] or placement["yaw_error_deg"]:
            T_rig_board = board_pose_facing_rig(distance_mm=distance_mm + placement["distance_error_mm"],
                                                board_size_mm=target.grid_size_mm,
                                                yaw_deg=placement["yaw_error_deg"])
        else:
            T_rig_board = board_pose_facing_rig(distance_mm=distance_mm, board_size_mm=target.grid_size_mm)
        return Scene(target=target, T_rig_board=T_rig_board, seed=int(seed), shape=board_shape(self.profile.target),
                     measured_target=True, placement=dict(placement, distance_mm=float(distance_mm)))

    # -- rendering ahead ---------------------------------------------------------------------------------------

    def stage(self, scenes: Sequence[tuple], *, at: RigPose, ahead: int = 16) -> None:
        """Announce the scenes that will be shown next, in order, all captured with the rig at ``at``.

        Each scene is ``("board", target, T_rig_board, seed)`` (as :meth:`show` will be called) or
        ``("target", target, distance_mm, seed[, placement])`` (as :meth:`place_target` will be called; the
        placement the operator will make is drawn as that call will draw it). Replaces what was
        staged before. Once the rig rests at ``at``, the first frame pair of up to ``ahead`` scenes
        not yet shown is rendered in the background (see the module docstring). Does nothing in
        bring-up, where the rig's rest is not observed.
        """
        if self.emulator is None:
            return
        placed, placement = self._placed, self._placement
        staged = []
        for kind, target, where, seed, *name in scenes:
            if kind == "board":
                scene = Scene(target=target, T_rig_board=np.array(where, dtype=np.float64), seed=int(seed),
                              shape=board_shape(self.profile.calibration_board))
            elif kind == "target":
                key, new_placement, _ = self._placement_for(target, where, *name)
                if key != placed:  # later frames at the same distance keep this placement
                    placed, placement = key, new_placement
                scene = self._target_scene(target, where, placement, seed)
            else:
                raise ValueError(f"staged scene kind must be 'board' or 'target', not {kind!r}")
            staged.append(_Staged(scene=scene, at=at))
        with self._lock:
            self._drop_staged(self._staged)
            self._staged = staged
            self._ahead = max(1, int(ahead))
            self._stage_changed.notify_all()
            if self._ahead_thread is None:
                self._ahead_pool = ThreadPoolExecutor(max_workers=len(SIDES), thread_name_prefix="sim-render-ahead")
                self._ahead_thread = threading.Thread(target=self._render_ahead, name="sim-render-ahead", daemon=True)
                self._ahead_thread.start()

    def staged_rendered(self) -> int:
        """How many staged scenes, not shown yet, have their frames rendered (or being rendered)."""
        with self._lock:
            return sum(1 for entry in self._staged if entry.frames is not None)

    @staticmethod
    def _drop_staged(staged: Sequence[_Staged]) -> None:
        for entry in staged:
            entry.dropped = True
            for future in (entry.frames or {}).values():
                future.cancel()

    @staticmethod
    def _at_pose(pose: RigPose, at: RigPose) -> bool:
        return all(abs(getattr(pose, name) - getattr(at, name)) <= REST_TOLERANCE for name in
                   ("baseline_mm", "alpha_left_deg", "alpha_right_deg", "tilt_left_deg", "tilt_right_deg"))

    def _at_rest(self, idle: bool, snapshot: _Snapshot, at: RigPose) -> bool:
        """The rig stands still at ``at`` and rings no more: a frame taken now or later looks the same.

        ``idle``: the controller was idle before ``snapshot`` was taken. Read after it, a move that ended in
        between would count as rest while the snapshot holds its last instant, before its landing.
        """
        if not idle or not self._at_pose(snapshot.pose, at):
            return False
        return snapshot.state is None or not (any(snapshot.state.ringing_deg.values())
                                              or any(snapshot.state.rock_deg.values()))

    def _predicted_snapshot(self) -> _Snapshot | None:
        """The pair at rest where the queued moves end: what a trigger will see there once the ringing stopped.

        None when it cannot be known now: homing or stopping, or a motion ended while the plan was read (the
        next look sees it in the history). The history the prediction starts from and the motions it adds are
        those of one instant, whatever the threads' timing: a motion's landing draw is made once, either in
        the history already or predicted here (a prediction read mid-move that also found the move's event in
        the history drew that landing twice, rendered for a state the rig never reached, and on a loaded
        machine the frames were rendered again at the trigger).
        """
        self._catch_up()
        plan = self.emulator.planned_motion()
        if plan is None:
            return None
        values = self._with_fixed(to_physical(self.rig_config, plan.end))
        pose = self._pose_of(values)
        if self.profile.mechanically_ideal and self.history is None:
            return _Snapshot(pose=pose, T_rig_cam={"left": pose.T_rig_left, "right": pose.T_rig_right})
        with self._history_lock:
            if self._motions_seen != plan.reported:
                return None
            history = copy.deepcopy(self.history)
            if history is not None:  # the motions' events will come: their directions and landing draws
                draws = self._draws.copy()
                for start, end in plan.pending:
                    end_values = to_physical(self.rig_config, end)  # as _on_motion will have it
                    approach = self._physical_approach(_approach_of(start, end))
                    history.moved(end_values, end_s=0.0, approach=approach,
                                  keys=self._landing_keys("move", end_values, approach, draws=draws))
        state = pair_state(self.profile, values, history=history, now_s=math.inf, tilting=self.tilting)
        return _Snapshot(pose=pose, T_rig_cam={"left": state.T_bench_left, "right": state.T_bench_right},
                         state=state)

    def _with_fixed(self, values: dict[str, float]) -> dict[str, float]:
        """``values`` with the config's fixed quantities added (their axis is ``fixed``)."""
        for quantity, mapping in self.rig_config.quantities.items():
            if mapping.axis == "fixed":
                values.setdefault(quantity, float(mapping.value))
        return values

    def _physical_approach(self, approach_by_axis: dict[str, int]) -> dict[str, int]:
        """Per moved quantity the direction it arrived in, from the emulator's per-axis (machine) directions."""
        approach = {}
        for quantity, axis in self.rig_config.driven.items():
            if quantity in self._moved and approach_by_axis.get(axis):
                sign = 1 if self.rig_config.quantities[quantity].scale > 0 else -1
                approach[quantity] = approach_by_axis[axis] * sign
        return approach

    def _render_ahead(self) -> None:
        """The thread that renders staged scenes for the state the rig will rest in, and checks it once it does."""
        while not self._stopping.is_set():
            with self._lock:
                entries = [e for e in self._staged if not e.dropped]
                unchecked = [e for e in entries if e.frames is not None and not e.checked]
                waiting = [e for e in entries if e.frames is None]
                render = bool(waiting) and len(entries) - len(waiting) < self._ahead
                if not unchecked and not render:
                    self._stage_changed.wait(0.1)
                    continue
                at = (unchecked or waiting)[0].at
            try:
                idle = self.emulator.state == "Idle"
                snapshot = self._snapshot()
                at_rest = self._at_rest(idle, snapshot, at)
                predicted = self._predicted_snapshot() if render and not at_rest else None
            except Exception:  # noqa: BLE001 - the emulator stopping under the thread ends it
                if self.emulator is None or not self.emulator.running:
                    return
                raise
            with self._lock:
                if at_rest:  # the real state: keep what was rendered for it, render again what was not
                    for entry in unchecked:
                        if any(e is entry for e in self._staged) and not _same_view(entry.snapshot, snapshot):
                            self._drop_staged([entry])
                            entry.dropped, entry.frames = False, None
                        entry.checked = True
                elif predicted is not None and self._at_pose(predicted.pose, at):
                    snapshot = predicted  # the move there is queued: render for where it will rest
                else:
                    self._stage_changed.wait(REST_POLL_S)
                    continue
                budget = self._ahead - sum(1 for e in self._staged if e.frames is not None and not e.dropped)
                for entry in [e for e in self._staged if e.frames is None and not e.dropped][:max(0, budget)]:
                    entry.snapshot, entry.checked = snapshot, at_rest
                    entry.frames = {side: self._ahead_pool.submit(self._render_job, side, snapshot, entry.scene, 0)
                                    for side in SIDES}
                if not at_rest:
                    self._stage_changed.wait(REST_POLL_S)  # until the rig rests, to check the prediction

    def reported_values(self) -> dict[str, float]:
        """Physical values (``baseline_mm``, ``toe_in_*_deg``, ...) of the axes now: what the mechanics are told.

        From where the emulator's motors stand (``physical_position()``, whole steps), not from its step
        counters: the two agree once the controller is homed, and before that the counters restart at 0
        wherever the axes stand while the cameras stand where the axes do. Bring-up: the pose source's.
        """
        if self.pose_source is not None:
            pose = self.pose_source()
            return {"baseline_mm": pose.baseline_mm, "toe_in_left_deg": pose.toe_in_left_deg,
                    "toe_in_right_deg": pose.toe_in_right_deg, "tilt_left_deg": pose.tilt_left_deg,
                    "tilt_right_deg": pose.tilt_right_deg}
        return self._with_fixed(to_physical(self.rig_config, self.emulator.physical_position()))

    def rig_pose(self) -> RigPose:
        """The rig pose the axes are at now (fixed quantities from the config): what the mechanics are commanded.

        On a mechanically ideal bench the cameras stand exactly there. Bring-up: the pose source's.
        """
        if self.pose_source is not None:
            return self.pose_source()
        return self._pose_of(self.reported_values())

    @staticmethod
    def _pose_of(physical: dict[str, float]) -> RigPose:
        return RigPose(
            baseline_mm=physical["baseline_mm"],
            alpha_left_deg=alpha_from_toe_in(physical["toe_in_left_deg"]),
            alpha_right_deg=alpha_from_toe_in(physical["toe_in_right_deg"]),
            tilt_left_deg=physical.get("tilt_left_deg", 0.0), tilt_right_deg=physical.get("tilt_right_deg", 0.0),
        )

    # -- the mechanics ---------------------------------------------------------------------------------------------

    def begin_configuration(self, config_id: str, *, targets: dict[str, float], arrivals: dict[str, str]) -> None:
        """The rig is about to be moved for ``config_id`` (a campaign's configuration or design visit).

        ``targets``: its commanded physical values; ``arrivals``: per quantity, the configuration at which the
        plan's rig arrived at that value (see :class:`MoveContext`). From now on a move that ends an axis at its
        target draws the landing error of (seed, quantity, arrival, the index of that arrival here): the same
        draw whether the rig came from the plan's previous configuration or from homing after a resume. Other
        moves (a homing, a re-approach, a stop) draw by their kind and index within the configuration; a
        homing by its index in the run.
        """
        with self._history_lock:
            self._context = MoveContext(config_id=config_id, targets=dict(targets), arrivals=dict(arrivals))
            self._draws = Counter()

    def _landing_keys(self, kind: str, end: dict[str, float], approach: dict[str, int], *,
                      draws: Counter) -> dict[str, tuple[int, ...]] | None:
        """Per moved quantity the key of its landing draw (call with the history lock held), counted in ``draws``
        (the bench's own when the motion happened, a copy when it is predicted). None without a context: the
        history keys the draws by position and visits."""
        context, keys = self._context, {}
        if context is None:
            return None
        if kind == "home":
            index = self._homings
            self._homings += draws is self._draws
            return {q: (0x40E, index) for q in approach}
        for q in approach:
            arrived = kind == "move" and q in context.targets and abs(end[q] - context.targets[q]) <= REST_TOLERANCE
            count = (q, "arrive" if arrived else kind)
            if arrived:
                keys[q] = (0xA441, _crc(context.arrivals.get(q, context.config_id)), draws[count])
            else:
                keys[q] = (0x7A45, _crc(context.config_id), _crc(kind), draws[count])
            draws[count] += 1
        return keys

    def _catch_up(self) -> None:
        """Bring the emulator's model up to the clock's now, so that every motion that has ended (the clock stops at
        its end; the emulator's thread may not have noticed yet) is in the history before the axes are read."""
        if self.history is not None:
            self.emulator.state  # noqa: B018 - the property advances the model

    def _on_motion(self, event: MotionEvent) -> None:
        """A motion ended (the emulator's thread, with its lock held): into the history, with its landing draws."""
        if self.history is None:
            return
        end = to_physical(self.rig_config, event.end)
        approach = self._physical_approach(event.approach)
        with self._history_lock:
            self._motions_seen += 1
            keys = self._landing_keys(event.kind, end, approach, draws=self._draws)
            self.history.moved(end, end_s=event.end_s, approach=approach, keys=keys)

    def _snapshot(self, at_s: float | None = None) -> _Snapshot:
        """The reported and true pose of the pair at a trigger starting at bench time ``at_s`` (default: now)."""
        if self.profile.mechanically_ideal and self.history is None:
            pose = self.rig_pose()
            return _Snapshot(pose=pose, T_rig_cam={"left": pose.T_rig_left, "right": pose.T_rig_right})
        now = self.clock.now() if at_s is None else at_s
        # The frame sees the pair at mid-exposure (exposure_s is in bench seconds).
        at = now + 0.5 * self.exposure_s
        # The axes and the history of one instant: reading where the motors stand does not advance the
        # emulator's model, so a motion can end between the catch-up and that read, and its landing draw reach
        # the history only at the next advance. Such a snapshot showed the rig at its end without its landing,
        # and the render-ahead check, which reads the state (an advance) after it, took it for the rest.
        while True:
            self._catch_up()
            with self._history_lock:
                seen = self._motions_seen
            values = self.reported_values()
            self._catch_up()
            with self._history_lock:
                if self._motions_seen == seen:
                    state = pair_state(self.profile, values, history=self.history, now_s=at, tilting=self.tilting)
                    break
        pose = self._pose_of(values)
        smear = {}
        for side in SIDES:
            camera = self.left_model if side == "left" else self.right_model
            # Pan ringing turns the camera about (nearly) its y axis: the image moves along x.
            rate = math.radians(state.ringing_rate_deg_s[side])
            sign = 1.0 if side == "left" else -1.0
            dx = -sign * rate * self.exposure_s * camera.fx
            smear[side] = (dx, 0.0) if dx else None
        return _Snapshot(pose=pose, T_rig_cam={"left": state.T_bench_left, "right": state.T_bench_right},
                         state=state, smear_px=smear, sim_time_s=at)

    def truth(self) -> dict:
        """JSON-ready truth of the bench now: reported and true axes, camera poses, R and T, the board.

        ``cameras.*.T_bench_cam`` are 4x4 camera-to-bench transforms (mm; the bench frame is the
        nominal rig frame), ``R``/``T`` the pair's true extrinsics (X_right = R X_left + T), and
        ``structure`` their optical baseline, alphas and rotation angle (as
        :func:`stereo_bench.geometry.stereo_structure` computes them). ``target`` describes the board
        in the scene, if any: its true pose, print scale, bow and, when placed by hand, the
        placement error; ``square_true_mm`` is the printed square as the board really is.
        """
        snapshot = self._snapshot()
        scene = self._scene
        return {
            "profile": self.profile.name,
            "profile_values": self.profile.model_dump(mode="json"),
            "sim_time_s": None if math.isnan(snapshot.sim_time_s) else snapshot.sim_time_s,
            "reported": {"baseline_mm": snapshot.pose.baseline_mm, "toe_in_left_deg": snapshot.pose.toe_in_left_deg,
                         "toe_in_right_deg": snapshot.pose.toe_in_right_deg,
                         "tilt_left_deg": snapshot.pose.tilt_left_deg, "tilt_right_deg": snapshot.pose.tilt_right_deg},
            "axes": self._axes_truth(snapshot),
            **self._pair_truth(snapshot),
            "cameras": {side: {"T_bench_cam": snapshot.T_rig_cam[side].tolist(),
                               "centre_mm": snapshot.T_rig_cam[side][:3, 3].tolist(),
                               "K": np.asarray(model.K).tolist(), "dist": np.asarray(model.dist).ravel().tolist()}
                        for side, model in (("left", self.left_model), ("right", self.right_model))},
            "target": self._board_truth(scene),
        }

    def truth_without_landing(self) -> dict:
        """The pair at rest at the reported axes without the moves' random landing errors: ``R``, ``T``, ``structure``.

        Backlash still follows each axis' direction of approach. What a model of the rig can know:
        the landing errors are the rig's repeatability, different at every move.
        """
        self._catch_up()
        values = self.reported_values()
        with self._history_lock:
            history = copy.deepcopy(self.history)
        if history is not None:
            for axis in history.axes.values():
                axis.landing = 0.0
        state = pair_state(self.profile, values, history=history, tilting=self.tilting)
        return self._pair_truth(_Snapshot(pose=self._pose_of(values),
                                          T_rig_cam={"left": state.T_bench_left, "right": state.T_bench_right}))

    def _axes_truth(self, snapshot: _Snapshot) -> dict:
        if snapshot.state is None:
            return {"separation_mm": snapshot.pose.baseline_mm, "pan_left_deg": snapshot.pose.toe_in_left_deg,
                    "pan_right_deg": snapshot.pose.toe_in_right_deg}
        state = snapshot.state
        axes = {"separation_mm": state.separation_mm, "pan_left_deg": state.pan_left_deg,
                "pan_right_deg": state.pan_right_deg, "ringing_deg": state.ringing_deg, "rock_deg": state.rock_deg}
        for side, tilt in state.tilt_deg.items():  # a driven tilt's joint angle (none on a rig without one)
            axes[f"tilt_{side}_deg"] = tilt
        if self.history is not None:
            axes["history"] = self.history.snapshot()
        return axes

    @staticmethod
    def _pair_truth(snapshot: _Snapshot) -> dict:
        T_right_left = invert_transform(snapshot.T_rig_cam["right"]) @ snapshot.T_rig_cam["left"]
        R, T = T_right_left[:3, :3], T_right_left[:3, 3]
        # Both centres on one point (B = 0 at home on the ideal bench) have no baseline and no alphas.
        structure = stereo_structure(R, T) if float(np.linalg.norm(T)) > 1e-9 else None
        return {"R": R.tolist(), "T": T.tolist(), "structure": structure}

    def _board_truth(self, scene: Scene) -> dict | None:
        if scene.target is None or scene.T_rig_board is None:
            return None
        shape = scene.shape or BoardShape()
        return {"kind": "target" if scene.measured_target else "calibration_board",
                "T_bench_board": scene.T_rig_board.tolist(), "print_scale": shape.scale, "bow_mm": shape.bow_mm,
                "square_nominal_mm": float(scene.target.square_mm),
                "square_true_mm": float(scene.target.square_mm * shape.scale), "placement": scene.placement}

    def _renderer(self, target: Target) -> StereoRenderer:
        # Built outside the lock (~1-2 s): a render of a target whose renderer exists never waits for another's.
        with self._renderers_lock:
            built = self._renderers.get(target)
            if built is None:
                built = self._renderers[target] = Future()
                built.set_running_or_notify_cancel()
                build = True
            else:
                build = False
        if build:
            try:
                built.set_result(StereoRenderer(target, self.left_model, self.right_model, optics=self.optics))
            except BaseException as error:
                built.set_exception(error)
                raise
        return built.result()

    def warm_up(self, *targets: Target) -> None:
        """Build the renderers of ``targets`` in the background (~1-2 s each, side by side), e.g. while the rig
        homes; a failure is raised by the first render that needs the renderer."""
        def build(target: Target) -> None:
            with contextlib.suppress(Exception):
                self._renderer(target)

        for target in targets:
            thread = threading.Thread(target=build, args=(target,), name="sim-warm-up", daemon=True)
            thread.start()
            self._warming.append(thread)

    def render(self, side: str) -> tuple[np.ndarray, dict]:
        """One frame of the ``side`` camera now, with its ground truth as metadata.

        Both cameras share a trigger, so the first grab of a pair renders the other camera's view
        too, on a second thread and from the same rig pose; the other grab then collects it.
        """
        with self._lock:
            new_trigger = self._start_exposure(side)
            prefetched = self._prefetched.pop(side, None)
            if prefetched is not None and not new_trigger:
                job = prefetched
            else:
                snapshot = self._snapshot(self._trigger_s)
                other = "right" if side == "left" else "left"
                ahead = self._prerendered(snapshot) if new_trigger else None
                if ahead is not None:  # rendered ahead for exactly this scene and state: claim both frames
                    job, self._prefetched[other] = ahead[side], ahead[other]
                    self._claim(side, snapshot)
                    self._claim(other, snapshot)
                    self.prerendered_used += 1
                else:
                    job = self._claim(side, snapshot)
                    if new_trigger:
                        other_job = self._claim(other, snapshot)
                        self._prefetched[other] = self._pool.submit(self._render_job, *other_job)
        if isinstance(job, Future):
            return job.result()
        return self._render_job(*job)

    def _prerendered(self, snapshot: _Snapshot) -> dict[str, Future] | None:
        """The frames rendered ahead for the current scene's first trigger, if this trigger sees what they show."""
        staged, self._staged_now = self._staged_now, None  # one use: a second trigger renders anew
        if staged is None or staged.dropped:
            return None
        if (staged.frames is None or any(self._scene.frames_rendered[side] for side in SIDES)
                or not _same_view(staged.snapshot, snapshot)):
            self._drop_staged([staged])
            return None
        return staged.frames

    def preview(self, side: str, width_px: int | None = None) -> np.ndarray:
        """The ``side`` camera's view of the scene now, for a live preview (aiming, watching).

        Not counted among the scene's frames and with noise of its own, so however many previews are
        taken, the frames a capture renders (and so a recording) stay the same. ``width_px``: render
        at most this wide, through the cameras scaled down (the same view in fewer pixels: 640 of
        1920 px renders ~10x faster than the full frame a preview would only shrink); None: full size.
        """
        with self._lock:
            scene, snapshot = self._scene, self._snapshot()
            self._previews += 1
            index = PREVIEW_FRAME_BASE + self._previews
        widest = max(self.left_model.image_size[0], self.right_model.image_size[0])
        scale = 1.0 if width_px is None else min(1.0, width_px / widest)
        return self._render_job(side, snapshot, scene, index, scale=scale)[0]

    def _preview_renderer(self, target: Target, scale: float) -> StereoRenderer:
        """A renderer of ``target`` for previews ``scale`` times the cameras' size (built once, ~0.1 s at 1/3)."""
        key = (target, scale)
        with self._renderers_lock:
            if key not in self._preview_renderers:
                optics = replace(self.optics, blur_sigma_px=self.optics.blur_sigma_px * scale,
                                 jitter_px=self.optics.jitter_px * scale)
                texels = max(32, round(_auto_px_per_square(target) * scale))  # as fine, in preview pixels
                self._preview_renderers[key] = StereoRenderer(
                    target, _scaled_camera(self.left_model, scale), _scaled_camera(self.right_model, scale),
                    optics=optics, texture_px_per_square=texels)
            return self._preview_renderers[key]

    def _claim(self, side: str, snapshot: _Snapshot) -> tuple:
        """Reserve the next frame index of ``side`` in the current scene (call with the lock held)."""
        scene = self._scene
        index = scene.frames_rendered[side]
        scene.frames_rendered[side] += 1
        return side, snapshot, scene, index

    def _render_job(self, side: str, snapshot: _Snapshot, scene: Scene, index: int, *,
                    scale: float = 1.0) -> tuple[np.ndarray, dict]:
        pose = snapshot.pose
        T_rig_cam = snapshot.T_rig_cam[side]
        rng = np.random.default_rng([scene.seed, SIDES.index(side), index])
        target = scene.target
        board = None
        if target is None:
            # Nothing in front of the rig: the renderer's wall only (the board behind the camera).
            target = Checkerboard(9, 6, 27.0)
            T_cam_board = np.eye(4)
            T_cam_board[2, 3] = -1000.0
        else:
            T_rig_board, skew_s = board_at_exposure(self.profile, scene.T_rig_board, seed=scene.seed, index=index,
                                                    side=side, measured_target=scene.measured_target)
            T_cam_board = np.linalg.inv(T_rig_cam) @ T_rig_board
            shape = scene.shape or BoardShape()
            board = {"T_cam_board": T_cam_board[:3].tolist(), "print_scale": shape.scale, "bow_mm": shape.bow_mm}
            if skew_s is not None:
                board["capture_skew_s"] = skew_s
        renderer, smear_px = self._renderer(target), snapshot.smear_px[side]
        carried = self._board_smear_px(side, scene, T_rig_cam) if board is not None else None
        if carried is not None:  # the hand's motion and the head's ringing add up
            smear_px = carried if smear_px is None else (smear_px[0] + carried[0], smear_px[1] + carried[1])
        # The image's velocity during the readout (a rolling shutter shears it): the ringing's, as its smear.
        velocity = None if smear_px is None else (smear_px[0] / self.exposure_s, smear_px[1] / self.exposure_s)
        if scale != 1.0:  # a preview's smaller image: the same view, every length in its pixels
            renderer = self._preview_renderer(target, scale)
            smear_px = None if smear_px is None else (smear_px[0] * scale, smear_px[1] * scale)
            velocity = None if velocity is None else (velocity[0] * scale, velocity[1] * scale)
        # The corner scatter beyond image noise is the scene's and the rig's, not the frame's: frames of one rest
        # in front of one scene share it (a still board's print texture and JPEG blocks, the optics' aberrations
        # where its corners fall), so averaging frames does not remove it, as at a real bench.
        jitter_rng = np.random.default_rng([scene.seed, SIDES.index(side), 0x717E5, _crc(repr(pose))])
        view = renderer.render_view(side, T_cam_board, rng, shape=scene.shape, smear_px=smear_px,
                                    velocity_px_s=velocity, jitter_rng=jitter_rng)
        truth = {"T_bench_cam": T_rig_cam[:3].tolist(), **self._pair_truth(snapshot), "board": board}
        if snapshot.state is not None:
            truth["ringing_deg"] = snapshot.state.ringing_deg[side]
            truth["rock_deg"] = snapshot.state.rock_deg[side]
        meta = {"baseline_mm": pose.baseline_mm, "alpha_left_deg": pose.alpha_left_deg,
                "alpha_right_deg": pose.alpha_right_deg, "scene_seed": scene.seed, "scene_frame": index,
                "truth": truth}
        return view.image, meta

    def _start_exposure(self, side: str) -> bool:
        """The simulated pair is hardware-triggered: both cameras of one capture share one trigger time.

        A grab starts a new trigger unless the other camera started one that this camera has not used
        yet, so the time spent rendering (which real sensors don't spend) never shows up as left-right
        skew. Purely logical, no timeout: a skew that depended on how long a render took would make
        the frames (and so a resumed campaign) depend on the machine's speed. A trigger starts at the bench
        clock's now and takes ``exposure_s`` of it (exposure and readout).
        """
        new = side in self._trigger_used
        if new:
            self._trigger_s, self._trigger_wall, self._trigger_used = self.clock.now(), time.monotonic(), set()
            self.clock.advance(self.exposure_s)
        self._trigger_used.add(side)
        return new

    def frame_clock(self) -> float:
        """Timestamp (bench-clock s) of the current capture: trigger + exposure (when both frames are read out)."""
        return self._trigger_s + self.exposure_s

    def frame_ready_at(self) -> float:
        """When (``time.monotonic()`` s) the current capture is read out: paces the simulation in real time."""
        return self._trigger_wall + self.exposure_s / self.time_scale

    def cameras(self, settings: CameraSettings | None = None) -> tuple[SyntheticCamera, SyntheticCamera]:
        """The left and right simulated cameras (not yet open)."""
        width, height = self.left_model.image_size
        settings = settings or CameraSettings(width_px=width, height_px=height)
        # SyntheticCamera scales its exposure delay by its own factor, the inverse of a speed-up.
        scale = 1.0 / self.time_scale
        # Both cameras expose on one trigger: a pair takes one exposure, not one per camera.
        return tuple(
            SyntheticCamera(lambda side=side: self.render(side), name=f"sim-{side}", settings=settings,
                            exposure_s=self.exposure_s, time_scale=scale, clock=self.frame_clock,
                            ready_at=self.frame_ready_at)
            for side in SIDES
        )
