"""The simulated bench: a GRBL emulator on a pseudo-terminal, a scene, and two cameras that render it.

The cameras render whatever the scene holds (the calibration board at some pose, the measured
target at some distance, or nothing) from the rig pose that the emulator's axes are at *at the
moment of the grab*, converted to physical units through the same ``RigConfig`` the real driver
uses. So the runner drives the real serial driver against the emulator, and what the cameras see
follows from where the motors really are — a move that did not finish shows up in the images.

Noise is reproducible per scene: every change of the scene carries a seed, and the n-th frame a
camera renders of that scene uses ``(seed, camera, n)``. A campaign that resumes after a crash
therefore renders the same frames as one that never stopped.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from drivers.camera.base import CameraSettings
from drivers.camera.synthetic import SyntheticCamera
from drivers.rig.config import RigConfig, alpha_from_toe_in, to_physical
from drivers.rig.motion import REFERENCE_HOMING_SEEK_RATE_PER_MIN, REFERENCE_HOMING_SETTLE_S
from drivers.sim.grbl_emulator import AxisSpec, GrblEmulator, axis_specs_for_travel
from drivers.sim.render import Optics, StereoRenderer
from stereo_bench.geometry import CameraModel, RigPose
from stereo_bench.targets import CharucoTarget, Checkerboard

Target = Checkerboard | CharucoTarget
SIDES = ("left", "right")
PREVIEW_FRAME_BASE = 1 << 40  # preview frames' noise streams start here, far from any captured frame's index


@dataclass
class Scene:
    """What stands in front of the rig: a target at ``T_rig_board`` (4x4, mm), or nothing."""

    target: Target | None = None
    T_rig_board: np.ndarray | None = None
    seed: int = 0
    frames_rendered: dict[str, int] = field(default_factory=lambda: {side: 0 for side in SIDES})


class SimulatedBench:
    """Emulator + scene + two rendering cameras; ``start()``/``stop()`` or a context manager.

    Args:
        rig_config: axis mapping shared with the real driver (default: X = B, Y/Z = toe-ins).
        left, right: camera intrinsics (default 1920x1080, f = 4 mm, 3 um pixels).
        optics: image formation (blur, noise, ...).
        time_scale: > 1 runs motion and exposures faster than real time.
        exposure_s: simulated exposure + readout per frame (real-time seconds).
        target_distance_axis: the emulator's axis letter for a motorised target distance, if any.
        pose_source: where the rig is, when a real controller drives it (bring-up: the cameras are not
            mounted yet and render from the positions the controller reports); no emulator is started.
    """

    def __init__(
        self, *, rig_config: RigConfig | None = None, left: CameraModel | None = None,
        right: CameraModel | None = None, optics: Optics | None = None, time_scale: float = 1.0,
        exposure_s: float = 0.02, homing_enabled: bool = True, axis_specs: dict[str, AxisSpec] | None = None,
        pose_source: Callable[[], RigPose] | None = None,
    ):
        self.rig_config = rig_config or RigConfig()
        self.left_model = left or CameraModel.from_sensor(name="left")
        self.right_model = right or CameraModel.from_sensor(name="right")
        self.optics = optics or Optics()
        self.time_scale = time_scale
        self.exposure_s = exposure_s
        self.pose_source = pose_source
        # The emulated controller's travel ($13x) comes from the rig config's soft limits, in the machine space
        # a stock Grbl gives (negative from the homing switch); a config with positive machine targets gets
        # the HOMING_FORCE_SET_ORIGIN build that serves them (see docs/RIG.md).
        specs, force_set_origin = axis_specs_for_travel(self.rig_config.machine_travel())
        self.emulator = None if pose_source is not None else GrblEmulator(
            axes=self.rig_config.axes, axis_specs=axis_specs or specs, time_scale=time_scale,
            homing_enabled=homing_enabled, force_set_origin=force_set_origin,
            homing_seek_rate_per_min=REFERENCE_HOMING_SEEK_RATE_PER_MIN, homing_settle_s=REFERENCE_HOMING_SETTLE_S,
        )
        self._scene = Scene()
        self._lock = threading.Lock()
        self._renderers: dict[Target, StereoRenderer] = {}
        self._renderers_lock = threading.Lock()
        self._trigger_time = time.monotonic()
        self._trigger_used: set[str] = set(SIDES)  # the first grab starts a trigger
        self._prefetched: dict[str, Future] = {}
        self._previews = 0
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-render")
        # What the operator would set by hand (the target distance unless it is motorised).
        self.manual_values: dict[str, float] = {}

    # -- lifecycle ---------------------------------------------------------------------------------------------

    def start(self) -> SimulatedBench:
        if self.emulator is not None:
            self.emulator.start()
        return self

    def stop(self) -> None:
        self._pool.shutdown(wait=True)
        if self.emulator is not None:
            self.emulator.stop()

    def __enter__(self) -> SimulatedBench:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def tty_path(self) -> str:
        if self.emulator is None:
            raise RuntimeError("this simulated bench renders from a real controller's positions: it has no emulator")
        return self.emulator.tty_path

    # -- the scene ---------------------------------------------------------------------------------------------

    def show(self, target: Target | None, T_rig_board: np.ndarray | None = None, *, seed: int = 0) -> None:
        """Put ``target`` at ``T_rig_board`` in front of the rig (None: an empty scene)."""
        with self._lock:
            self._scene = Scene(target=target, T_rig_board=None if T_rig_board is None else np.array(T_rig_board),
                                seed=int(seed))
            self._prefetched.clear()  # frames of the old scene
            self._trigger_used = set(SIDES)

    def operator_prompt(self, message: str) -> None:
        """Stands in for the operator at a manual step: records the values the rig asked for."""
        self.last_prompt = message

    def rig_pose(self) -> RigPose:
        """The rig pose the emulator's axes are at now (fixed quantities from the config), or the pose source's.

        Where the axes really are, not what the controller's step counters say: the two differ until the
        controller is homed (after a boot the counters start at 0 wherever the axes stand)."""
        if self.pose_source is not None:
            return self.pose_source()
        physical = to_physical(self.rig_config, self.emulator.physical_position())
        for quantity, mapping in self.rig_config.quantities.items():
            if mapping.axis == "fixed":
                physical.setdefault(quantity, float(mapping.value))
        return RigPose(
            baseline_mm=physical["baseline_mm"],
            alpha_left_deg=alpha_from_toe_in(physical["toe_in_left_deg"]),
            alpha_right_deg=alpha_from_toe_in(physical["toe_in_right_deg"]),
            tilt_left_deg=physical.get("tilt_left_deg", 0.0), tilt_right_deg=physical.get("tilt_right_deg", 0.0),
        )

    def _renderer(self, target: Target) -> StereoRenderer:
        with self._renderers_lock:
            if target not in self._renderers:
                self._renderers[target] = StereoRenderer(target, self.left_model, self.right_model,
                                                         optics=self.optics)
            return self._renderers[target]

    def warm_up(self, *targets: Target) -> None:
        """Build the renderers of ``targets`` in the background (~1-2 s each), e.g. while the rig homes."""
        for target in targets:
            self._pool.submit(self._renderer, target)

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
                pose = self.rig_pose()
                job = self._claim(side, pose)
                if new_trigger:
                    other = "right" if side == "left" else "left"
                    other_job = self._claim(other, pose)
                    self._prefetched[other] = self._pool.submit(self._render_job, *other_job)
        if isinstance(job, Future):
            return job.result()
        return self._render_job(*job)

    def preview(self, side: str) -> np.ndarray:
        """The ``side`` camera's view of the scene now, for a live preview (aiming, watching).

        Not counted among the scene's frames and with noise of its own, so however many previews are
        taken, the frames a capture renders (and so a recording) stay the same.
        """
        with self._lock:
            scene, pose = self._scene, self.rig_pose()
            self._previews += 1
            index = PREVIEW_FRAME_BASE + self._previews
        return self._render_job(side, pose, scene, index)[0]

    def _claim(self, side: str, pose: RigPose) -> tuple:
        """Reserve the next frame index of ``side`` in the current scene (call with the lock held)."""
        scene = self._scene
        index = scene.frames_rendered[side]
        scene.frames_rendered[side] += 1
        return side, pose, scene, index

    def _render_job(self, side: str, pose: RigPose, scene: Scene, index: int) -> tuple[np.ndarray, dict]:
        T_rig_cam = pose.T_rig_left if side == "left" else pose.T_rig_right
        rng = np.random.default_rng([scene.seed, SIDES.index(side), index])
        target = scene.target
        if target is None:
            # Nothing in front of the rig: the renderer's wall only (the board behind the camera).
            target = Checkerboard(9, 6, 27.0)
            T_cam_board = np.eye(4)
            T_cam_board[2, 3] = -1000.0
        else:
            T_cam_board = np.linalg.inv(T_rig_cam) @ scene.T_rig_board
        view = self._renderer(target).render_view(side, T_cam_board, rng)
        meta = {"baseline_mm": pose.baseline_mm, "alpha_left_deg": pose.alpha_left_deg,
                "alpha_right_deg": pose.alpha_right_deg, "scene_seed": scene.seed, "scene_frame": index}
        return view.image, meta

    def _start_exposure(self, side: str) -> bool:
        """The simulated pair is hardware-triggered: both cameras of one capture share one trigger time.

        A grab starts a new trigger unless the other camera started one that this camera has not used
        yet, so the time spent rendering (which real sensors don't spend) never shows up as left-right
        skew. Purely logical, no timeout: a skew that depended on how long a render took would make
        the frames (and so a resumed campaign) depend on the machine's speed.
        """
        new = side in self._trigger_used
        if new:
            self._trigger_time, self._trigger_used = time.monotonic(), set()
        self._trigger_used.add(side)
        return new

    def frame_clock(self) -> float:
        """Timestamp (monotonic s) of the current capture: trigger time + exposure."""
        return self._trigger_time + self.exposure_s / self.time_scale

    def cameras(self, settings: CameraSettings | None = None) -> tuple[SyntheticCamera, SyntheticCamera]:
        """The left and right simulated cameras (not yet open)."""
        width, height = self.left_model.image_size
        settings = settings or CameraSettings(width_px=width, height_px=height)
        # SyntheticCamera scales its exposure delay by its own factor, the inverse of a speed-up.
        scale = 1.0 / self.time_scale
        return tuple(
            SyntheticCamera(lambda side=side: self.render(side), name=f"sim-{side}", settings=settings,
                            exposure_s=self.exposure_s, time_scale=scale, clock=self.frame_clock)
            for side in SIDES
        )
