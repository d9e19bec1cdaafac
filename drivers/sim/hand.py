"""A simulated operator who presents a calibration board by hand: a board pose at every instant of bench time.

The hand carries the board from one presentation to the next along a minimum-jerk path (position and
rotation together; the speed profile of a human reaching movement), holds it for a while, and trembles
all the time. Now and then it first swings the board half out of one camera's view and holds it there
before moving on, as an operator looking at one screen does. Everything is a function of the seed and the
time: the same seed gives the same hand, at any frame rate.

Figures (defaults), each with its source:

- carrying speed: a move of distance d takes max(``min_move_s``, d / ``speed_mm_s``); 250 mm/s mean
  (reaching movements of the arm, 0.5-1.5 s over 20-40 cm);
- holding: ``dwell_s`` uniform in (0.6, 1.8) s (an operator told "hold it still" counts to one or two);
- tremor: physiological hand tremor, 8-12 Hz, with an amplitude of 0.1-0.3 mm at the hand
  (``tremor_mm``: std per axis) and ~0.05 deg of wrist rotation (``tremor_deg``);
- while held, the board is not perfectly still: it drifts by ``drift_mm_s`` (5 mm/s: a slow sag);
- ``p_half_out``: share of presentations that first pass a pose shifted sideways by the board's width
  (half out of a view) and hold there ``half_out_s``.

Units: mm, deg, s. Poses are T_rig_board (4x4, mm), as :func:`drivers.sim.render.calibration_board_poses`
gives them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class HandFigures:
    """How the hand moves (see the module docstring). mm, deg, s."""

    speed_mm_s: float = 250.0
    min_move_s: float = 0.6
    dwell_s: tuple[float, float] = (0.6, 1.8)
    tremor_mm: float = 0.2
    tremor_deg: float = 0.05
    tremor_hz: tuple[float, float] = (8.0, 12.0)
    drift_mm_s: float = 5.0
    p_half_out: float = 0.15
    half_out_s: float = 0.8


@dataclass(frozen=True)
class _Segment:
    start_s: float
    end_s: float
    pose_from: np.ndarray
    pose_to: np.ndarray
    kind: str  # "move" or "hold"
    drift: np.ndarray  # (3,) mm/s while holding


def _min_jerk(u: float) -> float:
    u = min(1.0, max(0.0, u))
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


def _interpolate(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """The pose a fraction ``s`` of the way from ``a`` to ``b`` (straight line, rotation about one axis)."""
    relative = cv2.Rodrigues(a[:3, :3].T @ b[:3, :3])[0].ravel()
    out = np.eye(4)
    out[:3, :3] = a[:3, :3] @ cv2.Rodrigues(relative * s)[0]
    out[:3, 3] = a[:3, 3] + s * (b[:3, 3] - a[:3, 3])
    return out


class HandPresentation:
    """A hand presenting ``poses`` (T_rig_board, 4x4 mm) in order, starting at rest at ``rest`` (default: the
    first pose pulled back 200 mm). :meth:`pose_at` gives the board at any bench time ``t_s`` >= 0;
    :attr:`holds` the (start, end, pose index) of each still presentation; :attr:`duration_s` its end."""

    def __init__(self, poses: Sequence[np.ndarray], *, seed: int, figures: HandFigures = HandFigures(),  # noqa: B008
                 board_width_mm: float = 250.0, rest: np.ndarray | None = None):
        if not poses:
            raise ValueError("a hand presentation needs at least one pose")
        self.figures = figures
        rng = np.random.default_rng(seed)
        previous = np.array(rest, float) if rest is not None else np.array(poses[0], float)
        if rest is None:
            previous[2, 3] -= 200.0
        t = 0.0
        segments: list[_Segment] = []
        holds: list[tuple[float, float, int]] = []
        zero = np.zeros(3)

        def move(to: np.ndarray) -> None:
            nonlocal t, previous
            distance = float(np.linalg.norm(to[:3, 3] - previous[:3, 3]))
            duration = max(figures.min_move_s, distance / figures.speed_mm_s)
            segments.append(_Segment(t, t + duration, previous, to, "move", zero))
            t += duration
            previous = to

        def hold(duration: float) -> None:
            nonlocal t, previous
            direction = rng.standard_normal(3)
            drift = direction / np.linalg.norm(direction) * figures.drift_mm_s
            sagged = previous.copy()
            sagged[:3, 3] += drift * duration
            segments.append(_Segment(t, t + duration, previous, sagged, "hold", drift))
            t += duration
            previous = sagged  # the next move starts where the sag left the board

        for index, pose in enumerate(poses):
            pose = np.array(pose, float)
            if rng.random() < figures.p_half_out:
                aside = pose.copy()
                aside[0, 3] += (1.0 if rng.random() < 0.5 else -1.0) * board_width_mm
                move(aside)
                hold(figures.half_out_s)
            move(pose)
            start = t
            hold(float(rng.uniform(*figures.dwell_s)))
            holds.append((start, t, index))
        self.segments = segments
        self.holds = holds
        self.duration_s = t
        # Tremor: two sinusoids per axis at frequencies in the tremor band, random phases; their sum has std
        # tremor per axis (each of amplitude tremor).
        self._tremor_f = rng.uniform(*figures.tremor_hz, size=(2, 6))
        self._tremor_phase = rng.uniform(0.0, 2.0 * math.pi, size=(2, 6))

    def _tremor(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        waves = np.sin(2.0 * math.pi * self._tremor_f * t_s + self._tremor_phase).sum(axis=0)  # (6,), std 1
        return waves[:3] * self.figures.tremor_mm, waves[3:] * math.radians(self.figures.tremor_deg)

    def pose_at(self, t_s: float) -> np.ndarray:
        """T_rig_board (4x4, mm) at bench time ``t_s`` (held at the last pose after :attr:`duration_s`)."""
        segment = self.segments[-1]
        for candidate in self.segments:
            if t_s < candidate.end_s:
                segment = candidate
                break
        if segment.kind == "move":
            pose = _interpolate(segment.pose_from, segment.pose_to,
                                _min_jerk((t_s - segment.start_s) / (segment.end_s - segment.start_s)))
        else:
            pose = segment.pose_from.copy()
            pose[:3, 3] += segment.drift * (min(t_s, segment.end_s) - segment.start_s)
        shift, turn = self._tremor(t_s)
        pose[:3, 3] += shift
        pose[:3, :3] = pose[:3, :3] @ cv2.Rodrigues(turn)[0]
        return pose

    def still_at(self, t_s: float) -> int | None:
        """The index of the presentation held at ``t_s``, or None while the hand carries the board."""
        for start, end, index in self.holds:
            if start <= t_s < end:
                return index
        return None


#: How far from the requested pose an operator stands a calibration board placed once (the fixed-board design):
#: by eye against a stand and a sketch of the pose, a few mm and degrees (std per axis).
PLACEMENT_POSITION_SIGMA_MM = 3.0
PLACEMENT_ROTATION_SIGMA_DEG = 1.5


def placed_board_pose(T_requested: np.ndarray, *, seed: int, centre_board: np.ndarray | None = None,
                      position_sigma_mm: float = PLACEMENT_POSITION_SIGMA_MM,
                      rotation_sigma_deg: float = PLACEMENT_ROTATION_SIGMA_DEG) -> np.ndarray:
    """T_rig_board (4x4, mm) where a simulated operator really stands a board asked for at ``T_requested``.

    The board's point ``centre_board`` (board frame, mm: its grid centre, say) is off by N(0, ``position_sigma_mm``)
    per axis and the board turned about it by a rotation vector of N(0, ``rotation_sigma_deg``) per axis: a pure
    function of ``seed``.
    """
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0xF1BD])
    shift = rng.normal(0.0, position_sigma_mm, 3)
    turn = cv2.Rodrigues(np.radians(rng.normal(0.0, rotation_sigma_deg, 3)))[0]
    return placed_about(T_requested, turn, shift, centre_board=centre_board)


def placed_about(T_requested: np.ndarray, turn: np.ndarray, shift: np.ndarray, *,
                 centre_board: np.ndarray | None = None) -> np.ndarray:
    """``T_requested`` turned by ``turn`` (3x3, rig axes) about the board's point ``centre_board`` (board frame,
    mm; default its origin, the first inner corner) and moved by ``shift`` (3,) mm."""
    T = np.array(T_requested, float)
    c = T[:3, 3] if centre_board is None else T[:3, :3] @ centre_board + T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = turn @ T[:3, :3]
    out[:3, 3] = turn @ (T[:3, 3] - c) + c + shift
    return out
