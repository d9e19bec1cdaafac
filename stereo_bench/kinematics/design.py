"""The calibration design of the kinematic fit: which configurations to visit, and the approach directions.

:func:`kinematic_design` is the small design of configurations :func:`stereo_bench.kinematics.fit.fit_kinematics`
identifies the parameters from; :func:`approach_directions` says from which side each axis reached a configuration.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from stereo_bench.geometry import alpha_from_toe_in
from stereo_bench.kinematics.model import AXES, TILT_AXES


@dataclass(frozen=True)
class DesignConfiguration:
    """One configuration of the calibration design (commanded values); the tilts only on a rig that drives them."""

    baseline_mm: float
    toe_in_left_deg: float
    toe_in_right_deg: float
    tilt_left_deg: float | None = None
    tilt_right_deg: float | None = None

    def axes(self) -> dict[str, float]:
        out = {"baseline_mm": self.baseline_mm, "toe_in_left_deg": self.toe_in_left_deg,
               "toe_in_right_deg": self.toe_in_right_deg}
        for axis in TILT_AXES:
            if getattr(self, axis) is not None:
                out[axis] = getattr(self, axis)
        return out

    @property
    def alpha_left_deg(self) -> float:
        return alpha_from_toe_in(self.toe_in_left_deg)

    @property
    def alpha_right_deg(self) -> float:
        return alpha_from_toe_in(self.toe_in_right_deg)


def _levels(low: float, high: float, n: int) -> list[float]:
    if high < low:
        raise ValueError(f"range ({low:g}, {high:g}) is empty")
    if high == low or n == 1:
        return [float(low)]
    return [float(v) for v in np.linspace(low, high, n)]


def kinematic_design(baseline_range_mm: tuple[float, float], toe_in_left_range_deg: tuple[float, float] = (0.0, 0.0),
                     toe_in_right_range_deg: tuple[float, float] | None = None, *,
                     levels: int = 3) -> list[DesignConfiguration]:
    """The configurations to calibrate, in the order to visit them: 3 baselines x 3 toe-ins per camera.

    Baselines and toe-ins are ``levels`` evenly spaced values spanning each range (one value for an
    empty range: that part of the model is then not identified and held nominal). Each baseline
    is visited with three toe-in pairs: equal toe-ins and the two pairs one level apart, rotated
    over the baselines, so the two heads' scales and axes separate and every pair of neighbouring
    levels occurs (large asymmetric pairs, whose views may not overlap, are avoided). The order
    B0 B1 B2 B1 B0 B2 B0 B1 B2 approaches baselines from both sides (backlash); toe-ins change
    in both directions too.
    """
    if levels not in (2, 3):
        raise ValueError(f"levels must be 2 or 3, not {levels}")
    toe_in_right_range_deg = toe_in_right_range_deg or toe_in_left_range_deg
    bs = _levels(*baseline_range_mm, levels)
    tl = _levels(*toe_in_left_range_deg, levels)
    tr = _levels(*toe_in_right_range_deg, levels)
    n = levels
    # (i_left, i_right) level pairs per baseline level, every neighbouring pair across the baselines.
    if n == 3:
        pairs = [[(0, 0), (1, 2), (2, 1)], [(1, 1), (0, 1), (2, 1)], [(2, 2), (1, 0), (1, 2)]]
        order = [0, 1, 2, 1, 0, 2, 0, 1, 2]
    else:
        pairs = [[(0, 0), (1, 0)], [(1, 1), (0, 1)]]
        order = [0, 1, 0, 1]
    used = {b: 0 for b in range(n)}
    design = []
    for b_index in order:
        i, j = pairs[b_index][used[b_index] % len(pairs[b_index])]
        used[b_index] += 1
        # A range with one value repeats it: a configuration visited again (from another side) still
        # tells the backlash and the landing scatter.
        design.append(DesignConfiguration(bs[min(b_index, len(bs) - 1)], tl[min(i, len(tl) - 1)],
                                          tr[min(j, len(tr) - 1)]))
    return design


def campaign_design(configurations: Sequence) -> tuple[list[DesignConfiguration], float] | None:
    """The kinematic design a campaign's plan visits for ``configurations`` (its planned
    :class:`stereo_bench.campaign.plan.Configuration` list, or anything with ``baseline_mm``, ``toe_in_deg``,
    ``distance_mm`` and ``runnable``) and the distance its board is shown at, as the plan chooses them
    (the kinematic extrinsics source's visits and the error model's prediction of its fit); None: nothing runnable."""
    runnable = [c for c in configurations if getattr(c, "runnable", True)]
    if not runnable:
        return None
    baselines = [float(c.baseline_mm) for c in runnable]
    toe_ins = [float(c.toe_in_deg) for c in runnable]
    distances = sorted(float(c.distance_mm) for c in runnable)
    toe_in_range = (min(toe_ins), max(toe_ins))
    design = kinematic_design((min(baselines), max(baselines)), toe_in_range, toe_in_range)
    return design, distances[len(distances) // 2]


def approach_directions(previous: Mapping[str, float] | None, current: Mapping[str, float],
                        before: Mapping[str, int] | None = None) -> dict[str, int]:
    """Per axis the direction of the move that reached ``current``: +1 increased, -1 decreased.

    An axis that did not move keeps its direction in ``before`` (0 if unknown).
    """
    before = before or {}
    out = {}
    for axis in AXES + tuple(a for a in TILT_AXES if a in current):
        if previous is None or axis not in previous or axis not in current:
            out[axis] = int(before.get(axis, 0))
            continue
        delta = float(current[axis]) - float(previous[axis])
        out[axis] = (1 if delta > 0 else -1) if abs(delta) > 1e-9 else int(before.get(axis, 0))
    return out
