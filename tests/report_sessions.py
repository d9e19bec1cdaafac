"""Sessions with the structure and uncertainty records (issues 11, 12), written with the typed session models.

Until the campaign records them, the report is tested against sessions built here: result rows with
``extrinsics_mode``, the ``*_used_*`` / ``*_true_*`` columns, ``u_combined_mm``, ``U_expanded_mm`` and the
nested ``uncertainty_mm`` budget, a ``structure`` event and a ``truth`` event per configuration (the shapes
``stereo_bench.report.collect.structure_of`` reads). The numbers follow a simple, stated model of a rig
whose true optical baseline is 4 mm short of the commanded one and whose cameras are turned a little,
so that every figure can be checked against the values written here (:func:`expected`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereo_bench.campaign.documents import ResultRow
from stereo_bench.campaign.session import SessionWriter

NOMINAL_SQUARE_MM = 27.0
PRINT_SCALE = 1.0008  # the simulated board is printed 0.08 % large
SQUARE_TRUE_MM = NOMINAL_SQUARE_MM * PRINT_SCALE
BASELINE_SHORT_MM = 4.0  # true optical baseline = commanded B - 4 mm (pan axes behind the optical centres)
ALPHA_LEFT_OFFSET_DEG = -0.6
ALPHA_RIGHT_OFFSET_DEG = 0.1
#: Error of the square measured with each extrinsics source, against the true square: per-config and kinematic
#: small, nominal the structure's (the square scales with the baseline the extrinsics claim).
SOURCE_ERROR = {"per-config": 0.0006, "kinematic": 0.0021}
#: The squares a session of each mode records per configuration (the same detections measured with the other
#: sources it has: a kinematic session has no calibration views at the configuration, a nominal one no model).
SQUARES_RECORDED = {"per-config": ("per-config", "kinematic", "nominal"), "kinematic": ("kinematic", "nominal"),
                    "nominal": ("nominal",)}
#: Standard uncertainties (mm) of each mode's budget; None: unknown (the calibration with no covariance).
BUDGETS = {
    "per-config": {"noise": 0.0004, "calibration": 0.0005, "structure": 0.0, "target": 0.0011},
    "kinematic": {"noise": 0.0004, "calibration": 0.0005, "structure": 0.0019, "target": 0.0011},
    "nominal": {"noise": 0.0004, "calibration": None, "structure": 0.35, "target": 0.0011},
}


@dataclass(frozen=True)
class Expected:
    """What a configuration of a built session holds."""

    config_id: str
    squares_mm: dict[str, float]  # per extrinsics mode
    used: str
    budget: dict[str, float | None]
    combined: float
    expanded: float
    truth: dict[str, float]
    nominal: dict[str, float]


def _structure(baseline: float, alpha_left: float, alpha_right: float) -> dict[str, float]:
    return {"baseline_mm": baseline, "alpha_left_deg": alpha_left, "alpha_right_deg": alpha_right,
            "rotation_deg": abs((90.0 - alpha_left) + (90.0 - alpha_right))}


def expected(baseline_mm: float, distance_mm: float, alpha_deg: float, mode: str) -> Expected:
    """The configuration ``B<b>_Z<z>_A<a>`` of a session measured with ``mode``."""
    truth = _structure(baseline_mm - BASELINE_SHORT_MM, alpha_deg + ALPHA_LEFT_OFFSET_DEG,
                       alpha_deg + ALPHA_RIGHT_OFFSET_DEG)
    nominal = _structure(baseline_mm, alpha_deg, alpha_deg)
    toe_in = 90.0 - alpha_deg
    squares = {
        "per-config": SQUARE_TRUE_MM + SOURCE_ERROR["per-config"],
        "kinematic": SQUARE_TRUE_MM + SOURCE_ERROR["kinematic"],
        # nominal extrinsics claim a baseline 4 mm too long: the square grows with it, and with toe-in
        "nominal": SQUARE_TRUE_MM * baseline_mm / truth["baseline_mm"] + 0.01 * toe_in,
    }
    budget = BUDGETS[mode]
    combined = float(np.sqrt(sum(v * v for v in budget.values() if v is not None)))
    return Expected(config_id=f"B{baseline_mm:g}_Z{distance_mm:g}_A{alpha_deg:g}", squares_mm=squares, used=mode,
                    budget=budget, combined=combined, expanded=2.0 * combined, truth=truth, nominal=nominal)


def write_structured_session(
    directory: Path, name: str, mode: str, geometries: list[tuple[float, float, float]], *,
    budget: bool = True, truth: bool = True, structure_event: bool = True, infeasible: tuple = (),
) -> Path:
    """A finished session of ``geometries`` (B, Z, alpha) measured with extrinsics ``mode``; no frames.

    ``budget``: rows carry the uncertainty columns and budget; ``truth``: the truth columns and a truth
    event (a simulated bench); ``structure_event``: the per-configuration structure event with every
    source and the square per source (else only the row says which extrinsics were used);
    ``infeasible``: geometries planned but not measurable.
    """
    plan = [{"config_id": f"B{b:g}_Z{z:g}_A{a:g}", "baseline_mm": float(b), "distance_mm": float(z),
             "alpha_deg": float(a), "toe_in_deg": 90.0 - a, "tilt_deg": 0.0, "fraction_in_both": 1.0}
            for b, z, a in [*geometries, *infeasible]]
    config = {"name": name, "description": f"built for the report tests: {mode} extrinsics",
              "plan": {"baseline_mm": sorted({float(b) for b, _, _ in geometries}),
                       "distance_mm": sorted({float(z) for _, z, _ in geometries})}}
    with SessionWriter(directory).open() as writer:
        writer.start(config=config, plan=plan, software={"stereo_bench": "test"})
        for b, z, a in geometries:
            e = expected(b, z, a, mode)
            used = e.nominal if mode == "nominal" else {
                key: value + (0.002 if mode == "kinematic" else 0.0005) for key, value in e.truth.items()}
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
                row.update(u_combined_mm=e.combined, U_expanded_mm=e.expanded,
                           uncertainty_mm={**e.budget, "combined": e.combined, "expanded": e.expanded, "k": 2.0})
            if structure_event:
                sources = {"used": used, "nominal": e.nominal,
                           "kinematic": {k: v + 0.002 for k, v in e.truth.items()},
                           "calibrated": None if mode != "per-config" else used,
                           "truth": e.truth if truth else None}
                writer.event("structure", config_id=e.config_id, data={
                    "extrinsics_mode": mode, "extrinsics": sources,
                    "square_mm": {source: e.squares_mm[source] for source in SQUARES_RECORDED[mode]}})
            if truth:
                writer.event("truth", config_id=e.config_id, data={
                    "structure": e.truth, "target": {"square_true_mm": SQUARE_TRUE_MM, "print_scale": PRINT_SCALE}})
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
