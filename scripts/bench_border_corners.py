"""Border corners: does the full cornerSubPix window pull a grid's border corner off its junction?

For every board the classic detector finds in the real checkerboard sets, as stored and resized to 0.75x and 0.5x
(INTER_AREA, as a lower-resolution camera would see them), prints per set and scale:

- how far each border corner moves when refined again with half the window from where the full window left it
  (median, 99th percentile, max, and how many move more than ``detect.BORDER_AGREEMENT_PX``), inner corners beside
  them for comparison;
- scale consistency of ``detect`` with and without the border check: each resized image's corners against the
  full-resolution detection mapped down (max and 99th percentile over corners), the ground truth a lower-resolution
  view of the same scene has;

and writes scripts/results/bench_border_corners.json.

Usage: python scripts/bench_border_corners.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
from real_data import SETS  # noqa: E402

from stereo_bench.vision import detect as detect_module  # noqa: E402

SCALES = (1.0, 0.75, 0.5)


def _images(real_set) -> list[np.ndarray]:
    paths = sorted(real_set.folder.glob(real_set.left_glob)) + sorted(real_set.folder.glob(real_set.right_glob))
    return [cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) for path in paths]


def _resized(gray: np.ndarray, scale: float) -> np.ndarray:
    return gray if scale == 1.0 else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def _moves(gray: np.ndarray, board) -> tuple[np.ndarray, np.ndarray] | None:
    """(border, inner) corners' moves (px) when refined with half the window from the full window's result."""
    found, corners = cv2.findChessboardCorners(gray, board.pattern_size, flags=detect_module._SEARCH_FLAGS)
    if not found:
        return None
    grid = corners.reshape(board.rows, board.cols, 2).astype(np.float64)
    half = detect_module.subpix_half_window(detect_module.grid_spacing_px(grid))
    full = detect_module._subpix(gray, grid.reshape(-1, 2), half)
    again = detect_module._subpix(gray, full, max(2, half // 2))
    moved = np.linalg.norm(again - full, axis=1).reshape(board.rows, board.cols)
    border = np.zeros(moved.shape, bool)
    border[[0, -1], :] = True
    border[:, [0, -1]] = True
    return moved[border], moved[~border]


def _stats(values: list[float]) -> dict:
    v = np.asarray(values)
    return {"n": int(v.size), "median_px": float(np.median(v)), "p99_px": float(np.percentile(v, 99)),
            "max_px": float(v.max()), "over_agreement": int((v > detect_module.BORDER_AGREEMENT_PX).sum())}


def _detect(gray: np.ndarray, board, *, border_check: bool):
    saved = detect_module.BORDER_AGREEMENT_PX
    detect_module.BORDER_AGREEMENT_PX = saved if border_check else np.inf
    try:
        return detect_module.detect(gray, board, thorough=True, noise=False)
    finally:
        detect_module.BORDER_AGREEMENT_PX = saved


def run() -> dict:
    rows = {}
    for name, real_set in SETS.items():
        images = _images(real_set)
        full_res = {check: [_detect(gray, real_set.board, border_check=check) for gray in images]
                    for check in (False, True)}
        for scale in SCALES:
            border, inner = [], []
            deviation = {False: [], True: []}
            for index, gray in enumerate(images):
                small = _resized(gray, scale)
                moves = _moves(small, real_set.board)
                if moves is not None:
                    border += list(moves[0])
                    inner += list(moves[1])
                if scale == 1.0:
                    continue
                for check in (False, True):
                    reference, found = full_res[check][index], _detect(small, real_set.board, border_check=check)
                    if reference is None or found is None:
                        continue
                    mapped = (reference.corners_px + 0.5) * scale - 0.5
                    deviation[check] += list(np.linalg.norm(found.corners_px - mapped, axis=1))
            row = {"border": _stats(border), "inner": _stats(inner)}
            for check, key in ((False, "scale_deviation_without_check"), (True, "scale_deviation_with_check")):
                if deviation[check]:
                    row[key] = {"max_px": float(np.max(deviation[check])),
                                "p99_px": float(np.percentile(deviation[check], 99)),
                                "over_0.5_px": int((np.asarray(deviation[check]) > 0.5).sum()),
                                "n": len(deviation[check])}
            rows[f"{name}@{scale}"] = row
    return rows


def main() -> None:
    rows = run()
    print(f"{'set@scale':20s} {'border: med':>11s} {'p99':>6s} {'max':>6s} {'>tol':>5s} {'inner: p99':>10s} {'max':>6s}"
          f" | {'scale dev. before: max':>22s} {'>0.5':>5s} {'after: max':>10s} {'>0.5':>5s}")
    for key, row in rows.items():
        b, i = row["border"], row["inner"]
        before, after = row.get("scale_deviation_without_check"), row.get("scale_deviation_with_check")
        tail = (f" | {before['max_px']:22.2f} {before['over_0.5_px']:5d} {after['max_px']:10.2f} "
                f"{after['over_0.5_px']:5d}") if before and after else " |"
        print(f"{key:20s} {b['median_px']:11.3f} {b['p99_px']:6.2f} {b['max_px']:6.2f} {b['over_agreement']:5d} "
              f"{i['p99_px']:10.2f} {i['max_px']:6.2f}{tail}")
    out = ROOT / "scripts" / "results" / "bench_border_corners.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"opencv": cv2.__version__, "agreement_px": detect_module.BORDER_AGREEMENT_PX,
                               "sets": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
