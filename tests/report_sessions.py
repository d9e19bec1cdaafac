"""Sessions with the structure and uncertainty records (issues 11, 12), written with the typed session models.

Until the campaign records them, the report is tested against sessions built here: result rows with
``extrinsics_mode``, the ``*_used_*`` / ``*_true_*`` columns, ``u_combined_mm``, ``U_expanded_mm`` and the
nested ``uncertainty`` budget, a ``structure`` event and a ``truth`` event per configuration, in the shapes
``stereo_bench.report.collect`` reads (those of the structure branch's ``StructureData``, ``SourceRecord``
and ``TruthData``). The numbers follow a simple, stated model of a rig whose true optical baseline is 4 mm
short of the commanded one and whose cameras are turned a little, so that every figure can be checked
against the values written here (:func:`expected`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from stereo_bench.campaign.config import recorded_campaign
from stereo_bench.campaign.documents import ResultRow
from stereo_bench.campaign.session import SessionWriter
from stereo_bench.geometry import RigPose, stereo_structure

NOMINAL_SQUARE_MM = 27.0
PRINT_SCALE = 1.0008  # the simulated board is printed 0.08 % large
SQUARE_TRUE_MM = NOMINAL_SQUARE_MM * PRINT_SCALE
BASELINE_SHORT_MM = 4.0  # true optical baseline ~ commanded B - 4 mm (pan axes behind the optical centres)
ALPHA_LEFT_OFFSET_DEG = -0.6
ALPHA_RIGHT_OFFSET_DEG = 0.1
TARGET_PRINT_U_MM = 0.001  # the measured board's own print-scale part of the target component
#: The source of extrinsics each mode measures with (as the campaign names them).
MODE_SOURCE = {"per-config": "calibrated", "kinematic": "kinematic", "nominal": "nominal"}
#: Error of the square measured with calibrated and kinematic extrinsics, against the true square; nominal
#: extrinsics give the structure's error (the square scales with the baseline the extrinsics claim).
SOURCE_ERROR = {"per-config": 0.0006, "kinematic": 0.0021}
#: The sources a session of each mode records per configuration (the same detections measured with the other
#: sources it has: a kinematic session has no calibration views at the configuration, a nominal one no model).
SQUARES_RECORDED = {"per-config": ("per-config", "kinematic", "nominal"), "kinematic": ("kinematic", "nominal"),
                    "nominal": ("nominal",)}
#: Standard uncertainties (mm) of the square measured with each source; None: unknown (no covariance).
BUDGETS = {
    "per-config": {"noise": 0.0004, "calibration": 0.0005, "structure": 0.0, "target": 0.0011},
    "kinematic": {"noise": 0.0004, "calibration": 0.0005, "structure": 0.0019, "target": 0.0011},
    "nominal": {"noise": 0.0004, "calibration": None, "structure": 0.35, "target": 0.0011},
}
#: The kinematic prediction's standard uncertainties.
KINEMATIC_SIGMA = {"baseline_mm": 0.02, "alpha_left_deg": 0.004, "alpha_right_deg": 0.004, "rotation_deg": 0.005}


def combined(mode: str) -> float:
    return math.sqrt(sum(v * v for v in BUDGETS[mode].values() if v is not None))


def uncertainty_record(mode: str) -> dict:
    """The ``uncertainty`` record of a square measured with ``mode``'s source."""
    u_c = combined(mode)
    return {**BUDGETS[mode], "combined": u_c, "expanded": 2.0 * u_c, "k": 2.0,
            "unknown": [n for n, v in BUDGETS[mode].items() if v is None], "target_print_mm": TARGET_PRINT_U_MM,
            "combined_vs_true": math.sqrt(u_c**2 - TARGET_PRINT_U_MM**2)}


@dataclass(frozen=True)
class Expected:
    """What a configuration of a built session holds."""

    config_id: str
    squares_mm: dict[str, float]  # per extrinsics mode
    structures: dict[str, dict[str, float]]  # per source: calibrated, kinematic, nominal, truth
    extrinsics: dict[str, tuple[list, list]]  # per source: R, T
    combined: float
    expanded: float

    @property
    def truth(self) -> dict[str, float]:
        return self.structures["truth"]

    @property
    def nominal(self) -> dict[str, float]:
        return self.structures["nominal"]


def _pose(baseline: float, alpha_left: float, alpha_right: float) -> tuple[list, list, dict]:
    R, T = RigPose(baseline, alpha_left, alpha_right).stereo_extrinsics()
    return R.tolist(), T.tolist(), stereo_structure(R, T)


def expected(baseline_mm: float, distance_mm: float, alpha_deg: float, mode: str) -> Expected:
    """The configuration ``B<b>_Z<z>_A<a>`` of a session measured with ``mode``."""
    poses = {
        "truth": _pose(baseline_mm - BASELINE_SHORT_MM, alpha_deg + ALPHA_LEFT_OFFSET_DEG,
                       alpha_deg + ALPHA_RIGHT_OFFSET_DEG),
        "calibrated": _pose(baseline_mm - BASELINE_SHORT_MM + 0.0005, alpha_deg + ALPHA_LEFT_OFFSET_DEG + 0.0005,
                            alpha_deg + ALPHA_RIGHT_OFFSET_DEG + 0.0005),
        "kinematic": _pose(baseline_mm - BASELINE_SHORT_MM + 0.002, alpha_deg + ALPHA_LEFT_OFFSET_DEG + 0.002,
                           alpha_deg + ALPHA_RIGHT_OFFSET_DEG + 0.002),
        "nominal": _pose(baseline_mm, alpha_deg, alpha_deg),
    }
    truth = poses["truth"][2]
    squares = {
        "per-config": SQUARE_TRUE_MM + SOURCE_ERROR["per-config"],
        "kinematic": SQUARE_TRUE_MM + SOURCE_ERROR["kinematic"],
        "nominal": SQUARE_TRUE_MM * baseline_mm / truth["baseline_mm"] + 0.01 * (90.0 - alpha_deg),
    }
    return Expected(config_id=f"B{baseline_mm:g}_Z{distance_mm:g}_A{alpha_deg:g}", squares_mm=squares,
                    structures={name: pose[2] for name, pose in poses.items()},
                    extrinsics={name: (pose[0], pose[1]) for name, pose in poses.items()},
                    combined=combined(mode), expanded=2.0 * combined(mode))


def _source_record(e: Expected, mode: str) -> dict:
    source = MODE_SOURCE[mode]
    square = e.squares_mm[mode]
    R, T = e.extrinsics[source]
    return {"R": R, "T": T, "structure": e.structures[source],
            "structure_sigma": KINEMATIC_SIGMA if source == "kinematic" else None, "square_mean_mm": square,
            "error_mm": square - NOMINAL_SQUARE_MM, "error_true_mm": square - SQUARE_TRUE_MM,
            "uncertainty": uncertainty_record(mode),
            "note": "calibration covariance unknown" if BUDGETS[mode]["calibration"] is None else None}


def write_structured_session(
    directory: Path, name: str, mode: str, geometries: list[tuple[float, float, float]], *,
    budget: bool = True, truth: bool = True, structure_event: bool = True, infeasible: tuple = (),
    kinematic_fit_rms_px: float | None = None,
) -> Path:
    """A finished session of ``geometries`` (B, Z, alpha) measured with extrinsics ``mode``; no frames.

    ``budget``: rows carry the uncertainty columns and budget; ``truth``: the truth columns and a truth
    event (a simulated bench); ``structure_event``: the per-configuration structure event with every
    source the mode has and the square and budget of each (else only the row says which extrinsics were
    used); ``infeasible``: geometries planned but not measurable; ``kinematic_fit_rms_px``: record the design's
    kinematic fit (its event) with this RMS.
    """
    plan = [{"config_id": f"B{b:g}_Z{z:g}_A{a:g}", "baseline_mm": float(b), "distance_mm": float(z),
             "alpha_deg": float(a), "toe_in_deg": 90.0 - a, "tilt_deg": 0.0, "fraction_in_both": 1.0,
             "corners_in_both": 54, "n_corners": 54}
            for b, z, a in [*geometries, *infeasible]]
    config = recorded_campaign({
        "name": name, "description": f"built for the report tests (constructed numbers): {mode} extrinsics",
        "plan": {"baseline_mm": sorted({float(b) for b, _, _ in geometries}),
                 "distance_mm": sorted({float(z) for _, z, _ in geometries})}}).model_dump(mode="json")
    with SessionWriter(directory).open() as writer:
        writer.start(config=config, plan=plan, software={"stereo_bench": "test"})
        if kinematic_fit_rms_px is not None:
            # The design's one fit, as the kinematic source records it before the first configuration.
            writer.event("kinematic_model", data={"source": "design", "n_views": 108, "rms_px": kinematic_fit_rms_px})
        for b, z, a in geometries:
            e = expected(b, z, a, mode)
            used = e.structures[MODE_SOURCE[mode]]
            row = {"config_id": e.config_id, "baseline_mm": float(b), "distance_mm": float(z), "alpha_deg": float(a),
                   "toe_in_deg": 90.0 - a, "tilt_deg": 0.0, "status": "measured",
                   "square_mean_mm": e.squares_mm[mode], "error_mm": e.squares_mm[mode] - NOMINAL_SQUARE_MM,
                   "sigma_mm": 0.0002, "n_squares": 93, "n_frames": 3, "fraction_in_both": 1.0,
                   "fraction_in_both_measured": 1.0, "extrinsics_mode": mode,
                   "baseline_used_mm": used["baseline_mm"], "alpha_left_used_deg": used["alpha_left_deg"],
                   "alpha_right_used_deg": used["alpha_right_deg"]}
            if truth:
                row.update(baseline_true_mm=e.truth["baseline_mm"], alpha_left_true_deg=e.truth["alpha_left_deg"],
                           alpha_right_true_deg=e.truth["alpha_right_deg"], square_true_mm=SQUARE_TRUE_MM)
            if budget:
                row.update(u_combined_mm=e.combined, U_expanded_mm=e.expanded, uncertainty=uncertainty_record(mode))
            R, T = e.extrinsics["truth"]
            truth_data = {"profile": "lab", "R": R, "T": T, "structure": e.truth,
                          "target": {"kind": "target", "square_true_mm": SQUARE_TRUE_MM, "print_scale": PRINT_SCALE}}
            if truth:
                writer.event("truth", config_id=e.config_id, data=truth_data)
            if structure_event:
                writer.event("structure", config_id=e.config_id, data={
                    "mode": mode, "used": MODE_SOURCE[mode],
                    "axes": {"baseline_mm": float(b), "toe_in_left_deg": 90.0 - a, "toe_in_right_deg": 90.0 - a},
                    "approach": {}, "sources": {MODE_SOURCE[m]: _source_record(e, m) for m in SQUARES_RECORDED[mode]},
                    "truth": {"R": R, "T": T, "structure": e.truth, "square_true_mm": SQUARE_TRUE_MM}
                    if truth else None})
            writer.result(e.config_id, ResultRow.model_validate(row).stored())
        for b, z, a in infeasible:
            config_id = f"B{b:g}_Z{z:g}_A{a:g}"
            writer.result(config_id, {"config_id": config_id, "baseline_mm": float(b), "distance_mm": float(z),
                                      "alpha_deg": float(a), "toe_in_deg": 90.0 - a, "tilt_deg": 0.0,
                                      "status": "infeasible", "reason": "the views do not overlap on the target"})
        writer.stop(exit_status="success")
    return directory


#: A small paper-like campaign: a B x Z grid at alpha 90 and an alpha sweep at B 100, Z 500.
GRID = [(b, z, 90.0) for b in (50.0, 100.0, 150.0) for z in (300.0, 500.0)]
SWEEP = [(100.0, 500.0, a) for a in (80.0, 85.0)]
INFEASIBLE = ((100.0, 500.0, 35.0),)
