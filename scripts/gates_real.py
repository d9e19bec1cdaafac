"""The calibration quality gates on the real sets and on faults built from their images (issue 22 item 3).

For each real set: every gate's measured value against its threshold (the margin = threshold / value for the
gates that fail above, value / threshold for left_right) on the set as it is, which must pass, and on faults
made from the same images: left i paired with right i+1 in 3 pairs and in every pair, left and right swapped,
Gaussian blur (sigma 4 px), a horizontal motion kernel (21 px), the wrong board size, and a board bent into a
cylinder (3 % of its width: the corners moved in each image as drivers/sim/render.BoardShape bends them).
Prints the tables and writes scripts/results/gates_real.json.

Usage: python scripts/gates_real.py [--data /work/shared/data] [--sets opencv_sample,present_cjn,...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from drivers.sim.render import BoardShape  # noqa: E402
from stereo_bench.targets import Checkerboard  # noqa: E402
from stereo_bench.vision.detect import Detection, detect  # noqa: E402
from stereo_bench.vision.gates import CalibrationRefused, mono_pose  # noqa: E402
from stereo_bench.vision.pipeline import calibrate_from_images  # noqa: E402

SETS = {
    "opencv_sample": ("left*.jpg", "right*.jpg", Checkerboard(9, 6, 30.0)),
    "present_cjn": ("leftPic*.jpg", "rightPic*.jpg", Checkerboard(8, 11, 12.0)),
    "smiler488_box": ("L_*.png", "R_*.png", Checkerboard(8, 5, 15.0)),
}
WRONG_BOARD = {"opencv_sample": Checkerboard(8, 5, 30.0), "present_cjn": Checkerboard(7, 10, 12.0),
               "smiler488_box": Checkerboard(9, 6, 15.0)}
MOTION_PX = 21
BLUR_SIGMA_PX = 4.0
BEND_OF_WIDTH = 0.03


def load(data: Path, name: str) -> tuple[list[np.ndarray], list[np.ndarray], Checkerboard]:
    left_glob, right_glob, board = SETS[name]
    left = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((data / name).glob(left_glob))]
    right = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((data / name).glob(right_glob))]
    return left, right, board


def motion_blur(image: np.ndarray, length: int = MOTION_PX) -> np.ndarray:
    kernel = np.zeros((length, length), np.float32)
    kernel[length // 2, :] = 1.0 / length
    return cv2.filter2D(image, -1, kernel)


def bent_detections(left, right, board: Checkerboard, bow_mm: float) -> list[tuple[Detection | None, Detection | None]]:
    """The real detections with each corner moved where a board bent by ``bow_mm`` would put it (pose from a
    calibration of the flat detections): the residual pattern of a bent print, on real corner noise."""
    flat = calibrate_from_images(left, right, board, gates=False).calib
    shape = BoardShape(bow_mm=bow_mm)
    bent = shape.object_points(board)
    out = []
    for left_image, right_image in zip(left, right, strict=True):
        pair = []
        for image, K, D in ((left_image, flat.K1, flat.D1), (right_image, flat.K2, flat.D2)):
            d = detect(image, board, thorough=True, noise=False)
            if d is None:
                pair.append(None)
                continue
            obj = board.object_points[d.ids].astype(np.float64)
            rvec, tvec, _ = mono_pose(obj, d.corners_px, K, D)
            moved = (cv2.projectPoints(bent[d.ids].reshape(-1, 1, 3), rvec, tvec, K, D)[0].reshape(-1, 2)
                     - cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, D)[0].reshape(-1, 2))
            pair.append(dataclasses.replace(d, corners_px=d.corners_px + moved))
        out.append(tuple(pair))
    return out


def faults(left, right, board, name):
    n = len(left)
    shifted3 = list(right)
    for i in (1, n // 2, n - 2):
        shifted3[i] = right[i + 1]
    yield "as_is", left, right, board, None
    yield "right_i+1_in_3_pairs", left, shifted3, board, None
    yield "right_i+1_in_every_pair", left[:-1], right[1:], board, None
    yield "left_right_swapped", right, left, board, None
    yield f"gaussian_blur_{BLUR_SIGMA_PX:g}px", [cv2.GaussianBlur(x, (0, 0), BLUR_SIGMA_PX) for x in left], \
        [cv2.GaussianBlur(x, (0, 0), BLUR_SIGMA_PX) for x in right], board, None
    yield f"motion_blur_{MOTION_PX}px", [motion_blur(x) for x in left], [motion_blur(x) for x in right], board, None
    yield f"board_given_as_{WRONG_BOARD[name].cols}x{WRONG_BOARD[name].rows}", left, right, WRONG_BOARD[name], None
    bow = BEND_OF_WIDTH * board.grid_size_mm[0]
    yield f"board_bent_{bow:.1f}mm", left, right, board, bent_detections(left, right, board, bow)


def run_case(left, right, board, detections) -> dict:
    try:
        result = calibrate_from_images(left, right, board, accept_poor=True, detections=detections)
        report = result.gates
        refused_line = report.refusal_line() if report.failed else None
        return {"gates": report.as_dict()["gates"], "failed": [r.name for r in report.failed], "line": refused_line,
                "rms_px": result.calib.rms_px, "epipolar_rms_px": result.epipolar_rms_px}
    except CalibrationRefused as error:
        return {"gates": error.report.as_dict()["gates"], "failed": [r.name for r in error.report.failed],
                "line": error.report.refusal_line()}
    except ValueError as error:
        return {"gates": {}, "failed": ["(no calibration)"], "line": str(error)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("/work/shared/data"))
    parser.add_argument("--sets", default=",".join(SETS))
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "gates_real.json")
    args = parser.parse_args()
    results = {}
    for name in args.sets.split(","):
        left, right, board = load(args.data, name)
        results[name] = {}
        for case, case_left, case_right, case_board, detections in faults(left, right, board, name):
            row = run_case(case_left, case_right, case_board, detections)
            results[name][case] = row
            print(f"{name} / {case}: failed {row['failed'] or 'none'}")
            if case == "as_is":
                for gate in row["gates"].values():
                    value, threshold = gate["value"], gate["threshold"]
                    above = gate["name"] == "left_right"  # these fail below their threshold
                    if above:
                        margin = value / threshold if threshold else float("inf")
                    else:
                        margin = threshold / value if value and value > 0 else float("inf")
                    print(f"   {gate['name']:17s} {gate['verdict']:4s} {value:9.4g} vs {threshold:<7.4g} "
                          f"{gate['unit']:12s} margin x{margin:.1f}")
            elif row["line"]:
                print(f"   {row['line']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
