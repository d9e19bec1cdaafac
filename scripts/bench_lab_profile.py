"""What the lab profile adds per frame, and what a calibration on the lab bench gives beside the real sets.

Three parts (each its own JSON):

- cost (default): times ``StereoRenderer.render_view`` at 1920x1080 (median of ``--runs`` after one warm-up)
  for the views a campaign renders - the 27 mm target facing the rig at 300 and 700 mm (bent and scaled on
  the lab bench) and a tilted calibration board (flat on both) - on the ideal optics and lens and on the lab
  ones, plus each lab addition alone; with the load average (other work inflates every figure).
- ``--calibration``: a lab-bench calibration (12 views of the 11x8 25 mm board at B = 100 mm, the bench's
  optics, lenses and mechanics, stereo_bench's detector and calibration) per seed: mono RMS left and right,
  stereo RMS, and the image statistics of the frames measured as the real sets' are (below); with
  ``--unsynchronised`` the same with ``cameras.synchronised = false``.
- ``--real``: the real sets in ../shared/data (or ``--data``) measured: plain OpenCV calibrations (RMS,
  per-view RMS, distortion, radial distortion at the image corner), the noise inside the squares (plane
  removed) and its level, the edge width across the squares' edges, the JPEG quality of the files (their
  luma quantisation table), and caliscope_charuco_2cam's capture skew (timestamps.csv) and board speed.

    .venv/bin/python scripts/bench_lab_profile.py [--runs 15] [--out scripts/results/bench_lab_profile.json]
    .venv/bin/python scripts/bench_lab_profile.py --calibration [--seeds 3] [--unsynchronised]
    .venv/bin/python scripts/bench_lab_profile.py --real [--data ../shared/data]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import statistics
import struct
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sim.bench import BenchSimulator, board_shape, camera_optics, true_lens  # noqa: E402
from drivers.sim.mechanics import pair_state  # noqa: E402
from drivers.sim.profile import LAB, CameraErrors, SimProfile  # noqa: E402
from drivers.sim.render import Optics, StereoRenderer, calibration_board_poses  # noqa: E402
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig, invert_transform  # noqa: E402
from stereo_bench.targets import Checkerboard  # noqa: E402

try:  # the skew of an unsynchronised pair (absent before it existed: --calibration still measures the old bench)
    from drivers.sim.bench import board_at_exposure  # noqa: E402
except ImportError:  # pragma: no cover
    board_at_exposure = None

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


# --------------------------------------------------------------------------------------------------
# Image statistics of board views, measured the same way on the real sets and on rendered frames

_STD_LUMA = np.array([16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
                      14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113,
                      92, 49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99], float)
_ZIGZAG = np.array([0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48, 41, 34, 27, 20, 13,
                    6, 7, 14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51, 58, 59, 52, 45,
                    38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63])


def jpeg_quality(path: Path) -> int | None:
    """The libjpeg quality whose scaled standard luma table is nearest a JPEG file's own (None: no JPEG table)."""
    data = path.read_bytes()
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            i += 1
            continue
        marker, length = data[i + 1], struct.unpack(">H", data[i + 2:i + 4])[0]
        if marker == 0xDB:
            segment, j = data[i + 4:i + 2 + length], 0
            while j < len(segment):
                precision, table_id = segment[j] >> 4, segment[j] & 15
                size = 64 * (1 + precision)
                values = np.frombuffer(segment[j + 1:j + 1 + size], dtype=">u2" if precision else "u1").astype(float)
                j += 1 + size
                if table_id == 0:
                    table = np.empty(64)
                    table[_ZIGZAG] = values

                    def mismatch(q: int, table: np.ndarray = table) -> float:
                        scale = 5000 / q if q < 50 else 200 - 2 * q
                        return float(np.abs(np.clip(np.floor((_STD_LUMA * scale + 50) / 100), 1, 255) - table).sum())

                    return min(range(1, 101), key=mismatch)
        i += 2 + length
    return None


def square_noise(gray: np.ndarray, corners: np.ndarray, pattern: tuple[int, int]) -> list[tuple[float, float]]:
    """(mean DN, residual variance DN^2) inside every square of the grid (its inner 45 %, a plane removed)."""
    cols, rows = pattern
    grid = corners.reshape(rows, cols, 2)
    image = gray.astype(np.float64)
    out = []
    for r in range(rows - 1):
        for c in range(cols - 1):
            quad = np.array([grid[r, c], grid[r, c + 1], grid[r + 1, c + 1], grid[r + 1, c]])
            centre = quad.mean(axis=0)
            mask = np.zeros(gray.shape, np.uint8)
            cv2.fillConvexPoly(mask, np.round(centre + 0.45 * (quad - centre)).astype(np.int32), 1)
            ys, xs = np.nonzero(mask)
            if len(ys) < 12:
                continue
            values = image[ys, xs]
            A = np.column_stack([xs, ys, np.ones_like(xs)]).astype(float)
            residual = values - A @ np.linalg.lstsq(A, values, rcond=None)[0]
            out.append((float(values.mean()), float(residual.var() * len(values) / (len(values) - 3))))
    return out


def edge_widths(gray: np.ndarray, corners: np.ndarray, pattern: tuple[int, int], half: float = 6.0) -> list[float]:
    """Edge width (px) across every inner edge between adjacent corners: the second moment of the gradient of
    the intensity profile along the edge's normal (averaged at 35, 50, 65 % of the edge), i.e. the Gaussian sigma
    of blur plus pixel integration (a perfect step sampled by ideal pixels: ~0.4 px)."""
    cols, rows = pattern
    grid = corners.reshape(rows, cols, 2)
    image = gray.astype(np.float32)
    steps = np.arange(-half, half + 1e-9, 0.25)
    pairs = [(grid[r, c], grid[r, c + 1]) for r in range(rows) for c in range(cols - 1)]
    pairs += [(grid[r, c], grid[r + 1, c]) for r in range(rows - 1) for c in range(cols)]
    out = []
    for a, b in pairs:
        d = b - a
        length = math.hypot(*d)
        if length < 2 * half:
            continue
        normal = np.array([-d[1], d[0]]) / length
        profiles = []
        for fraction in (0.35, 0.5, 0.65):
            xy = ((a + fraction * d)[None, :] + steps[:, None] * normal[None, :]).astype(np.float32)
            profiles.append(cv2.remap(image, xy[:, 0].reshape(1, -1), xy[:, 1].reshape(1, -1),
                                      cv2.INTER_LINEAR).ravel())
        v = np.mean(profiles, axis=0)
        if v[-1] < v[0]:
            v = v[::-1]
        if v[-4:].mean() - v[:4].mean() < 20:
            continue
        gradient = np.clip(np.diff(v), 0, None)
        if gradient.sum() <= 0:
            continue
        x = 0.5 * (steps[1:] + steps[:-1])
        w = gradient / gradient.sum()
        m = float((w * x).sum())
        out.append(math.sqrt(max(float((w * (x - m) ** 2).sum()), 1e-6)))
    return out


def image_statistics(stats: list[tuple[float, float]], widths: list[float]) -> dict:
    """Noise of the dark and light squares (mean level, std DN) and the median edge width."""
    values = np.array(stats)
    median = np.median(values[:, 0])
    dark, light = values[values[:, 0] < median], values[values[:, 0] >= median]
    return {"noise_dark_dn": [round(float(dark[:, 0].mean()), 1), round(math.sqrt(dark[:, 1].mean()), 3)],
            "noise_light_dn": [round(float(light[:, 0].mean()), 1), round(math.sqrt(light[:, 1].mean()), 3)],
            "edge_width_px": round(float(np.median(widths)), 3),
            "edge_width_p25_p75_px": [round(float(np.percentile(widths, 25)), 3),
                                      round(float(np.percentile(widths, 75)), 3)]}


def radial_at_corner(K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> float:
    """Relative radial distortion (r_distorted - r) / r at the image's corner pixel: a figure free of resolution."""
    w, h = size
    distorted = np.hypot((w - 1 - K[0, 2]) / K[0, 0], (h - 1 - K[1, 2]) / K[1, 1])
    ideal = float(np.hypot(*cv2.undistortPoints(np.array([[[w - 1, h - 1]]], np.float64), K, dist).reshape(2)))
    return float((distorted - ideal) / ideal)


# --------------------------------------------------------------------------------------------------
# The real sets

REAL_SETS = {"opencv_sample": ("left*.jpg", "right*.jpg", (9, 6), 30.0),
             "present_cjn": ("leftPic*.jpg", "rightPic*.jpg", (8, 11), 12.0),
             "smiler488_box": ("L_*.png", "R_*.png", (8, 5), 15.0)}


def _find(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    ok, corners = cv2.findChessboardCorners(gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                            | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    corners = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2).astype(np.float32), (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4))
    return corners.reshape(-1, 2).astype(float)


def _pair_key(path: Path) -> str:
    return path.name.replace("right", "left").replace("R_", "L_")


def measure_real_set(folder: Path, left_glob: str, right_glob: str, pattern: tuple[int, int], square: float) -> dict:
    """Plain OpenCV on one real set: per camera its calibration, noise and edges; the pair's stereo RMS."""
    grid = np.zeros((pattern[0] * pattern[1], 3), np.float32)
    grid[:, :2] = np.mgrid[0:pattern[0], 0:pattern[1]].T.reshape(-1, 2) * square
    files = {"left": sorted(folder.glob(left_glob)), "right": sorted(folder.glob(right_glob))}
    out: dict = {"jpeg_quality": jpeg_quality(files["left"][0]) if files["left"][0].suffix == ".jpg" else None}
    found: dict = {}
    for side, paths in files.items():
        stats, widths, points = [], [], {}
        for path in paths:
            gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            corners = _find(gray, pattern)
            if corners is None:
                continue
            points[_pair_key(path)] = corners
            stats += square_noise(gray, corners, pattern)
            widths += edge_widths(gray, corners, pattern)
        size = gray.shape[::-1]
        rms, K, dist, _, _, _, _, per_view = cv2.calibrateCameraExtended(
            [grid.reshape(-1, 1, 3)] * len(points), [p.astype(np.float32).reshape(-1, 1, 2) for p in points.values()],
            size, None, None)
        found[side] = (points, K, dist)
        out[side] = {"views": len(points), "rms_px": round(rms, 4),
                     "per_view_rms_median_px": round(float(np.median(per_view)), 4), "fx_px": round(K[0, 0], 1),
                     "dist": [round(float(v), 4) for v in dist.ravel()],
                     "radial_at_corner": round(radial_at_corner(K, dist, size), 4), **image_statistics(stats, widths)}
    keys = sorted(set(found["left"][0]) & set(found["right"][0]))
    stereo = cv2.stereoCalibrate([grid.reshape(-1, 1, 3)] * len(keys),
                                 [found["left"][0][k].astype(np.float32).reshape(-1, 1, 2) for k in keys],
                                 [found["right"][0][k].astype(np.float32).reshape(-1, 1, 2) for k in keys],
                                 found["left"][1], found["left"][2], found["right"][1], found["right"][2], size,
                                 flags=cv2.CALIB_FIX_INTRINSIC)
    out.update(size=list(size), pairs=len(keys), stereo_rms_px=round(stereo[0], 4))
    return out


def measure_caliscope(folder: Path) -> dict:
    """caliscope_charuco_2cam: the left-right capture skew of its pairs (timestamps.csv) and how fast the hand-held
    board moves (its ChArUco corners between consecutive frames, mm/s through the 54 mm squares' image size)."""
    times: dict[int, dict[int, float]] = {}
    for row in csv.DictReader((folder / "timestamps.csv").open()):
        times.setdefault(int(row["sync_index"]), {})[int(row["cam_id"])] = float(row["frame_time"])
    skew = np.array([t[1] - t[0] for t in times.values() if 0 in t and 1 in t]) * 1e3
    out = {"pairs": len(skew), "skew_ms": {"mean": round(float(skew.mean()), 2), "std": round(float(skew.std()), 2),
                                           "max_abs": round(float(np.abs(skew).max()), 2),
                                           "p95_abs": round(float(np.percentile(np.abs(skew), 95)), 2)}}
    board = cv2.aruco.CharucoBoard((4, 5), 54.0, 40.5, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_1000))
    detector = cv2.aruco.CharucoDetector(board)
    for cam in (0, 1):
        stamps = [t for _, t in sorted((i, t[cam]) for i, t in times.items() if cam in t)]
        capture = cv2.VideoCapture(str(folder / f"cam_{cam}.mp4"))
        previous, speeds, index = None, [], 0
        while True:
            ok, frame = capture.read()
            if not ok or index >= len(stamps):
                break
            gray = 255 - cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)  # inverted board
            corners, ids, *_ = detector.detectBoard(gray)
            current = None
            if ids is not None and len(ids) >= 6:
                current = dict(zip(ids.ravel().tolist(), corners.reshape(-1, 2), strict=True))
                if previous is not None:
                    common = set(current) & set(previous[0])
                    squares = [math.hypot(*(current[k] - current[k + 1])) for k in current
                               if k + 1 in current and k % 3 != 2]
                    if len(common) >= 4 and squares:
                        moved = float(np.median([math.hypot(*(current[k] - previous[0][k])) for k in common]))
                        speeds.append(moved / (stamps[index] - previous[1]) / (np.median(squares) / 54.0))
            previous = (current, stamps[index]) if current is not None else None
            index += 1
        out[f"board_speed_cam{cam}_mm_s"] = {"n": len(speeds), "median": round(float(np.median(speeds)), 1),
                                             "p90": round(float(np.percentile(speeds, 90)), 1)}
    return out


def real_main(args) -> int:
    result = {"benchmark": "bench_lab_profile --real", "sets": {}}
    for name, spec in REAL_SETS.items():
        result["sets"][name] = measure_real_set(args.data / name, *spec)
        print(name, json.dumps(result["sets"][name]))
    result["sets"]["caliscope_charuco_2cam"] = measure_caliscope(args.data / "caliscope_charuco_2cam")
    print("caliscope_charuco_2cam", json.dumps(result["sets"]["caliscope_charuco_2cam"]))
    out = args.out or Path("scripts/results/bench_lab_profile_real.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


# --------------------------------------------------------------------------------------------------
# A calibration on the lab bench

CALIBRATION_BOARD = Checkerboard(11, 8, 25.0)


def lab_calibration(profile: SimProfile, seed: int, *, views: int = 12, baseline_mm: float = 100.0) -> dict:
    """Mono RMS (left, right) and stereo RMS of a calibration on the bench of ``profile`` (the bench's own optics,
    lenses and mechanics at B = ``baseline_mm``, toe-in 0; board poses as the presenter draws them), and the image
    statistics of its first four left frames."""
    from stereo_bench.vision.calibrate import calibrate_mono, calibrate_stereo
    from stereo_bench.vision.detect import detect

    bench = BenchSimulator(profile=profile, seed=seed)  # not started: its optics, lenses and profile only
    left, right = bench.left_model, bench.right_model
    state = pair_state(profile, {"baseline_mm": baseline_mm, "toe_in_left_deg": 0.0, "toe_in_right_deg": 0.0})
    poses = calibration_board_poses(RigPose.symmetric(baseline_mm, 90.0), CALIBRATION_BOARD, n_views=views,
                                    rng=np.random.default_rng(seed), left=left, right=right)
    renderer = StereoRenderer(CALIBRATION_BOARD, left, right, optics=bench.optics)
    pattern = (CALIBRATION_BOARD.cols, CALIBRATION_BOARD.rows)
    objects, lefts, rights, stats, widths, skews = [], [], [], [], [], []
    for index, T_rig_board in enumerate(poses):
        images = {}
        for side, T_bench_cam in (("left", state.T_bench_left), ("right", state.T_bench_right)):
            T = T_rig_board
            if board_at_exposure is not None:
                T, skew = board_at_exposure(profile, T_rig_board, seed=seed, index=index, side=side)
                if skew is not None and side == "right":
                    skews.append(skew)
            images[side] = renderer.render_view(side, invert_transform(T_bench_cam) @ T,
                                                np.random.default_rng([seed, index, side == "right"])).image
        found = {side: detect(image, CALIBRATION_BOARD, noise=False) for side, image in images.items()}
        if any(d is None or d.n < len(CALIBRATION_BOARD.object_points) for d in found.values()):
            continue
        objects.append(np.asarray(CALIBRATION_BOARD.object_points, np.float64)[found["left"].ids])
        lefts.append(found["left"].corners_px)
        rights.append(found["right"].corners_px[np.argsort(found["right"].ids)][found["left"].ids])
        if index < 4:
            stats += square_noise(images["left"], found["left"].corners_px[np.argsort(found["left"].ids)], pattern)
            widths += edge_widths(images["left"], found["left"].corners_px[np.argsort(found["left"].ids)], pattern)
    size = left.image_size
    stereo = calibrate_stereo(objects, lefts, rights, size, covariance=False)
    return {"seed": seed, "views": len(objects), "views_used": len(stereo.views_used),
            "left_rms_px": round(calibrate_mono(objects, lefts, size, covariance=False).rms_px, 4),
            "right_rms_px": round(calibrate_mono(objects, rights, size, covariance=False).rms_px, 4),
            "stereo_rms_px": round(stereo.rms_px, 4), "baseline_mm": round(stereo.baseline_mm, 3),
            "skew_ms_rms": round(float(np.sqrt(np.mean(np.square(skews)))) * 1e3, 2) if skews else None,
            **image_statistics(stats, widths)}


def calibration_main(args) -> int:
    profile = LAB
    if args.unsynchronised:
        profile = LAB.model_copy(update={"name": "lab, unsynchronised", "cameras": LAB.cameras.model_copy(
            update={"synchronised": False})})
    rows = []
    print(f"lab-bench calibration ({profile.name}): 12 views of the 11x8 25 mm board, B = 100 mm, 1920x1080")
    for seed in range(args.seeds):
        started = time.perf_counter()
        rows.append(lab_calibration(profile, seed))
        print(json.dumps(rows[-1]), f"{time.perf_counter() - started:.1f} s", flush=True)
    summary = {key: [round(min(r[key] for r in rows), 4), round(float(np.mean([r[key] for r in rows])), 4),
                     round(max(r[key] for r in rows), 4)] for key in ("left_rms_px", "right_rms_px", "stereo_rms_px")}
    print("min, mean, max over seeds:", json.dumps(summary))
    result = {"benchmark": "bench_lab_profile --calibration", "profile": profile.name, "seeds": args.seeds,
              "rows": rows, "summary_min_mean_max": summary, "opencv": cv2.__version__}
    out = args.out or Path("scripts/results/bench_lab_profile_calibration"
                           f"{'_unsynchronised' if args.unsynchronised else ''}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    parser.add_argument("--calibration", action="store_true", help="lab-bench calibration RMS and image statistics")
    parser.add_argument("--real", action="store_true", help="measure the real sets")
    parser.add_argument("--seeds", type=int, default=3, help="--calibration: seeds")
    parser.add_argument("--unsynchronised", action="store_true", help="--calibration: cameras.synchronised = false")
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[3] / "shared" / "data",
                        help="--real: the folder holding the real sets (default ../shared/data of the worktree's "
                             "parent)")
    parser.add_argument("--out", type=Path, default=None, help="JSON (default scripts/results/bench_lab_profile"
                        "[_calibration[_unsynchronised]|_real].json)")
    args = parser.parse_args()
    if args.real:
        return real_main(args)
    if args.calibration:
        return calibration_main(args)
    args.out = args.out or Path("scripts/results/bench_lab_profile.json")

    nominal = CameraModel.from_sensor(name="left")
    lab_lens = true_lens(nominal, *LAB.cameras.lens_terms("left"))
    shape = board_shape(LAB.target)
    cams = LAB.cameras
    sensor_only = cams.model_copy(update={"corner_noise_px": 0.0, "line_time_us": 0.0})
    jitter_only = CameraErrors(corner_noise_px=cams.corner_noise_px, corner_noise_scale_px=cams.corner_noise_scale_px)
    variants = {
        "ideal": (nominal, Optics(), False),
        "lab: JPEG only": (nominal, Optics(jpeg_quality=cams.jpeg_quality), False),
        "lab: sensor noise, gain, defocus only": (nominal, camera_optics(Optics(), sensor_only), False),
        "lab: corner noise only": (nominal, camera_optics(Optics(), jitter_only), False),
        "lab: bent, scaled target only": (nominal, Optics(), True),
        "lab: lens only": (lab_lens, Optics(), False),
        "lab (all of it)": (lab_lens, camera_optics(Optics(jpeg_quality=cams.jpeg_quality), cams), True),
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
    rolling = StereoRenderer(TARGET, nominal, nominal, optics=Optics(line_time_s=cams.line_time_us * 1e-6))
    rolling_ms = _time(lambda: rolling.render_view("left", T, np.random.default_rng(0), smear_px=(3.0, 0.0),
                                                   velocity_px_s=(150.0, 0.0)), args.runs)
    load_after = os.getloadavg()

    names = list(variants)
    print(f"render_view at 1920x1080, median of {args.runs} (ms); load average {load_before[0]:.2f} -> "
          f"{load_after[0]:.2f} on {os.cpu_count()} cores")
    print(f"{'case':34s}" + "".join(f"{n:>40s}" for n in names))
    for row in rows:
        print(f"{row['case']:34s}" + "".join(f"{row[n]:40.1f}" for n in names))
    print(f"ringing smear (3 px), only on frames taken within 0.24 s of a move: {smear_ms - plain_ms:+.1f} ms; "
          f"with the rolling shutter's shear: {rolling_ms - plain_ms:+.1f} ms")
    result = {
        "benchmark": "bench_lab_profile", "runs": args.runs, "rows": rows,
        "smear_extra_ms": round(smear_ms - plain_ms, 1), "smear_and_rolling_shutter_extra_ms": round(
            rolling_ms - plain_ms, 1),
        "load_average": {"before": load_before, "after": load_after}, "cpu_count": os.cpu_count(),
        "python": platform.python_version(), "opencv": cv2.__version__, "numpy": np.__version__,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
