"""``fixed``: R, T (and the intrinsics) read from ``calib_dir`` (OpenCV stereo_calib layout), recorded into the
session; how far the rig has moved since that calibration is not known (the budget's structure component)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from stereo_bench.campaign.analysis import ConfigurationAnalysis
from stereo_bench.campaign.documents import CalibrationEvent, CalibrationFiles, Draft
from stereo_bench.campaign.extrinsics.base import ExtrinsicsSource, measured_with
from stereo_bench.campaign.extrinsics_run import Prepared
from stereo_bench.campaign.sources import Source, fixed_source


class FixedSource(ExtrinsicsSource):
    name = "fixed"
    used = "fixed"
    copies_calib_dir_intrinsics = False  # the whole calibration is recorded (start_drafts)
    report_note = " (extrinsics fixed from a file)"

    def check(self, section: Any) -> None:
        if section.calib_dir is None:
            raise ValueError("mode = \"fixed\" needs calib_dir (a directory with intrinsics.yml and extrinsics.yml)")

    def calib_dir_files(self) -> tuple[str, ...]:
        return ("intrinsics.yml", "extrinsics.yml")

    def describe(self, section: Any) -> str:
        return f"read from {section.calib_dir}"

    def read_calib_dir(self, calib_dir: Path, image_size: tuple[int, int]) -> tuple[int, int] | None:
        from stereo_bench.vision.calibio import read_calibration

        return tuple(read_calibration(calib_dir, image_size=image_size).image_size)

    def load_calibration(self, options: Any, section: Any, *, reader: Any, intrinsics_copy: Path | None,
                         image_size: tuple[int, int]) -> None:
        from stereo_bench.vision.calibio import read_calibration

        if reader is not None and reader.events(kind="calibration", config_id=None, attempt=None):
            options.fixed_calibration = reader.calibration(None)  # what the recording used, from inside it
        else:
            options.fixed_calibration = read_calibration(section.calib_dir, image_size=image_size)

    def start_drafts(self, options: Any, section: Any) -> list[Draft]:
        # the calibration used goes into the session
        return [Draft(CalibrationEvent, config_id=None, calibration=CalibrationFiles(
            options.fixed_calibration, None, board=f"fixed: {section.calib_dir}"))]

    def analyse(self, options: Any, prepared: Prepared, captured: Any, *,
                calibrate: Callable[[], ConfigurationAnalysis]) -> tuple[ConfigurationAnalysis, Source | None]:
        source = fixed_source(options.fixed_calibration, options.board_scale)
        return measured_with(source, calibrated=True), source
