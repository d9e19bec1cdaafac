"""Error surfaces of the rigorous model over (B, Z) and over α, optimum search, and the paper comparison.

Analogues of the paper's figures: Figure 5 (total error over baseline and object distance) is
:func:`surface_bz`; Figure 4a (error against the angle α at a fixed baseline) is
:func:`surface_alpha`. Every grid point is one :func:`~stereo_bench.errormodel.rigorous.predict`
plus the structural sensitivities to a baseline error and to one camera's angle error; points go
through an :class:`~stereo_bench.executors.Executor` in chunks, so a fine sweep can use a process
pool or a Dask cluster. Results are identical whatever the executor (no randomness here).

α policies for a (B, Z) surface: ``"converge"`` (symmetric, optical axes meet at the board
centre: cot α = K/2 — the paper's geometry), ``"parallel"`` (α = 90°), or a fixed angle in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from stereo_bench.errormodel import paper
from stereo_bench.errormodel.rig import RigErrors
from stereo_bench.errormodel.rigorous import DEFAULT_MARGIN_PX, CalibrationPlan, Setup, predict, sensitivities
from stereo_bench.executors import Executor, SerialExecutor, group
from stereo_bench.geometry import CameraModel
from stereo_bench.targets import Checkerboard

AlphaPolicy = Literal["converge", "parallel"] | float

#: Metrics a sweep can be minimised on: fields of :class:`SurfacePoint` (sensitivities by absolute value).
METRICS = (
    "sigma_square_mm", "sigma_length_mm", "sigma_z_mm", "gamma_xz_mm", "gamma_mm", "bias_square_mm",
    "square_per_mm_baseline", "depth_per_mm_baseline", "square_per_deg_alpha", "depth_per_deg_alpha",
    "square_per_deg_alpha_both", "depth_per_deg_alpha_both",
)


class SurfacePoint(BaseModel):
    """One configuration of a sweep. mm, deg, px; None where a value cannot be computed.

    ``paper_gamma_mm`` is the paper's γ for this K and Z (its model assumes the converging rig).
    ``square_per_mm_baseline`` etc.: first-order change of the measured square / centre depth per mm
    of baseline error and per degree of angle error of the right camera (calibration wrong by that).
    """

    model_config = ConfigDict(frozen=True)

    baseline_mm: float
    distance_mm: float
    alpha_deg: float  # left camera
    alpha_right_deg: float
    K: float
    feasible: bool
    measurable: bool
    fraction_in_both: float
    sigma_square_mm: float | None
    bias_square_mm: float | None
    sigma_length_mm: float | None
    sigma_x_mm: float | None
    sigma_y_mm: float | None
    sigma_z_mm: float | None
    gamma_xz_mm: float | None
    gamma_mm: float | None
    paper_gamma_mm: float
    square_per_mm_baseline: float | None
    depth_per_mm_baseline: float | None
    square_per_deg_alpha: float | None  # right camera only
    depth_per_deg_alpha: float | None
    square_per_deg_alpha_both: float | None  # both cameras turned by the same error
    depth_per_deg_alpha_both: float | None
    # The calibration's own error from the planned views (rigorous.calibration_sigmas); None: not asked/placeable.
    sigma_calibration_mm: float | None = None
    sigma_calibration_depth_mm: float | None = None
    # What the rig and boards add (errormodel.rig); None: not asked for, or not computable.
    sigma_structure_mm: float | None = None
    sigma_structure_depth_mm: float | None = None
    sigma_target_mm: float | None = None
    sigma_target_depth_mm: float | None = None


@dataclass(frozen=True, eq=False)
class _Job:
    """Picklable chunk of grid points: (B, Z, α_left, α_right) rows and the shared scene."""

    configs: tuple[tuple[float, float, float, float], ...]
    pixel_sigma_px: float
    board: Checkerboard
    left: CameraModel
    right: CameraModel
    margin_px: float
    with_sensitivities: bool
    calibration: CalibrationPlan | None = None
    rig: RigErrors | None = None


def _evaluate(job: _Job) -> list[SurfacePoint]:
    rows = []
    for baseline, distance, alpha_left, alpha_right in job.configs:
        setup = Setup.make(baseline, distance, alpha_left, alpha_right_deg=alpha_right, board=job.board,
                           left=job.left, right=job.right)
        pred = predict(setup, job.pixel_sigma_px, margin_px=job.margin_px, calibration=job.calibration, rig=job.rig)
        sens = {}
        if job.with_sensitivities:
            sens = sensitivities(setup, ("baseline_mm", "alpha_right_deg", "alpha_both_deg"), margin_px=job.margin_px)
        s_b, s_a, s_ab = sens.get("baseline_mm"), sens.get("alpha_right_deg"), sens.get("alpha_both_deg")
        k = baseline / distance
        rows.append(SurfacePoint(
            baseline_mm=baseline, distance_mm=distance, alpha_deg=alpha_left, alpha_right_deg=alpha_right, K=k,
            feasible=pred.feasible, measurable=pred.measurable, fraction_in_both=pred.fraction_in_both,
            sigma_square_mm=pred.sigma_square_mm, bias_square_mm=pred.bias_square_mm,
            sigma_length_mm=pred.sigma_length_mm, sigma_x_mm=pred.sigma_x_mm, sigma_y_mm=pred.sigma_y_mm,
            sigma_z_mm=pred.sigma_z_mm, gamma_xz_mm=pred.gamma_xz_mm, gamma_mm=pred.gamma_mm,
            paper_gamma_mm=float(paper.gamma_mm(k, distance, job.left.fx, job.pixel_sigma_px)),
            square_per_mm_baseline=s_b.square_mm_per_unit if s_b else None,
            depth_per_mm_baseline=s_b.depth_mm_per_unit if s_b else None,
            square_per_deg_alpha=s_a.square_mm_per_unit if s_a else None,
            depth_per_deg_alpha=s_a.depth_mm_per_unit if s_a else None,
            square_per_deg_alpha_both=s_ab.square_mm_per_unit if s_ab else None,
            depth_per_deg_alpha_both=s_ab.depth_mm_per_unit if s_ab else None,
            sigma_calibration_mm=pred.sigma_calibration_mm, sigma_calibration_depth_mm=pred.sigma_calibration_depth_mm,
            sigma_structure_mm=pred.sigma_structure_mm, sigma_structure_depth_mm=pred.sigma_structure_depth_mm,
            sigma_target_mm=pred.sigma_target_mm, sigma_target_depth_mm=pred.sigma_target_depth_mm,
        ))
    return rows


def alpha_for(policy: AlphaPolicy, baseline_mm: float, distance_mm: float) -> float:
    """α (deg) a policy gives a symmetric rig at (B, Z)."""
    if policy == "converge":
        return float(paper.converging_alpha_deg(baseline_mm / distance_mm))
    if policy == "parallel":
        return 90.0
    alpha = float(policy)
    if not 0.0 < alpha < 180.0:
        raise ValueError(f"alpha must lie strictly between 0 and 180 deg, not {alpha}")
    return alpha


def evaluate_configs(
    configs: list[tuple[float, float, float, float]], *, pixel_sigma_px: float = 0.1, board: Checkerboard | None = None,
    left: CameraModel | None = None, right: CameraModel | None = None, margin_px: float = DEFAULT_MARGIN_PX,
    with_sensitivities: bool = True, executor: Executor | None = None, points_per_task: int = 16,
    calibration: CalibrationPlan | None = None, rig: RigErrors | None = None,
) -> list[SurfacePoint]:
    """:class:`SurfacePoint` for each (B mm, Z mm, α_left deg, α_right deg), in order, run through ``executor``.

    ``calibration``: also predict each configuration's calibration error from these planned views.
    ``rig``: also the structure and target terms (:mod:`stereo_bench.errormodel.rig`).
    """
    probe = Setup.make(100.0, 500.0, board=board, left=left, right=right)
    chunks = group(list(configs), max(1, math.ceil(len(configs) / max(1, points_per_task))))
    jobs = [_Job(configs=tuple(tuple(float(v) for v in c) for c in chunk), pixel_sigma_px=float(pixel_sigma_px),
                 board=probe.board, left=probe.left, right=probe.right, margin_px=float(margin_px),
                 with_sensitivities=with_sensitivities, calibration=calibration, rig=rig) for chunk in chunks]
    results = (executor or SerialExecutor()).map(_evaluate, jobs)
    return [row for rows in results for row in rows]


def surface_bz(
    baselines_mm: np.ndarray, distances_mm: np.ndarray, *, alpha: AlphaPolicy = "converge", **kwargs,
) -> list[SurfacePoint]:
    """Rows over the (B, Z) grid, B-major (row i * len(Z) + j is (B_i, Z_j)). ``kwargs`` as :func:`evaluate_configs`."""
    configs = []
    for b in np.asarray(baselines_mm, float):
        for z in np.asarray(distances_mm, float):
            a = alpha_for(alpha, b, z)
            configs.append((b, z, a, a))
    return evaluate_configs(configs, **kwargs)


def surface_alpha(
    alphas_deg: np.ndarray, *, baseline_mm: float, distance_mm: float, one_camera: bool = False, **kwargs,
) -> list[SurfacePoint]:
    """Rows over α for a symmetric rig (or, ``one_camera``, only the right camera turned, the left parallel)."""
    configs = [(float(baseline_mm), float(distance_mm), 90.0 if one_camera else float(a), float(a))
               for a in np.asarray(alphas_deg, float)]
    return evaluate_configs(configs, **kwargs)


def grid(rows: list[SurfacePoint], field: str, shape: tuple[int, ...]) -> np.ndarray:
    """One field of a sweep as an array of ``shape`` (None -> NaN)."""
    values = [getattr(r, field) for r in rows]
    return np.array([np.nan if v is None else float(v) for v in values]).reshape(shape)


def metric_value(row: SurfacePoint, metric: str) -> float | None:
    """|value| of ``metric`` at ``row`` (None where it cannot be computed)."""
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {', '.join(METRICS)}, not {metric!r}")
    value = getattr(row, metric)
    return None if value is None else abs(float(value))


def optimum(rows: list[SurfacePoint], metric: str = "sigma_square_mm", *, feasible_only: bool = True,
            ) -> SurfacePoint | None:
    """The row with the smallest |``metric``| among the feasible (or merely measurable) ones; None if none."""
    candidates = [r for r in rows if (r.feasible if feasible_only else r.measurable)
                  and metric_value(r, metric) is not None]
    return min(candidates, key=lambda r: metric_value(r, metric)) if candidates else None


def feasible_range(rows: list[SurfacePoint], field: str) -> tuple[float, float] | None:
    """(min, max) of ``field`` over the feasible rows, or None."""
    values = [getattr(r, field) for r in rows if r.feasible]
    return (min(values), max(values)) if values else None




# ----------------------------------------------------------------------------------------------
# One-dimensional optima, refined


class Optimum(BaseModel):
    """Where |metric| is smallest along a one-parameter family of configurations (grid, then refined)."""

    model_config = ConfigDict(frozen=True)

    family: str
    variable: str  # "K" or "alpha_deg"
    metric: str
    x: float
    value: float
    limit: Literal["interior", "feasibility", "sweep_end"]  # why the optimum stops where it does
    near_optimal: tuple[float, float]  # grid range around the optimum where |metric| <= 1.1 x the optimum
    point: SurfacePoint


def _golden(f, a: float, b: float, tol: float) -> float:
    inv_phi = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - inv_phi * (b - a), a + inv_phi * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - inv_phi * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + inv_phi * (b - a)
            fd = f(d)
    return 0.5 * (a + b)


def _bisect_edge(evaluate, x_ok: float, x_bad: float, tol: float) -> float:
    """Last feasible x between a feasible ``x_ok`` and an infeasible ``x_bad``."""
    while abs(x_bad - x_ok) > tol:
        mid = 0.5 * (x_ok + x_bad)
        if evaluate(mid).feasible:
            x_ok = mid
        else:
            x_bad = mid
    return x_ok


def minimise_1d(
    evaluate, xs: np.ndarray, rows: list[SurfacePoint], metric: str, *, variable: str, family: str,
    tol: float = 1e-4,
) -> Optimum | None:
    """Refine the grid minimum of |metric| over feasible ``rows`` (``rows[i]`` = ``evaluate(xs[i])``).

    An interior minimum is refined by golden section between its grid neighbours; a minimum next to
    an infeasible neighbour is pushed to the feasibility limit (bisection) when that is better.
    """
    xs = [float(x) for x in xs]

    def score(row: SurfacePoint) -> float:
        value = metric_value(row, metric) if row.feasible else None
        return math.inf if value is None else value

    scores = [score(r) for r in rows]
    i = int(np.argmin(scores))
    if not math.isfinite(scores[i]):
        return None
    neighbours = [j for j in (i - 1, i + 1) if 0 <= j < len(xs)]
    infeasible = [j for j in neighbours if not rows[j].feasible]
    if len(neighbours) < 2 and not infeasible:
        best_x, limit = xs[i], "sweep_end"
    elif infeasible:
        # The metric still falls toward the infeasible side: the optimum is the feasibility limit.
        j = infeasible[0]
        best_x, limit = _bisect_edge(evaluate, xs[i], xs[j], tol), "feasibility"
        if score(evaluate(best_x)) > scores[i]:
            best_x, limit = xs[i], "interior"
    else:
        best_x = _golden(lambda x: score(evaluate(x)), xs[i - 1], xs[i + 1], tol)
        limit = "interior"
    point = evaluate(best_x)
    best = min(score(point), scores[i])
    lo = hi = i
    while lo > 0 and scores[lo - 1] <= 1.1 * best:
        lo -= 1
    while hi < len(xs) - 1 and scores[hi + 1] <= 1.1 * best:
        hi += 1
    return Optimum(family=family, variable=variable, metric=metric, x=best_x, value=score(point), limit=limit,
                   near_optimal=(min(xs[lo], best_x), max(xs[hi], best_x)), point=point)


# ----------------------------------------------------------------------------------------------
# The computed comparison with the paper's claims


class PaperComparison(BaseModel):
    """The paper's claims (K in 1-1.5, α in 30-40°) against the rigorous model on the bench's scene.

    ``converge``: optima along the symmetric rig whose axes meet at the board centre (the paper's
    geometry), over K at Z = ``distance_mm``; ``parallel``: along the parallel rig over K;
    ``experiment2``: over α at the paper's Experiment II (B = 100 mm, Z = 500 mm).
    """

    distance_mm: float
    pixel_sigma_px: float
    paper_optimum_K: float
    paper_optimum_converging_alpha_deg: float
    paper_claimed_K: tuple[float, float]
    paper_claimed_alpha_deg: tuple[float, float]
    converging_alpha_for_claimed_K_deg: tuple[float, float]  # α that K = 1.5 .. 1 imply when the axes converge
    converging_K_for_claimed_alpha: tuple[float, float]  # K that α = 40 .. 30° imply when the axes converge
    converge: list[Optimum]
    converge_feasible_K: tuple[float, float] | None
    parallel: list[Optimum]
    parallel_feasible_K: tuple[float, float] | None
    experiment2_baseline_mm: float
    experiment2: list[Optimum]
    experiment2_feasible_alpha_deg: tuple[float, float] | None  # board fully in both views
    experiment2_measurable_alpha_deg: tuple[float, float] | None  # at least a measurable partial view
    experiment2_claimed_alpha_measurable: bool  # anything measurable at α = 30-40°
    experiment2_sigma_square_at_90_mm: float | None
    bench_baseline_range_mm: tuple[float, float]
    bench_optimum: SurfacePoint | None  # min σ_square over B in the bench range and symmetric α, board in view


CONVERGE_METRICS = ("gamma_xz_mm", "sigma_square_mm", "square_per_deg_alpha", "depth_per_deg_alpha",
                    "square_per_deg_alpha_both", "depth_per_deg_alpha_both")
PARALLEL_METRICS = ("gamma_xz_mm", "sigma_square_mm", "square_per_deg_alpha", "square_per_mm_baseline")
ALPHA_METRICS = ("sigma_square_mm", "gamma_xz_mm", "square_per_deg_alpha", "depth_per_deg_alpha")


def compare_with_paper(
    *, distance_mm: float = 500.0, pixel_sigma_px: float = 0.1, experiment2_baseline_mm: float = 100.0,
    bench_baseline_range_mm: tuple[float, float] = (20.0, 350.0), bench_steps: tuple[float, float] = (10.0, 1.0),
    executor: Executor | None = None, k_values: np.ndarray | None = None, alphas_deg: np.ndarray | None = None,
    board: Checkerboard | None = None, left: CameraModel | None = None, right: CameraModel | None = None,
    margin_px: float = DEFAULT_MARGIN_PX,
) -> PaperComparison:
    """Compute where the rigorous optima lie against the paper's claims, at one object distance.

    Grids go through ``executor``; refinement of each optimum runs in this process. The bench's
    baseline range (20-350 mm) is the paper's own experiment system (§4.1); ``bench_steps`` = (B step mm,
    α step deg) of the search over it (α from 40 to 90°).
    """
    scene = {"pixel_sigma_px": pixel_sigma_px, "board": board, "left": left, "right": right, "margin_px": margin_px}
    k_values = np.round(np.arange(0.1, 4.0001, 0.1), 6) if k_values is None else np.asarray(k_values, float)
    alphas_deg = np.arange(5.0, 90.001, 1.0) if alphas_deg is None else np.asarray(alphas_deg, float)
    z, b2 = float(distance_mm), float(experiment2_baseline_mm)

    def at(config):
        return evaluate_configs([config], **scene)[0]

    def converge_at(k):
        a = alpha_for("converge", k * z, z)
        return at((k * z, z, a, a))

    def parallel_at(k):
        return at((k * z, z, 90.0, 90.0))

    def alpha_at(a):
        return at((b2, z, a, a))

    converge_rows = surface_bz(k_values * z, [z], alpha="converge", executor=executor, **scene)
    parallel_rows = surface_bz(k_values * z, [z], alpha="parallel", executor=executor, **scene)
    exp2_rows = surface_alpha(alphas_deg, baseline_mm=b2, distance_mm=z, executor=executor, **scene)
    b_lo, b_hi = bench_baseline_range_mm
    bench_rows = evaluate_configs(
        [(b, z, a, a) for b in np.arange(b_lo, b_hi + 1e-9, bench_steps[0])
         for a in np.arange(40.0, 90.001, bench_steps[1])],
        with_sensitivities=False, executor=executor, **scene,
    )
    family_c, family_p = f"converging rig, Z = {z:g} mm", f"parallel rig, Z = {z:g} mm"
    family_a = f"symmetric rig, B = {b2:g} mm, Z = {z:g} mm"
    converge = [minimise_1d(converge_at, k_values, converge_rows, m, variable="K", family=family_c)
                for m in CONVERGE_METRICS]
    parallel = [minimise_1d(parallel_at, k_values, parallel_rows, m, variable="K", family=family_p)
                for m in PARALLEL_METRICS]
    exp2 = [minimise_1d(alpha_at, alphas_deg, exp2_rows, m, variable="alpha_deg", family=family_a, tol=1e-3)
            for m in ALPHA_METRICS]
    measurable = [r.alpha_deg for r in exp2_rows if r.measurable]
    at90 = [r for r in exp2_rows if r.alpha_deg == 90.0]
    return PaperComparison(
        distance_mm=z, pixel_sigma_px=pixel_sigma_px,
        paper_optimum_K=paper.optimum_k(),
        paper_optimum_converging_alpha_deg=float(paper.converging_alpha_deg(paper.OPTIMUM_K)),
        paper_claimed_K=(1.0, 1.5), paper_claimed_alpha_deg=(30.0, 40.0),
        converging_alpha_for_claimed_K_deg=(float(paper.converging_alpha_deg(1.5)),
                                            float(paper.converging_alpha_deg(1.0))),
        converging_K_for_claimed_alpha=(float(paper.k_from_converging_alpha(40.0)),
                                        float(paper.k_from_converging_alpha(30.0))),
        converge=[o for o in converge if o is not None], converge_feasible_K=feasible_range(converge_rows, "K"),
        parallel=[o for o in parallel if o is not None], parallel_feasible_K=feasible_range(parallel_rows, "K"),
        experiment2_baseline_mm=b2, experiment2=[o for o in exp2 if o is not None],
        experiment2_feasible_alpha_deg=feasible_range(exp2_rows, "alpha_deg"),
        experiment2_measurable_alpha_deg=(min(measurable), max(measurable)) if measurable else None,
        experiment2_claimed_alpha_measurable=any(r.measurable for r in exp2_rows if 30.0 <= r.alpha_deg <= 40.0),
        experiment2_sigma_square_at_90_mm=at90[0].sigma_square_mm if at90 else None,
        bench_baseline_range_mm=(b_lo, b_hi), bench_optimum=optimum(bench_rows),
    )
