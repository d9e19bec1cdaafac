"""The operator's review of one configuration's calibration: the per-view error chart, a threshold, an exclude list.

After a configuration's calibration views are taken and calibrated (``[calibration] review``, default on with v4l2
cameras) the runner shows one screen (as MATLAB's Stereo Camera Calibrator shows its per-view error bars)::

    [B100_Z450_A90] calibration: 8 views, 7 used, stereo RMS 0.221 px; threshold none
       view  RMS px (the worse camera)
          0  ###################-----------  0.214
          5  ############################--  0.301  excluded by the operator
    keys, then Enter: t PX  threshold | x N  exclude or include view N | r  recalibrate | Enter alone  accept

and the operator answers with a line: ``t 0.25`` (views over 0.25 px are left out at the next calibration),
``x 5`` (view 5 left out, or taken back in), ``r`` (calibrate again with those), Enter (accept the calibration
shown: it is the one measured with). Pure: :class:`ReviewState` keeps what was chosen and what the calibration
shown was made with; :func:`review_message` draws it; the runner asks, calibrates and records.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stereo_bench.campaign.operator import CONTINUE, EXCLUDE_VIEW, RECALIBRATE, SET_THRESHOLD, Prompt

BAR_WIDTH = 30
BY_OPERATOR = "excluded by the operator"


@dataclass
class ReviewState:
    """What the operator has chosen (``exclude``: index -> why; ``threshold`` px or None) and the calibration shown
    (``analysis``, a :class:`~stereo_bench.campaign.analysis.ConfigurationAnalysis`, or ``failure``), made with
    ``applied_exclude`` and ``applied_threshold``; ``note``: what the last answer did, said on the next screen."""

    n_views: int
    exclude: dict[int, str] = field(default_factory=dict)
    threshold: float | None = None
    analysis: object | None = None
    failure: str | None = None
    applied_exclude: dict[int, str] = field(default_factory=dict)
    applied_threshold: float | None = None
    note: str | None = None

    def shown(self, analysis, failure: str | None) -> None:
        """The calibration made with the current choice (or why it failed) is what the next screen shows."""
        self.analysis, self.failure = analysis, failure
        self.applied_exclude, self.applied_threshold = dict(self.exclude), self.threshold

    @property
    def pending(self) -> bool:
        """Choices made since the calibration shown (applied by ``r``)."""
        return self.exclude != self.applied_exclude or self.threshold != self.applied_threshold

    def answer(self, action: str, value: float | None) -> bool:
        """Apply one answer; True when the configuration is to be calibrated again (``r``)."""
        self.note = None
        if action == RECALIBRATE:
            return True
        if action == SET_THRESHOLD:
            if value is None or not math.isfinite(value) or value <= 0:
                self.note = "t needs a threshold in px above 0, e.g. t 0.4"
            else:
                self.threshold = float(value)
                self.note = f"threshold {value:g} px: r recalibrates without the views over it"
        elif action == EXCLUDE_VIEW:
            if value is None or value != int(value) or not 0 <= value < self.n_views:
                self.note = f"x needs a view number from 0 to {self.n_views - 1}, e.g. x 3"
            elif int(value) in self.exclude and self.exclude[int(value)] == BY_OPERATOR:
                del self.exclude[int(value)]
                self.note = f"view {int(value)} taken back in: r recalibrates"
            else:
                self.exclude[int(value)] = BY_OPERATOR
                self.note = f"view {int(value)} excluded: r recalibrates without it"
        return False

    def view_rms(self) -> dict[int, float]:
        """Per view used by the calibration shown: its RMS, the worse camera's (px)."""
        analysis = self.analysis
        if analysis is None or analysis.calib is None:
            return {}
        used = analysis.calibration_views_used
        worst = np.max(np.asarray(analysis.calib.per_view_rms_px, float).reshape(len(used), -1), axis=1)
        return {int(index): float(rms) for index, rms in zip(used, worst, strict=True)}


def review_message(config_id: str, state: ReviewState) -> str:
    """The one-screen summary (see the module docstring), lines separated by newlines."""
    rms = state.view_rms()
    rejected = {} if state.analysis is None else {int(r["index"]): r["reason"]
                                                    for r in state.analysis.calibration_views_rejected}
    threshold = "none" if state.threshold is None else f"{state.threshold:g} px"
    if state.analysis is not None:
        head = (f"[{config_id}] calibration: {state.n_views} views, {len(rms)} used, stereo RMS "
                f"{state.analysis.calib.rms_px:.3f} px; threshold {threshold}")
    else:
        head = f"[{config_id}] calibration FAILED: {state.failure}; threshold {threshold}"
    scale = max([*rms.values(), state.threshold or 0.0]) or 1.0
    lines = [head, "   view  RMS px (the worse camera)"]
    for index in range(state.n_views):
        if index in rms:
            filled = round(BAR_WIDTH * rms[index] / scale)
            over = state.threshold is not None and rms[index] > state.threshold
            mark = ("  over the threshold" if over else "") + (f"  {state.exclude[index]} (r applies)"
                                                               if index in state.exclude else "")
            lines.append(f"   {index:4d}  {'#' * filled}{'-' * (BAR_WIDTH - filled)}  {rms[index]:.3f}{mark}")
        else:
            why = rejected.get(index) or state.exclude.get(index) or "not used"
            lines.append(f"   {index:4d}  {' ' * BAR_WIDTH}     -  {why}")
    if state.note:
        lines.append(f"   ({state.note})")
    elif state.pending:
        lines.append("   (changes not applied yet: r recalibrates with them, Enter keeps the calibration shown)")
    lines.append("keys, then Enter: t PX  threshold | x N  exclude or include view N | r  recalibrate | "
                 "Enter alone  accept")
    return "\n".join(lines)


def review_prompt(config_id: str, state: ReviewState) -> Prompt:
    return Prompt("calibration_errors", review_message(config_id, state), config_id=config_id,
                  actions=(CONTINUE, SET_THRESHOLD, EXCLUDE_VIEW, RECALIBRATE))


__all__ = ["BY_OPERATOR", "ReviewState", "review_message", "review_prompt"]
