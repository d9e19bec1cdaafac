"""Who puts boards in front of the rig: the operator at the bench, the simulator, or a replay.

The runner asks a presenter for "the next calibration view" and "the measured target"; at the bench
that is a prompt (with coverage feedback on the calibration views kept so far), in simulation it is
a change of the simulated scene, in replay it is the next recorded pair.
"""

from __future__ import annotations

import zlib
from collections import Counter
from collections.abc import Callable
from typing import Protocol

import numpy as np

from stereo_bench.geometry import RigPose, board_pose_facing_rig
from stereo_bench.targets import Target
from stereo_bench.vision.detect import Detection


class CalibrationPlacementError(RuntimeError):
    """The calibration board cannot be shown to both cameras at this configuration."""


class Presenter(Protocol):
    def begin_configuration(self, config_id: str, pose: RigPose, distance_mm: float, n_views: int, *,
                            calibration_range_mm: tuple[float, float] | None = None) -> None: ...

    def present_calibration_view(self, index: int) -> None: ...

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None: ...

    def present_target(self, frame_index: int) -> None: ...


def scene_seed(seed: int, config_id: str, kind: str, index: int) -> int:
    """A reproducible seed for one capture, independent of what ran before it (so resume = no crash)."""
    words = [seed & 0xFFFFFFFF, zlib.crc32(config_id.encode()), zlib.crc32(kind.encode()), index]
    return int(np.random.SeedSequence(words).generate_state(1)[0])


class SimulatedPresenter:
    """Places boards in a :class:`drivers.sim.bench.SimulatedBench` scene."""

    def __init__(self, bench, calibration_board: Target, target: Target, *, seed: int = 0,
                 calibration_distance_mm: Callable[[float], tuple[float, float]] | None = None):
        self.bench = bench
        self.calibration_board = calibration_board
        self.target = target
        self.seed = seed
        self.calibration_distance_mm = calibration_distance_mm or (lambda z: (max(250.0, 0.6 * z), 1.3 * z))
        self._poses: list[np.ndarray] = []
        self._config_id = ""
        self._target_requests: Counter = Counter()
        bench.warm_up(calibration_board, target)
        self._distance_mm = 0.0

    def begin_configuration(self, config_id: str, pose: RigPose, distance_mm: float, n_views: int, *,
                            calibration_range_mm: tuple[float, float] | None = None) -> None:
        from drivers.sim.render import calibration_board_poses

        self._config_id, self._distance_mm = config_id, distance_mm
        self._target_requests = Counter()
        near, far = self.calibration_distance_mm(distance_mm)
        if calibration_range_mm:  # where the plan found the board fits both views
            near, far = max(near, calibration_range_mm[0]), min(far, calibration_range_mm[1])
            if near > far:
                near, far = calibration_range_mm
        rng = np.random.default_rng(scene_seed(self.seed, config_id, "calibration-poses", 0))
        try:
            # Usable views by the rule the plan predicted with (geometry.calibration_view_fits).
            self._poses = calibration_board_poses(
                pose, self.calibration_board, n_views=n_views, rng=rng, distance_mm=(near, far),
                left=self.bench.left_model, right=self.bench.right_model,
            )
        except ValueError as error:
            raise CalibrationPlacementError(f"calibration board cannot be shown to both cameras: {error}") from None

    def present_calibration_view(self, index: int) -> None:
        self.bench.show(self.calibration_board, self._poses[index],
                        seed=scene_seed(self.seed, self._config_id, "calibration", index))

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None:
        return None

    def present_target(self, frame_index: int) -> None:
        T_rig_board = board_pose_facing_rig(distance_mm=self._distance_mm, board_size_mm=self.target.grid_size_mm)
        # Asked again for the same frame (the target was not found): a fresh frame, not the same one.
        retry = self._target_requests[frame_index]
        self._target_requests[frame_index] += 1
        kind = "target" if retry == 0 else f"target-retry{retry}"
        self.bench.show(self.target, T_rig_board, seed=scene_seed(self.seed, self._config_id, kind, frame_index))


class Coverage:
    """Where the kept calibration views put the board, as ROS camera_calibration shows it.

    Fractions (0..1) of a 3x3 grid of each image that held a detected corner, and the spread of the
    board's apparent size; a calibration wants both high.
    """

    def __init__(self, image_size: tuple[int, int]):
        self.width, self.height = image_size
        self.cells = {"left": np.zeros((3, 3), bool), "right": np.zeros((3, 3), bool)}
        self.sizes: list[float] = []

    def add(self, side: str, detection: Detection) -> None:
        u = np.clip((detection.corners_px[:, 0] / self.width * 3).astype(int), 0, 2)
        v = np.clip((detection.corners_px[:, 1] / self.height * 3).astype(int), 0, 2)
        self.cells[side][v, u] = True
        extent = np.ptp(detection.corners_px, axis=0)
        self.sizes.append(float(np.hypot(*extent) / np.hypot(self.width, self.height)))

    def summary(self) -> str:
        spread = (max(self.sizes) - min(self.sizes)) if self.sizes else 0.0
        return (f"coverage left {self.cells['left'].mean():.0%}, right {self.cells['right'].mean():.0%} of the image; "
                f"board size spread {spread:.0%}")


class OperatorPresenter:
    """At the real bench: prompts the operator for each board placement, with coverage feedback."""

    wants_detections = True

    def __init__(self, prompt: Callable[[str], None], *, image_size: tuple[int, int], target_description: str):
        self.prompt = prompt
        self.image_size = image_size
        self.target_description = target_description
        self.coverage = Coverage(image_size)
        self._n_views = 0

    def begin_configuration(self, config_id: str, pose: RigPose, distance_mm: float, n_views: int, *,
                            calibration_range_mm: tuple[float, float] | None = None) -> None:
        self.coverage = Coverage(self.image_size)
        self._n_views = n_views
        self.prompt(f"[{config_id}] calibration: present the calibration board {n_views} times, each time at a new "
                    "position and tilt (up to ~40 deg), near and far, filling the corners of both views.")

    def present_calibration_view(self, index: int) -> None:
        self.prompt(f"calibration view {index + 1}/{self._n_views}: hold the board still in both views, then press "
                    f"Enter ({self.coverage.summary()})")

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None:
        for side, detection in (("left", left), ("right", right)):
            if detection is not None:
                self.coverage.add(side, detection)

    def present_target(self, frame_index: int) -> None:
        if frame_index == 0:
            self.prompt(f"put the measured {self.target_description} back facing the rig, then press Enter")
