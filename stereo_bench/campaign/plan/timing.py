"""What a step's time depends on (:class:`DurationModel`: the rig, the cameras, who does the manual steps) and the
assumptions behind it; each step kind adds its own time to it (:mod:`~stereo_bench.campaign.plan.steps`)."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.rig.config import RigConfig
from drivers.rig.motion import REFERENCE_AXIS_MOTION
from stereo_bench.campaign.config import CampaignConfig

# Duration assumptions (each estimate lists them).
OPERATOR_S_PER_PROMPT = 30.0  # move the target (or set another manual quantity) and press Enter
OPERATOR_S_PER_CALIBRATION_VIEW = 5.0  # present the calibration board in a new pose by hand
# Stand the calibration board once where both views show it (the fixed-board design; the live page shows both views
# and the plan's requested pose), press Enter: no distance to measure out, unlike a target move. An assumption, not
# measured at a bench: a target move's 30 s less the measuring.
OPERATOR_S_PER_BOARD_PLACEMENT = 20.0
ASSUMED_FPS = 30.0  # a V4L2 camera's frame rate when the settings do not fix it
ASSUMED_FLUSH_FRAMES = 4  # frames a V4L2 flush discards when buffer_count is left to the driver


def _frame_time_s(config: CampaignConfig) -> float:
    if config.cameras.kind == "simulated":
        return config.cameras.optics.exposure_s
    settings = config.cameras.camera_settings()
    period = 1.0 / (settings.fps or ASSUMED_FPS)
    return max(period, (settings.exposure_us or 0.0) / 1e6)


@dataclass
class DurationModel:
    """What a step's time depends on (the rig, the cameras, who does the manual steps), and the time counted so far
    by component: each step kind adds its own (``StepKind.estimate``), in plan order; ``position`` is where the
    last move left the axes (machine units)."""

    rig_config: RigConfig
    speed_factor: float
    rates: dict[str, float]
    accels: dict[str, float]
    feeds: dict[str, float | None]
    position: dict[str, float]
    real_scene: bool  # boards and target are moved by hand
    real_rig: bool  # a manual rig quantity is set by hand
    frame_s: float
    flush_frames: int
    motion_s: float = 0.0
    settle_s: float = 0.0
    flush_s: float = 0.0
    capture_s: float = 0.0
    operator_s: float = 0.0
    # Seconds per calibration view presented by hand: measured by an earlier run (campaign/presentation.py) or
    # assumed; ``presentation_source`` says which.
    s_per_calibration_view: float = OPERATOR_S_PER_CALIBRATION_VIEW
    presentation_source: str = f"assumed {OPERATOR_S_PER_CALIBRATION_VIEW:g} s per calibration view done by hand"
    # Seconds per target move and per fixed-board placement: measured at a real bench by an earlier run, or assumed.
    s_per_target_move: float = OPERATOR_S_PER_PROMPT
    s_per_placement: float = OPERATOR_S_PER_BOARD_PLACEMENT
    prompts_source: tuple[str, ...] = ()

    @classmethod
    def of(cls, config: CampaignConfig, presentation=None) -> DurationModel:
        """The model of ``config``'s bench, nothing counted yet, the axes where the emulator homes them;
        ``presentation``: a measured :class:`~stereo_bench.campaign.presentation.PresentationTime` (None: assumed)."""
        rig_config = config.rig.rig_config()
        travel = rig_config.machine_travel()
        if config.cameras.kind == "simulated":
            flush_frames = 0
        else:
            flush_frames = config.cameras.camera_settings().buffer_count or ASSUMED_FLUSH_FRAMES
        return cls(
            rig_config=rig_config, speed_factor=config.rig.time_scale if config.rig.kind == "simulated" else 1.0,
            rates={a: REFERENCE_AXIS_MOTION[a].max_rate_per_min for a in travel},
            accels={a: REFERENCE_AXIS_MOTION[a].acceleration for a in travel},
            feeds=rig_config.axis_feeds_per_min(),
            position={a: min(max(0.0, low), high) for a, (low, high) in travel.items()},  # the emulator's home
            real_scene=config.cameras.kind != "simulated", real_rig=config.rig.kind != "simulated",
            frame_s=_frame_time_s(config), flush_frames=flush_frames, **_measured(presentation))


def _measured(presentation) -> dict:
    """The :class:`DurationModel` fields an earlier run's measured figures replace (none: the assumed ones)."""
    if presentation is None:
        return {}
    out: dict = {"prompts_source": tuple(presentation.describe_prompts())}
    if presentation.seconds_per_view is not None:
        out.update(s_per_calibration_view=presentation.seconds_per_view, presentation_source=presentation.describe())
    if presentation.seconds_per_target_move is not None:
        out["s_per_target_move"] = presentation.seconds_per_target_move
    if presentation.seconds_per_placement is not None:
        out["s_per_placement"] = presentation.seconds_per_placement
    return out
