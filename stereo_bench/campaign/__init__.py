"""Campaigns: a validated config (TOML), its plan as data, and (elsewhere) the runner that executes it.

    config = load_campaign("plan.toml")            # or load_preset("paper-exp1")
    configurations = expand_plan(config)            # ordered, with predicted feasibility and limit checks
    steps = plan_steps(config, configurations)      # Move, PromptTarget, Settle, Flush, Capture..., Checkpoint
    predict_duration_s(config, configurations, steps)
"""

from stereo_bench.campaign.config import (
    PRESETS,
    CamerasSection,
    CampaignConfig,
    CaptureSection,
    ConfigError,
    ExtrinsicsSection,
    OpticsConfig,
    PlanSection,
    RigSection,
    TargetConfig,
    campaign_from_dict,
    campaign_json_schema,
    load_campaign,
    load_preset,
)
from stereo_bench.campaign.plan import (
    CaptureCalibration,
    CaptureMeasurement,
    Checkpoint,
    Configuration,
    DurationEstimate,
    Flush,
    Move,
    PromptManual,
    PromptTarget,
    Settle,
    Step,
    estimate_duration,
    expand_plan,
    plan_steps,
    plan_summary,
    predict_duration_s,
)

__all__ = [
    "PRESETS", "CamerasSection", "CampaignConfig", "CaptureCalibration", "CaptureMeasurement",
    "CaptureSection", "Checkpoint", "ConfigError", "Configuration", "DurationEstimate", "ExtrinsicsSection", "Flush",
    "Move", "OpticsConfig", "PlanSection", "PromptManual", "PromptTarget", "RigSection", "Settle", "Step",
    "TargetConfig", "campaign_from_dict", "campaign_json_schema", "estimate_duration", "expand_plan", "load_campaign",
    "load_preset", "plan_steps", "plan_summary", "predict_duration_s",
]
