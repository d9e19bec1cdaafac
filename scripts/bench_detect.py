"""CPU per frame of checkerboard detection and of its parts, on the frames of recorded sessions.

Each frame is detected as the replay detects it (``detect(frame, board)``, OpenCV on one thread as in
``single_threaded_opencv``), with the board the frame shows (the session's target or calibration board).
Times are ``time.thread_time`` (CPU, not wall: the machine is shared), inclusive, summed over all frames and
divided by their number, best of --repeat passes; each part is timed by wrapping the module's function in
place (the plain total is timed unwrapped). The load average is recorded with the figures.

--against FILE loads another version of stereo_bench/vision/detect.py (e.g. ``git show
main:stereo_bench/vision/detect.py > /tmp/old_detect.py``), checks that both give the same detections, bit for
bit, on every frame, and times the two alternately, pass by pass.

    python scripts/bench_detect.py [SESSION ...] [--every 3] [--repeat 5] [--against FILE]
        [--out scripts/results/bench_detect.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np

from stereo_bench.campaign.session import SessionReader
from stereo_bench.frames import decode_frame
from stereo_bench.targets import Checkerboard
from stereo_bench.vision import detect as current

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("_search_image", "_find_chessboard_fast_checked", "refine_grid", "_subpix", "_grid_outliers",
         "grid_spacing_px", "canonical_order", "_grid_detection", "corner_noise_px", "image_noise_dn")
OPENCV_CALLS = ("findChessboardCorners", "checkChessboard", "cornerSubPix", "getRectSubPix")


def session_boards(session: Path) -> list[Checkerboard]:
    """The checkerboards a session's frames show (target, calibration board), from its start document."""
    config = SessionReader(session).start().config
    boards = []
    for key in ("target", "calibration_board"):
        spec = config[key]
        if spec["kind"] == "checkerboard":
            boards.append(Checkerboard(spec["cols"], spec["rows"], spec["square_mm"]))
    return boards


def load_jobs(sessions: list[Path], every: int) -> list[tuple[np.ndarray, Checkerboard]]:
    """(frame, board it shows) for every ``every``-th frame of each session; the first board if none is found."""
    jobs = []
    for session in sessions:
        boards = session_boards(session)
        for path in sorted((session / "frames").rglob("*.png"))[::every]:
            frame = decode_frame(path.read_bytes(), str(path))
            board = next((b for b in boards if current.detect(frame, b) is not None), boards[0])
            jobs.append((frame, board))
    return jobs


def load_module(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location("detect_against", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def same_detections(a: ModuleType, b: ModuleType, jobs) -> None:
    for index, (frame, board) in enumerate(jobs):
        x, y = a.detect(frame, board), b.detect(frame, board)
        if (x is None) != (y is None):
            raise SystemExit(f"frame {index}: found by one version only")
        if x is None:
            continue
        if (x.order, x.image_size) != (y.order, y.image_size) or any(
                getattr(x, f).tobytes() != getattr(y, f).tobytes() for f in ("ids", "corners_px", "sigma_px")):
            raise SystemExit(f"frame {index}: the detections differ")


def timed_pass(module: ModuleType, jobs) -> dict[str, float]:
    """CPU seconds of one pass over the frames: the plain total, then each part, wrapped in place."""
    start = time.thread_time()
    for frame, board in jobs:
        module.detect(frame, board)
    spent = {"detect (plain)": time.thread_time() - start}

    def timed(name, function):
        def wrapper(*args, **kwargs):
            begin = time.thread_time()
            try:
                return function(*args, **kwargs)
            finally:
                spent[name] = spent.get(name, 0.0) + time.thread_time() - begin
        return wrapper

    originals = {name: getattr(module, name) for name in PARTS if hasattr(module, name)}
    opencv = {name: getattr(cv2, name) for name in OPENCV_CALLS}
    try:
        for name, function in originals.items():
            setattr(module, name, timed(name, function))
        for name, function in opencv.items():
            setattr(cv2, name, timed(f"cv2.{name}", function))
        for frame, board in jobs:
            module.detect(frame, board)
    finally:
        for name, function in originals.items():
            setattr(module, name, function)
        for name, function in opencv.items():
            setattr(cv2, name, function)
    return spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sessions", nargs="*", type=Path, default=[ROOT / "calib_data" / "sample_session"])
    parser.add_argument("--every", type=int, default=3, help="take every N-th frame of each session")
    parser.add_argument("--repeat", type=int, default=5, help="passes over the frames; the best counts")
    parser.add_argument("--against", type=Path, help="another detect.py to compare with (checked, timed alternately)")
    parser.add_argument("--out", type=Path, default=ROOT / "scripts" / "results" / "bench_detect.json")
    args = parser.parse_args()

    cv2.setNumThreads(1)  # as the replay runs it (single_threaded_opencv)
    jobs = load_jobs(args.sessions, args.every)
    versions = {"current": current}
    if args.against:
        versions = {"against": load_module(args.against), "current": current}
        same_detections(versions["against"], current, jobs)
    best: dict[str, dict[str, float]] = {label: {} for label in versions}
    load_before = os.getloadavg()
    for _ in range(args.repeat):
        for label, module in versions.items():
            for name, seconds in timed_pass(module, jobs).items():
                best[label][name] = min(best[label].get(name, float("inf")), seconds)
    per_frame = {label: {name: 1000 * s / len(jobs) for name, s in times.items()} for label, times in best.items()}

    labels = list(versions)
    print(f"{len(jobs)} frames of {', '.join(str(s) for s in args.sessions)}; CPU ms per frame, best of "
          f"{args.repeat}; load {load_before[0]:.2f} -> {os.getloadavg()[0]:.2f}"
          + ("; detections bit-identical" if args.against else ""))
    print(f"{'':>36}" + "".join(f"{label:>10}" for label in labels))
    for name in sorted(per_frame["current"], key=lambda n: -per_frame["current"][n]):
        print(f"{name:>36}" + "".join(f"{per_frame[label].get(name, float('nan')):10.3f}" for label in labels))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "sessions": [str(s) for s in args.sessions], "frames": len(jobs), "every": args.every, "repeat": args.repeat,
        "against": str(args.against) if args.against else None, "loadavg": [load_before, os.getloadavg()],
        "cpu_ms_per_frame": per_frame, "opencv": cv2.__version__,
    }, indent=1) + "\n")
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
