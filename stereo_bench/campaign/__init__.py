"""Campaigns: a validated config (TOML), its plan as data, a bench, the runner, and the documents it records.

    config = load_campaign("plan.toml")            # or load_preset("paper-exp1"); the bench kind is validated here
    configurations = expand_plan(config)            # ordered, with predicted feasibility and limit checks
    steps = plan_steps(config, configurations)      # Move, PromptTarget, Settle, Flush, Capture..., Checkpoint
    predict_duration_s(config, configurations, steps)

Running it (``stereo_bench.campaign.execute.run_campaign``) opens a Bench (``campaign.bench``), lets the
runner (``campaign.runner``) execute the steps and publishes typed documents (``campaign.documents``)
through a DocumentBus (``campaign.stream``) to the session writer and any other subscriber.
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
