"""The cost of the inputs that scale the work, behind the bounds the CLI puts on them (docs/EXIT_STATUS.md).

Each row times one job in this process (wall time, load average before and after) at a few values of one
input, up to past its bound where that is affordable:

- render blur (``render --blur``, bound 50 px): one 1920x1080 stereo pair of the 9x6 board at 500 mm; also
  whether ``measure`` still finds the board in it.
- board size (``--board``, bound 10,000 inner corners): one rendered pair of an N x (N-1) checkerboard, and
  the peak memory the renderer's texture takes (``ru_maxrss`` growth, a lower bound when the process was
  already larger).
- Monte Carlo samples (``model predict --monte-carlo``, bound 1,000,000): serial, per sample.
- surface configurations (``model surface``, ``advise``: bound 100,000): serial, per configuration.
- planned calibration views (``--calibration-views``, bound 500): one prediction.

The campaign config's bounds (``stereo_bench/campaign/config.py``, ``drivers/rig/config.py``; docs/EXIT_STATUS.md):

- a stereo frame (``[capture] frames_per_config``, bound 1,000; ``board_retries``, bound 20; each calibration
  view is one too): one 1080p pair rendered, detected and encoded as the session writes it, and its bytes.
- the stereo calibration (``[capture] calibration_views``, bound 500): ``calibrate_stereo`` on N views of the
  calibration board (exact projections plus 0.1 px noise, poses as the simulator presents them).
- the simulated image (``[cameras.optics] width_px``/``height_px``, bound 8,192): one view rendered at that size.
- the TOML files (1 MiB, nesting 32, ``drivers/files.py``): ``tomllib`` on a plan written value by value, and the
  nesting scan; and the nesting at which ``tomllib`` fails (``RecursionError``).
- timeouts (``[rig.controller]``): the longest wait ``threading`` accepts (``threading.TIMEOUT_MAX``; a
  Condition wait beyond it raises ``OverflowError``, as ``home_timeout_s = inf`` did), and the simulated rig's
  homing cycle as ``campaign plan`` predicts it.

    python scripts/bench_input_bounds.py [--quick] [--out scripts/results/bench_input_bounds.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import time

import numpy as np


def _timed(fn):
    load = os.getloadavg()[0]
    started = time.perf_counter()
    value = fn()
    return time.perf_counter() - started, load, value


def render_pair(board_cols: int, board_rows: int, square_mm: float, blur_px: float):
    from drivers.sim.render import Optics, StereoRenderer
    from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
    from stereo_bench.targets import Checkerboard

    target = Checkerboard(board_cols, board_rows, square_mm)
    camera = CameraModel.from_sensor()
    renderer = StereoRenderer(target, camera, camera, optics=Optics(blur_sigma_px=blur_px))
    pose = board_pose_facing_rig(distance_mm=500.0, board_size_mm=target.grid_size_mm)
    return target, camera, renderer.render_pair(RigPose.symmetric(100.0, 90.0), pose, np.random.default_rng(0))


def blur_rows(values: list[float]) -> list[dict]:
    from stereo_bench.vision.detect import detect

    render_pair(9, 6, 27.0, 0.7)  # warm-up: imports, the renderer's first texture
    rows = []
    for blur in values:
        seconds, load, (target, _, pair) = _timed(lambda b=blur: render_pair(9, 6, 27.0, b))
        found = detect(pair.left.image, target, thorough=True) is not None
        rows.append({"input": "render --blur", "value": blur, "seconds": seconds, "load": load,
                     "board_detected": found})
    return rows


def board_rows(sizes: list[int]) -> list[dict]:
    from stereo_bench import targets

    targets.MAX_BOARD_CORNERS = 10**9  # lifted in this process only, to time boards past the bound
    rows = []
    for n in sizes:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        seconds, load, _ = _timed(lambda n=n: render_pair(n, n - 1, 200.0 / n, 0.7))
        grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
        rows.append({"input": "--board", "value": f"{n}x{n - 1}", "corners": n * (n - 1), "seconds": seconds,
                     "load": load, "peak_rss_growth_mb": grown_mb})
    return rows


def monte_carlo_rows(samples: list[int]) -> list[dict]:
    from stereo_bench.errormodel.montecarlo import monte_carlo
    from stereo_bench.errormodel.rigorous import Setup
    from stereo_bench.targets import Checkerboard

    setup = Setup.make(100.0, 500.0, 90.0, board=Checkerboard(9, 6, 27.0))
    rows = []
    for n in samples:
        seconds, load, _ = _timed(lambda n=n: monte_carlo(setup, 0.1, n, seed=0))
        rows.append({"input": "--monte-carlo", "value": n, "seconds": seconds, "load": load,
                     "us_per_sample": 1e6 * seconds / n})
    return rows


def surface_rows(sides: list[int]) -> list[dict]:
    from stereo_bench.errormodel.surfaces import surface_bz
    from stereo_bench.geometry import CameraModel
    from stereo_bench.targets import Checkerboard

    camera = CameraModel.from_sensor()
    rows = []
    for side in sides:
        baselines, distances = np.linspace(20, 400, side), np.linspace(300, 1100, side)
        seconds, load, _ = _timed(lambda b=baselines, d=distances: surface_bz(
            b, d, alpha="converge", pixel_sigma_px=0.1, with_sensitivities=True, board=Checkerboard(9, 6, 27.0),
            left=camera, right=camera, margin_px=10.0))
        rows.append({"input": "surface configurations", "value": side * side, "seconds": seconds, "load": load,
                     "ms_per_configuration": 1e3 * seconds / side**2})
    return rows


def calibration_view_rows(views: list[int]) -> list[dict]:
    from stereo_bench.errormodel.rigorous import CalibrationPlan, Setup, predict
    from stereo_bench.targets import Checkerboard

    setup = Setup.make(100.0, 500.0, 90.0, board=Checkerboard(9, 6, 27.0))
    rows = []
    for n in views:
        plan = CalibrationPlan(n_views=n, board=Checkerboard(11, 8, 25.0), mode="joint")
        seconds, load, _ = _timed(lambda p=plan: predict(setup, 0.1, calibration=p))
        rows.append({"input": "--calibration-views", "value": n, "seconds": seconds, "load": load,
                     "ms_per_view": 1e3 * seconds / n})
    return rows


def frame_rows(count: int) -> list[dict]:
    """One stereo frame as a campaign pays for it: rendered, both views detected, both encoded as recorded."""
    from stereo_bench.frames import encode_frame
    from stereo_bench.vision.detect import detect

    render_pair(9, 6, 27.0, 0.7)  # warm-up
    rows = []
    for _ in range(count):
        load = os.getloadavg()[0]
        started = time.perf_counter()
        target, _, pair = render_pair(9, 6, 27.0, 0.7)
        rendered = time.perf_counter()
        for image in (pair.left.image, pair.right.image):
            detect(image, target)
        detected = time.perf_counter()
        size = sum(len(encode_frame(image)) for image in (pair.left.image, pair.right.image))
        done = time.perf_counter()
        rows.append({"input": "stereo frame (frames_per_config, views)", "value": "1920x1080",
                     "seconds": done - started, "load": load, "render_s": rendered - started,
                     "detect_s": detected - rendered,
                     "encode_s": done - detected, "bytes": size})
    return rows


def stereo_calibration_rows(views: list[int]) -> list[dict]:
    """calibrate_stereo (joint) on N views of the 11x8 calibration board at B 100, Z 500 (0.1 px noise)."""
    from drivers.sim.render import calibration_board_poses
    from stereo_bench.geometry import CameraModel, RigPose, invert_transform, transform_points
    from stereo_bench.targets import Checkerboard
    from stereo_bench.vision.calibrate import calibrate_stereo

    camera, board, rig = CameraModel.from_sensor(), Checkerboard(11, 8, 25.0), RigPose.symmetric(100.0, 90.0)
    points = np.asarray(board.object_points, float)
    rows = []
    for n in views:
        rng = np.random.default_rng(n)
        poses = calibration_board_poses(rig, board, n_views=n, rng=rng, distance_mm=(300.0, 650.0))
        sides = [[camera.project(transform_points(invert_transform(T_rig_cam) @ pose, points))[0]
                  + rng.normal(0.0, 0.1, (len(points), 2)) for pose in poses]
                 for T_rig_cam in (rig.T_rig_left, rig.T_rig_right)]
        objects = [board.object_points] * len(poses)
        seconds, load, calib = _timed(lambda o=objects, s=sides: calibrate_stereo(o, s[0], s[1], camera.image_size,
                                                                                  mode="joint"))
        rows.append({"input": "calibration_views", "value": len(poses), "seconds": seconds, "load": load,
                     "ms_per_view": 1e3 * seconds / len(poses), "rms_px": calib.rms_px})
    return rows


def image_size_rows(sizes: list[tuple[int, int]]) -> list[dict]:
    """One simulated view rendered at each image size (the 9x6 board at 500 mm, the default lens)."""
    from drivers.sim.render import Optics, StereoRenderer
    from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
    from stereo_bench.targets import Checkerboard

    target = Checkerboard(9, 6, 27.0)
    rows = []
    for width, height in sizes:
        camera = CameraModel.from_sensor(pixel_um=3.0 * 1920 / width, image_size=(width, height))
        renderer = StereoRenderer(target, camera, camera, optics=Optics(blur_sigma_px=0.7))
        pose = board_pose_facing_rig(distance_mm=500.0, board_size_mm=target.grid_size_mm)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        seconds, load, _ = _timed(lambda r=renderer, p=pose: r.render_pair(RigPose.symmetric(100.0, 90.0), p,
                                                                           np.random.default_rng(0)))
        rows.append({"input": "cameras.optics width_px x height_px", "value": f"{width}x{height}",
                     "seconds": seconds / 2, "load": load,
                     "peak_rss_growth_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024})
    return rows


def toml_rows(values: list[int]) -> list[dict]:
    """tomllib and the nesting scan on a plan of N baselines written out; the depth tomllib itself fails at."""
    import tomllib

    from drivers.files import toml_nesting

    rows = []
    for n in values:
        text = "[plan]\nbaseline_mm = [" + ", ".join(f"{100 + i * 0.001:.3f}" for i in range(n)) + "]\n"
        scan, load, _ = _timed(lambda t=text: toml_nesting(t))
        parse, _, _ = _timed(lambda t=text: tomllib.loads(t))
        rows.append({"input": "TOML file", "value": len(text.encode()), "seconds": scan + parse, "load": load,
                     "scan_s": scan, "tomllib_s": parse, "values": n})
    fails_at = None
    for depth in (100, 300, 1000, 3000, 10000):
        try:
            tomllib.loads("x = " + "[" * depth + "]" * depth)
        except RecursionError:
            fails_at = depth
            break
    rows.append({"input": "TOML nesting", "value": fails_at, "seconds": 0.0, "load": os.getloadavg()[0],
                 "notes": "the first of 100, 300, 1000, 3000, 10000 nested arrays at which tomllib raises "
                          "RecursionError"})
    return rows


def timeout_rows() -> list[dict]:
    """The longest wait threading accepts, whether it refuses one beyond it, and the reference rig's homing."""
    import threading

    from stereo_bench.campaign.config import campaign_from_dict
    from stereo_bench.campaign.plan import estimate_duration, expand_plan, plan_steps

    try:  # a free lock: an accepted timeout returns at once, a refused one raises before trying
        refused = not threading.Lock().acquire(timeout=threading.TIMEOUT_MAX * 2) and False
    except OverflowError:
        refused = True
    config = campaign_from_dict({"plan": {"baseline_mm": [100.0], "distance_mm": [500.0]}})
    configurations = expand_plan(config)
    duration = estimate_duration(config, configurations, plan_steps(config, configurations))
    return [{"input": "[rig.controller] timeouts", "value": threading.TIMEOUT_MAX, "seconds": 0.0,
             "load": os.getloadavg()[0], "overflow_beyond_timeout_max": refused,
             "predicted_homing_s": duration.homing_s}]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer and smaller values (a smoke run)")
    parser.add_argument("--out", default="scripts/results/bench_input_bounds.json")
    args = parser.parse_args()
    quick = args.quick
    rows = (blur_rows([0.7, 50.0] if quick else [0.7, 10.0, 50.0, 200.0])
            + board_rows([30] if quick else [30, 100, 240])
            + monte_carlo_rows([2_000] if quick else [2_000, 100_000])
            + surface_rows([5] if quick else [10, 30])
            + calibration_view_rows([12] if quick else [12, 100, 500])
            + frame_rows(1 if quick else 3)
            + stereo_calibration_rows([12] if quick else [12, 50, 200, 500])
            + image_size_rows([(1920, 1080)] if quick else [(1920, 1080), (3840, 2160), (8192, 4608)])
            + toml_rows([1_000] if quick else [1_000, 20_000, 100_000])
            + timeout_rows())
    print(f"{'input':<24} {'value':>10} {'seconds':>8} {'load':>5}  per unit / notes")
    for row in rows:
        notes = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
                          if k not in ("input", "value", "seconds", "load"))
        print(f"{row['input']:<24} {row['value']!s:>10} {row['seconds']:8.2f} {row['load']:5.1f}  {notes}")
    result = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                          "load_after": os.getloadavg()}, "quick": quick, "rows": rows}
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    with open(args.out, "w") as handle:
        json.dump(result, handle, indent=1)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
