"""The report's first screen: how the square's error depends on B, Z and α, why, and our numbers beside the paper's.

Data only (the page is :mod:`stereo_bench.report.html`'s, the figure :func:`stereo_bench.report.figures.answer_figure`):

- per measured configuration, the error of the square against its nominal size and against the board as
  printed (the print's scale is its own term: ``true - nominal``), per extrinsics source the session measured;
- the prediction of each term at that configuration (:mod:`stereo_bench.errormodel.rig`: noise, calibration,
  the structure of each source, the print's scale) and the paper's γ (Yang et al. 2024, Eq. 5, the point where
  the axes meet), with the image noise the session's calibrations fitted to;
- the paper's published Table 1 and Table 2 beside ours, cell by cell;
- the verdicts on the paper's two claims, with the evidence this session and the rigorous model give.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from stereo_bench.report.collect import SessionReport
from stereo_bench.report.tables import finite_number as _finite

#: Yang et al. 2024 (J. Mar. Sci. Eng. 12, 1610), Table 1: the measured 27 mm square (mm) per (B, Z) in mm.
PAPER_TABLE1_MM: dict[tuple[float, float], float] = {
    (50.0, 300.0): 26.9195, (50.0, 400.0): 27.3054, (50.0, 500.0): 26.7151, (50.0, 600.0): 26.5440,
    (50.0, 700.0): 26.3830,
    (100.0, 300.0): 27.1043, (100.0, 400.0): 26.6551, (100.0, 500.0): 26.5797, (100.0, 600.0): 26.4722,
    (100.0, 700.0): 26.4097,
    (150.0, 300.0): 27.1504, (150.0, 400.0): 26.6189, (150.0, 500.0): 26.4629, (150.0, 600.0): 26.3282,
    (150.0, 700.0): 26.2018,
    (200.0, 300.0): 26.7665, (200.0, 400.0): 26.6601, (200.0, 500.0): 27.4959, (200.0, 600.0): 27.8492,
    (200.0, 700.0): 26.3031,
    (250.0, 300.0): 27.6544, (250.0, 400.0): 26.8131, (250.0, 500.0): 26.6576, (250.0, 600.0): 25.8550,
    (250.0, 700.0): 28.7729,
}
#: Its Table 2: the square (mm) per α (deg) at B = 100 mm, Z = 500 mm (Experiment II).
PAPER_TABLE2_MM: dict[float, float] = {5.0: 28.0896, 15.0: 26.3043, 25.0: 26.7151, 35.0: 27.1043, 45.0: 27.3276,
                                       55.0: 27.433}
PAPER_SQUARE_MM = 27.0
#: alpha (deg) -> the Table 1 cell (B, Z) whose published value its Table 2 value repeats to the last digit.
PAPER_TABLE2_REPEATS: dict[float, tuple[float, float]] = {
    alpha: cell for alpha, value in PAPER_TABLE2_MM.items() for cell, other in PAPER_TABLE1_MM.items()
    if other == value}
#: The paper's claims, as its abstract states them.
CLAIM_K = "the error is smallest for K = B/Z between 1 and 1.5"
CLAIM_ALPHA = "the error is smallest for α between 30° and 40°"


@dataclass
class AnswerPoint:
    """One measured configuration: its errors per source and the predicted terms (mm)."""

    config_id: str
    baseline_mm: float
    distance_mm: float
    alpha_deg: float
    used: str  # the source the measurement used
    square_true_mm: float | None  # the board as printed (simulated bench: its truth); None: unknown
    errors_nominal_mm: dict[str, float] = field(default_factory=dict)  # source -> measured - nominal
    expanded_mm: float | None = None  # U of the used source's budget
    predicted_mm: dict[str, float | None] = field(default_factory=dict)  # term -> 1 sigma
    paper_gamma_mm: float | None = None

    @property
    def K(self) -> float:
        return self.baseline_mm / self.distance_mm

    @property
    def print_scale_mm(self) -> float | None:
        """The print's own error: the true square minus the nominal one."""
        return None if self.square_true_mm is None else self.square_true_mm - PAPER_SQUARE_MM

    def error_true_mm(self, source: str) -> float | None:
        error = self.errors_nominal_mm.get(source)
        scale = self.print_scale_mm
        return None if error is None or scale is None else error - scale

    def error_mm(self, source: str) -> float | None:
        """The error the first screen judges: against the board as printed where it is known, else the nominal."""
        return self.error_true_mm(source) if self.square_true_mm is not None else self.errors_nominal_mm.get(source)


@dataclass
class PaperCell:
    """One cell of the paper's tables beside ours (mm)."""

    key: str  # 'B50_Z300' or 'alpha35'
    paper_mm: float
    ours_mm: dict[str, float] = field(default_factory=dict)  # source -> our square
    square_true_mm: float | None = None
    note: str = ""


@dataclass
class Claim:
    claim: str
    verdict: str  # "not supported", "not testable here", "supported", ...
    evidence: list[str]


@dataclass
class Answer:
    points: list[AnswerPoint]
    sources: list[str]
    pixel_sigma_px: float | None
    pixel_sigma_note: str
    table1: list[PaperCell]
    table2: list[PaperCell]
    claims: list[Claim]
    lines: list[str]  # the trends, one sentence each


def _pixel_sigma(session: SessionReport) -> tuple[float | None, str]:
    """Per coordinate, what the session's calibrations fitted to: RMS reprojection / sqrt(2) over configurations."""
    values = [v for c in session.configs if c.calibration and (v := _finite(c.calibration.get("rms_px"))) is not None]
    if not values and (fit := _finite(session.kinematic_fit_rms_px)) is not None:
        # A kinematic session calibrates nowhere but in its design's one fit.
        return fit / math.sqrt(2.0), f"the kinematic fit's reprojection RMS {fit:.3g} px, per coordinate"
    if not values:
        return None, "no calibration RMS recorded"
    rms = math.sqrt(sum(v * v for v in values) / len(values))
    return rms / math.sqrt(2.0), (f"the calibrations' reprojection RMS {rms:.3g} px over {len(values)} "
                                  "configurations, per coordinate")


def _kinematic_design(session: SessionReport):
    """(design, distance) the session's plan visits in kinematic mode (kinematics.campaign_design); None when the
    plan cannot be expanded again."""
    from stereo_bench.campaign.plan.configurations import expand_plan
    from stereo_bench.kinematics import campaign_design

    try:
        return campaign_design(expand_plan(session.config))
    except (ValueError, RuntimeError):
        return None


def _predicted(session: SessionReport, point: AnswerPoint, sigma_px: float, modes: Sequence[str],
               design=None) -> None:
    """The terms at ``point``: noise (per frame / sqrt(frames)), calibration (per-config's, and the kinematic fit's
    jointly with its R, T when ``design``, the plan's kinematic design, is known), the structure of each mode, the
    print's scale; and the paper's γ."""
    from stereo_bench.errormodel import paper
    from stereo_bench.errormodel.rig import rig_errors_of
    from stereo_bench.errormodel.rigorous import CalibrationPlan, Setup, predict
    from stereo_bench.targets import Checkerboard

    config = session.config
    target = config.target.build()
    if not isinstance(target, Checkerboard):
        return
    optics = config.cameras.optics
    board = config.calibration_board.build()
    plan = CalibrationPlan(n_views=max(5, config.capture.calibration_views),
                           board=board if isinstance(board, Checkerboard) else CalibrationPlan().board)
    try:
        setup = Setup.make(point.baseline_mm, point.distance_mm, point.alpha_deg, board=target,
                           left=optics.camera_model("left"), right=optics.camera_model("right"))
    except ValueError:
        return
    frames = max(1, config.capture.frames_per_config)
    for mode in modes:
        if mode not in ("per-config", "nominal", "kinematic"):
            continue
        joint = mode == "kinematic" and design is not None
        rig = rig_errors_of(config.extrinsics, config.target, config.calibration_board, mode=mode,
                            design=design[0] if joint else None, design_distance_mm=design[1] if joint else None,
                            source="the session's config")
        p = predict(setup, sigma_px, calibration=plan if mode == "per-config" or joint else None, rig=rig)
        # The image noise and its bias are every mode's (the same frames): drawn whichever modes were measured.
        point.predicted_mm["noise"] = None if p.sigma_square_mm is None else p.sigma_square_mm / math.sqrt(frames)
        point.predicted_mm["bias"] = p.bias_square_mm
        if mode == "per-config":
            point.predicted_mm["calibration"] = p.sigma_calibration_mm
            point.predicted_mm["target"] = p.sigma_target_mm
        else:
            point.predicted_mm[f"structure ({mode})"] = p.sigma_structure_mm
            if joint:
                point.predicted_mm[f"calibration ({mode})"] = p.sigma_calibration_mm
    point.paper_gamma_mm = float(paper.gamma_mm(point.K, point.distance_mm, setup.left.fx, sigma_px))


def answer_of(session: SessionReport) -> Answer:
    """The first screen's data of one session."""
    sigma_px, sigma_note = _pixel_sigma(session)
    points: list[AnswerPoint] = []
    sources: list[str] = []
    for c in session.configs:
        if c.status != "measured":
            continue
        values = [_finite(c.row.get(k)) for k in ("baseline_mm", "distance_mm", "alpha_deg")]
        if any(v is None for v in values):
            continue
        st = c.structure
        used = (st.mode if st and st.mode else str(c.row.get("extrinsics_mode") or "per-config"))
        squares = dict(st.squares_mm) if st else {}
        if not squares and (square := _finite(c.row.get("square_mean_mm"))) is not None:
            squares = {used: square}
        point = AnswerPoint(c.config_id, *values, used=used, square_true_mm=st.square_true_mm if st else None,
                            errors_nominal_mm={s: v - PAPER_SQUARE_MM for s, v in squares.items()},
                            expanded_mm=c.budget.expanded if c.budget else None)
        sources += [s for s in squares if s not in sources]
        points.append(point)
    if sigma_px is not None and session.config is not None:
        design = _kinematic_design(session) if "kinematic" in sources else None
        for point in points:
            _predicted(session, point, sigma_px, sources, design)
    return Answer(points=points, sources=sources, pixel_sigma_px=sigma_px, pixel_sigma_note=sigma_note,
                  table1=_table1(points), table2=_table2(points), claims=_claims(points, sources),
                  lines=_lines(points, sources))


def _table1(points: list[AnswerPoint]) -> list[PaperCell]:
    cells = []
    for (b, z), value in PAPER_TABLE1_MM.items():
        mine = [p for p in points if abs(p.baseline_mm - b) < 1e-6 and abs(p.distance_mm - z) < 1e-6
                and abs(p.alpha_deg - 90.0) < 1e-6]
        cell = PaperCell(f"B{b:g}_Z{z:g}", value)
        if mine:
            cell.ours_mm = {s: e + PAPER_SQUARE_MM for s, e in mine[0].errors_nominal_mm.items()}
            cell.square_true_mm = mine[0].square_true_mm
        cells.append(cell)
    return cells if any(c.ours_mm for c in cells) else []


def _table2(points: list[AnswerPoint]) -> list[PaperCell]:
    # An alpha sweep: the session's points when it measured more than one alpha (a single alpha of 90 is no sweep).
    sweep = points if len({p.alpha_deg for p in points}) > 1 else [p for p in points if abs(p.alpha_deg - 90) > 1e-6]
    cells = []
    for alpha, value in PAPER_TABLE2_MM.items():
        # The paper's alpha as this project reads it (docs/REPORTS.md): the angle between baseline and axis.
        mine = [p for p in sweep if abs(p.alpha_deg - alpha) < 1e-6]
        repeated = PAPER_TABLE2_REPEATS.get(alpha)
        note = (f"the paper's value equals its Table 1 cell B{repeated[0]:g}/Z{repeated[1]:g} to the last digit"
                if repeated else "")
        cell = PaperCell(f"alpha{alpha:g}", value, note=note)
        if mine:
            cell.ours_mm = {s: e + PAPER_SQUARE_MM for s, e in mine[0].errors_nominal_mm.items()}
            cell.square_true_mm = mine[0].square_true_mm
        cells.append(cell)
    return cells if any(c.ours_mm for c in cells) else []


def _rms(values: Sequence[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


def _by_k(points: list[AnswerPoint], source: str) -> list[tuple[float, float]]:
    return sorted((p.K, abs(e)) for p in points if (e := p.error_mm(source)) is not None)


def _claims(points: list[AnswerPoint], sources: list[str]) -> list[Claim]:
    ks = [p.K for p in points]
    paper_ks = sorted({b / z for b, z in PAPER_TABLE1_MM})
    k_evidence = [f"The paper's own Table 1 grid spans K = {paper_ks[0]:.3f}-{paper_ks[-1]:.3f}: no cell has "
                  "K >= 1, so its experiments cannot show a minimum between 1 and 1.5."]
    if ks:
        k_evidence.append(f"This session measured K = {min(ks):.3f}-{max(ks):.3f}.")
    for source in sources:
        pairs = _by_k(points, source)
        if len({k for k, _ in pairs}) >= 3:  # a trend over K needs K to vary (an alpha sweep holds it)
            best_k, best_error = min(pairs, key=lambda kv: kv[1])
            worst_k, worst_error = max(pairs, key=lambda kv: kv[1])
            what = "against the board as printed" if points[0].square_true_mm is not None else "against nominal"
            k_evidence.append(f"{source}: smallest |error| {what} {best_error:.3g} mm at K = {best_k:.3f}, largest "
                              f"{worst_error:.3g} mm at K = {worst_k:.3f}.")
    k_evidence.append("The rigorous model (docs/ERROR_MODEL.md §4) reproduces K = √2 for the error of the point "
                      "where the axes meet (the paper's γ), but puts the minimum of the measured square's σ at "
                      "K ≈ 0.8 (Z 500 mm), flat within 10 % over K 0.5-1.3; structural errors, not image noise, "
                      "set the accuracy.")
    verdict_k = "not supported by the paper's own data; the model agrees only for the point where the axes meet"
    alphas = sorted({p.alpha_deg for p in points})
    a_evidence = ["At the paper's Experiment II (B 100 mm, Z 500 mm) the rigorous model sees no corner of the board "
                  "in either view for α <= 45° under our reading of α (the paper's cot α = K/2 implies it); under the "
                  "toe-in reading (our α 50-60°) only part of the board is seen (docs/ERROR_MODEL.md §4).",
                  f"{len(PAPER_TABLE2_REPEATS)} of the paper's Table 2 values repeat its Table 1 cells to the last "
                  "digit (" + "; ".join(f"{a:g}°: B {b:g} / Z {z:g}" for a, (b, z) in PAPER_TABLE2_REPEATS.items())
                  + ")."]
    if len(alphas) > 1:
        for source in sources:
            pairs = sorted((p.alpha_deg, abs(e)) for p in points if (e := p.error_mm(source)) is not None)
            if len({a for a, _ in pairs}) >= 3:
                best = min(pairs, key=lambda ae: ae[1])
                a_evidence.append(f"{source}: over α = {pairs[0][0]:g}-{pairs[-1][0]:g}° measured, the smallest "
                                  f"|error| {best[1]:.3g} mm is at α = {best[0]:g}°.")
    a_evidence.append("The one place 35° is special in the model: on a converging rig at K ≈ 2.84 the square's mean "
                      "is insensitive to one camera's angle error (a cancellation between horizontal and vertical "
                      "pairs), at B ≈ 1.4 m for Z = 500 mm.")
    verdict_a = ("not testable at the paper's B and Z (the board is outside the views); where measurable, α changes "
                 "the noise by < 25 %")
    return [Claim(CLAIM_K, verdict_k, k_evidence), Claim(CLAIM_ALPHA, verdict_a, a_evidence)]


def _lines(points: list[AnswerPoint], sources: list[str]) -> list[str]:
    """One sentence per trend: which term makes it."""
    out = []
    scales = {round(p.print_scale_mm, 6) for p in points if p.print_scale_mm is not None}
    if len(scales) == 1:
        scale = next(iter(scales))
        out.append(f"Against the nominal 27 mm every measurement carries the print's own error, {scale:+.4f} mm "
                   f"({scale / PAPER_SQUARE_MM * 100:+.3f} % of scale): the same at every B, Z and α, so it hides "
                   "every trend of the rig. The figure shows the error against the board as printed.")
    for source in sources:
        errs = [abs(e) for p in points if (e := p.error_mm(source)) is not None]
        if not errs:
            continue
        largest: dict[str, int] = {}
        mine = ("noise", "bias", "calibration") if source == "per-config" else (
            "noise", "bias", f"calibration ({source})", f"structure ({source})")
        for p in points:
            terms = {k: v for k, v in p.predicted_mm.items() if v is not None and k in mine}
            if terms:
                name = max(terms, key=terms.get)
                largest[name] = largest.get(name, 0) + 1
        why = (f"; the predicted term that dominates: {max(largest, key=largest.get)}" if largest else "")
        against = "against the board as printed" if points[0].square_true_mm is not None else "against nominal"
        out.append(f"{source}: RMS |error| {against} {_rms(errs):.3g} mm over {len(errs)} configurations{why}.")
    return out
