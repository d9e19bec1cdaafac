"""Who puts boards in front of the rig: the operator at the bench, the simulator, or a replay.

The runner tells a presenter where each configuration stands and asks it for "the next calibration
view" and "the measured target"; at the bench the presenter answers with a :class:`Prompt` (with
coverage feedback on the calibration views kept so far) that the runner puts to the operators and
records, in simulation it changes the simulated scene (``stereo_bench.campaign.bench``), in replay it
queues the next recorded pair.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from stereo_bench.campaign.coverage import Coverage
from stereo_bench.campaign.operator import CAPTURE_NOW, CONTINUE, DISCARD_LAST_VIEW, Prompt
from stereo_bench.campaign.plan import Configuration, Visit
from stereo_bench.targets import Target
from stereo_bench.vision.detect import Detection


class CalibrationPlacementError(RuntimeError):
    """The calibration board cannot be shown to both cameras at this configuration."""


class Presenter(Protocol):
    """Puts boards in front of the cameras. A returned :class:`Prompt` is a step for the operator."""

    wants_detections: bool  # calibration_view_captured wants the views' detections (coverage feedback)
    # Calibration views are taken from a stream (``[capture] calibration_capture = "auto"``): the runner captures
    # pair after pair (next_stream_frame) and keeps those the ViewSelector takes; else one view per
    # present_calibration_view. ``presents_by_hand``: somebody presents the board (an operator, the simulated hand),
    # whose presentation time the runner measures.
    streams: bool
    presents_by_hand: bool

    def begin_run(self, sequence: Sequence[Configuration | Visit]) -> None:
        """The plan's moves in order (``approach.move_sequence``: every one, also those this run skips)."""

    def begin_configuration(self, configuration: Configuration) -> None:
        """The rig stands at ``configuration``: the measured target is at its distance from now on."""

    def place_board(self, T_rig_board: np.ndarray) -> Prompt | None:
        """A fixed-board design starts: the calibration board goes to ``T_rig_board`` (4x4, mm), once, and stays
        there for every visit whose ``board_fixed`` is true (their calibration views are captured, not presented)."""

    def prepare_calibration(self, n_views: int) -> Prompt | None:
        """``n_views`` calibration views follow; raises CalibrationPlacementError if none can be shown."""

    def present_calibration_view(self, index: int) -> Prompt | None: ...

    def next_stream_frame(self, offered: int) -> bool:
        """Streaming: the stream's ``offered``-th pair is about to be captured; False: nothing more is presented."""

    def stream_prompt(self, n_kept: int, gate: str) -> Prompt | None:
        """Streaming: what the operator is told while views are taken (a background prompt: Enter ends it)."""

    def recorded_detections(self, index: int) -> tuple | None:
        """A replay of views kept as detections only: view ``index``'s recorded (left, right); else None (detect)."""

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None: ...

    def calibration_view_discarded(self, index: int) -> None:
        """The operator dropped kept view ``index``; it is presented again next."""

    def review_calibration(self) -> Prompt | None:
        """After the last view: a prompt to check the views (and discard the last one) before calibrating."""

    def present_target(self, frame_index: int) -> Prompt | None:
        """Show the measured target (asked again for the same frame when the target was not found)."""


def scene_seed(seed: int, config_id: str, kind: str, index: int) -> int:
    """A reproducible seed for one capture, independent of what ran before it (so resume = no crash)."""
    words = [seed & 0xFFFFFFFF, zlib.crc32(config_id.encode()), zlib.crc32(kind.encode()), index]
    return int(np.random.SeedSequence(words).generate_state(1)[0])


class OperatorPresenter:
    """At the real bench: a prompt for each board placement, with coverage feedback."""

    wants_detections = True
    presents_by_hand = True

    def __init__(self, *, image_size: tuple[int, int], target_description: str, calibration_board: Target,
                 streams: bool = False):
        self.streams = streams
        self.image_size = image_size
        self.target_description = target_description
        self.calibration_board = calibration_board
        self.coverage = Coverage(image_size, calibration_board)
        self._n_views = 0
        self._config_id: str | None = None
        self._fixed = False  # the current visit captures the board placed once: nothing to present

    def begin_run(self, sequence: Sequence[Configuration | Visit]) -> None:
        return None

    def begin_configuration(self, configuration: Configuration) -> None:
        self._config_id = configuration.config_id
        self._fixed = isinstance(configuration, Visit) and configuration.board_fixed

    def place_board(self, T_rig_board: np.ndarray) -> Prompt:
        centre = T_rig_board[:3, :3] @ np.array([*self.calibration_board.grid_size_mm, 0.0]) / 2.0 + T_rig_board[:3, 3]
        yaw = float(np.degrees(np.arctan2(T_rig_board[0, 2], T_rig_board[2, 2])))
        return Prompt("fixed_board", f"[{self._config_id}] place the calibration board ONCE, about {centre[2]:.0f} mm "
                      f"in front of the rig and {centre[0]:+.0f} mm across, turned ~{abs(yaw):.0f} deg toward one "
                      "side and tilted back, wholly in both views (the live page shows them); leave it standing "
                      "while the rig moves until the target prompt; press Enter", config_id=self._config_id)

    def prepare_calibration(self, n_views: int) -> Prompt | None:
        if self._fixed:
            return None
        self.coverage = Coverage(self.image_size, self.calibration_board)
        self._n_views = n_views
        if self.streams:
            return Prompt("calibration_board", f"[{self._config_id}] calibration: views are taken automatically. "
                          "Move the board slowly from pose to pose, each at a new position and tilt (up to ~40 "
                          "deg), near and far, filling the corners of both views, and hold it still for a moment at "
                          f"each (at least {n_views} views); press Enter to begin", config_id=self._config_id)
        return Prompt("calibration_board", f"[{self._config_id}] calibration: present the calibration board "
                      f"{n_views} times, each time at a new position and tilt (up to ~40 deg), near and far, "
                      "filling the corners of both views; press Enter to begin", config_id=self._config_id)

    def present_calibration_view(self, index: int) -> Prompt | None:
        if self._fixed:
            return None  # the rig moved; the board stands where it was placed
        actions = (CONTINUE, CAPTURE_NOW, DISCARD_LAST_VIEW) if index > 0 else (CONTINUE, CAPTURE_NOW)
        discard = "; d + Enter: discard the previous view" if index > 0 else ""
        return Prompt("calibration_view", f"calibration view {index + 1}/{self._n_views}: hold the board still in "
                      f"both views, then press Enter ({self.coverage.summary()}{discard})",
                      config_id=self._config_id, index=index, actions=actions)

    def recorded_detections(self, index: int) -> None:
        return None  # the views are detected as they are captured

    def next_stream_frame(self, offered: int) -> bool:
        return True  # the operator presents until the gate opens or Enter ends the collection

    def stream_prompt(self, n_kept: int, gate: str) -> Prompt:
        return Prompt("calibration_stream", f"taking calibration views: {n_kept} kept ({gate}; "
                      f"{self.coverage.summary()}); hold the board still at each new pose; press Enter to calibrate "
                      "with the views kept so far", config_id=self._config_id, background=True)

    def calibration_view_captured(self, index: int, left: Detection | None, right: Detection | None) -> None:
        for side, detection in (("left", left), ("right", right)):
            if detection is not None:
                self.coverage.add(side, index, detection)

    def calibration_view_discarded(self, index: int) -> None:
        self.coverage.discard(index)

    def review_calibration(self) -> Prompt | None:
        if self._fixed:
            return None
        return Prompt("calibration_review", f"{self._n_views} calibration views taken ({self.coverage.summary()}); "
                      "press Enter to calibrate, or d + Enter to discard the last view and take it again",
                      config_id=self._config_id, actions=(CONTINUE, DISCARD_LAST_VIEW))

    def present_target(self, frame_index: int) -> Prompt | None:
        if frame_index == 0:
            return Prompt("measured_target", f"put the measured {self.target_description} back facing the rig, "
                          "then press Enter", config_id=self._config_id, index=frame_index)
        return None
