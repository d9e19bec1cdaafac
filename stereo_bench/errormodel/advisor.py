"""Design advisor: which baselines and angles meet an error target at a given object distance.

For every (B, α) of a grid (symmetric rig, board facing the rig at Z) the rigorous model predicts
the error of the chosen quantity and whether the whole board is in both views. The predicted error
combines, in quadrature (all 1σ, mm):

- image noise: σ of the quantity from ``pixel_sigma_px`` per image coordinate (first order);
- for the square and single lengths, the noise bias (second order; a length is the norm of a noisy
  difference, so noise lengthens it on average);
- the calibration's own error (by default): each configuration's stereo calibration is predicted
  from its planned views (``calibration``: a :class:`~stereo_bench.errormodel.rigorous.CalibrationPlan`,
  by default the campaign's 12 views of the 11x8, 25 mm board) with the same image noise, and its
  covariance pushed through the measurement (``rigorous.calibration_sigmas``). One calibration
  serves all frames of a configuration, so no number of frames averages it away: without it a
  recommendation rests on image noise alone. ``calibration=None`` leaves it out (and says so);
- the rig and the boards (``rig``: a :class:`~stereo_bench.errormodel.rig.RigErrors`): the structure term
  of where R, T come from (the rig's stated tolerances, its repeatability or a kinematic model) and the
  boards' scale, as the campaign's budget counts them;
- structural errors, when given by hand: a baseline wrong by ``baseline_error_mm`` and each camera's angle
  independently wrong by ``alpha_error_deg`` (first-order sensitivities × error; √2 × one camera's
  sensitivity for the two cameras).

Metrics: ``square`` = the measured square (mean of all adjacent pair lengths, what the bench
reports); ``length`` = one adjacent pair length (RMS over pairs); ``depth`` = rig-z of the board
centre.

The recommendation is the largest rectangle of grid cells (B range × α range) in which every
configuration meets the target with the board in view, plus the single best configuration.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from stereo_bench.errormodel.rig import RigErrors, combined, dominant_term
from stereo_bench.errormodel.rigorous import DEFAULT_MARGIN_PX, CalibrationPlan
from stereo_bench.errormodel.surfaces import SurfacePoint, evaluate_configs
from stereo_bench.executors import Executor
from stereo_bench.geometry import CameraModel
from stereo_bench.targets import Checkerboard

AdviceMetric = Literal["square", "length", "depth"]
ADVICE_METRICS = ("square", "length", "depth")
#: The paper's experiment system (§4.1): baseline slide 20-350 mm.
DEFAULT_BASELINES_MM = tuple(float(b) for b in np.arange(20.0, 350.001, 10.0))
DEFAULT_ALPHAS_DEG = tuple(float(a) for a in np.arange(30.0, 90.001, 2.0))


def error_terms(point: SurfacePoint, metric: str, *, baseline_error_mm: float = 0.0, alpha_error_deg: float = 0.0,
                calibration: bool = False, rig: bool = False) -> dict[str, float | None]:
    """The 1σ terms (mm) of ``metric`` at a configuration, by name (:data:`stereo_bench.errormodel.rig.TERM_NAMES`):
    only the terms asked for; a term None where it cannot be computed.

    ``calibration``: the point's predicted calibration component. ``rig``: its structure and target terms
    (the point was evaluated with a :class:`~stereo_bench.errormodel.rig.RigErrors`). ``given``: the baseline
    and angle errors given by hand. A single length's calibration error is taken as the square's (the
    calibration scales every length alike).
    """
    if metric not in ADVICE_METRICS:
        raise ValueError(f"metric must be one of {', '.join(ADVICE_METRICS)}, not {metric!r}")
    depth = metric == "depth"
    if depth:
        terms: dict[str, float | None] = {"noise": point.sigma_z_mm}
        per_b, per_a = point.depth_per_mm_baseline, point.depth_per_deg_alpha
    else:
        terms = {"noise": point.sigma_square_mm if metric == "square" else point.sigma_length_mm,
                 "bias": point.bias_square_mm}
        per_b, per_a = point.square_per_mm_baseline, point.square_per_deg_alpha
    if calibration:
        terms["calibration"] = point.sigma_calibration_depth_mm if depth else point.sigma_calibration_mm
    if rig:
        terms["structure"] = point.sigma_structure_depth_mm if depth else point.sigma_structure_mm
        terms["target"] = point.sigma_target_depth_mm if depth else point.sigma_target_mm
    given = []
    if baseline_error_mm:
        given.append(None if per_b is None else per_b * baseline_error_mm)
    if alpha_error_deg:
        given.append(None if per_a is None else math.sqrt(2.0) * per_a * alpha_error_deg)
    if given:
        terms["given"] = combined({str(i): g for i, g in enumerate(given)})
    return terms


def predicted_error_mm(point: SurfacePoint, metric: str, *, baseline_error_mm: float = 0.0,
                       alpha_error_deg: float = 0.0, calibration: bool = False, rig: bool = False) -> float | None:
    """Combined 1σ error (mm) of ``metric`` at a configuration (:func:`error_terms` in quadrature); None when
    any term cannot be computed."""
    return combined(error_terms(point, metric, baseline_error_mm=baseline_error_mm, alpha_error_deg=alpha_error_deg,
                                calibration=calibration, rig=rig))


class AdviceRow(BaseModel):
    """Per baseline: the α values (deg) that meet the target with the board fully in both views."""

    model_config = ConfigDict(frozen=True)

    baseline_mm: float
    alphas_ok_deg: list[float]
    alpha_min_deg: float | None
    alpha_max_deg: float | None
    contiguous: bool
    best_alpha_deg: float | None
    best_error_mm: float | None


class Configuration(BaseModel):
    model_config = ConfigDict(frozen=True)

    baseline_mm: float
    alpha_deg: float
    K: float
    predicted_error_mm: float
    sigma_noise_mm: float | None
    bias_mm: float | None
    sigma_calibration_mm: float | None = None
    # Every term of predicted_error_mm by name (errormodel.rig.TERM_NAMES), and the largest.
    terms_mm: dict[str, float | None] = {}
    dominant_term: str | None = None


class Advice(BaseModel):
    """The advisor's answer. All lengths mm, angles deg, noise px."""

    distance_mm: float
    target_error_mm: float
    pixel_sigma_px: float
    metric: str
    baseline_error_mm: float
    alpha_error_deg: float
    calibration_views: int  # planned calibration views behind the calibration component; 0: left out
    extrinsics_mode: str | None = None  # where R, T come from (errormodel.rig); None: no rig or target terms
    rig_note: str = ""  # what the rig and target terms rest on
    baselines_mm: tuple[float, float, float]  # first, last, step of the grid
    alphas_deg: tuple[float, float, float]
    meets_target: bool
    recommended_baseline_mm: tuple[float, float] | None  # largest all-passing rectangle of the grid
    recommended_alpha_deg: tuple[float, float] | None
    recommended_worst_error_mm: float | None  # worst predicted error inside that rectangle
    best: Configuration | None
    n_feasible: int
    n_meeting: int
    rows: list[AdviceRow]
    message: str


def _largest_rectangle(ok: np.ndarray) -> tuple[int, int, int, int] | None:
    """(row0, row1, col0, col1) inclusive of the largest all-True rectangle of a 2-D bool array."""
    n_rows, n_cols = ok.shape
    heights = np.zeros(n_cols, int)
    best, best_area = None, 0
    for r in range(n_rows):
        heights = np.where(ok[r], heights + 1, 0)
        stack: list[int] = []
        for c in range(n_cols + 1):
            h = heights[c] if c < n_cols else 0
            while stack and heights[stack[-1]] >= h:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = int(heights[top]) * (c - left)
                if area > best_area:
                    best_area, best = area, (r - int(heights[top]) + 1, r, left, c - 1)
            stack.append(c)
    return best


def _grid_spec(values: tuple[float, ...]) -> tuple[float, float, float]:
    step = values[1] - values[0] if len(values) > 1 else 0.0
    return (values[0], values[-1], step)


def advise(
    distance_mm: float, target_error_mm: float, *, pixel_sigma_px: float = 0.1, metric: str = "square",
    baseline_error_mm: float = 0.0, alpha_error_deg: float = 0.0,
    baselines_mm: tuple[float, ...] | np.ndarray = DEFAULT_BASELINES_MM,
    alphas_deg: tuple[float, ...] | np.ndarray = DEFAULT_ALPHAS_DEG, board: Checkerboard | None = None,
    left: CameraModel | None = None, right: CameraModel | None = None, margin_px: float = DEFAULT_MARGIN_PX,
    executor: Executor | None = None, calibration: CalibrationPlan | None = CalibrationPlan(),  # noqa: B008
    rig: RigErrors | None = None,
) -> Advice:
    """Recommend B and α ranges (symmetric rig) meeting ``target_error_mm`` on ``metric`` at ``distance_mm``.

    ``calibration``: the planned calibration views whose predicted error is included; None: image noise
    (and the structural errors given) only. ``rig``: where R, T come from and what the rig and boards state:
    the structure and target terms of the campaign's budget (:mod:`stereo_bench.errormodel.rig`); None: left out.
    """
    if not distance_mm > 0:
        raise ValueError(f"distance_mm must be positive, not {distance_mm}")
    if not target_error_mm > 0:
        raise ValueError(f"target_error_mm must be positive, not {target_error_mm}")
    if metric not in ADVICE_METRICS:
        raise ValueError(f"metric must be one of {', '.join(ADVICE_METRICS)}, not {metric!r}")
    for name, value in (("baseline_error_mm", baseline_error_mm), ("alpha_error_deg", alpha_error_deg),
                        ("pixel_sigma_px", pixel_sigma_px)):
        if not value >= 0:
            raise ValueError(f"{name} must be >= 0, not {value}")
    baselines = tuple(float(b) for b in baselines_mm)
    alphas = tuple(float(a) for a in alphas_deg)
    if not baselines or not alphas:
        raise ValueError("the baseline and angle grids must not be empty")
    structural = bool(baseline_error_mm or alpha_error_deg)
    points = evaluate_configs(
        [(b, distance_mm, a, a) for b in baselines for a in alphas], pixel_sigma_px=pixel_sigma_px, board=board,
        left=left, right=right, margin_px=margin_px, with_sensitivities=structural, executor=executor,
        calibration=calibration, rig=rig,
    )
    asked = {"baseline_error_mm": baseline_error_mm, "alpha_error_deg": alpha_error_deg,
             "calibration": calibration is not None, "rig": rig is not None}
    errors = np.array([
        np.nan if (e := predicted_error_mm(p, metric, **asked)) is None else e for p in points
    ]).reshape(len(baselines), len(alphas))
    feasible = np.array([p.feasible for p in points]).reshape(errors.shape)
    ok = feasible & np.isfinite(errors) & (errors <= target_error_mm)

    rows = []
    for i, b in enumerate(baselines):
        passing = [alphas[j] for j in np.flatnonzero(ok[i])]
        j_best = None
        if feasible[i].any() and np.isfinite(errors[i][feasible[i]]).any():
            j_best = int(np.nanargmin(np.where(feasible[i], errors[i], np.nan)))
        span = np.flatnonzero(ok[i])
        rows.append(AdviceRow(
            baseline_mm=b, alphas_ok_deg=passing, alpha_min_deg=min(passing) if passing else None,
            alpha_max_deg=max(passing) if passing else None,
            contiguous=bool(len(span) == 0 or span[-1] - span[0] + 1 == len(span)),
            best_alpha_deg=alphas[j_best] if j_best is not None else None,
            best_error_mm=float(errors[i, j_best]) if j_best is not None else None,
        ))

    best = None
    if (feasible & np.isfinite(errors)).any():
        i, j = np.unravel_index(np.nanargmin(np.where(feasible, errors, np.nan)), errors.shape)
        p = points[i * len(alphas) + j]
        best = Configuration(
            baseline_mm=baselines[i], alpha_deg=alphas[j], K=baselines[i] / distance_mm,
            predicted_error_mm=float(errors[i, j]),
            sigma_noise_mm={"square": p.sigma_square_mm, "length": p.sigma_length_mm, "depth": p.sigma_z_mm}[metric],
            bias_mm=None if metric == "depth" else p.bias_square_mm,
            sigma_calibration_mm=p.sigma_calibration_depth_mm if metric == "depth" else p.sigma_calibration_mm,
            terms_mm=(terms := error_terms(p, metric, **asked)), dominant_term=dominant_term(terms),
        )
    rect = _largest_rectangle(ok)
    rec_b = rec_a = worst = None
    if rect is not None:
        r0, r1, c0, c1 = rect
        rec_b, rec_a = (baselines[r0], baselines[r1]), (alphas[c0], alphas[c1])
        worst = float(np.max(errors[r0:r1 + 1, c0:c1 + 1]))
    n_ok = int(ok.sum())
    what = {"square": "the measured square (mean of all pairs)", "length": "one square length",
            "depth": "the board-centre depth"}[metric]
    if n_ok:
        message = (f"{n_ok} of {ok.size} configurations meet {target_error_mm:g} mm on {what} with the board in "
                   f"view; recommended B {rec_b[0]:g}-{rec_b[1]:g} mm with alpha {rec_a[0]:g}-{rec_a[1]:g} deg "
                   f"(worst {worst:.4g} mm); best B {best.baseline_mm:g} mm, alpha {best.alpha_deg:g} deg: "
                   f"{best.predicted_error_mm:.4g} mm")
    elif best is not None:
        message = (f"no configuration meets {target_error_mm:g} mm on {what}; the best feasible one, B "
                   f"{best.baseline_mm:g} mm, alpha {best.alpha_deg:g} deg, predicts {best.predicted_error_mm:.4g} mm")
    else:
        message = f"no configuration of the grid keeps the whole board in both views at Z = {distance_mm:g} mm"
    parts = ["image noise"] + ([] if calibration is None else
                               [f"the error of a calibration from {calibration.n_views} views"])
    if rig is not None:
        parts.append(f"the rig and boards ({rig.describe()})")
    if structural:
        parts.append("the baseline and angle errors given")
    message += f" ({', '.join(parts)}"
    if calibration is None and rig is None and not structural:
        message += "; no calibration, rig or target error"
    message += ")"
    if best is not None and best.dominant_term is not None:
        message += f"; the largest term at the best configuration: {best.dominant_term}"
    return Advice(
        distance_mm=distance_mm, target_error_mm=target_error_mm, pixel_sigma_px=pixel_sigma_px, metric=metric,
        baseline_error_mm=baseline_error_mm, alpha_error_deg=alpha_error_deg,
        calibration_views=0 if calibration is None else calibration.n_views,
        extrinsics_mode=None if rig is None else rig.mode, rig_note="" if rig is None else rig.describe(),
        baselines_mm=_grid_spec(baselines),
        alphas_deg=_grid_spec(alphas), meets_target=bool(n_ok),
        recommended_baseline_mm=rec_b, recommended_alpha_deg=rec_a, recommended_worst_error_mm=worst, best=best,
        n_feasible=int(feasible.sum()), n_meeting=n_ok, rows=rows, message=message,
    )
