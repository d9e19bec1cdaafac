"""Regenerate calib_data/real/opencv_stereo_calib_format/: files in the layout of OpenCV's stereo_calib sample.

Runs the calibration of OpenCV's samples/cpp/stereo_calib.cpp (same flags, squareSize = 1, so T is
in squares) on calib_data/real/opencv_sample and writes intrinsics.yml / extrinsics.yml the way
OpenCV 4.x's FileStorage writes them (``%YAML:1.0``, ``dt: d``), because OpenCV 5 writes
``%YAML 1.2`` and the point of the fixture is to prove that files from the 4.x sample load.

    python scripts/make_opencv_format_fixture.py
"""

from __future__ import annotations

import glob
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "calib_data" / "real" / "opencv_sample"
OUT = ROOT / "calib_data" / "real" / "opencv_stereo_calib_format"


def opencv4_matrix(name: str, matrix: np.ndarray) -> str:
    matrix = np.atleast_2d(np.asarray(matrix, np.float64))
    values = [("0." if v == 0 else "1." if v == 1 else f"{v:.16e}") for v in matrix.ravel()]
    lines, line = [], "   data: [ "
    for i, text in enumerate(values):
        piece = text + (", " if i < len(values) - 1 else " ]")
        if len(line) + len(piece) > 78:
            lines.append(line.rstrip())
            line = "       "
        line += piece
    lines.append(line)
    return f"{name}: !!opencv-matrix\n   rows: {matrix.shape[0]}\n   cols: {matrix.shape[1]}\n   dt: d\n" + \
        "\n".join(lines) + "\n"


def main() -> None:
    pattern = (9, 6)
    objects, lefts, rights = [], [], []
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    size = None
    for left_path in sorted(glob.glob(str(IMAGES / "left*.jpg"))):
        pair = []
        for path in (left_path, left_path.replace("left", "right")):
            image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            size = image.shape[::-1]
            found, corners = cv2.findChessboardCorners(image, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH |
                                                       cv2.CALIB_CB_NORMALIZE_IMAGE)
            if not found:
                break
            criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
            pair.append(cv2.cornerSubPix(image, corners.reshape(-1, 1, 2), (11, 11), (-1, -1), criteria))
        if len(pair) == 2:
            objects.append(obj)
            lefts.append(pair[0])
            rights.append(pair[1])
    K1 = cv2.initCameraMatrix2D(objects, lefts, size, 0)
    K2 = cv2.initCameraMatrix2D(objects, rights, size, 0)
    D1, D2 = np.zeros((1, 8)), np.zeros((1, 8))
    flags = (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_USE_INTRINSIC_GUESS |
             cv2.CALIB_SAME_FOCAL_LENGTH | cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_K4 |
             cv2.CALIB_FIX_K5)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-5)
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(objects, lefts, rights, K1, D1, K2, D2, size,
                                                          flags=flags, criteria=criteria)
    # OpenCV 5 returns 14 coefficients; with the rational model the last six are zero and the 4.x sample wrote 8.
    D1, D2 = np.asarray(D1).reshape(1, -1)[:, :8], np.asarray(D2).reshape(1, -1)[:, :8]
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(K1, D1, K2, D2, size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=1)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "intrinsics.yml").write_text("%YAML:1.0\n---\n" + "".join(
        opencv4_matrix(n, m) for n, m in (("M1", K1), ("D1", D1), ("M2", K2), ("D2", D2))))
    (OUT / "extrinsics.yml").write_text("%YAML:1.0\n---\n" + "".join(
        opencv4_matrix(n, m) for n, m in (("R", R), ("T", T), ("R1", R1), ("R2", R2), ("P1", P1), ("P2", P2),
                                          ("Q", Q))))
    print(f"{len(objects)} pairs, RMS {rms:.4f} px, |T| = {np.linalg.norm(T):.4f} squares; wrote {OUT}")


if __name__ == "__main__":
    main()
