"""Running a campaign and replaying one: config → plan → Bench + Runner → documents → subscribers.

``run_campaign`` is what ``stereo-bench campaign run`` does; ``replay_session`` what ``stereo-bench
replay`` does. Both put the same :class:`~stereo_bench.campaign.runner.CampaignRunner` to work on a
:class:`~stereo_bench.campaign.bench.Bench` from one of its three factories (simulated, hardware,
replay), publishing through a :class:`~stereo_bench.campaign.stream.DocumentBus` whose recorder is the
session writer (or, for a replay that records nothing, memory). Callers watch a run by subscribing to
its documents and steer it through a :class:`RunControl`; nothing reaches into the runner.
"""

from __future__ import annotations

from stereo_bench.campaign.execute.control import RunControl
from stereo_bench.campaign.execute.options import runner_options
from stereo_bench.campaign.execute.planned import CampaignPlan, plan_drift
from stereo_bench.campaign.execute.replay import (
    ReplaySummary,
    check_replay_out,
    replay_job,
    replay_session,
    reproducibility,
)
from stereo_bench.campaign.execute.run import (
    RunSummary,
    default_operators,
    recorded_config,
    resume_sources,
    run_campaign,
    software_versions,
)
from stereo_bench.campaign.operator import OperatorAbsent

__all__ = [
    "CampaignPlan", "OperatorAbsent", "ReplaySummary", "RunControl", "RunSummary", "check_replay_out",
    "default_operators", "plan_drift", "recorded_config", "replay_job", "replay_session", "reproducibility",
    "resume_sources", "run_campaign", "runner_options", "software_versions",
]
