"""Physically consistent stereo renderer: a planar target seen by two calibrated cameras.

Image formation, per view (every step an OpenCV call on whole images, no per-pixel Python):

1. **Scene radiance on an ideal pinhole canvas, supersampled.** The board's printable image
   (``target.texture()``, i.e. the very pixels a printer would get, at 0.07 mm per texel by default)
   is turned into digital numbers (``black_dn`` .. ``white_dn``) and kept as a Gaussian pyramid
   (each level pre-blurred by 2 of its texels). For each view the plane homography
   ``S @ K @ [r1 r2 t] @ A_level`` maps the texture onto a canvas ``supersample`` times finer than
   the sensor, in the *undistorted* (pinhole) image, with bilinear sampling. The level is the
   coarsest whose texels stay below 0.6 canvas px on the visible board: then bilinear sampling
   neither aliases nor beats against the texel grid (which would shift edges by up to 0.03 px).
   The canvas holds the background (a smooth grey wall); the board is warped on top of it.
2. **Lens distortion.** Each supersample looks up the ideal canvas at ``undistort(p)``: a float
   remap map computed once per camera (exact ``cv2.undistortPoints`` with iteration criteria on an
   8 px grid, Catmull-Rom interpolated; error < 1e-4 px).
   A rolling shutter's shear (``line_time_s`` times the image's velocity, per row) and the
   pattern's random jitter (``jitter_px``: a field of random displacements ``jitter_scale_px``
   apart, bilinear between them, drawn per view) move the samples' lookups in the same remap, on
   the board's rows and columns only (no extra pass over the frame).
3. **Pixel integration.** ``cv2.resize(INTER_AREA)`` by the integer ``supersample`` factor: each
   pixel is the mean of its s x s samples, a box filter over the pixel area.
4. **Optics and sensor.** Gaussian optical blur (``blur_sigma_px``, less the share the texture
   pre-filter already gave), vignetting, read noise (and optional shot noise), rounding to 8 bits.

Only the sensor rows and columns that can see the board are warped, remapped and integrated; the
rest of the frame is the pre-rendered background. Intermediate images are uint16 holding DN * 256:
sub-DN precision at half the memory traffic of float32.

Accuracy (measured, see tests/test_render.py): edge positions within 0.003 px of the projection on
average; quarter-resolution findChessboardCorners + 11x11 cornerSubPix find corners 0.03-0.04 px
RMS from the truth (the detector's own pixel locking), with a bias < 0.002 px.

Conventions: pixel coordinates follow OpenCV (pixel (0, 0)'s centre is (0.0, 0.0)); a texture pixel
``u`` covers board x in [x0 + u * mm, x0 + (u + 1) * mm], so its centre is at x0 + (u + 0.5) * mm,
and pyramid level l's texel ``u`` is centred on level-0 texel ``2**l * u``. Transforms are
``T_a_b`` (maps b to a), poses in millimetres.

This module is a simulator: it imports only the leaf modules ``stereo_bench.geometry`` and
``stereo_bench.targets``.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from stereo_bench.geometry import (
    CALIBRATION_MARGIN_PX,
    CALIBRATION_MAX_OBLIQUITY_DEG,
    CameraModel,
    RigPose,
    board_faces_camera,
    board_pose_in_view,
    calibration_views_fit,
    invert_transform,
    mean_view_frame,
    transform_points,
)
from stereo_bench.targets import CharucoTarget, Checkerboard

Target = Checkerboard | CharucoTarget

# Intermediate images are uint16 holding DN * 256 (sub-DN precision, 8-bit range).
_FIXED = 256.0
# Nothing closer than this (mm) to a camera's optical centre is drawn: clips boards that reach
# behind the camera, where the plane homography would otherwise draw a mirrored ghost.
_Z_NEAR_MM = 1.0
# Texture sampling. Bilinear sampling of a texture whose texel grid beats against the canvas grid
# shifts blurred edges by a phase-dependent amount (a moire of the interpolation error): up to
# 0.03 px with texels about as large as canvas pixels, whatever the pre-filter. It vanishes when
# every canvas pixel spans >= 1/0.6 texels of a level pre-blurred by 2 texels: then the texture
# reaching the canvas is also blurred by 0.6-1.2 canvas px, enough that sampling it does not
# alias either. A 1-D model of the pipeline (box-averaged, gradient centroid) puts the remaining
# edge bias below 0.003 px. The optical blur applied later is reduced by the pre-filter's share.
_TEXTURE_SIGMA = 2.0  # texels of each pyramid level
_MAX_CANVAS_PX_PER_TEXEL = 0.6
# Largest level-0 texture (texels): bounds memory (2 bytes/texel, +1/3 for the pyramid).
_MAX_TEXELS = 24_000_000
# Sensor blocks (px) over which the ideal-coordinate extent is tabulated to find the board's ROI.
_BLOCK = 8
# Extra canvas around the undistorted sensor extent (1x px) so bilinear taps never leave it.
_CANVAS_PAD = 4
# Largest node spacing (canvas px) of the texel map that draws a bent board (see _warp_bent).
_BEND_STEP = 8


@dataclass(frozen=True)
class Optics:
    """Physical image formation; defaults describe a realistic cheap USB camera in a lab.

    Attributes:
        blur_sigma_px: optical blur, Gaussian sigma in sensor pixels. The texture pre-filter delivers
            part of it (0.3-0.6 px at s = 2), a Gaussian after pixel integration the rest (the
            convolutions commute, and the integrated frame is band-limited, so blurring after
            sampling is exact). Boards nearer than ~310 mm (27 mm squares, f = 1333 px) get a little
            more than asked from the texture alone.
        noise_sigma_dn: signal-independent read noise, 8-bit digital numbers (std).
        shot_noise_gain: shot-noise variance per DN of signal (DN^2 / DN); 0 disables it. The total
            noise std is sqrt(noise_sigma_dn**2 + shot_noise_gain * signal_dn).
        black_dn, white_dn: the print's black and white under the lab light, at the image centre.
        supersample: anti-aliasing factor s: s x s samples per pixel, box-averaged (``INTER_AREA``),
            i.e. integration over the pixel area. s = 1 samples each pixel once and uses a Gaussian
            of the pixel box's variance instead; its texture pre-filter alone is 0.6-1.2 px, so its
            images are softer than ``blur_sigma_px`` asks. s = 3 or 4 cost ~2-4x the time of s = 2.
        vignetting: relative illumination loss at the image corners (0.1 = corners get 90 %),
            falling off with the square of the distance from the principal point.
        wall_dn: mean level of the background wall.
        wall_gradient: peak-to-peak relative illumination change across the wall (lab light from one
            side).
        wall_texture_dn: std of the wall's smooth, low-contrast texture (no edges, no corners).
        back_dn: level of the board's back, drawn when a camera sees the board from behind.
        jpeg_quality: None (default): the 8-bit frame as the sensor gives it. An integer 1..100: the
            frame passes through JPEG at this libjpeg quality, as UVC cameras deliver 1080p (MJPG).
            The luma channel only: the pipeline works on grey images.
        jitter_px: the pattern's random image displacement per view (std in sensor px of each coordinate
            at the nodes of a field ``jitter_scale_px`` apart, linearly interpolated between them): the
            corner scatter real cameras show beyond what their image noise explains. 0 (default): none,
            and no random draw (frames bit-identical to a renderer without it).
        jitter_scale_px: node spacing of that field (sensor px): corners further apart than this move
            nearly independently.
        line_time_s: rolling shutter: each sensor row is exposed this much later than the one above (s);
            it matters only for image motion (``render_view(..., velocity_px_s=...)``). 0: global shutter.
    """

    blur_sigma_px: float = 0.7
    noise_sigma_dn: float = 2.0
    shot_noise_gain: float = 0.0
    black_dn: float = 25.0
    white_dn: float = 225.0
    supersample: int = 2
    vignetting: float = 0.1
    wall_dn: float = 115.0
    wall_gradient: float = 0.25
    wall_texture_dn: float = 3.0
    back_dn: float = 70.0
    jpeg_quality: int | None = None
    jitter_px: float = 0.0
    jitter_scale_px: int = 16
    line_time_s: float = 0.0

    def __post_init__(self):
        if not (isinstance(self.supersample, int) and 1 <= self.supersample <= 4):
            raise ValueError(f"supersample must be an integer 1..4, not {self.supersample!r}")
        for name in ("blur_sigma_px", "noise_sigma_dn", "shot_noise_gain", "wall_texture_dn", "jitter_px",
                     "line_time_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, not {getattr(self, name)}")
        for name in ("black_dn", "white_dn", "wall_dn", "back_dn"):
            if not 0.0 <= getattr(self, name) <= 255.0:
                raise ValueError(f"{name} must lie in 0..255 DN, not {getattr(self, name)}")
        if not 0.0 <= self.vignetting < 1.0:
            raise ValueError(f"vignetting must lie in [0, 1), not {self.vignetting}")
        if not (isinstance(self.jitter_scale_px, int) and 2 <= self.jitter_scale_px <= 1024):
            raise ValueError(f"jitter_scale_px must be an integer 2..1024, not {self.jitter_scale_px!r}")
        if self.jpeg_quality is not None and not (isinstance(self.jpeg_quality, int) and 1 <= self.jpeg_quality <= 100):
            raise ValueError(f"jpeg_quality must be None or an integer 1..100, not {self.jpeg_quality!r}")


@dataclass(frozen=True, eq=False)  # eq=False: array fields cannot be compared with ==
class RenderedView:
    """One rendered camera view and its ground truth.

    Attributes:
        image: (H, W) uint8 frame.
        corners_px: (N, 2) float64 true (distorted) pixel position of every target corner, in target
            id order, OpenCV pixel-centre convention.
        visible: (N,) bool: the corner is in front of the camera, on the board's side facing the
            camera, and inside the image.
        T_cam_board: (4, 4) board -> camera transform (mm).
    """

    image: np.ndarray
    corners_px: np.ndarray
    visible: np.ndarray
    T_cam_board: np.ndarray


@dataclass(frozen=True, eq=False)
class RenderedPair:
    """A stereo pair and its ground truth: X_right = R @ X_left + T (T (3,) in mm)."""

    left: RenderedView
    right: RenderedView
    R: np.ndarray
    T: np.ndarray
    T_rig_left: np.ndarray
    T_rig_right: np.ndarray
    T_rig_board: np.ndarray


@dataclass(frozen=True)
class BoardShape:
    """A print as it really is: ``scale`` times its nominal size and bent by ``bow_mm``.

    The print is scaled about the board origin (the first inner corner), then the sheet is bent into
    a cylinder about the vertical centre line of the inner-corner grid: the centre line stands
    ``bow_mm`` nearer the cameras (board -z) than the grid's left and right edge columns. A bent
    sheet keeps its lengths along the print, so the chord between two corners is a little shorter
    than their distance on the print (1e-6 relative for 1 mm over 200 mm).
    """

    scale: float = 1.0
    bow_mm: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.scale) and self.scale > 0.0):
            raise ValueError(f"scale must be a positive number, not {self.scale}")
        if not math.isfinite(self.bow_mm):
            raise ValueError(f"bow_mm must be a number, not {self.bow_mm}")

    @staticmethod
    def _curvature(half_width_mm: float, bow_mm: float) -> float:
        """Curvature (1/mm) of an arc of half-length ``half_width_mm`` whose sagitta is ``bow_mm``."""
        if bow_mm == 0.0:
            return 0.0
        if abs(bow_mm) >= 0.6 * half_width_mm:
            raise ValueError(f"a bow of {bow_mm:g} mm is too deep for a board {2 * half_width_mm:g} mm wide")
        h, kappa = half_width_mm, 2.0 * bow_mm / half_width_mm**2
        for _ in range(20):  # Newton on (1 - cos(kappa h)) / kappa = bow
            f = (1.0 - math.cos(kappa * h)) / kappa - bow_mm
            df = (kappa * h * math.sin(kappa * h) - (1.0 - math.cos(kappa * h))) / kappa**2
            kappa -= f / df
        return kappa

    def surface(self, target: Target, xy_mm: np.ndarray) -> np.ndarray:
        """(N, 3) board-frame points (mm) of the print points whose nominal coordinates are ``xy_mm`` (N, 2)."""
        xy = np.asarray(xy_mm, dtype=np.float64).reshape(-1, 2)
        u, y = self.scale * xy[:, 0], self.scale * xy[:, 1]
        half = 0.5 * self.scale * target.grid_size_mm[0]
        kappa = self._curvature(half, self.bow_mm)
        if kappa == 0.0:
            return np.column_stack([u, y, np.zeros(len(u))])
        a = u - half
        x = half + np.sin(kappa * a) / kappa
        z = (1.0 - np.cos(kappa * a)) / kappa - self.bow_mm
        return np.column_stack([x, y, z])

    def object_points(self, target: Target) -> np.ndarray:
        """(N, 3) true board-frame corners (mm), in target id order."""
        return self.surface(target, np.asarray(target.object_points, dtype=np.float64)[:, :2])


# --------------------------------------------------------------------------------------------
# Precomputed target textures


@dataclass(frozen=True, eq=False)
class _Mip:
    """A texture pyramid in DN * 256 (uint16) and where its texels lie on the board.

    ``levels[l]`` texel (u, v) is centred on board (x0 + (2**l * u + 0.5) * mm_x, y0 + (2**l * v + 0.5) * mm_y).
    """

    levels: tuple[np.ndarray, ...]
    origin_mm: tuple[float, float]
    mm_per_px: tuple[float, float]

    @property
    def outline_mm(self) -> np.ndarray:
        """(4, 2) board-frame corners of the printed area (mm), in polygon order."""
        h, w = self.levels[0].shape
        x0, y0 = self.origin_mm
        x1, y1 = x0 + w * self.mm_per_px[0], y0 + h * self.mm_per_px[1]
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])

    def board_from_texel(self, level: int) -> np.ndarray:
        """(3, 3) affine map from level-``level`` texel coordinates to board (x, y) in mm."""
        scale = 2.0**level
        (x0, y0), (mx, my) = self.origin_mm, self.mm_per_px
        return np.array([[scale * mx, 0.0, x0 + 0.5 * mx], [0.0, scale * my, y0 + 0.5 * my], [0.0, 0.0, 1.0]])


def _to_fixed(dn: np.ndarray | float) -> np.ndarray:
    dn = np.asarray(dn)
    if dn.dtype == np.float32 and dn.ndim:
        # In float32, in place: scaling by a power of two is exact, so this rounds the very values the float64
        # form does (a 3500 x 2500 board print: 0.55 -> 0.1 s of every renderer's set-up).
        scaled = dn * np.float32(_FIXED)
        np.rint(scaled, out=scaled)
        np.clip(scaled, 0, 65535, out=scaled)
        return scaled.astype(np.uint16)
    return np.clip(np.rint(np.asarray(dn, dtype=np.float64) * _FIXED), 0, 65535).astype(np.uint16)


@lru_cache(maxsize=4)
def _target_mip(target: Target, px_per_square: int, black_dn: float, white_dn: float) -> _Mip:
    """The target's print in DN * 256 as a Gaussian pyramid with a blur of ``_TEXTURE_SIGMA`` texels per level.

    Level l is the print blurred by ``_TEXTURE_SIGMA * 2**l`` level-0 texels and sampled every
    ``2**l`` texels (cascaded: blur the previous level by the missing variance, keep even texels,
    so level-l texel u stays centred on level-0 texel 2**l * u). The blur makes each level smooth
    enough that bilinear sampling at a canvas pixel no finer than a texel does not alias.
    """
    texture = target.texture(px_per_square=px_per_square)
    # The print's DN * 256 per grey level, looked up: the float32 arithmetic of every texel, done on 256 values.
    reflectance = np.arange(256, dtype=np.uint8).astype(np.float32) / 255.0
    print_dn = ((black_dn + (white_dn - black_dn) * reflectance) * np.float32(_FIXED)).astype(np.float32)
    current = cv2.GaussianBlur(print_dn[texture.image], (0, 0), _TEXTURE_SIGMA)
    levels = [_to_fixed(current / _FIXED)]
    increment = _TEXTURE_SIGMA * math.sqrt(3.0)  # sqrt((2 sigma)^2 - sigma^2), in the finer level's texels
    while min(current.shape) > 32:
        current = np.ascontiguousarray(cv2.GaussianBlur(current, (0, 0), increment)[::2, ::2])
        levels.append(_to_fixed(current / _FIXED))
    for lvl in levels:
        lvl.setflags(write=False)
    mm = texture.mm_per_px
    return _Mip(levels=tuple(levels), origin_mm=tuple(map(float, texture.origin_mm)), mm_per_px=(mm, mm))


def _back_panel(front: _Mip, back_dn: float) -> _Mip:
    """The board seen from behind: a uniform panel with the print's outline and texel grid.

    Same texel grid as the front so the outline is drawn (and anti-aliased) identically.
    """
    levels = []
    for level in front.levels:
        image = np.full(level.shape, _to_fixed(back_dn), np.uint16)
        image.setflags(write=False)
        levels.append(image)
    return _Mip(levels=tuple(levels), origin_mm=front.origin_mm, mm_per_px=front.mm_per_px)


# --------------------------------------------------------------------------------------------
# Per-camera precomputation: distortion maps, background, vignetting


def _cubic_weights(positions: np.ndarray, n: int) -> np.ndarray:
    """(len(positions), n) Catmull-Rom interpolation weights of samples at fractional node indices."""
    base = np.floor(positions).astype(int)
    t = positions - base
    weights = np.zeros((len(positions), n))
    rows = np.arange(len(positions))
    taps = (
        ((-t + 2.0) * t - 1.0) * t / 2.0,
        ((3.0 * t - 5.0) * t * t + 2.0) / 2.0,
        ((-3.0 * t + 4.0) * t + 1.0) * t / 2.0,
        (t - 1.0) * t * t / 2.0,
    )
    for k, tap in enumerate(taps):
        np.add.at(weights, (rows, np.clip(base - 1 + k, 0, n - 1)), tap)
    return weights


def _ideal_coordinates(camera: CameraModel, s: int) -> np.ndarray:
    """(H*s, W*s, 2) float32: undistorted (pinhole) pixel coordinates of every supersample centre.

    Supersample (a, b) of an s-times finer grid sits at sensor pixel ((a - (s-1)/2) / s, ...), so
    the s x s samples of pixel (i, j) average to its centre. Undistortion is exact (iterated to
    1e-12) on a grid every 8 px and Catmull-Rom interpolated in between (separable, as two matrix
    products); 8.3 M exact undistortions would take seconds. OpenCV's own interpolators would not do:
    remap and resize quantise positions to 1/32 of a grid cell, here 0.25 px.
    """
    w, h = camera.image_size
    step, pad = 8.0, 3  # pad: nodes beyond the image so the cubic kernel never reaches a border
    gx = np.arange(-pad, int(np.ceil((w - 1) / step)) + pad + 1) * step
    gy = np.arange(-pad, int(np.ceil((h - 1) / step)) + pad + 1) * step
    grid = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    ideal = cv2.undistortPoints(grid, camera.K, camera.dist, P=camera.K, criteria=criteria)
    coarse = ideal.reshape(len(gy), len(gx), 2).astype(np.float64)
    Wx = _cubic_weights(((np.arange(w * s) - (s - 1) / 2) / s - gx[0]) / step, len(gx))
    Wy = _cubic_weights(((np.arange(h * s) - (s - 1) / 2) / s - gy[0]) / step, len(gy))
    fine = np.empty((h * s, w * s, 2), np.float32)
    for c in range(2):
        fine[..., c] = Wy @ (coarse[..., c] @ Wx.T)
    return fine


def _wall(size: tuple[int, int], optics: Optics, seed: int) -> np.ndarray:
    """(h, w) float32 DN: a smooth grey wall under a lamp, with faint blotchy texture.

    Drawn on each camera's ideal canvas, i.e. fixed to the camera (like a distant wall, without the
    parallax a near one would show): a plausible surround for the board, not part of the truth.

    Built from heavily blurred noise only (sigma >= 12 px) and smooth gradients, so it holds no edges
    or corners a board detector could latch onto.
    """
    w, h = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xx / w - 0.5, yy / h - 0.5
    # Lamp to the upper left: linear falloff plus a broad hot spot.
    light = 1.0 + optics.wall_gradient * (-0.6 * u - 0.4 * v) + 0.5 * optics.wall_gradient * np.exp(
        -((u + 0.2) ** 2 + (v + 0.15) ** 2) / 0.18
    )
    rng = np.random.default_rng(seed)
    texture = np.zeros((h, w), np.float32)
    for sigma, weight in ((12.0, 0.5), (40.0, 0.8), (120.0, 1.0)):
        # Blur at 1/4 resolution then upsample: a sigma of 120 px at full size costs seconds.
        small = (max(2, w // 4), max(2, h // 4))
        blob = cv2.GaussianBlur(rng.standard_normal((small[1], small[0]), dtype=np.float32), (0, 0), sigma / 4)
        blob = cv2.resize(blob, (w, h), interpolation=cv2.INTER_CUBIC)
        texture += weight * blob / max(float(blob.std()), 1e-12)
    texture *= optics.wall_texture_dn / max(float(texture.std()), 1e-12)
    return (optics.wall_dn * light + texture).astype(np.float32)


class _CameraRaster:
    """Everything about one camera that does not change from view to view.

    Holds the supersampled ideal canvas (background only between views), the distortion remap, the
    rendered background frame and the vignetting gain. ``lock`` guards the canvas, which each view
    draws into and restores.
    """

    def __init__(self, camera: CameraModel, optics: Optics, background_seed: int):
        s = optics.supersample
        w, h = camera.image_size
        self.s, self.size = s, (w, h)
        ideal = _ideal_coordinates(camera, s)  # (h*s, w*s, 2)

        # Ideal canvas (1x, pinhole image): covers every ideal coordinate the sensor looks at.
        lo = np.floor(ideal.reshape(-1, 2).min(axis=0)).astype(int) - _CANVAS_PAD
        hi = np.ceil(ideal.reshape(-1, 2).max(axis=0)).astype(int) + _CANVAS_PAD
        self.origin = lo.astype(float)  # ideal coordinate of canvas pixel (0, 0)
        self.canvas_size = (int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1))
        # Ideal coordinate p -> supersampled canvas coordinate s * (p - origin) + (s - 1) / 2.
        self.S = np.array([[s, 0.0, -s * lo[0] + (s - 1) / 2], [0.0, s, -s * lo[1] + (s - 1) / 2], [0.0, 0.0, 1.0]])

        # Per 8x8 sensor block: extent of the ideal coordinates it samples (for the per-view ROI).
        # The map is a smooth near-identity, so a block's extremes sit at its corners to far better
        # than the 1 px margin added here (and a full min/max over 16 M values takes ~1 s).
        nby, nbx = -(-h // _BLOCK), -(-w // _BLOCK)
        rows = np.minimum(np.arange(nby + 1) * _BLOCK * s, h * s - 1)
        cols = np.minimum(np.arange(nbx + 1) * _BLOCK * s, w * s - 1)
        nodes = ideal[rows][:, cols]
        quad = np.stack([nodes[:-1, :-1], nodes[:-1, 1:], nodes[1:, :-1], nodes[1:, 1:]])
        self.block_min = quad.min(axis=0) - 1.0
        self.block_max = quad.max(axis=0) + 1.0

        # Float maps: OpenCV 5 interpolates them exactly and faster than fixed-point CV_16SC2 maps
        # (which quantise positions to 1/32 px; 4.x quantises float maps the same way internally).
        self.map_x = np.ascontiguousarray(ideal[..., 0] * s + np.float32(self.S[0, 2]))
        self.map_y = np.ascontiguousarray(ideal[..., 1] * s + np.float32(self.S[1, 2]))
        del ideal

        cw, ch = self.canvas_size
        wall = _wall((cw, ch), optics, background_seed)
        self.background = _to_fixed(cv2.resize(wall, (cw * s, ch * s), interpolation=cv2.INTER_LINEAR))
        self.background.setflags(write=False)
        self.canvas = self.background.copy()
        self.lock = threading.Lock()
        self.background_frame = self._sample(0, h, 0, w)
        self.background_frame.setflags(write=False)

        # Vignetting gain, divided by the fixed-point scale, applied when converting to DN.
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        cx, cy = camera.K[0, 2], camera.K[1, 2]
        r2_corner = max((cx + 0.5) ** 2, (w - 0.5 - cx) ** 2) + max((cy + 0.5) ** 2, (h - 0.5 - cy) ** 2)
        gain = 1.0 - optics.vignetting * ((xx - cx) ** 2 + (yy - cy) ** 2) / r2_corner
        self.gain = (gain / _FIXED).astype(np.float32)

    def _sample(self, y0: int, y1: int, x0: int, x1: int, displacement: _Displacement | None = None) -> np.ndarray:
        """Sensor rows y0:y1, columns x0:x1 (1x px) of the current canvas: distort, then integrate.

        ``displacement``: the image content moved by that field (sensor px) before integration.
        """
        s = self.s
        map_x, map_y = self.map_x[y0 * s : y1 * s, x0 * s : x1 * s], self.map_y[y0 * s : y1 * s, x0 * s : x1 * s]
        if displacement is not None:
            map_x, map_y = displacement.moved(map_x, map_y, y0 * s, x0 * s, s)
        fine = cv2.remap(self.canvas, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if s == 1:
            return fine
        return cv2.resize(fine, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)

    def sensor_roi(self, bbox_ideal: tuple[float, float, float, float]) -> tuple[int, int, int, int] | None:
        """(y0, y1, x0, x1) sensor pixels whose samples can land in the ideal box (x0, y0, x1, y1)."""
        bx0, by0, bx1, by1 = bbox_ideal
        hit = (
            (self.block_max[..., 0] >= bx0) & (self.block_min[..., 0] <= bx1)
            & (self.block_max[..., 1] >= by0) & (self.block_min[..., 1] <= by1)
        )
        rows, cols = np.flatnonzero(hit.any(axis=1)), np.flatnonzero(hit.any(axis=0))
        if rows.size == 0:
            return None
        w, h = self.size
        return (int(rows[0]) * _BLOCK, min(h, (int(rows[-1]) + 1) * _BLOCK),
                int(cols[0]) * _BLOCK, min(w, (int(cols[-1]) + 1) * _BLOCK))

    def render(self, mip: _Mip, H_ideal_board: np.ndarray, depths_ok: bool,
               displace: _BentBoard | None = None, displacement: _Displacement | None = None,
               ) -> tuple[np.ndarray, float]:
        """(H, W) uint16 (DN * 256) frame before blur and noise, with the board drawn by ``H_ideal_board``.

        Also returns the blur (Gaussian sigma, sensor px) the texture pre-filter already gave the
        board, typical over its visible part, so the optical blur can make up only the rest.

        ``H_ideal_board`` maps board (x, y, 1) to ideal pixels, built as K @ [r1 r2 t] so that the
        third homogeneous coordinate of its inverse is positive exactly for rays that meet the board
        in front of the camera. ``depths_ok`` says the whole print is in front of the camera.
        ``displace`` (a bent board, ``depths_ok`` only): maps ideal points to where the flat print
        shows what the bent one shows there; the board is then drawn through a dense remap.
        ``displacement``: moves the drawn board's image (rolling shutter, corner jitter), see :class:`_Displacement`.
        """
        frame = self.background_frame.copy()
        bbox = self._board_bbox(mip, H_ideal_board, depths_ok)
        if bbox is None:
            return frame, 0.0
        if displace is not None:
            bbox = self._bent_bbox(mip, H_ideal_board, displace, bbox)
        roi = self.sensor_roi(bbox)
        if roi is None:
            return frame, 0.0
        level, texture_sigma_px = self._choose_level(mip, H_ideal_board)
        H_canvas_texel = self.S @ H_ideal_board @ mip.board_from_texel(level)

        s = self.s
        cw, ch = self.canvas_size[0] * s, self.canvas_size[1] * s
        corners = np.array([[bbox[0], bbox[1], 1.0], [bbox[2], bbox[3], 1.0]]) @ self.S.T
        cx0 = max(0, math.floor(corners[0, 0]) - 2)
        cy0 = max(0, math.floor(corners[0, 1]) - 2)
        cx1 = min(cw, math.ceil(corners[1, 0]) + 3)
        cy1 = min(ch, math.ceil(corners[1, 1]) + 3)
        if cx1 <= cx0 or cy1 <= cy0:
            return frame, 0.0
        shift = np.array([[1.0, 0.0, -cx0], [0.0, 1.0, -cy0], [0.0, 0.0, 1.0]])
        H_roi = shift @ H_canvas_texel
        with self.lock:
            # Draw straight into the canvas (a strided view: OpenCV writes through it), sample the
            # sensor, then put the background back for the next view.
            patch = self.canvas[cy0:cy1, cx0:cx1]
            source = mip.levels[level]
            try:
                if displace is not None:
                    self._warp_bent(source, H_roi, patch, displace, (cx0, cy0))
                elif depths_ok:
                    drawn = cv2.warpPerspective(source, H_roi, (cx1 - cx0, cy1 - cy0), dst=patch,
                                                flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_TRANSPARENT)
                    if drawn is not patch:  # an OpenCV build that did not write in place
                        patch[...] = drawn
                else:
                    self._warp_clipped(source, H_roi, patch)
                y0, y1, x0, x1 = roi
                frame[y0:y1, x0:x1] = self._sample(y0, y1, x0, x1, displacement)
            finally:
                patch[...] = self.background[cy0:cy1, cx0:cx1]
        return frame, texture_sigma_px

    def _bent_bbox(self, mip: _Mip, H_ideal_board: np.ndarray, displace: _BentBoard,
                   bbox: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        """The flat print's ideal bounding box grown by the largest displacement of the bend (+2 px)."""
        (x0, y0), (x1, y1) = mip.outline_mm.min(axis=0), mip.outline_mm.max(axis=0)
        u, v = np.meshgrid(np.linspace(x0, x1, 9), np.linspace(y0, y1, 9))
        board = np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)]) @ H_ideal_board.T
        q = board[:, :2] / board[:, 2:3]
        pad = float(np.abs(displace(q) - q).max()) * 1.5 + 2.0
        cw, ch = self.canvas_size
        ox, oy = self.origin
        return (max(bbox[0] - pad, ox), max(bbox[1] - pad, oy), min(bbox[2] + pad, ox + cw - 1),
                min(bbox[3] + pad, oy + ch - 1))

    def _warp_bent(self, source: np.ndarray, H_roi: np.ndarray, patch: np.ndarray, displace: _BentBoard,
                   origin_px: tuple[int, int]) -> None:
        """Draw a bent print into ``patch`` (canvas pixels from ``origin_px``) by a remap.

        Each canvas pixel samples the texel that the flat print would show at its displaced position.
        That texel map is computed exactly on nodes at most ``_BEND_STEP`` canvas pixels apart and
        interpolated bilinearly in between (cv2.resize to the patch size samples node k at
        (k + 0.5) * spacing - 0.5, where the nodes are put): the bend is smooth, and so is the
        projective map over 8 px (measured: < 0.0002 px for a board facing the camera, 0.0017 px
        tilted 30 deg, 0.003 px at 45 deg). Sampling is bilinear, as warpPerspective's.
        """
        h, w = patch.shape
        s = self.s
        nx, ny = -(-w // _BEND_STEP), -(-h // _BEND_STEP)
        gx = (np.arange(nx) + 0.5) * (w / nx) - 0.5
        gy = (np.arange(ny) + 0.5) * (h / ny) - 0.5
        local = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)  # patch canvas px
        ideal = (local + np.asarray(origin_px, dtype=float) - self.S[:2, 2]) / s
        shown = (displace(ideal) - ideal) * s + local  # where the flat print shows it, patch px
        tx, ty = _BentBoard._apply(np.linalg.inv(H_roi), shown[:, 0], shown[:, 1])
        texels = np.stack([tx, ty], axis=-1).reshape(ny, nx, 2).astype(np.float32)
        texels = cv2.resize(texels, (w, h), interpolation=cv2.INTER_LINEAR)
        drawn = cv2.remap(source, texels, None, cv2.INTER_LINEAR, dst=patch, borderMode=cv2.BORDER_TRANSPARENT)
        if drawn is not patch:
            patch[...] = drawn

    @staticmethod
    def _warp_clipped(source: np.ndarray, H_roi: np.ndarray, patch: np.ndarray) -> None:
        """Warp a board that reaches behind the camera: keep only rays that meet it in front.

        The homography also maps the part behind the camera, mirrored, onto the image. The third
        homogeneous coordinate of H^-1 @ (x, y, 1) is 1 / (distance along the ray) for H built as
        K [r1 r2 t]: positive exactly where the ray meets the board in front of the camera.
        """
        h, w = patch.shape
        drawn = patch.copy()
        out = cv2.warpPerspective(source, H_roi, (w, h), dst=drawn, flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_TRANSPARENT)
        a, b, c = np.linalg.inv(H_roi)[2]
        # Clip the patch rectangle to the half-plane a x + b y + c > 0 (Sutherland-Hodgman, one edge).
        rect = [(-0.5, -0.5), (w - 0.5, -0.5), (w - 0.5, h - 0.5), (-0.5, h - 0.5)]
        polygon = []
        for (x1, y1), (x2, y2) in zip(rect, rect[1:] + rect[:1], strict=True):
            f1, f2 = a * x1 + b * y1 + c, a * x2 + b * y2 + c
            if f1 > 0:
                polygon.append((x1, y1))
            if (f1 > 0) != (f2 > 0):
                k = f1 / (f1 - f2)
                polygon.append((x1 + k * (x2 - x1), y1 + k * (y2 - y1)))
        if len(polygon) < 3:
            return
        mask = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask, [np.round(np.array(polygon) * 16).astype(np.int32)], 255, shift=4)
        np.copyto(patch, out, where=mask.astype(bool))

    def _board_bbox(self, mip: _Mip, H_ideal_board: np.ndarray, depths_ok: bool):
        """Ideal-image bounding box (x0, y0, x1, y1) of the print's visible part, clipped to the canvas."""
        outline = np.column_stack([mip.outline_mm, np.ones(4)])
        if depths_ok:
            projected = outline @ H_ideal_board.T
            points = projected[:, :2] / projected[:, 2:3]
            x0, y0 = points.min(axis=0)
            x1, y1 = points.max(axis=0)
        else:
            # Part of the print is behind the camera: its image is unbounded, take the whole canvas.
            x0, y0, x1, y1 = -np.inf, -np.inf, np.inf, np.inf
        cw, ch = self.canvas_size
        ox, oy = self.origin
        x0, y0 = max(x0, ox), max(y0, oy)
        x1, y1 = min(x1, ox + cw - 1), min(y1, oy + ch - 1)
        if x1 < x0 or y1 < y0:
            return None
        return (float(x0), float(y0), float(x1), float(y1))

    def _choose_level(self, mip: _Mip, H_ideal_board: np.ndarray) -> tuple[int, float]:
        """(pyramid level, texture blur in sensor px) for a board drawn by ``H_ideal_board``.

        The level is the coarsest whose texels stay below ``_MAX_CANVAS_PX_PER_TEXEL`` canvas pixels
        in every direction everywhere on the visible board (sampled on a 9x9 grid); level 0 when the
        board is so near that even level-0 texels are larger (then edges may slip by ~0.01 px). One
        level serves the whole board, so on a steeply receding board the far part, minified well
        below the limit, is pre-filtered less than 0.6 canvas px and may alias slightly. The blur
        is that level's pre-filter in sensor pixels at the board's typical (median) scale.
        """
        H = self.S @ H_ideal_board @ mip.board_from_texel(0)
        h0, w0 = mip.levels[0].shape
        u, v = np.meshgrid(np.linspace(0, w0 - 1, 9), np.linspace(0, h0 - 1, 9))
        X = np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)]) @ H.T
        wgt = X[:, 2]
        ok = wgt > 1e-12
        if not ok.any():
            return 0, 0.0
        x, y, wgt = X[ok, 0] / wgt[ok], X[ok, 1] / wgt[ok], wgt[ok]
        cw, ch = self.canvas_size[0] * self.s, self.canvas_size[1] * self.s
        inside = (x >= 0) & (x < cw) & (y >= 0) & (y < ch)
        if not inside.any():
            return 0, 0.0
        x, y, wgt = x[inside], y[inside], wgt[inside]
        # Jacobian d(canvas)/d(level-0 texel) of the homography at each sample.
        J = np.empty((x.size, 2, 2))
        J[:, 0, 0] = (H[0, 0] - x * H[2, 0]) / wgt
        J[:, 0, 1] = (H[0, 1] - x * H[2, 1]) / wgt
        J[:, 1, 0] = (H[1, 0] - y * H[2, 0]) / wgt
        J[:, 1, 1] = (H[1, 1] - y * H[2, 1]) / wgt
        singular = np.linalg.svd(J, compute_uv=False)  # canvas px per level-0 texel, (N, 2) descending
        largest = max(float(singular[:, 0].max()), 1e-12)
        level = math.floor(math.log2(_MAX_CANVAS_PX_PER_TEXEL / largest) + 1e-9)
        level = int(min(max(level, 0), len(mip.levels) - 1))
        typical = float(np.median(np.sqrt(singular[:, 0] * singular[:, 1])))
        return level, _TEXTURE_SIGMA * (2.0**level) * typical / self.s


def _camera_key(camera: CameraModel) -> tuple:
    return (np.asarray(camera.K, float).tobytes(), np.asarray(camera.dist, float).tobytes(), tuple(camera.image_size))


_RASTERS: dict[tuple, _CameraRaster] = {}
_RASTERS_LOCK = threading.Lock()
_RASTERS_MAX = 4


def _raster(camera: CameraModel, optics: Optics, background_seed: int) -> _CameraRaster:
    """The shared raster of ``camera``: identical cameras (the usual pair) share one (~110 MB at s = 2)."""
    # Only what the raster depends on: renderers differing in noise, blur or print levels share it.
    key = (_camera_key(camera), optics.supersample, optics.vignetting, optics.wall_dn, optics.wall_gradient,
           optics.wall_texture_dn, background_seed)
    with _RASTERS_LOCK:
        raster = _RASTERS.get(key)
        if raster is None:
            raster = _CameraRaster(camera, optics, background_seed)
            if len(_RASTERS) >= _RASTERS_MAX:
                _RASTERS.pop(next(iter(_RASTERS)))
            _RASTERS[key] = raster
        return raster


# --------------------------------------------------------------------------------------------
# The renderer


class StereoRenderer:
    """Renders a target seen by a stereo pair, with ground truth.

    Everything that does not depend on the view is computed here, once: the target's texture
    pyramid (``texture_px_per_square`` texels per square at level 0, in DN) and, per camera, the
    distortion remap, the background and the vignetting. Cameras with identical intrinsics share
    that state. ``render_view`` is thread-safe (the per-camera canvas is locked while in use).

    Args:
        target: Checkerboard or CharucoTarget; its own ``texture()`` supplies the board's pixels.
        left, right: intrinsics (default ``CameraModel.from_sensor()``: 1920x1080, f = 4 mm, 3 um).
        optics: image formation parameters.
        texture_px_per_square: level-0 texture resolution; default: 0.07 mm texels (386 per 27 mm
            square), which keeps texture sampling exact down to ~310 mm at f = 1333 px, s = 2.
        background_seed: seed of the wall's fixed texture (the wall does not change between frames).
    """

    def __init__(
        self, target: Target, left: CameraModel | None = None, right: CameraModel | None = None, *,
        optics: Optics = Optics(), texture_px_per_square: int | None = None, background_seed: int = 0,  # noqa: B008
    ):
        self.target = target
        self.left = left if left is not None else CameraModel.from_sensor(name="left")
        self.right = right if right is not None else CameraModel.from_sensor(name="right")
        self.optics = optics
        self._object_points = np.asarray(target.object_points, dtype=np.float64)
        if texture_px_per_square is None:
            texture_px_per_square = _auto_px_per_square(target)
        self.texture_px_per_square = int(texture_px_per_square)
        self._front = _target_mip(target, self.texture_px_per_square, float(optics.black_dn), float(optics.white_dn))
        self._back: _Mip | None = None  # built the first time a camera sees the board from behind
        self._rasters = {
            "left": _raster(self.left, optics, background_seed),
            "right": _raster(self.right, optics, background_seed),
        }

    def camera(self, side: str) -> CameraModel:
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', not {side!r}")
        return self.left if side == "left" else self.right

    def truth(self, side: str, T_cam_board: np.ndarray, *, shape: BoardShape | None = None,
              ) -> tuple[np.ndarray, np.ndarray]:
        """((N, 2) distorted corner pixels, (N,) visible) of the target in the ``side`` camera.

        ``shape``: the print as it really is (None: flat and to scale).
        """
        camera = self.camera(side)
        T_cam_board = np.asarray(T_cam_board, dtype=np.float64)
        points = self._object_points if shape is None else shape.object_points(self.target)
        corners_px, valid = camera.project(transform_points(T_cam_board, points))
        return corners_px, valid & camera.in_image(corners_px) & board_faces_camera(T_cam_board)

    def render_view(self, side: str, T_cam_board: np.ndarray, rng: np.random.Generator, *,
                    shape: BoardShape | None = None, smear_px: tuple[float, float] | None = None,
                    velocity_px_s: tuple[float, float] | None = None,
                    jitter_rng: np.random.Generator | None = None) -> RenderedView:
        """Render the ``side`` ('left' or 'right') camera's frame of the target at ``T_cam_board`` (4x4, mm).

        ``rng`` drives the sensor noise only (one draw per call), so a seeded generator reproduces
        the frame exactly. ``shape``: the print as it really is (scale, bow; None: flat and to
        scale). ``smear_px``: (dx, dy) image motion during the exposure (a camera still ringing after
        a move), integrated as a uniform smear along that segment; None: none. ``velocity_px_s``: the
        image's velocity (px/s) during the readout, which a rolling shutter (``optics.line_time_s``)
        turns into a shear of the board's image; None: still.

        With ``optics.jitter_px`` > 0 the board's image is also displaced by a random field drawn from
        ``jitter_rng`` (None: from ``rng``, first, then the sensor noise): the corner scatter of a real camera
        beyond its image noise. What it stands for (print texture, the optics' local aberrations, JPEG blocks)
        does not change between frames of a still board seen by a still camera: a caller that renders several
        frames of one still view passes the same ``jitter_rng`` seed for each.
        """
        camera = self.camera(side)
        raster = self._rasters[side]
        T_cam_board = np.array(T_cam_board, dtype=np.float64)
        if T_cam_board.shape != (4, 4):
            raise ValueError(f"T_cam_board must be 4x4, not {T_cam_board.shape}")
        corners_px, visible = self.truth(side, T_cam_board, shape=shape)

        R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
        facing = board_faces_camera(T_cam_board)
        if not facing and self._back is None:
            self._back = _back_panel(self._front, self.optics.back_dn)
        mip = self._front if facing else self._back
        scale = 1.0 if shape is None else shape.scale
        outline = np.column_stack([scale * mip.outline_mm, np.zeros(4)])
        depths = (outline @ R.T + t)[:, 2]
        edge_on = abs(float(R[:, 2] @ t)) < 1e-9 * max(float(np.linalg.norm(t)), 1.0)
        if edge_on or not (depths > _Z_NEAR_MM).any():
            frame, texture_sigma_px = raster.background_frame, 0.0
        else:
            # K [r1 r2 t] maps board (x, y, 1) to the ideal image; its sign convention matters for clipping.
            # A print scaled by s maps its nominal (x, y) to (s x, s y): K [s r1, s r2, t].
            if shape is None:
                H_ideal_board = camera.K @ np.column_stack([R[:, 0], R[:, 1], t])
            else:
                H_ideal_board = camera.K @ np.column_stack([scale * R[:, 0], scale * R[:, 1], t])
            depths_ok = bool((depths > _Z_NEAR_MM).all())
            # A bent board is drawn through the displacement a flat one would need; a board that
            # reaches behind the camera or is seen from behind is drawn flat.
            bent = shape is not None and shape.bow_mm != 0.0 and facing and depths_ok
            displace = _BentBoard(shape, self.target, camera.K, T_cam_board, H_ideal_board) if bent else None
            frame, texture_sigma_px = raster.render(mip, H_ideal_board, depths_ok=depths_ok, displace=displace,
                                                    displacement=self._displacement(
                                                        camera, rng if jitter_rng is None else jitter_rng,
                                                        velocity_px_s))
        image = self._sensor(frame, raster, rng, texture_sigma_px, smear_px=smear_px)
        return RenderedView(image=image, corners_px=corners_px, visible=visible, T_cam_board=T_cam_board)

    def _displacement(self, camera: CameraModel, rng: np.random.Generator,
                      velocity_px_s: tuple[float, float] | None) -> _Displacement | None:
        """The view's rolling-shutter shear and corner jitter (None without either: no draw from ``rng``)."""
        o = self.optics
        shear = None
        if velocity_px_s is not None and o.line_time_s > 0.0 and any(velocity_px_s):
            shear = (velocity_px_s[0] * o.line_time_s, velocity_px_s[1] * o.line_time_s)
        nodes = None
        if o.jitter_px > 0.0:
            w, h = camera.image_size
            shape = (h // o.jitter_scale_px + 3, w // o.jitter_scale_px + 3, 2)
            nodes = (rng.standard_normal(shape) * o.jitter_px).astype(np.float32)
        if shear is None and nodes is None:
            return None
        return _Displacement(shear=shear, centre_row=(camera.image_size[1] - 1) / 2.0, nodes=nodes,
                             step=o.jitter_scale_px)

    def render_pair(self, rig: RigPose, T_rig_board: np.ndarray, rng: np.random.Generator, *,
                    shape: BoardShape | None = None) -> RenderedPair:
        """Both views of the target at ``T_rig_board`` (4x4, mm) with the rig's true geometry; ``shape`` as
        :meth:`render_view` takes it."""
        T_rig_board = np.array(T_rig_board, dtype=np.float64)
        T_rig_left, T_rig_right = rig.T_rig_left, rig.T_rig_right
        left = self.render_view("left", invert_transform(T_rig_left) @ T_rig_board, rng, shape=shape)
        right = self.render_view("right", invert_transform(T_rig_right) @ T_rig_board, rng, shape=shape)
        R, T = rig.stereo_extrinsics()
        return RenderedPair(left=left, right=right, R=R, T=T, T_rig_left=T_rig_left, T_rig_right=T_rig_right,
                            T_rig_board=T_rig_board)

    def _sensor(self, frame: np.ndarray, raster: _CameraRaster, rng: np.random.Generator,
                texture_sigma_px: float, *, smear_px: tuple[float, float] | None = None) -> np.ndarray:
        """Optical blur, motion smear, vignetting, noise, 8-bit quantisation (and JPEG) of a DN * 256 frame.

        The frame is band-limited (texture pre-filter, pixel integration), so blurring it after
        sampling equals blurring before; the texture pre-filter counts toward the optical blur.
        With s = 1 there is no pixel integration: a Gaussian of the box's variance (1/12 px^2)
        stands in for it. A smear (image motion during the exposure) is a uniform line kernel.
        """
        o = self.optics
        signal = cv2.multiply(frame, raster.gain, dtype=cv2.CV_32F)  # DN, vignetted
        variance = o.blur_sigma_px**2 + (1.0 / 12.0 if raster.s == 1 else 0.0) - texture_sigma_px**2
        if variance > 0.01:
            # After the vignetting (smooth, so the two commute); float32 blurs 3x faster than uint16.
            signal = cv2.GaussianBlur(signal, (0, 0), math.sqrt(variance))
        if smear_px is not None and math.hypot(*smear_px) >= _MIN_SMEAR_PX:
            signal = cv2.filter2D(signal, -1, _smear_kernel(*smear_px), borderType=cv2.BORDER_REPLICATE)
        # cv2.randn is ~4x faster than numpy's normal generator on 2 Mpx; seed its per-thread RNG
        # from the caller's generator so frames stay reproducible.
        cv2.setRNGSeed(int(rng.integers(0, 2**31 - 1)))
        noise = np.empty_like(signal)
        if o.shot_noise_gain > 0:
            cv2.randn(noise, 0.0, 1.0)
            variance = cv2.max(signal, 0.0) * o.shot_noise_gain + o.noise_sigma_dn**2
            noise *= cv2.sqrt(variance)
        elif o.noise_sigma_dn > 0:
            cv2.randn(noise, 0.0, o.noise_sigma_dn)
        else:
            noise[:] = 0.0
        # saturate_cast rounds to nearest and clips to 0..255.
        image = cv2.add(signal, noise, dtype=cv2.CV_8U)
        if o.jpeg_quality is not None:
            image = jpeg_roundtrip(image, o.jpeg_quality)
        return image


# Image motion below this (px over the exposure) is not drawn: far below the corner noise.
_MIN_SMEAR_PX = 0.05


def _smear_kernel(dx: float, dy: float) -> np.ndarray:
    """Normalised kernel of a uniform motion along (dx, dy) px, centred (bilinear splats of 8 samples per px)."""
    length = math.hypot(dx, dy)
    radius = int(math.ceil(length / 2.0)) + 1
    kernel = np.zeros((2 * radius + 1, 2 * radius + 1), np.float32)
    n = max(2, int(math.ceil(8 * length)))
    for f in (np.arange(n) + 0.5) / n - 0.5:
        x, y = radius + f * dx, radius + f * dy
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        ax, ay = x - x0, y - y0
        kernel[y0, x0] += (1 - ax) * (1 - ay)
        kernel[y0, x0 + 1] += ax * (1 - ay)
        kernel[y0 + 1, x0] += (1 - ax) * ay
        kernel[y0 + 1, x0 + 1] += ax * ay
    return kernel / kernel.sum()


def jpeg_roundtrip(image: np.ndarray, quality: int) -> np.ndarray:
    """``image`` (uint8) encoded as JPEG at libjpeg ``quality`` and decoded again."""
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)


class _Displacement:
    """A displacement of the image content over the sensor (px): rolling shutter and corner jitter.

    ``shear``: (vx, vy) px per row: row y is exposed ``(y - cy) * line_time`` after the middle row while
    the image moves at velocity v, so its content stands ``shear * (y - cy)`` px further along v.
    ``nodes``: (ny, nx, 2) random displacements (px) at sensor positions (k * step, j * step), interpolated
    bilinearly (cv2.resize by the integer factor step * s: its node k lands on supersample k * step * s +
    (step * s - 1) / 2, a fixed offset of the random field, the same for every view).
    """

    def __init__(self, *, shear: tuple[float, float] | None = None, centre_row: float = 0.0,
                 nodes: np.ndarray | None = None, step: int = 16):
        self.shear, self.centre_row, self.nodes, self.step = shear, float(centre_row), nodes, int(step)

    def moved(self, map_x: np.ndarray, map_y: np.ndarray, y0: int, x0: int, s: int) -> tuple[np.ndarray, np.ndarray]:
        """``map_x``, ``map_y`` (canvas px, s per sensor px) of the supersamples from (y0, x0) on, each looking
        back by the displacement (content moved by +d: a sample sees what stood d before it)."""
        h, w = map_x.shape
        if self.nodes is not None:
            f = self.step * s
            k0, k1 = y0 // f, min(self.nodes.shape[0] - 1, -(-(y0 + h) // f) + 1)
            j0, j1 = x0 // f, min(self.nodes.shape[1] - 1, -(-(x0 + w) // f) + 1)
            oy, ox = y0 - k0 * f, x0 - j0 * f
            size = ((j1 - j0 + 1) * f, (k1 - k0 + 1) * f)
            maps = []
            for c, base in enumerate((map_x, map_y)):
                sub = np.ascontiguousarray(self.nodes[k0 : k1 + 1, j0 : j1 + 1, c] * np.float32(s))
                up = cv2.resize(sub, size, interpolation=cv2.INTER_LINEAR)
                maps.append(cv2.subtract(base, up[oy : oy + h, ox : ox + w]))
            map_x, map_y = maps
        if self.shear is not None:
            rows = ((np.arange(y0, y0 + h, dtype=np.float32) - (s - 1) / 2) / s - np.float32(self.centre_row))[:, None]
            map_x = map_x - np.float32(self.shear[0] * s) * rows
            map_y = map_y - np.float32(self.shear[1] * s) * rows
        return map_x, map_y


class _BentBoard:
    """Where a flat board would have to be drawn so that a canvas pixel shows the bent board.

    For ideal-image points q (N, 2) returns q' (N, 2): the point of the flat print (the homography
    ``H_ideal_board``) that the bent print shows at q. The bent surface point seen at q is found by
    a fixed-point iteration from the flat solution; the bend moves points by at most a few pixels
    and its gradient is tiny, so four iterations converge far below 1e-4 px. Products with 3x3
    matrices are written out: as BLAS calls on (N, 3) arrays they spin for 10-100x longer on a
    loaded 2-core machine.
    """

    def __init__(self, shape: BoardShape, target: Target, K: np.ndarray, T_cam_board: np.ndarray,
                 H_ideal_board: np.ndarray):
        self.shape, self.target = shape, target
        self.K = np.asarray(K, dtype=np.float64)
        self.T = np.asarray(T_cam_board, dtype=np.float64)
        self.H = np.asarray(H_ideal_board, dtype=np.float64)
        self.H_inv = np.linalg.inv(self.H)

    @staticmethod
    def _apply(H: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
        return (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w

    def __call__(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
        fx, fy = self._apply(self.H_inv, q[:, 0], q[:, 1])  # nominal print coordinates of the flat solution
        x, y = fx.copy(), fy.copy()
        R, t, K = self.T[:3, :3], self.T[:3, 3], self.K
        for _ in range(4):
            p = self.shape.surface(self.target, np.column_stack([x, y]))
            cam = [R[i, 0] * p[:, 0] + R[i, 1] * p[:, 1] + R[i, 2] * p[:, 2] + t[i] for i in range(3)]
            u = (K[0, 0] * cam[0] + K[0, 1] * cam[1]) / cam[2] + K[0, 2]
            v = K[1, 1] * cam[1] / cam[2] + K[1, 2]
            sx, sy = self._apply(self.H_inv, u, v)
            x += fx - sx
            y += fy - sy
        return np.column_stack(self._apply(self.H, x, y))


def _auto_px_per_square(target: Target) -> int:
    """Level-0 texture resolution: 0.07 mm texels, capped at ``_MAX_TEXELS``.

    0.07 mm keeps a canvas pixel (s = 2, f = 1333 px) >= 1/0.6 texels down to ~310 mm; nearer,
    level 0 is sampled more coarsely than ideal (edges may slip by ~0.01 px).
    """
    px = max(32, math.ceil(target.square_mm / 0.07))
    probe = target.texture(px_per_square=64)  # small and cheap: only its size matters
    texels_at_px = probe.image.size * (px / 64) ** 2
    if texels_at_px > _MAX_TEXELS:
        px = max(32, int(px * math.sqrt(_MAX_TEXELS / texels_at_px)))
    return px


# --------------------------------------------------------------------------------------------
# Calibration views


def _bisect_largest(fits, good: float, bad: float, *, steps: int, levels_per_call: int = 3) -> float | None:
    """What ``steps`` bisections of [good, bad] find as the largest ``x`` with ``fits(x)`` (None if ``good`` does
    not fit), asking ``fits`` ((N,) array -> (N,) bool) for ``levels_per_call`` levels of the bisection at once.

    Every midpoint the sequential bisection could visit in those levels is asked for in one call (2**L - 1 of
    them), then the path is walked: the same midpoints, computed alike, so the same answer. A call of the view
    rule costs mostly its fixed overhead: asking 8 poses at once (3 levels) placed a board's views 1.9x faster
    than asking one at a time; 64 at once (6 levels) was slower again.
    """
    first = True
    while steps > 0:
        levels = min(levels_per_call, steps)
        nodes, intervals = [], [(good, bad)]
        for _ in range(levels):  # the subtree's midpoints, level by level
            children = []
            for g, b in intervals:
                mid = 0.5 * (g + b)
                nodes.append(mid)
                children += [(mid, b), (g, mid)]
            intervals = children
        asked = np.array(([good] if first else []) + nodes)
        answers = fits(asked)
        if first:
            if not answers[0]:
                return None
            answers = answers[1:]
            first = False
        index = 0  # walk: node k's children sit at 2k + 1 (it fits: [mid, bad]) and 2k + 2 ([good, mid])
        for _ in range(levels):
            mid = nodes[index]
            if answers[index]:
                good, index = mid, 2 * index + 1
            else:
                bad, index = mid, 2 * index + 2
        steps -= levels
    return good


def calibration_board_poses(
    rig: RigPose, target: Target, *, n_views: int, rng: np.random.Generator,
    distance_mm: tuple[float, float] = (300.0, 700.0), left: CameraModel | None = None,
    right: CameraModel | None = None, min_fraction_visible: float | None = None, max_tilt_deg: float = 40.0,
    margin_px: float = CALIBRATION_MARGIN_PX, max_obliquity_deg: float = CALIBRATION_MAX_OBLIQUITY_DEG,
    max_attempts: int = 200,
) -> list[np.ndarray]:
    """T_rig_board (4x4, mm) poses of a calibration board presented as an operator would for calibration.

    Views vary in distance (stratified over ``distance_mm``, measured along the rig's mean viewing
    direction), in tilt (up to ``max_tilt_deg`` about the board's x and y axes, direction stratified
    around the circle, plus a +-15 deg roll) and in position: most boards are pushed out toward the
    edge of the common field of view (where distortion is observable), a quarter stay near its
    centre. Each pose is a usable calibration view by the project's one rule,
    :func:`stereo_bench.geometry.calibration_view_fits` (the plan predicts with it too): at least
    ``min_fraction_visible`` of the corners (default: the board's own, all of a checkerboard with its
    outer squares, half of a ChArUco board) inside both images ``margin_px`` from the border, on the
    board's printed side and no more than ``max_obliquity_deg`` off each camera's line of sight.

    Raises:
        ValueError: if a view cannot be placed in ``max_attempts`` tries (e.g. the rig's views
            overlap too little at these distances for the board).
    """
    if n_views < 1:
        raise ValueError(f"n_views must be >= 1, not {n_views}")
    if min_fraction_visible is None:
        min_fraction_visible = target.min_calibration_fraction
    if not 0.0 < min_fraction_visible <= 1.0:
        raise ValueError(f"min_fraction_visible must lie in (0, 1], not {min_fraction_visible}")
    lo, hi = distance_mm
    if not 0.0 < lo <= hi:
        raise ValueError(f"distance_mm must be (near, far) with 0 < near <= far, not {distance_mm}")
    left = left if left is not None else CameraModel.from_sensor(name="left")
    right = right if right is not None else CameraModel.from_sensor(name="right")
    object_points = np.asarray(target.object_points, dtype=np.float64)
    width_mm, height_mm = target.grid_size_mm
    grid_centre = np.array([width_mm / 2.0, height_mm / 2.0, 0.0])

    R_view = mean_view_frame(rig.T_rig_left, rig.T_rig_right)
    f = 0.5 * (left.fx + right.fx)
    half_fov = np.array([left.image_size[0] / 2.0 / f, left.image_size[1] / 2.0 / f])

    def pose(distance, offset, yaw, pitch, roll):
        # Face the rig origin, then tilt about the board's own axes through its centre.
        return board_pose_in_view(R_view, grid_centre, distance, offset, yaw, pitch, roll)

    def acceptable(T_rig_boards):  # (K, 4, 4) -> (K,) bool
        return calibration_views_fit(target, T_rig_boards, rig=rig, left=left, right=right, margin_px=margin_px,
                                     max_obliquity_deg=max_obliquity_deg, min_fraction=min_fraction_visible)

    distance_order = rng.permutation(n_views)
    tilt_phase, position_phase = rng.uniform(0, 2 * np.pi, size=2)
    poses = []
    for i in range(n_views):
        for attempt in range(max_attempts):
            # Later attempts back off: farther and less tilted, so a hard view still gets placed.
            ease = attempt / max_attempts
            distance = lo + (hi - lo) * min(1.0, (distance_order[i] + rng.uniform()) / n_views + ease)
            tilt = max_tilt_deg * rng.uniform(0.4, 1.0) * (1.0 - ease)
            if rng.uniform() < 0.1:
                tilt *= 0.25  # a few nearly fronto-parallel views
            phi = tilt_phase + 2 * np.pi * (i + rng.uniform(-0.3, 0.3)) / n_views
            yaw, pitch, roll = tilt * math.cos(phi), tilt * math.sin(phi), rng.uniform(-15.0, 15.0) * (1 - ease)
            theta = position_phase + 2 * np.pi * ((i * 0.618034) % 1.0) + rng.uniform(-0.2, 0.2)
            direction = np.array([math.cos(theta), math.sin(theta)]) * half_fov

            def fits(pushes, distance=distance, direction=direction, yaw=yaw, pitch=pitch, roll=roll):
                return acceptable(pose(distance, np.multiply.outer(pushes, direction), yaw, pitch, roll))

            # The largest acceptable push toward the edge along ``direction``; none if the centre is not.
            good = _bisect_largest(fits, 0.0, 1.5, steps=12)
            if good is None:
                continue
            fraction = rng.uniform(0.75, 1.0) if rng.uniform() < 0.75 else rng.uniform(0.0, 0.5)
            candidate = pose(distance, fraction * good * direction, yaw, pitch, roll)
            if acceptable(candidate[None])[0]:
                poses.append(candidate)
                break
        else:
            raise ValueError(
                f"could not place calibration view {i + 1} of {n_views} with {min_fraction_visible:.0%} of the "
                f"{len(object_points)} corners in both views at {lo:g}-{hi:g} mm: the views overlap too little "
                f"for this board (B = {rig.baseline_mm:g} mm, "
                f"alpha = {rig.alpha_left_deg:g}/{rig.alpha_right_deg:g} deg)"
            )
    return poses
