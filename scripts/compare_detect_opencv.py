"""Does stereo-bench's detector find every board plain OpenCV finds?  (issue 22 item 3)

For every image of the real sets (and of the 1280x720 hand-held-print kind, built from them: see
``webcam_views``), runs :func:`stereo_bench.vision.detect.detect` (``thorough=True``, as ``calibrate`` does)
beside plain OpenCV: ``findChessboardCorners`` with its default flags + ``cornerSubPix`` (11x11), and
``findChessboardCornersSB``. Prints a table (found by each, missed by stereo-bench but found by OpenCV,
corner agreement on the boards both find: RMS over images of each image's RMS nearest-corner distance, against
OpenCV's 11x11 cornerSubPix, against the same detection refined with stereo-bench's window, and against SB)
and writes scripts/results/compare_detect_opencv.json.

Usage: python scripts/compare_detect_opencv.py [--data /work/shared/data] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from stereo_bench.targets import Checkerboard  # noqa: E402
from stereo_bench.vision.detect import detect, grid_spacing_px, subpix_half_window  # noqa: E402

SETS = {
    "opencv_sample": ("left*.jpg", "right*.jpg", Checkerboard(9, 6, 30.0)),
    "present_cjn": ("leftPic*.jpg", "rightPic*.jpg", Checkerboard(8, 11, 12.0)),
    "smiler488_box": ("L_*.png", "R_*.png", Checkerboard(8, 5, 15.0)),
}
SUBPIX = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def opencv_classic(gray: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    found, corners = cv2.findChessboardCorners(gray, board.pattern_size)
    if not found:
        return None
    return cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (11, 11), (-1, -1), SUBPIX).reshape(-1, 2)


def opencv_same_window(gray: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """findChessboardCorners + cornerSubPix with stereo-bench's window (half a square's 0.4) instead of 11x11."""
    found, corners = cv2.findChessboardCorners(gray, board.pattern_size)
    if not found:
        return None
    half = subpix_half_window(grid_spacing_px(corners.reshape(board.rows, board.cols, 2)))
    return cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (half, half), (-1, -1), SUBPIX).reshape(-1, 2)


def opencv_sb(gray: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    found, corners = cv2.findChessboardCornersSB(gray, board.pattern_size)
    return corners.reshape(-1, 2) if found else None


def agreement_px(ours: np.ndarray, theirs: np.ndarray) -> float:
    """Per-corner distance (px) after matching each OpenCV corner to our nearest one (order-free)."""
    d = np.linalg.norm(theirs[:, None, :] - ours[None, :, :], axis=2)
    return float(np.sqrt(np.mean(d.min(axis=1) ** 2)))


def webcam_views(gray: np.ndarray) -> np.ndarray:
    """A 1280x720 frame holding ``gray`` as a hand-held print seen smaller, off-centre, on a grey room, with
    MJPEG-like JPEG recompression: the search image then sees squares half as large as in the original."""
    height, width = gray.shape
    frame = np.full((720, 1280), 118, np.uint8)
    rng = np.random.default_rng(height * 7 + width)
    frame = np.clip(frame + rng.normal(0, 12, frame.shape), 0, 255).astype(np.uint8)
    frame = cv2.GaussianBlur(frame, (0, 0), 4)
    scale = 0.9 * min(720 / height, 1280 / width)
    small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    y0, x0 = (720 - small.shape[0]) // 2, (1280 - small.shape[1]) // 3
    frame[y0:y0 + small.shape[0], x0:x0 + small.shape[1]] = small
    ok, jpeg = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 80])
    return cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE)


def run(data: Path, kinds: list[str]) -> dict:
    rows = {}
    for name, (left_glob, right_glob, board) in SETS.items():
        folder = data / name
        paths = sorted(folder.glob(left_glob)) + sorted(folder.glob(right_glob))
        if not paths:
            continue
        for kind in kinds:
            counts = {"images": 0, "stereo_bench": 0, "opencv_classic": 0, "opencv_sb": 0, "opencv_any": 0}
            missed, agree, agree_sb, agree_window, seconds = [], [], [], [], 0.0
            for path in paths:
                gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
                if kind == "webcam_1280x720":
                    gray = webcam_views(gray)
                counts["images"] += 1
                start = time.perf_counter()
                ours = detect(gray, board, thorough=True, noise=False)
                seconds += time.perf_counter() - start
                classic, sb = opencv_classic(gray, board), opencv_sb(gray, board)
                counts["stereo_bench"] += ours is not None
                counts["opencv_classic"] += classic is not None
                counts["opencv_sb"] += sb is not None
                counts["opencv_any"] += classic is not None or sb is not None
                if ours is None and (classic is not None or sb is not None):
                    missed.append(path.name)
                if ours is not None and classic is not None:
                    agree.append(agreement_px(ours.corners_px, classic))
                if ours is not None and classic is not None:
                    agree_window.append(agreement_px(ours.corners_px, opencv_same_window(gray, board)))
                if ours is not None and sb is not None:
                    agree_sb.append(agreement_px(ours.corners_px, sb))
            rows[f"{name}/{kind}"] = {
                **counts, "missed_where_opencv_finds": missed,
                "agreement_classic_rms_px": float(np.sqrt(np.mean(np.square(agree)))) if agree else None,
                "agreement_classic_max_px": float(np.max(agree)) if agree else None,
                "agreement_same_window_rms_px": float(np.sqrt(np.mean(np.square(agree_window)))) if agree_window
                else None,
                "agreement_same_window_max_px": float(np.max(agree_window)) if agree_window else None,
                "agreement_sb_rms_px": float(np.sqrt(np.mean(np.square(agree_sb)))) if agree_sb else None,
                "stereo_bench_ms_per_image": 1000 * seconds / max(1, counts["images"]),
            }
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("/work/shared/data"))
    parser.add_argument("--quick", action="store_true", help="the real images only, not the 1280x720 kind")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "compare_detect_opencv.json")
    args = parser.parse_args()
    kinds = ["as_is"] + ([] if args.quick else ["webcam_1280x720"])
    rows = run(args.data, kinds)
    print(f"{'set/kind':34s} {'imgs':>4s} {'ours':>4s} {'cv':>4s} {'SB':>4s} {'any':>4s} {'missed':>6s} "
          f"{'agree cv':>9s} {'max':>6s} {'same win':>9s} {'max':>6s} {'agree SB':>9s} {'ms':>6s}")
    for key, r in rows.items():
        fmt = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
        print(f"{key:34s} {r['images']:4d} {r['stereo_bench']:4d} {r['opencv_classic']:4d} {r['opencv_sb']:4d} "
              f"{r['opencv_any']:4d} {len(r['missed_where_opencv_finds']):6d} {fmt(r['agreement_classic_rms_px']):>9s} "
              f"{fmt(r['agreement_classic_max_px']):>6s} {fmt(r['agreement_same_window_rms_px']):>9s} "
              f"{fmt(r['agreement_same_window_max_px']):>6s} {fmt(r['agreement_sb_rms_px']):>9s} "
              f"{r['stereo_bench_ms_per_image']:6.1f}")
        if r["missed_where_opencv_finds"]:
            print("   missed:", " ".join(r["missed_where_opencv_finds"]))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"opencv": cv2.__version__, "sets": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
