"""Calibrate and check the corner-noise model against the renderer's repeated noise.

For each configuration, renders the same pose with N noise seeds, measures the real scatter of
each detected corner (random part only), and compares it with the first-order structure-tensor
bound of stereo_bench.vision.detect.corner_noise_px without its empirical factor. The ratio is
the factor CORNER_NOISE_FACTOR must hold; the table shows how constant it is.

    python scripts/bench_corner_noise.py [--seeds 12] [--out bench_corner_noise.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from drivers.sim.render import Optics, StereoRenderer
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig, invert_transform
from stereo_bench.targets import Checkerboard
from stereo_bench.vision import detect as detect_module

CASES = [  # (alpha_deg, distance_mm, noise_dn, blur_px)
    (90, 500, 2.0, 0.7), (70, 500, 2.0, 0.7), (90, 300, 2.0, 0.7), (90, 700, 2.0, 0.7),
    (90, 500, 5.0, 0.7), (90, 500, 1.0, 0.7), (90, 500, 2.0, 1.2), (90, 500, 2.0, 0.5),
]

RESULTS = Path(__file__).resolve().parent / "results"  # where the latest run of each benchmark is kept


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--out", default=str(RESULTS / "bench_corner_noise.json"))
    args = parser.parse_args()
    board, camera = Checkerboard(9, 6, 27.0), CameraModel.from_sensor()
    factor = detect_module.CORNER_NOISE_FACTOR
    rows = []
    print(f"{'alpha':>5} {'Z mm':>6} {'noise':>5} {'blur':>5} {'scatter px':>10} {'bound px':>9} {'ratio':>6}")
    for alpha, distance, noise, blur in CASES:
        renderer = StereoRenderer(board, camera, camera, optics=Optics(noise_sigma_dn=noise, blur_sigma_px=blur))
        rig = RigPose.symmetric(100.0, alpha)
        T_cam_board = invert_transform(rig.T_rig_left) @ board_pose_facing_rig(
            distance_mm=distance, board_size_mm=board.grid_size_mm)
        corners, predicted = [], []
        for seed in range(args.seeds):
            view = renderer.render_view("left", T_cam_board, np.random.default_rng(seed))
            found = detect_module.detect(view.image, board)
            corners.append(found.corners_px)
            predicted.append(np.sqrt(np.mean(found.sigma_px**2)) / factor)
        scatter = float(np.sqrt(np.var(np.array(corners), axis=0, ddof=1).mean()))
        bound = float(np.mean(predicted))
        rows.append({"alpha_deg": alpha, "distance_mm": distance, "noise_dn": noise, "blur_px": blur,
                     "scatter_px": scatter, "bound_px": bound, "ratio": scatter / bound})
        print(f"{alpha:5.0f} {distance:6.0f} {noise:5.1f} {blur:5.1f} {scatter:10.4f} {bound:9.4f} "
              f"{scatter / bound:6.2f}")
    ratios = np.array([r["ratio"] for r in rows])
    print(f"ratio: median {np.median(ratios):.2f}, range {ratios.min():.2f}-{ratios.max():.2f} "
          f"(CORNER_NOISE_FACTOR = {factor})")
    with open(args.out, "w") as handle:
        json.dump({"cases": rows, "median_ratio": float(np.median(ratios)), "factor_in_code": factor}, handle, indent=1)


if __name__ == "__main__":
    main()
