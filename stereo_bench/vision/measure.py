"""The square measurement: 3-D lengths of adjacent corner pairs, their statistics and propagated sigma."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from stereo_bench.targets import Target
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.rectify import undistort_points
from stereo_bench.vision.triangulate import triangulate, triangulation_jacobian


@dataclass(frozen=True)
class SquareMeasurement:
    """Lengths (mm) of every horizontally and vertically adjacent corner pair seen in both views.

    ``sigma_mean_mm`` is the first-order standard deviation of ``mean_mm`` propagated from the corner
    noise (``pixel_sigma_px`` per image coordinate, left and right) through the triangulation.
    """

    nominal_mm: float
    lengths_mm: np.ndarray  # (M,)
    pairs: np.ndarray  # (M, 2) corner ids
    ids: np.ndarray  # (N,) corner ids triangulated
    points_mm: np.ndarray  # (N, 3) left camera frame
    pixel_sigma_px: tuple[float, float]  # (left, right) RMS over the corners of the per-coordinate noise
    sigma_mean_mm: float
    sigma_length_mm: np.ndarray  # (M,) first-order sigma of each length
    # (N, 3, 4) d(points_mm)/d(u_left, v_left, u_right, v_right) (triangulation_jacobian) and the calibration
    # both were computed with: an uncertainty budget with that very calibration reads them instead of
    # triangulating the corners again. None for a measurement made otherwise.
    jacobian: np.ndarray | None = field(default=None, repr=False)
    calib: StereoCalibration | None = field(default=None, repr=False)

    @property
    def n(self) -> int:
        return int(len(self.lengths_mm))

    @property
    def mean_mm(self) -> float:
        return float(np.mean(self.lengths_mm)) if self.n else float("nan")

    @property
    def std_mm(self) -> float:
        return float(np.std(self.lengths_mm, ddof=1)) if self.n > 1 else float("nan")

    @property
    def error_mm(self) -> float:
        return self.mean_mm - self.nominal_mm

    @property
    def depth_mm(self) -> float:
        """Mean Z of the triangulated corners in the left camera frame."""
        return float(np.mean(self.points_mm[:, 2])) if len(self.points_mm) else float("nan")

    def summary(self) -> dict:
        return {
            "mean": self.mean_mm, "std": self.std_mm, "n": self.n, "sigma_mean": self.sigma_mean_mm,
        }


def planar_fit_rms_px(
    object_points: np.ndarray, image_px: np.ndarray, K: np.ndarray, D: np.ndarray
) -> float:
    """Per-coordinate RMS (px) of the corners about the best homography of the board plane.

    The undistorted corners of a flat board are related to its plane coordinates by a homography;
    what it cannot explain is corner noise plus systematic error (lens-model misfit, a bent print,
    detector bias). sigma^2 = SSR / (2N - 8). An upper bound on the random corner noise and a
    quality figure in its own right.
    """
    n = len(image_px)
    if n < 6:
        return float("nan")
    ideal_px = undistort_points(image_px, K, D, P=K)
    H, _ = cv2.findHomography(object_points[:, :2].astype(np.float64), ideal_px, 0)
    if H is None:
        return float("nan")
    mapped = cv2.perspectiveTransform(object_points[:, :2].reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    ssr = float(np.sum((mapped - ideal_px) ** 2))
    return float(np.sqrt(ssr / (2 * n - 8)))


def measure_square(
    calib: StereoCalibration, target: Target, ids: np.ndarray, left_px: np.ndarray, right_px: np.ndarray, *,
    pixel_sigma_px: tuple[np.ndarray | float, np.ndarray | float] | float | None = None,
) -> SquareMeasurement:
    """Triangulate matched corners and measure every adjacent pair among them.

    Args:
        ids: (N,) corner ids seen in both views, ``left_px``/``right_px`` (N, 2) their raw pixels.
        pixel_sigma_px: random corner noise per image coordinate: one value, or (left, right) each a
            value or (N,) per corner. None falls back on the planar-fit RMS of each view, which
            includes systematic error and so overstates the random part.
    """
    ids = np.asarray(ids)
    points = triangulate(calib, left_px, right_px)
    if pixel_sigma_px is None:
        pixel_sigma_px = (
            planar_fit_rms_px(target.object_points[ids], left_px, calib.K1, calib.D1),
            planar_fit_rms_px(target.object_points[ids], right_px, calib.K2, calib.D2),
        )
    elif np.isscalar(pixel_sigma_px):
        pixel_sigma_px = (pixel_sigma_px, pixel_sigma_px)
    sigma_left = np.broadcast_to(np.asarray(pixel_sigma_px[0], float), (len(ids),))
    sigma_right = np.broadcast_to(np.asarray(pixel_sigma_px[1], float), (len(ids),))
    # (N, 4) variance of (u_left, v_left, u_right, v_right) per corner.
    pixel_var = np.column_stack([sigma_left**2, sigma_left**2, sigma_right**2, sigma_right**2])

    position = {corner_id: i for i, corner_id in enumerate(ids.tolist())}
    pairs = np.array([p for p in target.adjacent_pairs() if p[0] in position and p[1] in position], int).reshape(-1, 2)
    a = np.array([position[i] for i in pairs[:, 0]], int)
    b = np.array([position[i] for i in pairs[:, 1]], int)
    vectors = points[a] - points[b]
    lengths = np.linalg.norm(vectors, axis=1)

    # First-order propagation: d(length_k) = u_k . (dX_a - dX_b), dX_i = J_i d(pixels_i).
    jac = triangulation_jacobian(calib, left_px, right_px)  # (N, 3, 4)
    units = vectors / np.maximum(lengths, 1e-12)[:, None]
    # Gradient of each length w.r.t. each corner's four pixel coordinates.
    grad_a = np.einsum("kj,kjc->kc", units, jac[a])
    grad_b = -np.einsum("kj,kjc->kc", units, jac[b])
    sigma_length = np.sqrt(np.sum(grad_a**2 * pixel_var[a], axis=1) + np.sum(grad_b**2 * pixel_var[b], axis=1))
    # The mean shares corners between lengths: accumulate per corner before squaring.
    grad_mean = np.zeros((len(ids), 4))
    if len(pairs):
        np.add.at(grad_mean, a, grad_a / len(pairs))
        np.add.at(grad_mean, b, grad_b / len(pairs))
    sigma_mean = float(np.sqrt(np.sum(grad_mean**2 * pixel_var))) if len(pairs) else float("nan")

    return SquareMeasurement(
        nominal_mm=float(target.square_mm), lengths_mm=lengths, pairs=pairs, ids=ids, points_mm=points,
        pixel_sigma_px=(float(np.sqrt(np.mean(sigma_left**2))), float(np.sqrt(np.mean(sigma_right**2)))),
        sigma_mean_mm=sigma_mean, sigma_length_mm=sigma_length, jacobian=jac, calib=calib,
    )
