"""Calibration views by hand on the simulated lab bench: automatic capture against today's Enter-to-capture.

A simulated operator (drivers/sim/hand.py) presents the 11x8, 25 mm calibration board by hand at
``--views`` poses (as the simulated presenter draws them) in front of the lab bench's rig (B 100 mm,
parallel): carried along minimum-jerk paths, held for 0.6-1.8 s with tremor and a slow sag, now and then
swung half out of a view first. The cameras (the lab profile's: 0.2 px corner noise, JPEG, rolling shutter)
stream at ``--fps`` on the bench clock; every frame is rendered with the motion smear of its exposure and
the rolling shutter's shear.

- **auto**: every pair is detected and offered to stereo_bench.campaign.autocapture.ViewSelector (still,
  settled, new, both views whole; the coverage gate ends the collection);
- **enter**: today's runner at a hand-held board: the operator presses Enter once per presentation, as the
  hand stops (uniform from 0.3 s before the hold to 0.5 s into it); the pair at that instant is kept if
  both views show the whole board;
- **static**: the same poses rendered perfectly still (the simulated bench as it presents boards today).

Each set is calibrated (joint stereo calibration); printed: views kept and rejected (by reason), stereo and
mono RMS, |T| error against the rig's truth, bench time to collect. Writes JSON.

    .venv/bin/python scripts/bench_autocapture.py [--seeds 3] [--views 24] [--fps 10] [--out bench_autocapture.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sim.bench import BenchSimulator  # noqa: E402
from drivers.sim.hand import HandPresentation  # noqa: E402
from drivers.sim.mechanics import pair_state  # noqa: E402
from drivers.sim.profile import LAB  # noqa: E402
from drivers.sim.render import StereoRenderer, calibration_board_poses  # noqa: E402
from stereo_bench.campaign.autocapture import AutoCaptureRule, ViewSelector  # noqa: E402
from stereo_bench.geometry import RigPose, invert_transform  # noqa: E402
from stereo_bench.targets import Checkerboard  # noqa: E402
from stereo_bench.vision.calibrate import calibrate_stereo  # noqa: E402
from stereo_bench.vision.detect import detect  # noqa: E402

BOARD = Checkerboard(11, 8, 25.0)
BASELINE_MM = 100.0
EXPOSURE_S = 1.0 / 60.0  # a USB camera indoors

RESULTS = Path(__file__).resolve().parent / "results"  # where the latest run of each benchmark is kept


class Scene:
    """The lab bench's cameras at B 100 mm and the hand's board, rendered at any bench time."""

    def __init__(self, seed: int):
        bench = BenchSimulator(profile=LAB, seed=seed)  # not started: its optics, lenses and profile only
        self.left, self.right = bench.left_model, bench.right_model
        self.state = pair_state(LAB, {"baseline_mm": BASELINE_MM, "toe_in_left_deg": 0.0, "toe_in_right_deg": 0.0})
        self.renderer = StereoRenderer(BOARD, self.left, self.right, optics=bench.optics)
        self.T_cam_bench = {"left": invert_transform(self.state.T_bench_left),
                            "right": invert_transform(self.state.T_bench_right)}
        self.true_baseline_mm = float(np.linalg.norm(self.state.T_bench_left[:3, 3] - self.state.T_bench_right[:3, 3]))

    def _centre_px(self, side: str, T_rig_board: np.ndarray) -> np.ndarray:
        camera = self.left if side == "left" else self.right
        centre = (self.T_cam_bench[side] @ T_rig_board @ np.array([*(np.array(BOARD.grid_size_mm) / 2), 0.0, 1.0]))[:3]
        return (np.asarray(camera.K) @ (centre / centre[2]))[:2]

    def pair(self, pose_at, t_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Both frames exposed around ``t_s``: the board at mid-exposure, smeared by its image motion."""
        images = []
        for k, side in enumerate(("left", "right")):
            before, after = pose_at(t_s - EXPOSURE_S / 2), pose_at(t_s + EXPOSURE_S / 2)
            smear = self._centre_px(side, after) - self._centre_px(side, before)
            rng = np.random.default_rng([seed, int(round(t_s * 1e6)), k])
            view = self.renderer.render_view(side, self.T_cam_bench[side] @ pose_at(t_s), rng,
                                             smear_px=(float(smear[0]), float(smear[1])),
                                             velocity_px_s=(float(smear[0] / EXPOSURE_S), float(smear[1] / EXPOSURE_S)))
            images.append(view.image)
        return images[0], images[1]


def _whole(d) -> bool:
    return d is not None and d.n == len(BOARD.object_points)


def calibrate(views: list[tuple], size: tuple[int, int], true_baseline_mm: float) -> dict:
    if len(views) < 5:
        return {"views": len(views), "failed": "fewer than 5 views"}
    objects = [np.asarray(BOARD.object_points, np.float64)[left.ids] for left, _ in views]
    lefts = [left.corners_px for left, _ in views]
    rights = [right.corners_px[np.argsort(right.ids)][left.ids] for left, right in views]
    try:
        stereo = calibrate_stereo(objects, lefts, rights, size, covariance=False)
    except Exception as error:  # a failed calibration is a result here, not a crash of the benchmark
        return {"views": len(views), "failed": str(error)}
    return {"views": len(views), "views_used": len(stereo.views_used), "stereo_rms_px": round(stereo.rms_px, 4),
            "baseline_error_mm": round(stereo.baseline_mm - true_baseline_mm, 4)}


def run_seed(seed: int, n_views: int, fps: float, rule: AutoCaptureRule) -> dict:
    scene = Scene(seed)
    size = scene.left.image_size
    poses = calibration_board_poses(RigPose.symmetric(BASELINE_MM, 90.0), BOARD, n_views=n_views,
                                    rng=np.random.default_rng(seed), left=scene.left, right=scene.right)
    hand = HandPresentation(poses, seed=seed, board_width_mm=BOARD.grid_size_mm[0])
    out = {"seed": seed, "presentations": n_views, "hand_s": round(hand.duration_s, 2)}

    # auto: every frame offered
    selector = ViewSelector(rule, BOARD, size)
    kept: list[tuple] = []
    t, frames = 1.0 / fps, 0
    while t < hand.duration_s and not selector.gate_open()[0]:
        left_image, right_image = scene.pair(hand.pose_at, t, seed)
        left, right = detect(left_image, BOARD, noise=False), detect(right_image, BOARD, noise=False)
        frames += 1
        if selector.offer(t, left, right).kept:
            kept.append((left, right))
        t += 1.0 / fps
    out["auto"] = {"frames": frames, "collect_s": round(t, 2), "tally": selector.tally(),
                   "gate": selector.gate_open()[1], **calibrate(kept, size, scene.true_baseline_mm),
                   "kept_while_moving": sum(hand.still_at(d.time_s) is None for d in selector.decisions if d.kept)}

    # enter: one press per presentation as the hand stops
    rng = np.random.default_rng([seed, 99])
    pressed, rejected, moving = [], 0, 0
    for start, _, _ in hand.holds:
        t_press = start + float(rng.uniform(-0.3, 0.5))
        left_image, right_image = scene.pair(hand.pose_at, t_press, seed)
        left, right = detect(left_image, BOARD, noise=False), detect(right_image, BOARD, noise=False)
        moving += hand.still_at(t_press) is None
        if _whole(left) and _whole(right):
            pressed.append((left, right))
        else:
            rejected += 1
    out["enter"] = {"presses": len(hand.holds), "not_in_both_views": rejected, "pressed_while_moving": moving,
                    "collect_s": round(hand.duration_s, 2), **calibrate(pressed, size, scene.true_baseline_mm)}

    # static: the poses exactly, no hand
    still = []
    for index, pose in enumerate(poses):
        left_image, right_image = scene.pair(lambda _t, pose=pose: pose, 1000.0 + index, seed)
        left, right = detect(left_image, BOARD, noise=False), detect(right_image, BOARD, noise=False)
        if _whole(left) and _whole(right):
            still.append((left, right))
    out["static"] = calibrate(still, size, scene.true_baseline_mm)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--views", type=int, default=24, help="presentations the hand makes")
    parser.add_argument("--fps", type=float, default=10.0, help="the cameras' stream on the bench clock")
    parser.add_argument("--min-views", type=int, default=12)
    parser.add_argument("--out", default=str(RESULTS / "bench_autocapture.json"))
    args = parser.parse_args()
    rule = AutoCaptureRule(min_views=args.min_views)
    started = time.perf_counter()
    rows = []
    print(f"{'seed':>4} {'method':>6} {'frames':>6} {'kept':>4} {'rejected (why)':48s} {'RMS px':>7} "
          f"{'|T| err mm':>10} {'bench s':>7}")
    for seed in range(args.seeds):
        row = run_seed(seed, args.views, args.fps, rule)
        rows.append(row)
        a, e, s = row["auto"], row["enter"], row["static"]
        why = ", ".join(f"{k} {v}" for k, v in a["tally"].items() if k != "kept" and v)
        print(f"{seed:4d} {'auto':>6} {a['frames']:6d} {a.get('views', 0):4d} {why:48s} "
              f"{a.get('stereo_rms_px', float('nan')):7.3f} {a.get('baseline_error_mm', float('nan')):10.4f} "
              f"{a['collect_s']:7.1f}")
        why = f"not in both views {e['not_in_both_views']}, pressed while moving {e['pressed_while_moving']}"
        print(f"{seed:4d} {'enter':>6} {e['presses']:6d} {e.get('views', 0):4d} {why:48s} "
              f"{e.get('stereo_rms_px', float('nan')):7.3f} {e.get('baseline_error_mm', float('nan')):10.4f} "
              f"{e['collect_s']:7.1f}")
        print(f"{seed:4d} {'static':>6} {args.views:6d} {s.get('views', 0):4d} {'':48s} "
              f"{s.get('stereo_rms_px', float('nan')):7.3f} {s.get('baseline_error_mm', float('nan')):10.4f}")
    Path(args.out).write_text(json.dumps({
        "benchmark": "bench_autocapture", "views": args.views, "fps": args.fps, "rule": rule.__dict__,
        "rows": rows, "total_s": round(time.perf_counter() - started, 1), "load_average": os.getloadavg(),
        "cpu_count": os.cpu_count(), "python": platform.python_version()}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
