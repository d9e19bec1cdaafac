"""``per-config`` (the default): R, T calibrated at each configuration from its own views of the calibration board."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from stereo_bench.campaign.analysis import ConfigurationAnalysis
from stereo_bench.campaign.extrinsics.base import ExtrinsicsSource
from stereo_bench.campaign.extrinsics_run import Prepared
from stereo_bench.campaign.sources import Source


class PerConfigSource(ExtrinsicsSource):
    """Each configuration shows the calibration board and is calibrated from those views; the budget's structure
    component is zero (the rig did not move since its views)."""

    name = "per-config"
    used = "calibrated"
    calibrates_each_configuration = True

    def describe(self, section: Any) -> str:
        return "calibrated at every configuration from its own views"

    def after_calibration_views(self, captured: Any, start_calibration: Callable[[], Any]) -> None:
        # calibrate from the views just taken while the measurement frames are captured
        captured.calibration = start_calibration()

    def analyse(self, options: Any, prepared: Prepared, captured: Any, *,
                calibrate: Callable[[], ConfigurationAnalysis]) -> tuple[ConfigurationAnalysis, Source | None]:
        started = captured.calibration
        return (started.result() if started is not None else calibrate()), None
