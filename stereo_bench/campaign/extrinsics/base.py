"""The extrinsics source protocol: what an ``[extrinsics] mode`` decides, asked of one object instead of its name.

A source (one subclass of :class:`ExtrinsicsSource` per mode, registered in :data:`SOURCES` by its ``name``)
owns, from the config to the report:

- the config: what its section must say (:meth:`~ExtrinsicsSource.check`), whether it needs calibration views
  (:meth:`~ExtrinsicsSource.needs_calibration_views`), the files ``calib_dir`` must hold;
- the plan: the visits it needs before the configurations (:meth:`~ExtrinsicsSource.visit_purpose`,
  :meth:`~ExtrinsicsSource.visits`) and whether each configuration shows the calibration board
  (:attr:`~ExtrinsicsSource.calibrates_each_configuration`: the plan's steps, ``bench.planned_captures``);
- preflight: reading ``calib_dir`` as the run will (:meth:`~ExtrinsicsSource.read_calib_dir`);
- the run: the calibration it starts with (:meth:`~ExtrinsicsSource.load_calibration`) and records
  (:meth:`~ExtrinsicsSource.start_drafts`), the runner's hooks (once a configuration's calibration views are
  taken, :meth:`~ExtrinsicsSource.after_calibration_views`; after the visits, :meth:`~ExtrinsicsSource.prepare`;
  at each configuration, :meth:`~ExtrinsicsSource.analyse`, which gives the R, T measured with and their
  budget), and the comparison with the other sources (:meth:`~ExtrinsicsSource.compare`: the structure event);
- a resume: whether the recording already holds what the visits prepare (:meth:`~ExtrinsicsSource.is_prepared`).

The math of each source's R, T and budget is :mod:`stereo_bench.campaign.sources`; the fit and what a recording
holds, :mod:`stereo_bench.campaign.extrinsics_run`. Sources are stateless: a method takes the config's
``[extrinsics]`` section (``section``) or the runner's options where it needs them. This package imports neither
the config nor the plan (the config asks it, ``ExtrinsicsSection.source()``, and the plan passes what it builds).
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar

from stereo_bench.campaign.analysis import ConfigurationAnalysis
from stereo_bench.campaign.documents import Draft
from stereo_bench.campaign.extrinsics_run import Prepared
from stereo_bench.campaign.sources import (
    Source,
    StructureComparison,
    assess,
    calibrated_source,
    compare,
    kinematic_source,
    nominal_source,
    result_columns,
    structure_data,
    truth_columns,
)
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.rectify import rectify

#: ``[extrinsics] mode`` -> its source class (every module of this package registers one).
SOURCES: dict[str, type[ExtrinsicsSource]] = {}


def extrinsics_source(mode: str) -> ExtrinsicsSource:
    """The source of ``[extrinsics] mode`` ``mode``; ValueError for a name no module defines."""
    try:
        return SOURCES[mode]()
    except KeyError:
        raise ValueError(f"unknown extrinsics mode {mode!r}; known: {', '.join(SOURCES)}") from None


class ExtrinsicsSource(ABC):
    """Where a campaign's stereo extrinsics R, T come from (one subclass per ``[extrinsics] mode``)."""

    #: the ``[extrinsics] mode`` (the result rows' ``extrinsics_mode``, the structure event's ``mode``)
    name: ClassVar[str]
    #: the source (:data:`stereo_bench.campaign.sources.SOURCE_NAMES`) it measures with: the structure event's "used"
    used: ClassVar[str]
    #: the other sources measured beside it on the same detections (the structure event), in this order
    compared_with: ClassVar[tuple[str, ...]] = ("kinematic", "nominal")
    #: every configuration shows the calibration board and is calibrated from its own views
    calibrates_each_configuration: ClassVar[bool] = False
    #: the session's calib_dir intrinsics are copied into the session (a replay reads them from there)
    copies_calib_dir_intrinsics: ClassVar[bool] = True
    #: what the report's title adds for this source
    report_note: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if not inspect.isabstract(cls):
            SOURCES[cls.name] = cls

    # -- the config ----------------------------------------------------------------------------------------------

    def check(self, section: Any) -> None:
        """ValueError when the ``[extrinsics]`` section does not say what this source needs."""
        return None

    def visit_purpose(self, section: Any) -> str | None:
        """The purpose of the visits the plan starts with ("kinematic", "intrinsics"), or None: no visits."""
        return None

    def needs_calibration_views(self, section: Any) -> bool:
        """Whether the campaign calibrates from ``capture.calibration_views`` (then at least the minimum)."""
        return self.calibrates_each_configuration

    def calib_dir_files(self) -> tuple[str, ...]:
        """The files ``calib_dir`` must hold."""
        return ("intrinsics.yml",)

    @abstractmethod
    def describe(self, section: Any) -> str:
        """Where R, T come from, in one line (``campaign plan``)."""

    # -- the plan ------------------------------------------------------------------------------------------------

    def visits(self, section: Any, configurations: Sequence, ranges: dict, *, visit: Callable[..., Any],
               format_id: Callable[[float], str]) -> list:
        """The visits before the configurations (asked only when :meth:`visit_purpose` is not None).

        ``visit(index, config_id, purpose, baseline, toe_left, toe_right, distance, tilts=None)`` makes one, checked
        like a configuration (``tilts``: per-camera tilts the design steps; None: the campaign's); ``ranges``: the
        span of the runnable configurations (``plan.design_ranges``; ``tilt_ranges_deg`` where the design steps
        the tilts, ``plan.design_tilt``);
        ``format_id``: how a value is written in a config id.
        """
        return []

    # -- preflight and the run's inputs --------------------------------------------------------------------------

    def read_calib_dir(self, calib_dir: Path, image_size: tuple[int, int]) -> tuple[int, int] | None:
        """Read ``calib_dir`` as the run will (CalibrationFileError); the image size it states, if any."""
        from stereo_bench.vision.calibio import read_intrinsics, read_intrinsics_covariance

        size = read_intrinsics(calib_dir)[4]
        read_intrinsics_covariance(calib_dir)
        return size

    def load_calibration(self, options: Any, section: Any, *, reader: Any, intrinsics_copy: Path | None,
                         image_size: tuple[int, int]) -> None:
        """Set the runner's ``options`` from ``calib_dir`` (CalibrationFileError): the intrinsics to start from or
        hold. ``reader``: a replay's recording; ``intrinsics_copy``: the copy of calib_dir's intrinsics it holds
        (sessions recorded before the copy was made for every mode: calib_dir itself)."""
        from stereo_bench.vision.calibio import read_intrinsics, read_intrinsics_covariance

        if section.calib_dir is None:
            return
        source = intrinsics_copy or section.calib_dir
        options.intrinsics = read_intrinsics(source)[:4]
        options.intrinsics_covariance = read_intrinsics_covariance(source)

    def start_drafts(self, options: Any, section: Any) -> list[Draft]:
        """Documents recorded once the bench is open, before the configurations (what the run starts with)."""
        return []

    # -- the runner's hooks --------------------------------------------------------------------------------------

    def after_calibration_views(self, captured: Any, start_calibration: Callable[[], Any]) -> None:
        """A configuration's calibration views are taken (runner): ``start_calibration()`` queues its calibration
        on the analysis pool and returns the future."""
        return None

    def prepare(self, captures: Sequence, config: Any, options: Any, *, purpose: str | None = None,
                earlier: Prepared | None = None) -> Prepared:
        """After the visits (analysis thread): what the visits' ``captures`` prepare. A failure is kept
        (``Prepared.error``): every configuration then fails with it. ``purpose``: the preparation step's (a plan
        that prepares in stages: a fixed-board design's lens calibration, ``"intrinsics"``, then its fit);
        ``earlier``: what the stage before prepared (or a resume read back), None if there was none."""
        raise ValueError(f"extrinsics mode {self.name!r} visits nothing to prepare")

    def is_prepared(self, recorded: Prepared) -> bool:
        """A resume: whether ``recorded`` (what the earlier attempts recorded) holds what the visits prepare."""
        return True

    @abstractmethod
    def analyse(self, options: Any, prepared: Prepared, captured: Any, *,
                calibrate: Callable[[], ConfigurationAnalysis]) -> tuple[ConfigurationAnalysis, Source | None]:
        """The calibration a configuration is measured with (analysis thread; AnalysisError if it has none), and
        the source it is (None: the configuration's own calibration). ``calibrate()`` calibrates from its views."""

    def compare(self, options: Any, prepared: Prepared, configuration: Any, captured: Any,
                analysis: ConfigurationAnalysis, target: Any, *, used: Source | None) -> StructureComparison:
        """The used source's budget and columns, and every source of :attr:`compared_with` available there, on
        the same detections: the kinematic model's prediction wherever a model is (kinematic mode, or
        ``kinematic_file``); the nominal geometry with the used calibration's intrinsics."""
        if used is None:  # the configuration's own calibration
            used = calibrated_source(analysis.calib, options.board_scale)
        others = [source for name in self.compared_with
                  if (source := COMPARISONS[name](options, prepared, configuration, captured, used)) is not None]
        results = {used.name: assess(used, analysis.frames, target)}
        results.update(compare(others, [(f.left, f.right) for f in analysis.frames], target))
        axes = captured.axes or {"baseline_mm": configuration.baseline_mm,
                                 "toe_in_left_deg": configuration.toe_in_deg,
                                 "toe_in_right_deg": configuration.toe_in_deg}
        columns = {**result_columns(self.name, results[used.name]), **truth_columns(captured.truth)}
        return StructureComparison(columns=columns, data=structure_data(
            self.name, results, used=self.used, axes=axes, approach=captured.approach or {}, truth=captured.truth))


# --------------------------------------------------------------------------------------------------
# Shared by the sources


def measured_with(source: Source, *, calibrated: bool = False) -> ConfigurationAnalysis:
    """A configuration's analysis measuring with ``source``'s R, T (``calibrated``: R, T from a calibration)."""
    return ConfigurationAnalysis(calib=source.calib, rect=rectify(source.calib), calibrated=calibrated)


def nominal_at(options: Any, intrinsics: StereoCalibration, configuration: Any) -> Source:
    """The nominal geometry at ``configuration``'s commanded B and alphas, with ``intrinsics``."""
    return nominal_source(intrinsics, baseline_mm=configuration.baseline_mm, alpha_left_deg=configuration.alpha_deg,
                          alpha_right_deg=configuration.alpha_deg, tilt_deg=configuration.tilt_deg,
                          tolerances=options.tolerances, board_scale=options.board_scale)


def _kinematic_comparison(options: Any, prepared: Prepared, configuration: Any, captured: Any,
                          used: Source) -> Source | None:
    model = prepared.kinematic_model
    if model is None or captured.axes is None:
        return None
    return kinematic_source(model, captured.axes, captured.approach or {}, options.board_scale)


def _nominal_comparison(options: Any, prepared: Prepared, configuration: Any, captured: Any,
                        used: Source) -> Source | None:
    return nominal_at(options, used.calib, configuration)


#: The comparison sources a configuration can be measured with beside the used one (None: not available there).
COMPARISONS: dict[str, Callable[..., Source | None]] = {"kinematic": _kinematic_comparison,
                                                        "nominal": _nominal_comparison}


def intrinsics_visit(configurations: Sequence, visit: Callable[..., Any]) -> Any | None:
    """The intrinsics visit (12 presented views for one stereo calibration) at the first runnable configuration
    where the calibration board fits both views (``visit``: as :meth:`ExtrinsicsSource.visits` gets it); else the
    last one tried (not runnable, with the reason), or None without a runnable configuration."""
    first = None
    for c in (c for c in configurations if c.runnable):
        first = visit(0, f"intrinsics-{c.config_id}", "intrinsics", c.baseline_mm, c.toe_in_deg, c.toe_in_deg,
                      c.distance_mm)
        if first.runnable:
            break
    return first


def calibrate_intrinsics_visit(captures: Sequence, config: Any, *, what: str,
                               note: str = "intrinsics of nominal extrinsics") -> Prepared:
    """One joint stereo calibration of the intrinsics visit's views (its intrinsics and their covariance:
    ``Prepared.lens``), recorded as the visit's calibration event (``note``: its purpose); an error names ``what``
    was to be calibrated."""
    from stereo_bench.campaign.analysis import AnalysisError, calibrate_configuration

    board = config.calibration_board.build()
    captured, ids = visit_captures(captures)
    if not captured:
        return Prepared(error=f"no {what}: the calibration visit captured nothing")
    try:
        analysis = calibrate_configuration(captured[0].calibration_pairs, board, mode="joint",
                                           detections=captured[0].detections())
    except AnalysisError as error:
        return Prepared(error=f"no {what}: calibration at {ids[0]} failed: {error}")
    return Prepared(lens=analysis.calib, calibration=(ids[0], analysis), calibration_note=note)


def visit_captures(captures: Sequence) -> tuple[list, list[str]]:
    """The visits' captures that took calibration views, and their ids."""
    captured = [c for c in captures if c.calibration_pairs]
    return captured, [c.configuration.config_id for c in captured]


__all__ = ["COMPARISONS", "SOURCES", "ExtrinsicsSource", "calibrate_intrinsics_visit", "extrinsics_source",
           "intrinsics_visit", "measured_with", "nominal_at", "visit_captures"]
