"""Calibration views taken by themselves: the board kept when it is still and new, as ROS takes them, and better.

ROS ``camera_calibration`` keeps a detected board when its (X, Y, size, skew) parameters
(:func:`stereo_bench.campaign.coverage.view_parameters`) lie far enough from every kept view's (an L1
distance above 0.2) and, with ``max_chessboard_speed`` set, when its corners moved less than that between
two frames. Here, per stereo pair:

- **both views**: the whole board is detected in the left and the right image (a stereo calibration needs
  the same corners in both; a board half out of one view is not kept);
- **still**: the median corner speed between this pair and the previous one is at most
  ``max_speed_px_s`` in both cameras (a speed, not a per-frame displacement: the same rule at any frame
  rate). A board moving at v px/s smears by v x exposure in the image and shears by v x the rolling
  shutter's readout: 30 px/s at 1/30 s is a 1 px smear, below what cornerSubPix notices;
- **new**: the smallest L1 distance in (X, Y, size, skew) to every kept view, the larger over the two
  cameras, is at least ``min_novelty`` (ROS's 0.2);
- **settled**: the board has been still for ``settle_s`` (a hand stopping overshoots and comes back).

The **coverage gate** says when the kept views are enough to calibrate: every ROS bar full in both cameras
(``gate = "bars"``), or ``min_views`` kept (``gate = "count"``), and never fewer than ``min_views``.

Pure: detections and bench-clock times in, decisions out (the runner and the live page decide what to
show; :mod:`drivers.sim.hand` is the simulated hand that tests it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from stereo_bench.campaign.coverage import Coverage, ViewParameters, view_parameters
from stereo_bench.targets import Target

Reason = Literal["kept", "not in both views", "moving", "settling", "not new", "gate open"]
REASONS: tuple[str, ...] = ("kept", "not in both views", "moving", "settling", "not new", "gate open")


@dataclass(frozen=True)
class AutoCaptureRule:
    """The thresholds of automatic capture (see the module docstring). Units: px/s, s, 1."""

    max_speed_px_s: float = 30.0
    settle_s: float = 0.3
    min_novelty: float = 0.2
    gate: Literal["bars", "count"] = "bars"
    min_views: int = 12
    max_views: int = 40  # ROS calls 40 samples good enough whatever the bars say

    def __post_init__(self):
        for name in ("max_speed_px_s", "settle_s", "min_novelty"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, not {value}")
        if self.gate not in ("bars", "count"):
            raise ValueError(f"gate must be 'bars' or 'count', not {self.gate!r}")
        if not 1 <= self.min_views <= self.max_views:
            raise ValueError(f"need 1 <= min_views <= max_views, not {self.min_views} and {self.max_views}")


def corner_speed_px_s(previous, current, dt_s: float) -> float | None:
    """Median speed (px/s) of the corners two detections share (``ids``, ``corners_px``); None without a
    shared corner or a positive ``dt_s``."""
    if previous is None or current is None or not dt_s > 0:
        return None
    _, a, b = np.intersect1d(previous.ids, current.ids, assume_unique=True, return_indices=True)
    if not len(a):
        return None
    moved = np.linalg.norm(np.asarray(current.corners_px)[b] - np.asarray(previous.corners_px)[a], axis=1)
    return float(np.median(moved) / dt_s)


def novelty(parameters: ViewParameters, kept: list[ViewParameters]) -> float:
    """Smallest L1 distance of ``parameters`` to the kept views' (inf with none kept)."""
    if not kept:
        return math.inf
    p = np.array(parameters.as_tuple())
    return float(min(np.abs(np.array(k.as_tuple()) - p).sum() for k in kept))


@dataclass(frozen=True)
class Decision:
    """What :meth:`ViewSelector.offer` made of one pair: ``reason`` and the numbers behind it."""

    reason: str
    time_s: float
    speed_px_s: float | None = None  # the larger of the two cameras'
    novelty: float | None = None  # the larger of the two cameras'

    @property
    def kept(self) -> bool:
        return self.reason == "kept"


@dataclass
class ViewSelector:
    """Offered every stereo pair of a hand presentation in time order; keeps the still, new, whole ones."""

    rule: AutoCaptureRule
    board: Target
    image_size: tuple[int, int]
    coverage: Coverage = field(init=False)
    decisions: list[Decision] = field(default_factory=list)
    _previous: tuple | None = None
    _still_since: float | None = None

    def __post_init__(self):
        self.coverage = Coverage(self.image_size, self.board)

    @property
    def n_kept(self) -> int:
        return len(self.coverage.views["left"])

    def offer(self, time_s: float, left, right) -> Decision:
        """Decide on the pair detected at bench time ``time_s`` (``left``/``right``: detections or None)."""
        previous, self._previous = self._previous, (time_s, left, right)
        decision = self._decide(time_s, left, right, previous)
        if decision.kept:
            index = self.n_kept
            self.coverage.add("left", index, left)
            self.coverage.add("right", index, right)
        self.decisions.append(decision)
        return decision

    def _decide(self, time_s: float, left, right, previous) -> Decision:
        if self.gate_open()[0]:
            return Decision("gate open", time_s)
        # The corners a calibration view needs (a checkerboard: all; a ChArUco board: its own share).
        needed = math.ceil(self.board.min_calibration_fraction * len(self.board.object_points))
        if left is None or right is None or left.n < needed or right.n < needed:
            self._still_since = None
            return Decision("not in both views", time_s)
        speeds = [None, None] if previous is None else [corner_speed_px_s(old, new, time_s - previous[0])
                                                        for old, new in ((previous[1], left), (previous[2], right))]
        if any(s is None for s in speeds):
            self._still_since = None
            return Decision("settling", time_s)
        speed = max(speeds)
        if speed > self.rule.max_speed_px_s:
            self._still_since = None
            return Decision("moving", time_s, speed_px_s=speed)
        if self._still_since is None:
            self._still_since = previous[0]
        if time_s - self._still_since < self.rule.settle_s:
            return Decision("settling", time_s, speed_px_s=speed)
        new = max(novelty(view_parameters(d.corners_px, d.ids, self.board, self.image_size),
                          [v.parameters for v in self.coverage.views[side]])
                  for side, d in (("left", left), ("right", right)))
        if new < self.rule.min_novelty:
            return Decision("not new", time_s, speed_px_s=speed, novelty=new)
        return Decision("kept", time_s, speed_px_s=speed, novelty=new)

    def gate_open(self) -> tuple[bool, str]:
        """(enough views to calibrate, why): the coverage gate of the rule."""
        n = self.n_kept
        if n >= self.rule.max_views:
            return True, f"{n} views kept (at most {self.rule.max_views})"
        if n < self.rule.min_views:
            return False, f"{n} of at least {self.rule.min_views} views kept"
        if self.rule.gate == "count":
            return True, f"{n} views kept"
        short = [f"{side} {bar.name} {bar.progress:.0%}" for side in ("left", "right")
                 for bar in self.coverage.bars(side) if bar.progress < 1.0]
        if short:
            return False, "bars short: " + ", ".join(short)
        return True, "every coverage bar full in both cameras"

    def tally(self) -> dict[str, int]:
        """How many pairs each reason decided, in :data:`REASONS` order."""
        return {reason: sum(d.reason == reason for d in self.decisions) for reason in REASONS}
