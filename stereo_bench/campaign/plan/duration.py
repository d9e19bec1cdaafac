"""How long a campaign should take: :func:`estimate_duration` adds up each step's time under the
:class:`~stereo_bench.campaign.plan.timing.DurationModel` of its bench."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from drivers.rig.motion import REFERENCE_AXIS_MOTION, REFERENCE_HOMING, homing_time_s
from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan.configurations import Configuration
from stereo_bench.campaign.plan.steps import Step
from stereo_bench.campaign.plan.timing import OPERATOR_S_PER_BOARD_PLACEMENT, OPERATOR_S_PER_PROMPT, DurationModel


@dataclass(frozen=True)
class DurationEstimate:
    """Predicted campaign time (s) by component, and the assumptions behind it."""

    homing_s: float
    motion_s: float
    settle_s: float
    flush_s: float
    capture_s: float
    operator_s: float
    assumptions: tuple[str, ...] = field(default=())

    @property
    def total_s(self) -> float:
        return self.homing_s + self.motion_s + self.settle_s + self.flush_s + self.capture_s + self.operator_s

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["assumptions"] = list(self.assumptions)
        data["total_s"] = self.total_s
        return data


def estimate_duration(config: CampaignConfig, configurations: Sequence[Configuration],
                      steps: Sequence[Step], *, presentation=None) -> DurationEstimate:
    """How long the campaign should take, step by step.

    - Motion: each Move as one straight GRBL move from the previous position (the first from where
      homing leaves the axes), at the rig config's axis feeds where every moving axis has one (else a
      rapid), capped by the axis max rates and accelerations of the reference rig
      (:data:`drivers.rig.motion.REFERENCE_AXIS_MOTION`, which the simulated rig runs with; a real
      controller's $110-$125 are not known offline), timed by the model the emulator uses
      (:func:`drivers.rig.motion.move_time_s`).
    - Homing (if enabled): the firmware's sequence (:func:`homing_estimate_s`): per cycle (Z, then X and Y) a
      seek to the switches, pull-off, locate and pull-off, each with its debounce, at the reference homing
      settings (:data:`drivers.rig.motion.REFERENCE_HOMING`, the simulated rig's). The simulated rig powers up
      at machine 0; a real rig may stand anywhere: the far end of the config's range is assumed (the worst
      case). On the simulated rig, homing and motion run ``time_scale`` times faster.
    - Settle as configured. Frames: one exposure each on simulated cameras; max(exposure, 1/fps) on
      V4L2 (30 fps assumed when not set); a V4L2 flush discards ``buffer_count`` frames.
    - Operator: 30 s per prompt and 5 s per calibration view presented by hand (or ``presentation``'s measured
      seconds per view: :mod:`stereo_bench.campaign.presentation`), where a human does it:
      boards and the target stand in the cameras' world (none with simulated cameras, bring-up
      included), a manual rig quantity on the rig (none on the simulated rig).
    - Not included: computation (rendering, detection, calibration) and parking the rig at the end.
    """
    del configurations  # the steps carry what is needed; the argument keeps the documented signature
    model = DurationModel.of(config, presentation)
    travel, speed_factor = model.rig_config.machine_travel(), model.speed_factor
    real_scene, frame_s, flush_frames = model.real_scene, model.frame_s, model.flush_frames
    human = real_scene or model.real_rig

    homing = 0.0
    if config.rig.homing and travel:
        homing = homing_estimate_s(travel, simulated=config.rig.kind == "simulated") / speed_factor
    for step in steps:
        step.estimate(model)
    motion, settle, flush, capture, operator = (model.motion_s, model.settle_s, model.flush_s, model.capture_s,
                                                model.operator_s)

    assumptions = (
        "axis max rates and accelerations of the reference rig (the simulated rig's)"
        + (f", simulated rig {speed_factor:g}x faster than real time" if speed_factor != 1.0 else ""),
        f"{frame_s:g} s per stereo frame" + ("" if config.cameras.kind == "simulated"
                                              else f", {flush_frames} frames per flush"),
        (_prompt_assumption(model) + model.presentation_source
         + (f", {OPERATOR_S_PER_BOARD_PLACEMENT:g} s to place the fixed board (assumed)"
            if config.extrinsics.fixed_board and model.s_per_placement == OPERATOR_S_PER_BOARD_PLACEMENT else "")
         + ("" if real_scene else " (the scene is simulated: boards and target placed by the simulator)")
         if human else "no operator time: rig and cameras simulated"),
        "computation (rendering, detection, calibration) not included",
    ) + ((f"homing at the reference rig's $25={REFERENCE_HOMING.seek_rate_per_min:g}, "
          f"$24={REFERENCE_HOMING.feed_rate_per_min:g} mm/min, $26={REFERENCE_HOMING.debounce_ms:g} ms, "
          f"$27={REFERENCE_HOMING.pulloff:g}, from "
          + ("machine 0 (where the simulated rig powers up)" if config.rig.kind == "simulated"
             else "the far end of each axis' range (the longest seek)"),) if homing else ())
    return DurationEstimate(homing_s=homing, motion_s=motion, settle_s=settle, flush_s=flush, capture_s=capture,
                            operator_s=operator, assumptions=assumptions)


def _prompt_assumption(model) -> str:
    """The operator's seconds per prompt the estimate counts, and the figures an earlier run measured instead."""
    measured = "".join(f"{line}; " for line in model.prompts_source)
    return f"operator {OPERATOR_S_PER_PROMPT:g} s per prompt; " + measured


def homing_estimate_s(travel: Mapping[str, tuple[float, float]], *, simulated: bool) -> float:
    """How long ``$H`` takes (s, real time) on a rig whose config spans ``travel`` (axis -> (low, high) machine
    units, :meth:`RigConfig.machine_travel`), by the firmware's sequence (:func:`drivers.rig.motion.homing_time_s`).

    The controller is taken as the simulated bench sets it up (``$13x`` one pull-off beyond the range, the
    reference axes and homing settings): a range at or below 0 homes toward + to a switch at machine 0; one at
    or above 0 (a set-origin build) toward - to a switch one pull-off below 0. Where the axes stand first:
    ``simulated``, machine 0, where the simulated rig powers up; else the end of the range farthest from the
    switch (the longest seek).
    """
    pulloff = REFERENCE_HOMING.pulloff
    to_switch: dict[str, float] = {}
    max_travel: dict[str, float] = {}
    for axis, (low, high) in travel.items():
        if low >= 0.0 and high > 0.0:  # HOMING_FORCE_SET_ORIGIN: homes toward -, the switch at -$27
            max_travel[axis] = high + pulloff
            to_switch[axis] = pulloff if simulated else high + pulloff
        else:
            max_travel[axis] = (-low + pulloff) if high <= 0.0 else high - low
            to_switch[axis] = 0.0 if simulated else max(0.0, -low)
    return homing_time_s(to_switch, max_travel=max_travel, homing=REFERENCE_HOMING,
                         max_rate_per_min={a: REFERENCE_AXIS_MOTION[a].max_rate_per_min for a in travel},
                         acceleration={a: REFERENCE_AXIS_MOTION[a].acceleration for a in travel})


def predict_duration_s(config: CampaignConfig, configurations: Sequence[Configuration],
                       steps: Sequence[Step]) -> float:
    """Predicted campaign duration (s); :func:`estimate_duration` says what it counts and assumes."""
    return estimate_duration(config, configurations, steps).total_s
