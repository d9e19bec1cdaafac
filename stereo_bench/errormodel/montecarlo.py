"""Monte Carlo check of the first-order model: noisy true pixels through the real triangulation.

Each sample adds independent Gaussian noise (σ_px per image coordinate, both cameras) to the true
pixels of every corner seen in both views and of the board centre, triangulates them with the rig's
true calibration (:func:`stereo_bench.vision.triangulate.triangulate`, the pipeline's own) and
measures the square exactly as the pipeline does (mean of all adjacent pair lengths).

Reproducibility: the samples are cut into blocks of :data:`BLOCK_SAMPLES`; block i draws from
child i of ``SeedSequence(seed).spawn(n_blocks)``. Blocks are then grouped into tasks for the
executor, so the samples (and every statistic) are identical whatever executor runs them and however
the blocks are grouped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict

from stereo_bench.errormodel.rigorous import (
    DEFAULT_MARGIN_PX,
    Setup,
    calibration_of,
    project_both,
    square_means,
    visible_corners,
)
from stereo_bench.executors import Executor, SerialExecutor, group, spawn_seeds
from stereo_bench.geometry import transform_points
from stereo_bench.vision.triangulate import triangulate

#: Samples per seeded block: part of what defines the samples for a given seed, do not change lightly.
BLOCK_SAMPLES = 500


@dataclass(frozen=True, eq=False)
class MonteCarloTask:
    """One executor task: consecutive seeded blocks of samples for one setup (picklable)."""

    setup: Setup
    pixel_sigma_px: float
    ids: np.ndarray  # (n,) corners seen in both views
    seeds: tuple[np.random.SeedSequence, ...]
    block_sizes: tuple[int, ...]


def run_task(task: MonteCarloTask) -> tuple[np.ndarray, np.ndarray]:
    """(square means (S,) mm, board centres (S, 3) rig frame mm) for the task's S samples."""
    setup = task.setup
    calib = calibration_of(setup)
    points = np.vstack([setup.corners_rig[task.ids], setup.board_centre_rig[None, :]])  # corners, then centre
    left_px, right_px, _ = project_both(setup, points)
    true = np.hstack([left_px, right_px])  # (P, 4)
    T_rig_left = setup.rig.T_rig_left
    squares, centres = [], []
    for seed, n in zip(task.seeds, task.block_sizes, strict=True):
        rng = np.random.default_rng(seed)
        noisy = true[None] + rng.normal(0.0, task.pixel_sigma_px, size=(n, *true.shape))  # (n, P, 4)
        flat = noisy.reshape(-1, 4)
        xyz = triangulate(calib, flat[:, :2], flat[:, 2:]).reshape(n, len(points), 3)  # left camera frame
        squares.append(square_means(xyz[:, :-1], task.ids, setup.board))
        centres.append(transform_points(T_rig_left, xyz[:, -1]))
    return np.concatenate(squares), np.vstack(centres)


def monte_carlo_samples(
    setup: Setup, pixel_sigma_px: float, n_samples: int, *, seed: int = 0, executor: Executor | None = None,
    n_tasks: int | None = None, margin_px: float = DEFAULT_MARGIN_PX,
) -> tuple[np.ndarray, np.ndarray]:
    """(square means (n_samples,) mm — NaN when nothing is measurable —, centres (n_samples, 3) rig mm).

    ``n_tasks``: how many executor tasks the blocks are grouped into (default: one per block, at most
    64); the samples do not depend on it nor on the executor.
    """
    if n_samples < 2:
        raise ValueError(f"a Monte Carlo run needs at least 2 samples, not {n_samples}")
    if not pixel_sigma_px >= 0:
        raise ValueError(f"pixel_sigma_px must be >= 0, not {pixel_sigma_px}")
    ids, _ = visible_corners(setup, margin_px=margin_px)
    n_blocks = math.ceil(n_samples / BLOCK_SAMPLES)
    sizes = [BLOCK_SAMPLES] * (n_blocks - 1) + [n_samples - BLOCK_SAMPLES * (n_blocks - 1)]
    blocks = list(zip(spawn_seeds(seed, n_blocks), sizes, strict=True))
    tasks = [
        MonteCarloTask(setup=setup, pixel_sigma_px=float(pixel_sigma_px), ids=ids,
                       seeds=tuple(s for s, _ in chunk), block_sizes=tuple(n for _, n in chunk))
        for chunk in group(blocks, n_tasks or min(n_blocks, 64))
    ]
    results = (executor or SerialExecutor()).map(run_task, tasks)
    return np.concatenate([r[0] for r in results]), np.vstack([r[1] for r in results])


class MonteCarloResult(BaseModel):
    """Sample statistics (mm) of N simulated measurements; the σ fields mirror :class:`Prediction`'s."""

    model_config = ConfigDict(frozen=True)

    n_samples: int
    seed: int
    pixel_sigma_px: float
    mean_square_mm: float | None
    bias_square_mm: float | None  # mean - nominal square size
    sigma_square_mm: float | None
    sigma_x_mm: float
    sigma_y_mm: float
    sigma_z_mm: float
    gamma_xz_mm: float
    gamma_mm: float


def summarise(squares: np.ndarray, centres: np.ndarray, *, nominal_mm: float, seed: int,
              pixel_sigma_px: float) -> MonteCarloResult:
    """Sample means and standard deviations (ddof=1) of Monte Carlo samples."""
    measurable = bool(np.all(np.isfinite(squares)))
    sx, sy, sz = (float(v) for v in np.std(centres, axis=0, ddof=1))
    return MonteCarloResult(
        n_samples=int(len(squares)), seed=int(seed), pixel_sigma_px=float(pixel_sigma_px),
        mean_square_mm=float(np.mean(squares)) if measurable else None,
        bias_square_mm=float(np.mean(squares) - nominal_mm) if measurable else None,
        sigma_square_mm=float(np.std(squares, ddof=1)) if measurable else None,
        sigma_x_mm=sx, sigma_y_mm=sy, sigma_z_mm=sz, gamma_xz_mm=math.hypot(sx, sz),
        gamma_mm=math.sqrt(sx * sx + sy * sy + sz * sz),
    )


def monte_carlo(
    setup: Setup, pixel_sigma_px: float, n_samples: int, *, seed: int = 0, executor: Executor | None = None,
    n_tasks: int | None = None, margin_px: float = DEFAULT_MARGIN_PX,
) -> MonteCarloResult:
    """Monte Carlo estimate of the σs :func:`stereo_bench.errormodel.rigorous.predict` gives to first order."""
    squares, centres = monte_carlo_samples(setup, pixel_sigma_px, n_samples, seed=seed, executor=executor,
                                           n_tasks=n_tasks, margin_px=margin_px)
    return summarise(squares, centres, nominal_mm=setup.board.square_mm, seed=seed, pixel_sigma_px=pixel_sigma_px)
