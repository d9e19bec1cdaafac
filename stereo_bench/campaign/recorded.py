"""What a session's start document recorded, read typed: its campaign config, configurations and visits.

The start document keeps the config and plan exactly as recorded (``StartDocument.config``, ``plan``,
``design``: a resume compares them byte for byte, and the schema layer imports nothing above it). A reader
that needs them typed makes one :class:`RecordedStart` per start (or resume) document and asks it; each part is
parsed once, on first use. It lives here, above :mod:`~stereo_bench.campaign.documents`,
:mod:`~stereo_bench.campaign.config` and :mod:`~stereo_bench.campaign.plan`, because the config's extrinsics
sources import the documents.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

from stereo_bench.campaign.config import CampaignConfig, recorded_campaign
from stereo_bench.campaign.documents import ResumeDocument, StartDocument
from stereo_bench.campaign.plan import Configuration, Visit


class RecordedStart:
    """A session's recorded config and plan, typed (each parsed on first use, then kept).

    ``config``, ``plan``, ``design``: as recorded (``StartDocument``'s fields; a resume carries the first two).
    """

    def __init__(self, config: dict[str, Any], plan: list[dict[str, Any]], design: list[dict[str, Any]] | None = None):
        self.config, self.plan, self.design = config, plan, design or []

    @classmethod
    def of(cls, start: StartDocument) -> RecordedStart:
        return cls(start.config, start.plan, start.design)

    @classmethod
    def of_resume(cls, resume: ResumeDocument) -> RecordedStart:
        """The start's config and plan as a resume carries them (not its design: a resume runs no visit again)."""
        if resume.config is None or resume.plan is None:
            raise ValueError("the resume document does not carry its start's config and plan (recorded before them)")
        return cls(resume.config, resume.plan)

    @functools.cached_property
    def campaign(self) -> CampaignConfig:
        """The recorded config (:func:`~stereo_bench.campaign.config.recorded_campaign`; raises pydantic's
        ``ValidationError``)."""
        return recorded_campaign(self.config)

    def campaign_with(self, sections: Mapping[str, Mapping[str, Any]]) -> CampaignConfig:
        """The recorded config with ``sections``' values laid over the recorded sections (a replay's pipeline
        overrides, the recording's copy of a file), validated again (raises pydantic's ``ValidationError``)."""
        config = dict(self.config)
        for section, values in sections.items():
            recorded = config.get(section)
            config[section] = {**(recorded if isinstance(recorded, dict) else {}), **values}
        return recorded_campaign(config)

    @functools.cached_property
    def configurations(self) -> list[Configuration]:
        """The recorded plan's configurations, in order."""
        return [Configuration.from_dict(entry) for entry in self.plan]

    @functools.cached_property
    def visits(self) -> list[Visit]:
        """The recorded visits before the configurations (the kinematic design, the intrinsics calibration)."""
        return [Visit.from_dict(entry) for entry in self.design]


__all__ = ["RecordedStart"]
