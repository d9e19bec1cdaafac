"""A synthetic stereo bench without images: exact projections of boards plus seeded corner noise.

Calibration views are placed as the simulated campaign places them (drivers.sim.render's
``calibration_board_poses``, the presenter's distance range); the measured board faces the rig at Z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.sim.render import calibration_board_poses
from stereo_bench.errormodel.rigorous import Setup, visible_corners
from stereo_bench.geometry import CameraModel, RigPose, invert_transform, transform_points
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import StereoCalibration, calibrate_stereo
from stereo_bench.vision.measure import measure_square
from stereo_bench.vision.uncertainty import FrameCorners

CALIBRATION_BOARD = Checkerboard(11, 8, 25.0)  # the campaign's default calibration board
TARGET = Checkerboard(9, 6, 27.0)
CAMERA = CameraModel.from_sensor()


@dataclass(frozen=True)
class Configuration:
    baseline_mm: float
    distance_mm: float
    alpha_deg: float

    @property
    def rig(self) -> RigPose:
        return RigPose.symmetric(self.baseline_mm, self.alpha_deg)

    @property
    def setup(self) -> Setup:
        return Setup.make(self.baseline_mm, self.distance_mm, self.alpha_deg, board=TARGET)


def project_pair(rig: RigPose, T_rig_board: np.ndarray, points_board: np.ndarray, rng: np.random.Generator,
                 noise_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(left (N, 2), right (N, 2)) pixels of board points, plus Gaussian noise per coordinate."""
    out = []
    for T_rig_cam in (rig.T_rig_left, rig.T_rig_right):
        pixels, _ = CAMERA.project(transform_points(invert_transform(T_rig_cam) @ T_rig_board, points_board))
        out.append(pixels + rng.normal(0.0, noise_px, pixels.shape) if noise_px else pixels)
    return out[0], out[1]


def calibrate(config: Configuration, rng: np.random.Generator, *, noise_px: float, n_views: int = 12,
              mode: str = "joint") -> StereoCalibration:
    """Stereo calibration from ``n_views`` noisy views of the calibration board at this configuration."""
    z = config.distance_mm
    poses = calibration_board_poses(config.rig, CALIBRATION_BOARD, n_views=n_views, rng=rng,
                                    distance_mm=(max(250.0, 0.6 * z), 1.3 * z))
    points = np.asarray(CALIBRATION_BOARD.object_points, float)
    views = [project_pair(config.rig, pose, points, rng, noise_px) for pose in poses]
    return calibrate_stereo([CALIBRATION_BOARD.object_points] * len(views), [v[0] for v in views],
                            [v[1] for v in views], CAMERA.image_size, mode=mode)


def measurement_frames(config: Configuration, calib: StereoCalibration, rng: np.random.Generator, *, noise_px: float,
                       n_frames: int) -> list[FrameCorners]:
    """Frames of the target facing the rig at Z, measured with ``calib`` (noise propagated as the pipeline does)."""
    setup = config.setup
    ids, _ = visible_corners(setup)
    points = np.asarray(TARGET.object_points, float)[ids]
    frames = []
    for _ in range(n_frames):
        left, right = project_pair(config.rig, setup.T_rig_board, points, rng, noise_px)
        square = measure_square(calib, TARGET, ids, left, right, pixel_sigma_px=noise_px)
        frames.append(FrameCorners(ids, left, right, square.sigma_mean_mm, (noise_px, noise_px)))
    return frames
