"""Who puts boards in front of the rig: the operator at the bench, the simulator, or a replay.

The runner tells a presenter where each configuration stands and asks it for "the next calibration
view" and "the measured target"; at the bench the presenter answers with a :class:`Prompt` (with
coverage feedback on the calibration views kept so far) that the runner puts to the operators and
records, in simulation it changes the simulated scene (``stereo_bench.campaign.bench``), in replay it
queues the next recorded pair.
"""

from __future__ import annotations

import zlib
from typing import Protocol

import numpy as np

from stereo_bench.campaign.operator import Prompt
from stereo_bench.campaign.plan import Configuration
from stereo_bench.vision.detect import Detection


class CalibrationPlacementError(RuntimeError):
    """The calibration board cannot be shown to both cameras at this configuration."""


class Presenter(Protocol):
    """Puts boards in front of the cameras. A returned :class:`Prompt` is a step for the operator."""

    wants_detections: bool  # calibration_view_captured wants the views' detections (coverage feedback)

    def begin_configuration(self, configuration: Configuration) -> None:
        """The rig stands at ``configuration``: the measured target is at its distance from now on."""

    def prepare_calibration(self, n_views: int) -> Prompt | None:
        """``n_views`` calibration views follow; raises CalibrationPlacementError if none can be shown."""

    def present_calibration_view(self, index: int) -> Prompt | None: ...

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None: ...

    def present_target(self, frame_index: int) -> Prompt | None:
        """Show the measured target (asked again for the same frame when the target was not found)."""


def scene_seed(seed: int, config_id: str, kind: str, index: int) -> int:
    """A reproducible seed for one capture, independent of what ran before it (so resume = no crash)."""
    words = [seed & 0xFFFFFFFF, zlib.crc32(config_id.encode()), zlib.crc32(kind.encode()), index]
    return int(np.random.SeedSequence(words).generate_state(1)[0])


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
    """At the real bench: a prompt for each board placement, with coverage feedback."""

    wants_detections = True

    def __init__(self, *, image_size: tuple[int, int], target_description: str):
        self.image_size = image_size
        self.target_description = target_description
        self.coverage = Coverage(image_size)
        self._n_views = 0
        self._config_id: str | None = None

    def begin_configuration(self, configuration: Configuration) -> None:
        self._config_id = configuration.config_id

    def prepare_calibration(self, n_views: int) -> Prompt:
        self.coverage = Coverage(self.image_size)
        self._n_views = n_views
        return Prompt("calibration_board", f"[{self._config_id}] calibration: present the calibration board "
                      f"{n_views} times, each time at a new position and tilt (up to ~40 deg), near and far, "
                      "filling the corners of both views; press Enter to begin", config_id=self._config_id)

    def present_calibration_view(self, index: int) -> Prompt:
        return Prompt("calibration_view", f"calibration view {index + 1}/{self._n_views}: hold the board still in "
                      f"both views, then press Enter ({self.coverage.summary()})", config_id=self._config_id,
                      index=index)

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None:
        for side, detection in (("left", left), ("right", right)):
            if detection is not None:
                self.coverage.add(side, detection)

    def present_target(self, frame_index: int) -> Prompt | None:
        if frame_index == 0:
            return Prompt("measured_target", f"put the measured {self.target_description} back facing the rig, "
                          "then press Enter", config_id=self._config_id, index=frame_index)
        return None
