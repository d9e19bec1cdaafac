"""What the calibration's held-out check costs: model_adequacy and the view deltas beside the calibration itself.

Per real set (calib_data/real): the median over repeats of calibrate_stereo without covariance, with the
covariance (its view deltas included) and model_adequacy alone. Prints a table; writes
scripts/results/bench_adequacy.json.

    python scripts/bench_adequacy.py [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from stereo_bench.vision.calibrate import calibrate_stereo  # noqa: E402
from stereo_bench.vision.detect import common_corners  # noqa: E402
from stereo_bench.vision.uncertainty import model_adequacy  # noqa: E402
from tests.real_data import SETS, detections, images  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def _median_time(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    rows = {}
    print(f"{'set':>14} {'views':>5} {'no cov s':>9} {'cov s':>7} {'adequacy s':>10} {'adequacy / calib':>16}")
    for name, real in SETS.items():
        views = [common_corners(*d) for d in detections(name) if d[0] is not None and d[1] is not None]
        inputs = ([real.board.object_points[v[0]] for v in views], [v[1] for v in views], [v[2] for v in views],
                  images(name)[0][0].shape[::-1])
        calib = calibrate_stereo(*inputs)
        used = calib.views_used
        bare = _median_time(lambda inputs=inputs: calibrate_stereo(*inputs, covariance=False), args.repeats)
        full = _median_time(lambda inputs=inputs: calibrate_stereo(*inputs), args.repeats)
        adequacy = _median_time(lambda calib=calib, inputs=inputs, used=used: model_adequacy(
            calib, *([part[i] for i in used] for part in inputs[:3])), args.repeats)
        rows[name] = {"views": len(used), "calibrate_no_covariance_s": bare, "calibrate_s": full,
                      "adequacy_s": adequacy}
        print(f"{name:>14} {len(used):5d} {bare:9.3f} {full:7.3f} {adequacy:10.3f} {adequacy / bare:16.2f}")
    print(f"load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f} (2 cores)")
    out = RESULTS / "bench_adequacy.json"
    out.write_text(json.dumps({"benchmark": "bench_adequacy", "sets": rows, "repeats": args.repeats,
                               "load_average_before": load_before, "load_average_after": os.getloadavg()},
                              indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
