"""What the lab profile adds per frame: JPEG, the bent target's dense remap, the lens, the ringing smear.

Times ``StereoRenderer.render_view`` at 1920x1080 (median of ``--runs`` after one warm-up) for the
views a campaign renders - the 27 mm target facing the rig at 300 and 700 mm (bent and scaled on
the lab bench) and a tilted calibration board (flat on both) - on the ideal optics and lens and on
the lab ones (JPEG at quality 85, the lab lens), plus each lab addition alone. Prints a table and
writes JSON (with the load average: other work on the machine inflates every figure).

    .venv/bin/python scripts/bench_lab_profile.py [--runs 15] [--out scripts/results/bench_lab_profile.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sim.bench import board_shape, true_lens  # noqa: E402
from drivers.sim.profile import LAB  # noqa: E402
from drivers.sim.render import Optics, StereoRenderer  # noqa: E402
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig, invert_transform  # noqa: E402
from stereo_bench.targets import Checkerboard  # noqa: E402

TARGET = Checkerboard(9, 6, 27.0)
CALIBRATION = Checkerboard(11, 8, 25.0)
# (case, board, distance mm, yaw deg, pitch deg, is the measured target)
CASES = [
    ("target 300 mm", TARGET, 300.0, 0.0, 0.0, True),
    ("target 700 mm", TARGET, 700.0, 0.0, 0.0, True),
    ("calibration board 450 mm, tilted", CALIBRATION, 450.0, 25.0, -15.0, False),
]


def _time(fn, runs: int) -> float:
    fn()
    samples = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples) * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    parser.add_argument("--out", type=Path, default=Path("scripts/results/bench_lab_profile.json"))
    args = parser.parse_args()

    nominal = CameraModel.from_sensor(name="left")
    lab_lens = true_lens(nominal, *LAB.cameras.lens_terms("left"))
    shape = board_shape(LAB.target)
    variants = {
        "ideal": (nominal, Optics(), False),
        "lab: JPEG only": (nominal, Optics(jpeg_quality=LAB.cameras.jpeg_quality), False),
        "lab: bent, scaled target only": (nominal, Optics(), True),
        "lab: lens only": (lab_lens, Optics(), False),
        "lab (all of it)": (lab_lens, Optics(jpeg_quality=LAB.cameras.jpeg_quality), True),
    }
    pose = RigPose.symmetric(100.0, 90.0)
    load_before = os.getloadavg()
    rows = []
    for case, board, distance, yaw, pitch, measured in CASES:
        T = invert_transform(pose.T_rig_left) @ board_pose_facing_rig(
            distance_mm=distance, board_size_mm=board.grid_size_mm, yaw_deg=yaw, pitch_deg=pitch)
        row = {"case": case}
        for name, (camera, optics, bent) in variants.items():
            renderer = StereoRenderer(board, camera, camera, optics=optics)
            rng = np.random.default_rng(0)
            view_shape = shape if (bent and measured) else None
            row[name] = round(_time(lambda r=renderer, s=view_shape, T=T, g=rng: r.render_view("left", T, g, shape=s),
                                    args.runs), 1)
        rows.append(row)
    smear = StereoRenderer(TARGET, nominal, nominal)
    T = invert_transform(pose.T_rig_left) @ board_pose_facing_rig(distance_mm=500.0,
                                                                  board_size_mm=TARGET.grid_size_mm)
    smear_ms = _time(lambda: smear.render_view("left", T, np.random.default_rng(0), smear_px=(3.0, 0.0)), args.runs)
    plain_ms = _time(lambda: smear.render_view("left", T, np.random.default_rng(0)), args.runs)
    load_after = os.getloadavg()

    names = list(variants)
    print(f"render_view at 1920x1080, median of {args.runs} (ms); load average {load_before[0]:.2f} -> "
          f"{load_after[0]:.2f} on {os.cpu_count()} cores")
    print(f"{'case':34s}" + "".join(f"{n:>32s}" for n in names))
    for row in rows:
        print(f"{row['case']:34s}" + "".join(f"{row[n]:32.1f}" for n in names))
    print(f"ringing smear (3 px), only on frames taken within 0.24 s of a move: {smear_ms - plain_ms:+.1f} ms")
    result = {
        "benchmark": "bench_lab_profile", "runs": args.runs, "rows": rows,
        "smear_extra_ms": round(smear_ms - plain_ms, 1),
        "load_average": {"before": load_before, "after": load_after}, "cpu_count": os.cpu_count(),
        "python": platform.python_version(), "opencv": cv2.__version__, "numpy": np.__version__,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
