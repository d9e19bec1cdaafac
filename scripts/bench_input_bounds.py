"""The cost of the inputs that scale the work, behind the bounds the CLI puts on them (docs/EXIT_STATUS.md).

Each row times one job in this process (wall time, load average before and after) at a few values of one
input, up to past its bound where that is affordable:

- render blur (``render --blur``, bound 50 px): one 1920x1080 stereo pair of the 9x6 board at 500 mm; also
  whether ``measure`` still finds the board in it.
- board size (``--board``, bound 10,000 inner corners): one rendered pair of an N x (N-1) checkerboard, and
  the peak memory the renderer's texture takes (``ru_maxrss`` growth, a lower bound when the process was
  already larger).
- Monte Carlo samples (``model predict --monte-carlo``, bound 1,000,000): serial, per sample.
- surface configurations (``model surface``, ``advise``: bound 100,000): serial, per configuration.
- planned calibration views (``--calibration-views``, bound 500): one prediction.

    python scripts/bench_input_bounds.py [--quick] [--out scripts/results/bench_input_bounds.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import time

import numpy as np


def _timed(fn):
    load = os.getloadavg()[0]
    started = time.perf_counter()
    value = fn()
    return time.perf_counter() - started, load, value


def render_pair(board_cols: int, board_rows: int, square_mm: float, blur_px: float):
    from drivers.sim.render import Optics, StereoRenderer
    from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
    from stereo_bench.targets import Checkerboard

    target = Checkerboard(board_cols, board_rows, square_mm)
    camera = CameraModel.from_sensor()
    renderer = StereoRenderer(target, camera, camera, optics=Optics(blur_sigma_px=blur_px))
    pose = board_pose_facing_rig(distance_mm=500.0, board_size_mm=target.grid_size_mm)
    return target, camera, renderer.render_pair(RigPose.symmetric(100.0, 90.0), pose, np.random.default_rng(0))


def blur_rows(values: list[float]) -> list[dict]:
    from stereo_bench.vision.detect import detect

    render_pair(9, 6, 27.0, 0.7)  # warm-up: imports, the renderer's first texture
    rows = []
    for blur in values:
        seconds, load, (target, _, pair) = _timed(lambda b=blur: render_pair(9, 6, 27.0, b))
        found = detect(pair.left.image, target, thorough=True) is not None
        rows.append({"input": "render --blur", "value": blur, "seconds": seconds, "load": load,
                     "board_detected": found})
    return rows


def board_rows(sizes: list[int]) -> list[dict]:
    from stereo_bench import targets

    targets.MAX_BOARD_CORNERS = 10**9  # lifted in this process only, to time boards past the bound
    rows = []
    for n in sizes:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        seconds, load, _ = _timed(lambda n=n: render_pair(n, n - 1, 200.0 / n, 0.7))
        grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
        rows.append({"input": "--board", "value": f"{n}x{n - 1}", "corners": n * (n - 1), "seconds": seconds,
                     "load": load, "peak_rss_growth_mb": grown_mb})
    return rows


def monte_carlo_rows(samples: list[int]) -> list[dict]:
    from stereo_bench.errormodel.montecarlo import monte_carlo
    from stereo_bench.errormodel.rigorous import Setup
    from stereo_bench.targets import Checkerboard

    setup = Setup.make(100.0, 500.0, 90.0, board=Checkerboard(9, 6, 27.0))
    rows = []
    for n in samples:
        seconds, load, _ = _timed(lambda n=n: monte_carlo(setup, 0.1, n, seed=0))
        rows.append({"input": "--monte-carlo", "value": n, "seconds": seconds, "load": load,
                     "us_per_sample": 1e6 * seconds / n})
    return rows


def surface_rows(sides: list[int]) -> list[dict]:
    from stereo_bench.errormodel.surfaces import surface_bz
    from stereo_bench.geometry import CameraModel
    from stereo_bench.targets import Checkerboard

    camera = CameraModel.from_sensor()
    rows = []
    for side in sides:
        baselines, distances = np.linspace(20, 400, side), np.linspace(300, 1100, side)
        seconds, load, _ = _timed(lambda b=baselines, d=distances: surface_bz(
            b, d, alpha="converge", pixel_sigma_px=0.1, with_sensitivities=True, board=Checkerboard(9, 6, 27.0),
            left=camera, right=camera, margin_px=10.0))
        rows.append({"input": "surface configurations", "value": side * side, "seconds": seconds, "load": load,
                     "ms_per_configuration": 1e3 * seconds / side**2})
    return rows


def calibration_view_rows(views: list[int]) -> list[dict]:
    from stereo_bench.errormodel.rigorous import CalibrationPlan, Setup, predict
    from stereo_bench.targets import Checkerboard

    setup = Setup.make(100.0, 500.0, 90.0, board=Checkerboard(9, 6, 27.0))
    rows = []
    for n in views:
        plan = CalibrationPlan(n_views=n, board=Checkerboard(11, 8, 25.0), mode="joint")
        seconds, load, _ = _timed(lambda p=plan: predict(setup, 0.1, calibration=p))
        rows.append({"input": "--calibration-views", "value": n, "seconds": seconds, "load": load,
                     "ms_per_view": 1e3 * seconds / n})
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer and smaller values (a smoke run)")
    parser.add_argument("--out", default="scripts/results/bench_input_bounds.json")
    args = parser.parse_args()
    quick = args.quick
    rows = (blur_rows([0.7, 50.0] if quick else [0.7, 10.0, 50.0, 200.0])
            + board_rows([30] if quick else [30, 100, 240])
            + monte_carlo_rows([2_000] if quick else [2_000, 100_000])
            + surface_rows([5] if quick else [10, 30])
            + calibration_view_rows([12] if quick else [12, 100, 500]))
    print(f"{'input':<24} {'value':>10} {'seconds':>8} {'load':>5}  per unit / notes")
    for row in rows:
        notes = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
                          if k not in ("input", "value", "seconds", "load"))
        print(f"{row['input']:<24} {row['value']!s:>10} {row['seconds']:8.2f} {row['load']:5.1f}  {notes}")
    result = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                          "load_after": os.getloadavg()}, "quick": quick, "rows": rows}
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=1)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
