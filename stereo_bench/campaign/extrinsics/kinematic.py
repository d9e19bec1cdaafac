"""``kinematic``: R, T predicted at each configuration by the kinematic rig model (:mod:`stereo_bench.kinematics`)
from the rig's reported axes and directions of approach; the model (with both cameras' intrinsics) fitted once,
in one joint adjustment, to the views of a design of visits the plan chooses, or read from ``kinematic_file``."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np

from stereo_bench.campaign.analysis import AnalysisError, ConfigurationAnalysis
from stereo_bench.campaign.extrinsics.base import (
    ExtrinsicsSource,
    calibrate_intrinsics_visit,
    measured_with,
    visit_captures,
)
from stereo_bench.campaign.extrinsics_run import Prepared
from stereo_bench.campaign.sources import Source, kinematic_source
from stereo_bench.kinematics import ConfigurationViews, campaign_design, fit_kinematics
from stereo_bench.kinematics.fixed_board import fixed_board_design
from stereo_bench.kinematics.model import TILT_AXES

#: The purpose a fixed-board design's lens calibration records (its ``calibration`` event's ``purpose``).
LENS_NOTE = "lens calibration: the fixed-board fit's intrinsics prior"


class KinematicSource(ExtrinsicsSource):
    name = "kinematic"
    used = "kinematic"
    compared_with = ("nominal",)

    def visit_purpose(self, section: Any) -> str | None:
        # without a saved model the plan starts with the design's calibration visits
        return "kinematic" if section.kinematic_file is None else None

    def describe(self, section: Any) -> str:
        return ("predicted by the kinematic rig model "
                + (f"read from {section.kinematic_file}" if section.kinematic_file
                   else "fitted once to a fixed board's views as the rig moves in front of it" if section.fixed_board
                   else "fitted once to the design's views"))

    def visits(self, section: Any, configurations: Sequence, ranges: dict, *, visit: Callable[..., Any],
               format_id: Callable[[float], str]) -> list:
        """The design of :func:`stereo_bench.kinematics.kinematic_design` over ``ranges``; the board is shown
        around the middle of the plan's target distances."""
        # The same design a prediction of this campaign fits (kinematics.campaign_design); ``ranges`` are
        # design_ranges(configurations), which it spans.
        designs, distance = campaign_design(configurations)
        if section.fixed_board:
            # Slide and pan positions in front of one board (where it stands: plan_visits asks the feasibility
            # rules), and the tilts where the plan steps them (plan.design_tilt); presented: 9 visits, the board
            # presented 12 times at each.
            designs = fixed_board_design(ranges["baseline_mm"], ranges["toe_in_deg"], ranges["toe_in_deg"],
                                         tilt_ranges_deg=ranges.get("tilt_ranges_deg"))
        visits = []
        for k, design in enumerate(designs):
            config_id = (f"design-{k + 1}_B{format_id(design.baseline_mm)}_L{format_id(design.toe_in_left_deg)}"
                         f"_R{format_id(design.toe_in_right_deg)}")
            tilts = {axis: value for axis, value in design.axes().items() if axis in TILT_AXES}
            config_id += "".join(f"_T{axis.split('_')[1][0].upper()}{format_id(value)}"  # _TLm5_TR5
                                 for axis, value in tilts.items())
            visits.append(visit(k, config_id, "kinematic", design.baseline_mm, design.toe_in_left_deg,
                                design.toe_in_right_deg, distance, tilts=tilts or None))
        return visits

    def prepare(self, captures: Sequence, config: Any, options: Any, *, purpose: str | None = None,
                earlier: Prepared | None = None) -> Prepared:
        """Fit the kinematic model to the design's views (:func:`stereo_bench.kinematics.fit_kinematics`); a
        fixed-board design's lens calibration first where the plan presents one (``purpose`` "intrinsics": the
        intrinsics visit's stereo calibration, whose intrinsics and covariance the fit then takes from
        ``earlier`` as it would ``calib_dir``'s)."""
        if purpose == "intrinsics":
            return calibrate_intrinsics_visit(captures, config, what="lens calibration for the fixed-board fit",
                                              note=LENS_NOTE)
        if earlier is not None and earlier.error and earlier.lens is None:
            return Prepared(error=f"kinematic fit (fixed board): {earlier.error}",
                            record={"source": "design", "design": "fixed-board", "error": earlier.error})
        board = config.calibration_board.build()
        captured, ids = visit_captures(captures)
        record: dict[str, Any] = {"source": "design", "visits_used": ids}
        if not captured:
            return Prepared(error="kinematic fit: no design visit captured views", record={**record, "error":
                            "no design visit captured views"})
        configurations = []
        for capture in captured:
            try:
                views = capture.detections()  # made while capturing (or recorded, in a replay)
            except AnalysisError as error:
                return Prepared(error=f"kinematic fit failed: {error}", record={**record, "error": str(error)})
            configurations.append(ConfigurationViews(axes=_design_axes(capture), approach=capture.approach,
                                                     views=views))
        image = captured[0].calibration_pairs[0][0]
        image_size = (int(image.shape[1]), int(image.shape[0]))
        slide_mm, heads_deg = options.repeatability
        started = time.perf_counter()
        if config.extrinsics.fixed_board:
            lens = earlier.lens if earlier is not None else None
            return self._prepare_fixed_board(configurations, board, image_size, options, record, ids, started,
                                             lens=lens)
        try:
            fit = fit_kinematics(configurations, board.object_points, (int(image.shape[1]), int(image.shape[0])),
                                 intrinsics=options.intrinsics, refine_intrinsics=True, repeatability_mm=slide_mm,
                                 repeatability_left_deg=heads_deg, repeatability_right_deg=heads_deg)
        except (ValueError, np.linalg.LinAlgError) as error:
            return Prepared(error=f"kinematic fit failed: {error}", record={**record, "error": str(error)})
        model = fit.model
        record.update(n_views=model.fit.n_views, rms_px=model.fit.rms_px, fit_s=time.perf_counter() - started,
                      views_dropped=[{"visit": ids[c], "view": i, "reason": why} for c, i, why in fit.views_dropped])
        return Prepared(kinematic_model=model, record=record)

    @staticmethod
    def _prepare_fixed_board(configurations: list, board: Any, image_size: tuple[int, int], options: Any,
                             record: dict[str, Any], ids: list[str], started: float, *, lens: Any = None) -> Prepared:
        """The fixed-board fit (:func:`stereo_bench.kinematics.fixed_board.fit_fixed_board`): intrinsics from a lens
        calibration (its covariance a prior): ``lens``, the plan's intrinsics visit's, else ``calib_dir``'s; without
        either, each camera calibrated from the same views first and refined jointly."""
        from stereo_bench.kinematics.fixed_board import INTRINSIC_NAMES, fit_fixed_board
        from stereo_bench.vision.calibrate import DEFAULT_FLAGS, calibrate_mono

        record["design"] = "fixed-board"
        slide_mm, heads_deg = options.repeatability
        intrinsics, prior = options.intrinsics, None
        covariance = options.intrinsics_covariance
        if lens is not None:  # the lens calibration of the presented views (recorded as that visit's calibration)
            intrinsics, covariance = (lens.K1, lens.D1, lens.K2, lens.D2), lens.covariance
            record["lens_visit"] = next((v.config_id for v in options.visits if v.purpose == "intrinsics"), None)
        if intrinsics is not None and covariance is not None and all(n in covariance.names for n in INTRINSIC_NAMES):
            index = covariance.index(INTRINSIC_NAMES)
            prior = np.asarray(covariance.matrix, float)[np.ix_(index, index)]
        try:
            if intrinsics is None:
                views = [v for conf in configurations for v in conf.views if v[0] is not None and v[1] is not None]
                views = views[:: max(1, len(views) // 30)]  # a start the joint fit refines: 30 views as good as all
                mono = [calibrate_mono([board.object_points[np.asarray(v[side].ids)] for v in views],
                                       [np.asarray(v[side].corners_px, float) for v in views], image_size,
                                       flags=DEFAULT_FLAGS) for side in (0, 1)]
                intrinsics = (mono[0].K, mono[0].dist, mono[1].K, mono[1].dist)
            fit = fit_fixed_board(configurations, board.object_points, image_size, intrinsics=intrinsics,
                                  intrinsics_covariance=prior, repeatability_mm=slide_mm,
                                  repeatability_left_deg=heads_deg, repeatability_right_deg=heads_deg,
                                  # a head's tilt lands as its pan does ([extrinsics] repeatability_deg)
                                  repeatability_tilt_left_deg=heads_deg, repeatability_tilt_right_deg=heads_deg)
        except (ValueError, np.linalg.LinAlgError, cv2.error) as error:
            return Prepared(error=f"kinematic fit (fixed board) failed: {error}",
                            record={**record, "error": str(error)})
        model = fit.model
        record.update(n_views=model.fit.n_views, rms_px=model.fit.rms_px, fit_s=time.perf_counter() - started,
                      views_dropped=[{"visit": ids[c], "view": i, "reason": why} for c, i, why in fit.views_dropped],
                      identifiability=[{"name": r.name, "unit": r.unit, "identified": r.identified, "sigma": r.sigma,
                                        "note": r.note} for r in fit.identifiability],
                      fixed_board={"T_ref_board": fit.T_ref_board.tolist(), "left_share": fit.left_share})
        return Prepared(kinematic_model=model, record=record)

    def is_prepared(self, recorded: Prepared) -> bool:
        return recorded.kinematic_model is not None

    def analyse(self, options: Any, prepared: Prepared, captured: Any, *,
                calibrate: Callable[[], ConfigurationAnalysis]) -> tuple[ConfigurationAnalysis, Source | None]:
        if prepared.kinematic_model is None:
            raise AnalysisError(prepared.error or "no kinematic rig model")
        source = kinematic_source(prepared.kinematic_model, captured.axes, captured.approach, options.board_scale)
        return measured_with(source), source


def _design_axes(capture: Any) -> dict[str, float]:
    """The reported axes of a design visit the fit takes: the tilts only where the design steps them (the visit's
    ``tilts_in_design``; a rig that drives them reports them at every move, held or not)."""
    design = getattr(capture.configuration, "tilts_in_design", ())
    return {axis: value for axis, value in capture.axes.items() if axis not in TILT_AXES or axis in design}
