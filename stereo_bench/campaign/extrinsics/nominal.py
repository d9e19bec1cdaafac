"""``nominal``: R, T of the ideal geometry at the commanded B and alphas (a user who trusts the rig's scales), the
intrinsics from ``calib_dir`` if given, else from one stereo calibration at a visit of the first configuration;
the uncertainty of R, T is the rig's stated ``tolerances``."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from stereo_bench.campaign.analysis import AnalysisError, ConfigurationAnalysis
from stereo_bench.campaign.extrinsics.base import (
    ExtrinsicsSource,
    calibrate_intrinsics_visit,
    intrinsics_visit,
    measured_with,
    nominal_at,
)
from stereo_bench.campaign.extrinsics_run import Prepared, intrinsics_from_dir
from stereo_bench.campaign.sources import Source


class NominalSource(ExtrinsicsSource):
    name = "nominal"
    used = "nominal"
    compared_with = ("kinematic",)

    def visit_purpose(self, section: Any) -> str | None:
        # without a calibration directory: one calibration at the first configuration
        return "intrinsics" if section.calib_dir is None else None

    def needs_calibration_views(self, section: Any) -> bool:
        return self.visit_purpose(section) is not None

    def describe(self, section: Any) -> str:
        return ("the ideal geometry at the commanded B and alpha, intrinsics "
                + (f"from {section.calib_dir}" if section.calib_dir
                   else "from one calibration at the first configuration"))

    def visits(self, section: Any, configurations: Sequence, ranges: dict, *, visit: Callable[..., Any],
               format_id: Callable[[float], str]) -> list:
        """The first runnable configuration at which the calibration board fits."""
        first = intrinsics_visit(configurations, visit)
        return [first] if first is not None else []

    def load_calibration(self, options: Any, section: Any, *, reader: Any, intrinsics_copy: Path | None,
                         image_size: tuple[int, int]) -> None:
        super().load_calibration(options, section, reader=reader, intrinsics_copy=intrinsics_copy,
                                 image_size=image_size)
        if section.calib_dir is not None and reader is None:  # a replay: the recorded copy (recorded_sources)
            options.nominal_intrinsics = intrinsics_from_dir(section.calib_dir, image_size)

    def prepare(self, captures: Sequence, config: Any, options: Any, *, purpose: str | None = None,
                earlier: Prepared | None = None) -> Prepared:
        """The intrinsics of one stereo calibration at the intrinsics visit."""
        prepared = calibrate_intrinsics_visit(captures, config, what="intrinsics for nominal extrinsics")
        prepared.nominal_intrinsics = prepared.lens
        return prepared

    def is_prepared(self, recorded: Prepared) -> bool:
        return recorded.nominal_intrinsics is not None

    def analyse(self, options: Any, prepared: Prepared, captured: Any, *,
                calibrate: Callable[[], ConfigurationAnalysis]) -> tuple[ConfigurationAnalysis, Source | None]:
        if prepared.nominal_intrinsics is None:
            raise AnalysisError(prepared.error or "no intrinsics for nominal extrinsics")
        source = nominal_at(options, prepared.nominal_intrinsics, captured.configuration)
        return measured_with(source), source
