"""Rig geometry conventions: the one place that says where the cameras are.

Conventions (see docs/ARCHITECTURE.md and the project brief):

- Units: millimetres and degrees at every interface; radians only inside functions.
- Rig frame: origin midway between the optical centres, x along the baseline from the left
  camera to the right one, y down, z forward toward the target.
- Left optical centre at (-B/2, 0, 0), right at (+B/2, 0, 0).
- alpha: angle in the x-z plane between the baseline and a camera's optical axis, on the target
  side; 90 deg is a parallel rig. Toe-in t = 90 - alpha (0 = parallel, > 0 turns inward).
  Left optical axis (cos a, 0, sin a); right (-cos a, 0, sin a).
- Tilt tau: rotation of a camera about its own x axis after the pan; tau > 0 turns the optical axis
  down (toward +y).
- Camera frames are OpenCV's. ``T_a_b`` is a 4x4 homogeneous transform mapping b-coordinates to a.
  Stereo extrinsics follow cv2.stereoCalibrate: X_right = R @ X_left + T.

This module is a leaf: numpy and OpenCV only, so both the measurement code and the simulators
(drivers/sim) use the same conventions without depending on anything else.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

PARALLEL_ALPHA_DEG = 90.0

# The default camera, the one definition the campaign config (OpticsConfig), the error model and the
# simulators take: 1920x1080, a 4 mm lens on 3 um pixels (f = 1333.3 px), mild barrel distortion.
DEFAULT_FOCAL_MM = 4.0
DEFAULT_PIXEL_UM = 3.0
DEFAULT_IMAGE_SIZE = (1920, 1080)
DEFAULT_DIST = (-0.05, 0.02, 0.0, 0.0, 0.0)


def toe_in_from_alpha(alpha_deg: float) -> float:
    """Toe-in angle (deg, 0 = parallel) of a camera whose optical axis makes ``alpha_deg`` with the baseline."""
    return PARALLEL_ALPHA_DEG - alpha_deg


def alpha_from_toe_in(toe_in_deg: float) -> float:
    """Inverse of :func:`toe_in_from_alpha`."""
    return PARALLEL_ALPHA_DEG - toe_in_deg


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert_transform(T_a_b: np.ndarray) -> np.ndarray:
    """T_b_a from T_a_b (rigid transforms only)."""
    R = T_a_b[:3, :3]
    t = T_a_b[:3, 3]
    return make_transform(R.T, -R.T @ t)


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map (N, 3) points from frame b to frame a."""
    points_b = np.asarray(points_b, dtype=float).reshape(-1, 3)
    return points_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def _rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_deg(axis: str, angle_deg: float) -> np.ndarray:
    """(3, 3) right-handed rotation by ``angle_deg`` about the frame's ``axis`` ("x", "y" or "z")."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    if axis == "x":
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == "y":
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    if axis == "z":
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    raise ValueError(f"axis must be 'x', 'y' or 'z', not {axis!r}")


@dataclass(frozen=True)
class RigPose:
    """Where the two cameras of the rig stand, as set by the slide and the pan-tilt heads."""

    baseline_mm: float
    alpha_left_deg: float = PARALLEL_ALPHA_DEG
    alpha_right_deg: float = PARALLEL_ALPHA_DEG
    tilt_left_deg: float = 0.0
    tilt_right_deg: float = 0.0

    @classmethod
    def symmetric(cls, baseline_mm: float, alpha_deg: float = PARALLEL_ALPHA_DEG, tilt_deg: float = 0.0):
        return cls(baseline_mm, alpha_deg, alpha_deg, tilt_deg, tilt_deg)

    @property
    def toe_in_left_deg(self) -> float:
        return toe_in_from_alpha(self.alpha_left_deg)

    @property
    def toe_in_right_deg(self) -> float:
        return toe_in_from_alpha(self.alpha_right_deg)

    @property
    def T_rig_left(self) -> np.ndarray:
        return self._T_rig_cameras[0].copy()  # a copy: the pose is immutable, a caller may not be

    @property
    def T_rig_right(self) -> np.ndarray:
        return self._T_rig_cameras[1].copy()

    @cached_property
    def T_cameras_rig(self) -> tuple[np.ndarray, np.ndarray]:
        """(T_left_rig, T_right_rig): the inverse camera poses, computed once per pose (read-only arrays)."""
        inverses = tuple(invert_transform(T) for T in self._T_rig_cameras)
        for T in inverses:
            T.flags.writeable = False
        return inverses

    @cached_property
    def _T_rig_cameras(self) -> tuple[np.ndarray, np.ndarray]:
        # Computed once per pose: a plan asks each pose for them several times (a 10,000-configuration plan).
        return (camera_pose_in_rig(baseline_mm=self.baseline_mm, side="left", toe_in_deg=self.toe_in_left_deg,
                                   tilt_deg=self.tilt_left_deg),
                camera_pose_in_rig(baseline_mm=self.baseline_mm, side="right", toe_in_deg=self.toe_in_right_deg,
                                   tilt_deg=self.tilt_right_deg))

    def stereo_extrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        """(R (3, 3), T (3,) mm) with X_right = R @ X_left + T, as cv2.stereoCalibrate returns them."""
        T_right_left = invert_transform(self.T_rig_right) @ self.T_rig_left
        return T_right_left[:3, :3].copy(), T_right_left[:3, 3].copy()


def stereo_structure(R: np.ndarray, T: np.ndarray) -> dict[str, float]:
    """The rig structure a pair of extrinsics (X_right = R @ X_left + T, T in mm) describes.

    Returns ``baseline_mm`` (the optical baseline |T|), ``alpha_left_deg`` (angle between the baseline,
    from the left optical centre to the right one, and the left optical axis), ``alpha_right_deg``
    (between the baseline from the right centre to the left one and the right optical axis) and
    ``rotation_deg`` (the angle of R). For a pose of :class:`RigPose` these are its B and alphas
    (alpha 90 = parallel), whatever the tilt; angles are 3-D, so a camera that also looks up or down
    counts that too.
    """
    R = np.asarray(R, dtype=float).reshape(3, 3)
    T = np.asarray(T, dtype=float).reshape(3)
    baseline = float(np.linalg.norm(T))
    if baseline == 0.0:
        raise ValueError("T is zero: the two optical centres coincide, there is no baseline")
    right_in_left = -R.T @ T  # the right optical centre in left-camera coordinates
    rvec, _ = cv2.Rodrigues(R)
    return {
        "baseline_mm": baseline,
        "alpha_left_deg": float(np.degrees(np.arccos(np.clip(right_in_left[2] / baseline, -1.0, 1.0)))),
        "alpha_right_deg": float(np.degrees(np.arccos(np.clip(T[2] / baseline, -1.0, 1.0)))),
        "rotation_deg": float(np.degrees(np.linalg.norm(rvec))),
    }


def camera_pose_in_rig(*, baseline_mm: float, side: str, toe_in_deg: float, tilt_deg: float = 0.0) -> np.ndarray:
    """T_rig_cam (4x4, mm): camera frame -> rig frame for the ``side`` ('left' or 'right') camera.

    The pan turns the camera about the rig's y axis so that a positive toe-in points it toward the
    other camera's side; the tilt then turns it about its own x axis (positive: optical axis down).
    """
    if side not in ("left", "right"):
        raise ValueError(f"side must be 'left' or 'right', not {side!r}")
    sign = 1.0 if side == "left" else -1.0
    pan_rad = sign * np.radians(toe_in_deg)
    # R_x(-tau) sends the camera's z axis to (0, sin tau, cos tau): down for tau > 0.
    R_rig_cam = _rot_y(pan_rad) @ _rot_x(-np.radians(tilt_deg))
    centre = np.array([-sign * baseline_mm / 2.0, 0.0, 0.0])
    return make_transform(R_rig_cam, centre)


def board_pose_facing_rig(
    *, distance_mm: float, board_size_mm: tuple[float, float], centre_offset_mm: tuple[float, float] = (0.0, 0.0),
    yaw_deg: float = 0.0, pitch_deg: float = 0.0,
) -> np.ndarray:
    """T_rig_board (4x4) for a board whose inner-corner grid is centred on the rig z axis at ``distance_mm``.

    The board frame is the one OpenCV's calibration uses for object points: origin at the first inner
    corner, x along a row, y down the columns, z into the board (away from the cameras). With no yaw
    or pitch the board plane is parallel to the baseline and faces the rig.

    Args:
        board_size_mm: (width, height) of the inner-corner grid, i.e. ((cols-1)*s, (rows-1)*s).
        centre_offset_mm: (x, y) of the grid centre in the rig frame.
        yaw_deg, pitch_deg: rotation of the board about its centre (rig y, then board x).
    """
    width_mm, height_mm = board_size_mm
    R = _rot_y(np.radians(yaw_deg)) @ _rot_x(np.radians(pitch_deg))
    centre = np.array([centre_offset_mm[0], centre_offset_mm[1], distance_mm])
    origin = centre - R @ np.array([width_mm / 2.0, height_mm / 2.0, 0.0])
    return make_transform(R, origin)


def mean_view_frame(T_rig_left: np.ndarray, T_rig_right: np.ndarray) -> np.ndarray:
    """(3, 3) R_rig_view: the rig's mean viewing frame, z along the sum of the two optical axes, x along the
    baseline (the rig's x made perpendicular to z), y = z x x. Columns are the view axes in the rig frame."""
    z_axis = T_rig_left[:3, 2] + T_rig_right[:3, 2]
    z_axis = z_axis / np.linalg.norm(z_axis)
    x_axis = np.array([1.0, 0.0, 0.0]) - z_axis[0] * z_axis
    x_axis /= np.linalg.norm(x_axis)
    return np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis])


def board_pose_in_view(
    R_rig_view: np.ndarray, grid_centre: np.ndarray, distance_mm: float, offset: tuple[float, float] | np.ndarray,
    yaw_deg: float, pitch_deg: float, roll_deg: float,
) -> np.ndarray:
    """T_rig_board (4x4, mm) of a board whose grid centre ``grid_centre`` (3,) (board frame, mm) sits at
    ``distance_mm`` along the view direction (offset[0], offset[1], 1) of :func:`mean_view_frame`
    ``R_rig_view``, facing the rig origin and then turned about its own y, x, z axes (degrees, in that order).

    ``offset`` may also be (N, 2): then (N, 4, 4), one pose per offset (a search along a direction in one call).
    """
    offsets = np.asarray(offset, dtype=np.float64)
    single = offsets.ndim == 1
    offsets = offsets.reshape(-1, 2)
    x_axis = R_rig_view[:, 0]
    directions = np.column_stack([offsets, np.ones(len(offsets))])
    centres = distance_mm * (directions @ R_rig_view.T)  # (N, 3)
    normals = centres / np.linalg.norm(centres, axis=1, keepdims=True)
    bx = x_axis - (normals @ x_axis)[:, None] * normals
    bx /= np.linalg.norm(bx, axis=1, keepdims=True)
    R_face = np.stack([bx, np.cross(normals, bx), normals], axis=2)  # columns bx, normal x bx, normal
    R = R_face @ (rotation_deg("y", yaw_deg) @ rotation_deg("x", pitch_deg) @ rotation_deg("z", roll_deg))
    T = np.zeros((len(offsets), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = centres - R @ np.asarray(grid_centre, dtype=np.float64)
    T[:, 3, 3] = 1.0
    return T[0] if single else T


def _coefficients(dist) -> tuple[float, ...]:
    if isinstance(dist, tuple) and len(dist) == 12:
        return dist
    values = [float(v) for v in np.asarray(dist, dtype=float).ravel()]
    return tuple(values + [0.0] * (12 - len(values)))


def distort_normalised(normalised: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of (N, 2) normalised image coordinates through OpenCV's distortion model (k1 k2 p1 p2
    [k3 [k4 k5 k6 [s1 s2 s3 s4]]]) and ``K`` (fx, fy, cx, cy): what ``cv2.projectPoints`` computes, ~20x faster
    on small point sets (it always computes its Jacobians); tests/test_plan_checks.py holds them to 1e-9 px."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = _coefficients(dist)
    x, y = normalised[:, 0], normalised[:, 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    radial = 1.0 + k1 * r2 + k2 * r4 + k3 * (r4 * r2)
    if k4 or k5 or k6:  # the rational model
        radial = radial / (1.0 + k4 * r2 + k5 * r4 + k6 * (r4 * r2))
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    if s1 or s2 or s3 or s4:  # thin prism
        xd = xd + s1 * r2 + s2 * r4
        yd = yd + s3 * r2 + s4 * r4
    pixels = np.empty_like(normalised)
    pixels[:, 0] = K[0, 0] * xd + K[0, 2]
    pixels[:, 1] = K[1, 1] * yd + K[1, 2]
    return pixels


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Pinhole + OpenCV distortion camera. ``K`` (3, 3) px, ``dist`` (5,) or longer, ``image_size`` (w, h) px.

    Equal (and hashed alike) when K, dist and image size are; the name is a label only.
    """

    K: np.ndarray
    dist: np.ndarray
    image_size: tuple[int, int]
    name: str = field(default="camera")

    def _key(self) -> tuple:
        return (np.asarray(self.K, float).tobytes(), np.asarray(self.dist, float).ravel().tobytes(),
                tuple(int(v) for v in self.image_size))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, CameraModel) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    @classmethod
    def from_sensor(
        cls, *, focal_mm: float = DEFAULT_FOCAL_MM, pixel_um: float = DEFAULT_PIXEL_UM,
        image_size: tuple[int, int] = DEFAULT_IMAGE_SIZE, dist: tuple[float, ...] = DEFAULT_DIST, name: str = "camera",
    ) -> CameraModel:
        """A camera from its lens and sensor: f_px = focal / pixel pitch, principal point at the centre."""
        f_px = focal_mm * 1000.0 / pixel_um
        w, h = image_size
        K = np.array([[f_px, 0.0, (w - 1) / 2.0], [0.0, f_px, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(K=K, dist=np.asarray(dist, dtype=float), image_size=(int(w), int(h)), name=name)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @cached_property
    def _trusted_radius(self) -> float:
        # The radial polynomial folds back beyond the lens's field of view; only trust it up to a
        # margin past the image corners.
        w, h = self.image_size
        corner_norm = np.abs(np.array([[-0.5, -0.5], [w - 0.5, h - 0.5]]) - self.K[:2, 2]) / np.diag(self.K)[:2]
        return 1.25 * float(np.hypot(*corner_norm.max(axis=0)))

    @cached_property
    def _dist_12(self) -> tuple[float, ...] | None:
        """The distortion as 12 floats for :func:`distort_normalised`; None for the tilted-sensor model."""
        dist = np.asarray(self.dist, dtype=float).ravel()
        return _coefficients(dist) if len(dist) in (4, 5, 8, 12) else None

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) camera-frame points (mm) to (N, 2) pixels.

        Returns (pixels, valid) where ``valid`` (N,) is False for points behind the camera or so far
        outside the field of view that the distortion polynomial is meaningless there.
        """
        points_cam = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        z = points_cam[:, 2]
        in_front = z > 1e-6
        safe_z = np.where(in_front, z, 1.0)
        normalised = points_cam[:, :2] / safe_z[:, None]
        sane = in_front & (np.hypot(normalised[:, 0], normalised[:, 1]) < self._trusted_radius)
        if self._dist_12 is not None:
            return distort_normalised(normalised, self.K, self._dist_12), sane
        pixels, _ = cv2.projectPoints(  # the tilted-sensor model (14 coefficients): OpenCV's own
            np.column_stack([normalised, np.ones(len(normalised))]).reshape(-1, 1, 3),
            np.zeros(3), np.zeros(3), self.K, self.dist,
        )
        return pixels.reshape(-1, 2), sane

    def in_image(self, pixels: np.ndarray, *, margin_px: float = 0.0) -> np.ndarray:
        """(N,) bool: pixel lies inside the image, at least ``margin_px`` from its border."""
        w, h = self.image_size
        u, v = pixels[:, 0], pixels[:, 1]
        return (u >= margin_px - 0.5) & (u <= w - 0.5 - margin_px) & (v >= margin_px - 0.5) & (v <= h - 0.5 - margin_px)


VIEW_MARGIN_PX = 10.0  # a corner closer than this to the image border counts as not seen


def board_faces_camera(T_cam_board: np.ndarray) -> bool:
    """The camera is on the board's printed side (board z points into the board, away from the viewer)."""
    return float(T_cam_board[:3, 2] @ T_cam_board[:3, 3]) > 0.0


def visible_in_view(
    points_rig: np.ndarray, camera: CameraModel, T_rig_cam: np.ndarray, *, margin_px: float = VIEW_MARGIN_PX,
) -> np.ndarray:
    """(N,) bool: which rig-frame points (N, 3) one camera sees at least ``margin_px`` inside its image."""
    pixels, valid = camera.project(transform_points(invert_transform(T_rig_cam), points_rig))
    return valid & camera.in_image(pixels, margin_px=margin_px)


def visible_in_both(
    points_rig: np.ndarray, *, rig: RigPose, left: CameraModel, right: CameraModel,
    margin_px: float = VIEW_MARGIN_PX,
) -> np.ndarray:
    """(N,) bool: which rig-frame points (N, 3) project inside both images (``margin_px`` from the border).

    This is the geometric prediction of how much of a target a configuration shows both cameras,
    made before anything moves.
    """
    return (visible_in_view(points_rig, left, rig.T_rig_left, margin_px=margin_px)
            & visible_in_view(points_rig, right, rig.T_rig_right, margin_px=margin_px))


# -- the calibration-fit rule ---------------------------------------------------------------------
# One definition of "this pose of the calibration board is a usable calibration view", used by the
# plan (does such a pose exist at this configuration?), the simulator's board poses and the presenter.
CALIBRATION_MARGIN_PX = 20.0  # a calibration corner this far inside both images: room for cornerSubPix
CALIBRATION_MAX_OBLIQUITY_DEG = 60.0  # a board turned further from a camera's line of sight is too foreshortened
CALIBRATION_OUTLINE_POINTS_PER_SIDE = 8


def calibration_outline(board) -> np.ndarray:
    """(32, 3) board-frame points around the outer squares (one square beyond the inner corners, 8 per side).

    A chessboard detector needs the outer squares of a whole board in view, not only its inner corners.
    ``board`` has ``grid_size_mm`` and ``square_mm`` (``stereo_bench.targets`` boards).
    """
    return _calibration_outline(tuple(board.grid_size_mm), float(board.square_mm)).copy()


@functools.lru_cache(maxsize=64)
def _calibration_outline(grid_size_mm: tuple[float, float], square_mm: float) -> np.ndarray:
    width_mm, height_mm = grid_size_mm
    sq = square_mm
    t = np.linspace(0.0, 1.0, CALIBRATION_OUTLINE_POINTS_PER_SIDE)
    x0, x1, y0, y1 = -sq, width_mm + sq, -sq, height_mm + sq
    outline = np.concatenate([
        np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y0)]),
        np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y1)]),
        np.column_stack([np.full_like(t, x0), y0 + (y1 - y0) * t]),
        np.column_stack([np.full_like(t, x1), y0 + (y1 - y0) * t]),
    ])
    return np.column_stack([outline, np.zeros(len(outline))])


def calibration_view_fits(
    board, T_rig_board: np.ndarray, *, rig: RigPose, left: CameraModel, right: CameraModel,
    margin_px: float = CALIBRATION_MARGIN_PX, max_obliquity_deg: float = CALIBRATION_MAX_OBLIQUITY_DEG,
    min_fraction: float | None = None,
) -> bool:
    """True when the calibration board at ``T_rig_board`` (4x4, mm) is a usable view for both cameras.

    Both cameras see its printed side, no more than ``max_obliquity_deg`` off their line of sight to
    its centre; at least ``min_fraction`` (default: the board's ``min_calibration_fraction``: 1 for a
    checkerboard, 0.5 for ChArUco) of its inner corners land ``margin_px`` inside both images, and a
    board needed whole shows its outer squares too (:func:`calibration_outline`).
    ``board``: a ``stereo_bench.targets`` board (object_points, grid_size_mm, square_mm).
    """
    return bool(calibration_views_fit(board, np.asarray(T_rig_board, dtype=float)[None], rig=rig, left=left,
                                      right=right, margin_px=margin_px, max_obliquity_deg=max_obliquity_deg,
                                      min_fraction=min_fraction)[0])


def calibration_views_fit(
    board, T_rig_boards: np.ndarray, *, rig: RigPose, left: CameraModel, right: CameraModel,
    margin_px: float = CALIBRATION_MARGIN_PX, max_obliquity_deg: float = CALIBRATION_MAX_OBLIQUITY_DEG,
    min_fraction: float | None = None,
) -> np.ndarray:
    """(K,) bool: :func:`calibration_view_fits` for K board poses ``T_rig_boards`` (K, 4, 4) at once (the one
    implementation of the rule; a plan asks it for many distances per rig pose)."""
    fraction = board.min_calibration_fraction if min_fraction is None else min_fraction
    points, n_corners, centre_board = _calibration_points(board, fraction >= 1.0)  # (P, 3) board frame
    cos_limit = math.cos(math.radians(max_obliquity_deg))
    T_rig_boards = np.asarray(T_rig_boards, dtype=np.float64).reshape(-1, 4, 4)
    K = len(T_rig_boards)
    ok = np.ones(K, dtype=bool)
    in_views = []
    for T_cam_rig in rig.T_cameras_rig:
        T_cam_boards = T_cam_rig @ T_rig_boards  # (K, 4, 4)
        R, t = T_cam_boards[:, :3, :3], T_cam_boards[:, :3, 3]
        normal = R[:, :, 2]
        ok &= (normal * t).sum(axis=1) > 0.0  # board_faces_camera
        centre_cam = R @ centre_board + t
        ok &= ~(np.abs((normal * centre_cam).sum(axis=1)) < cos_limit * np.linalg.norm(centre_cam, axis=1))
        in_views.append((points @ R.transpose(0, 2, 1) + t[:, None, :]).reshape(-1, 3))  # (K * P, 3)
    inside = [visible.reshape(K, -1) for visible in _in_images(in_views, (left, right), margin_px)]
    seen = inside[0][:, :n_corners] & inside[1][:, :n_corners]
    if fraction >= 1.0:
        ok &= inside[0][:, n_corners:].all(axis=1) & inside[1][:, n_corners:].all(axis=1)
    return ok & (seen.mean(axis=1) >= fraction - 1e-12)


@functools.lru_cache(maxsize=16)
def _calibration_points(board, with_outline: bool) -> tuple[np.ndarray, int, np.ndarray]:
    """(the board's inner corners [and outline], float64 (P, 3); the number of corners; the grid's centre)."""
    object_points = np.asarray(board.object_points, dtype=np.float64)
    outline = calibration_outline(board) if with_outline else np.zeros((0, 3))
    width_mm, height_mm = board.grid_size_mm
    points = np.vstack([object_points, outline])
    points.flags.writeable = False
    return points, len(object_points), np.array([width_mm / 2.0, height_mm / 2.0, 0.0])


def _in_images(points_cam: list[np.ndarray], cameras: tuple[CameraModel, ...], margin_px: float) -> list[np.ndarray]:
    """Per camera, (N_i,) bool: its camera-frame points (N_i, 3) land ``margin_px`` inside its image; cameras
    with the same intrinsics (the usual pair) project in one call."""
    if all(camera == cameras[0] for camera in cameras[1:]):
        pixels, valid = cameras[0].project(np.concatenate(points_cam))
        inside = valid & cameras[0].in_image(pixels, margin_px=margin_px)
        return np.split(inside, np.cumsum([len(p) for p in points_cam])[:-1])
    out = []
    for camera, points in zip(cameras, points_cam, strict=True):
        pixels, valid = camera.project(points)
        out.append(valid & camera.in_image(pixels, margin_px=margin_px))
    return out
