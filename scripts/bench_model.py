"""Monte Carlo throughput of the rigorous error model: in-process, local process pool, Dask LocalCluster.

One configuration (B = 100 mm, Z = 500 mm, alpha = 85 deg, the 9x6 board, 0.1 px noise); every
executor runs the same seeded samples (the script checks they are bit-identical) and is timed
warm (workers started and the code imported before the clock starts; median and best of --repeats
runs; the sweep: best of --repeats // 2).
Start-up times are reported separately. A design-space sweep (configurations per second) is timed
the same way. The load average is recorded: on a shared machine other jobs take the pool's share.

    python scripts/bench_model.py [--samples 100000] [--workers 2] [--out scripts/results/bench_model.json]

Measured on this machine (2 CPUs, load average ~1.3-2.3 from other jobs; 100 000 samples, 5 runs):
serial 15 700 samples/s; local pool of 2 processes 29 100 (1.85x; start-up 0.33 s); Dask
LocalCluster of 2 worker processes 21 700 median, 24 800 best (start-up 1.1 s); samples identical
on all three. (B, Z) sweep with sensitivities: 184 / 320 / 308 configurations/s. Most of a sample's
cost is cv2.triangulatePoints (65 %) and undistortPoints (20 %). On a loaded machine the pools
fall to the serial rate: compare runs only at similar load averages.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from stereo_bench.errormodel.montecarlo import BLOCK_SAMPLES, monte_carlo_samples
from stereo_bench.errormodel.rigorous import Setup
from stereo_bench.errormodel.surfaces import surface_bz
from stereo_bench.executors import DaskExecutor, LocalExecutor, SerialExecutor


def timed(fn, repeats: int) -> tuple[list[float], object]:
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return times, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=100_000)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sweep", type=int, default=20, help="sweep grid is N x N (B, Z) configurations")
    parser.add_argument("--out", default="scripts/results/bench_model.json")
    args = parser.parse_args()

    from dask.distributed import LocalCluster

    setup = Setup.make(100.0, 500.0, 85.0)
    n_tasks = 4 * args.workers
    baselines = np.linspace(50.0, 350.0, args.sweep)
    distances = np.linspace(300.0, 800.0, args.sweep)
    results: dict = {
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count(),
                    "numpy": np.__version__},
        "config": {"baseline_mm": 100.0, "distance_mm": 500.0, "alpha_deg": 85.0, "pixel_sigma_px": 0.1,
                   "samples": args.samples, "block_samples": BLOCK_SAMPLES, "tasks": n_tasks,
                   "workers": args.workers, "repeats": args.repeats, "sweep_configs": args.sweep**2},
        "executors": {},
        "load_average_before": [round(v, 2) for v in os.getloadavg()],
    }
    reference = None

    def mc(executor):
        return monte_carlo_samples(setup, 0.1, args.samples, seed=1, executor=executor, n_tasks=n_tasks)

    def sweep(executor):
        return surface_bz(baselines, distances, alpha="converge", with_sensitivities=True, executor=executor,
                          points_per_task=max(1, args.sweep**2 // n_tasks))

    def measure(name: str, executor, startup_s: float) -> None:
        nonlocal reference
        mc(executor)  # warm-up: imports in the workers, caches
        times, samples = timed(lambda: mc(executor), args.repeats)
        seconds, best = statistics.median(times), min(times)
        if reference is None:
            reference = samples
        identical = bool(np.array_equal(samples[0], reference[0]) and np.array_equal(samples[1], reference[1]))
        sweep_times, _ = timed(lambda: sweep(executor), max(1, args.repeats // 2))
        sweep_s = min(sweep_times)
        results["executors"][name] = {
            "startup_s": round(startup_s, 3), "mc_seconds": round(seconds, 4),
            "mc_samples_per_s": round(args.samples / seconds), "mc_samples_per_s_best": round(args.samples / best),
            "identical_to_serial": identical,
            "sweep_seconds": round(sweep_s, 3), "sweep_configs_per_s": round(args.sweep**2 / sweep_s, 1),
        }
        print(f"{name:28s} start {startup_s:6.2f} s  MC {args.samples / seconds:8.0f} samples/s median, "
              f"{args.samples / best:8.0f} best "
              f"(identical: {identical})  sweep {args.sweep**2 / sweep_s:7.1f} configs/s")

    measure("serial", SerialExecutor(), 0.0)

    start = time.perf_counter()
    with LocalExecutor(args.workers) as local:
        local.map(abs, range(args.workers))
        measure(f"local ({args.workers} processes)", local, time.perf_counter() - start)

    start = time.perf_counter()
    cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        with DaskExecutor(cluster) as dask:
            measure(f"dask LocalCluster ({args.workers} proc)", dask, time.perf_counter() - start)
    finally:
        cluster.close()

    results["load_average_after"] = [round(v, 2) for v in os.getloadavg()]
    print(f"load average before {results['load_average_before']}, after {results['load_average_after']} "
          f"({os.cpu_count()} CPUs; other jobs on a shared machine take from the pool's share)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
