"""Annotated images of a configuration: detected corners, and the rectified pair with epipolar lines.

- :func:`corners_image`: the left and right measurement frames side by side with the target's
  corners drawn: green = seen in both views (these are triangulated), orange = in one view only; the
  first corner (id 0) is ringed, so the board's orientation is visible.
- :func:`rectified_image`: both frames remapped with the recorded calibration, zoomed onto the
  target (one scale and vertical shift for both views, so rows still correspond), side by side, with
  horizontal epipolar lines across both; the corners seen in both views are drawn at their rectified
  positions, each left/right pair in one colour — on a good calibration partners sit on one row.

Both return BGR uint8 images at most ``max_width_px`` wide (downscaled for the page).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from stereo_bench.targets import Target
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.detect import AmbiguousViewError, Detection, detect
from stereo_bench.vision.rectify import rectification_maps, rectify, undistort_points

GREEN = (60, 180, 60)
ORANGE = (0, 140, 255)
LINE = (255, 200, 0)
RED = (40, 40, 220)
DEFAULT_MAX_WIDTH_PX = 1400
GAP_PX = 8


@dataclass
class Detections:
    """The target found in a stereo pair (either may be None) and the ids seen in both."""

    left: Detection | None
    right: Detection | None
    common_ids: np.ndarray
    note: str = ""


def to_bgr(image: np.ndarray) -> np.ndarray:
    """A BGR uint8 copy of a grey, BGR or BGRA image (16-bit scaled down to 8)."""
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image.copy()


def detect_pair(left: np.ndarray, right: np.ndarray, target: Target, *, partial: bool) -> Detections:
    """Detect the target in both frames as the pipeline does (``partial`` for cut boards)."""
    found: list[Detection | None] = []
    notes = []
    for side, image in (("left", left), ("right", right)):
        try:
            detection = detect(image, target, partial=partial)
        except AmbiguousViewError as error:
            detection = None
            notes.append(f"{side}: {error}")
        if detection is None and not notes[-1:]:
            notes.append(f"target not found in the {side} frame")
        found.append(detection)
    if found[0] is not None and found[1] is not None:
        common = np.intersect1d(found[0].ids, found[1].ids)
    else:
        common = np.zeros(0, int)
    return Detections(found[0], found[1], common, "; ".join(notes))


def side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Two BGR images next to each other with a white gap (heights padded to the taller)."""
    height = max(left.shape[0], right.shape[0])

    def pad(image: np.ndarray) -> np.ndarray:
        return cv2.copyMakeBorder(image, 0, height - image.shape[0], 0, 0, cv2.BORDER_CONSTANT, value=(0, 0, 0))

    gap = np.full((height, GAP_PX, 3), 255, np.uint8)
    return np.hstack([pad(left), gap, pad(right)])


def downscale(image: np.ndarray, max_width_px: int = DEFAULT_MAX_WIDTH_PX) -> np.ndarray:
    """``image`` shrunk (area interpolation) to at most ``max_width_px`` wide; never enlarged."""
    if image.shape[1] <= max_width_px:
        return image
    scale = max_width_px / image.shape[1]
    size = (max_width_px, max(1, round(image.shape[0] * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def _marker_radius(image: np.ndarray) -> int:
    return max(3, round(image.shape[1] / 240))


def _draw_corners(image: np.ndarray, detection: Detection | None, common_ids: np.ndarray) -> np.ndarray:
    out = to_bgr(image)
    radius = _marker_radius(out)
    thickness = max(1, radius // 2)
    if detection is None:
        cv2.putText(out, "target not found", (20, 20 + 3 * radius), cv2.FONT_HERSHEY_SIMPLEX, radius / 5, RED,
                    thickness + 1, cv2.LINE_AA)
        return out
    common = set(np.asarray(common_ids).tolist())
    for corner_id, (u, v) in zip(detection.ids.tolist(), detection.corners_px, strict=True):
        centre = (round(float(u)), round(float(v)))
        colour = GREEN if corner_id in common else ORANGE
        cv2.circle(out, centre, radius, colour, thickness, cv2.LINE_AA)
        if corner_id == 0:
            cv2.circle(out, centre, 2 * radius, RED, thickness, cv2.LINE_AA)
    return out


def corners_image(
    left: np.ndarray, right: np.ndarray, detections: Detections, *, max_width_px: int = DEFAULT_MAX_WIDTH_PX,
) -> np.ndarray:
    """The measurement pair side by side with the detected corners drawn (see the module docstring)."""
    pair = side_by_side(_draw_corners(left, detections.left, detections.common_ids),
                        _draw_corners(right, detections.right, detections.common_ids))
    return downscale(pair, max_width_px)


def _zoom_to_corners(
    rect_points: list[np.ndarray], size: tuple[int, int], *, margin: float = 0.5,
) -> list[np.ndarray] | None:
    """Per view a 3x3 pixel map (same scale and vertical shift for both, so rows stay epipolar lines)
    that puts the rectified corners ``rect_points`` (left, right; (N, 2) each) in the middle of an
    image of ``size`` (w, h) with ``margin`` of their extent around them. None if there are no corners.
    """
    if any(len(p) == 0 or not np.all(np.isfinite(p)) for p in rect_points):
        return None
    width, height = size
    spans_u = [float(np.ptp(p[:, 0])) for p in rect_points]
    v_low = min(float(p[:, 1].min()) for p in rect_points)
    v_high = max(float(p[:, 1].max()) for p in rect_points)
    span_u = max(max(spans_u), 1.0) * (1 + 2 * margin)
    span_v = max(v_high - v_low, 1.0) * (1 + 2 * margin)
    scale = min(width / span_u, height / span_v)
    ty = height / 2 - scale * (v_low + v_high) / 2
    maps = []
    for points in rect_points:
        tx = width / 2 - scale * float(points[:, 0].min() + points[:, 0].max()) / 2
        maps.append(np.array([[scale, 0.0, tx], [0.0, scale, ty], [0.0, 0.0, 1.0]]))
    return maps


def rectified_image(
    left: np.ndarray, right: np.ndarray, calib: StereoCalibration, detections: Detections | None = None, *,
    n_lines: int = 16, max_width_px: int = DEFAULT_MAX_WIDTH_PX,
) -> np.ndarray:
    """The pair rectified with ``calib``, side by side, with ``n_lines`` horizontal epipolar lines.

    With corners in both views (from ``detections``) the rectified views are zoomed onto the target
    (one scale and one vertical shift for both, so rows still correspond) and the corners are drawn at
    their rectified positions, each pair in one colour; otherwise the whole rectified views are shown
    (``alpha`` = 1: every source pixel kept).
    """
    rect = rectify(calib, alpha=1.0)
    width, height = calib.image_size
    P1, P2 = rect.P1, rect.P2
    views = []
    if detections is not None and len(detections.common_ids) and detections.left and detections.right:
        for detection, R, P, K, D in ((detections.left, rect.R1, P1, calib.K1, calib.D1),
                                      (detections.right, rect.R2, P2, calib.K2, calib.D2)):
            keep = np.isin(detection.ids, detections.common_ids)
            views.append((detection.ids[keep], undistort_points(detection.corners_px[keep], K, D, R, P)))
    zoom = _zoom_to_corners([points for _, points in views], (width, height)) if views else None
    if zoom is not None:
        P1, P2 = zoom[0] @ P1, zoom[1] @ P2
        views = [(ids, cv2.perspectiveTransform(points.reshape(-1, 1, 2), A).reshape(-1, 2))
                 for (ids, points), A in zip(views, zoom, strict=True)]
    else:
        views = []
    (map1x, map1y), (map2x, map2y) = rectification_maps(calib, replace(rect, P1=P1, P2=P2))
    rectified = [cv2.remap(to_bgr(left), map1x, map1y, cv2.INTER_LINEAR),
                 cv2.remap(to_bgr(right), map2x, map2y, cv2.INTER_LINEAR)]
    radius = _marker_radius(rectified[0])
    for image, (ids, points) in zip(rectified, views, strict=False):
        for (u, v), corner_id in zip(points, ids.tolist(), strict=True):
            hue = int(179 * (corner_id % 12) / 12)
            colour = cv2.cvtColor(np.uint8([[[hue, 230, 255]]]), cv2.COLOR_HSV2BGR)[0, 0].tolist()
            cv2.circle(image, (round(float(u)), round(float(v))), radius, colour, max(1, radius // 2), cv2.LINE_AA)
    pair = side_by_side(*rectified)
    for k in range(1, n_lines + 1):
        y = round(k * pair.shape[0] / (n_lines + 1))
        cv2.line(pair, (0, y), (pair.shape[1] - 1, y), LINE, max(1, radius // 3), cv2.LINE_AA)
    return downscale(pair, max_width_px)


def encode_jpeg(image: np.ndarray, quality: int = 85) -> bytes:
    """JPEG bytes of a BGR image (camera images on the page: a tenth of a PNG's size for noisy frames)."""
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("could not encode the annotated image as JPEG")
    return data.tobytes()


__all__ = [
    "Detections", "corners_image", "detect_pair", "downscale", "encode_jpeg", "rectified_image", "side_by_side",
    "to_bgr",
]
