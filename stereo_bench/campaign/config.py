"""Campaign configuration: one TOML file, validated by pydantic before anything moves.

The minimal file a user writes is the plan; every other section has a working default that runs on
the simulated rig with simulated cameras::

    [plan]
    baseline_mm = [100, 150]
    distance_mm = [400, 500]
    alpha_deg = [90]

Sections (all optional except ``[plan]``; units in every key's name):

    name, description, seed
    [rig]                 kind = "simulated" | "grbl", port, config_file (a RigConfig TOML) or inline
                          [rig.controller] / [rig.quantities.*] tables, time_scale, homing
    [cameras]             kind = "simulated" | "v4l2", left, right, max_skew_s, [cameras.settings]
                          (CameraSettings fields), [cameras.optics] (simulated optics; also the nominal
                          lens the feasibility prediction uses for real cameras)
    [calibration_board]   the board shown for stereo calibration (11x8 inner corners, 25 mm)
    [target]              the measured board (9x6 inner corners, 27 mm squares)
    [capture]             settle_s, frames_per_config, calibration_views, board_retries, keep_frames,
                          calibration_capture = "auto" | "enter", coverage_gate, max_calibration_views
    [calibration]         max_view_rms_px, exclude_views, review (the per-view errors shown to the operator)
    [extrinsics]          mode = "per-config" | "kinematic" | "nominal" | "fixed", intrinsics = "joint" |
                          "fixed", calib_dir, kinematic_file, repeatability_mm, repeatability_deg,
                          [extrinsics.tolerances] (the rig's stated tolerances, for nominal extrinsics)
    [sim]                 profile = "lab" | "ideal" (the simulated bench's imperfections), and
                          [sim.slide] / [sim.left_head] / ... overrides (drivers/sim/profile.py)
    [plan]                baseline_mm, distance_mm, alpha_deg or toe_in_deg, tilt_deg or tilts_deg

Rig and cameras: simulated + simulated (the default), grbl + v4l2 (the real bench), or grbl +
simulated ("bring-up": the real controller moves, simulated cameras render from the positions it
reports); simulated rig + v4l2 cameras is refused.

Every model forbids unknown keys, so a typo is an error naming the key. Relative paths
(``rig.config_file``, ``extrinsics.calib_dir``, ``extrinsics.kinematic_file``) are resolved against the
campaign file's directory (the working directory for a config with no file) and kept absolute, never
relative to the working directory, so a session records where they are however the command was spelled.
Errors are :class:`ConfigError` with one line: ``FILE: dotted.field: what is wrong``.

Angles: alpha is the angle between the baseline and an optical axis (90 deg = parallel rig); the pan
heads are driven in toe-in t = 90 - alpha.
"""

from __future__ import annotations

import json
import math
import sys
from collections import Counter
from collections.abc import Mapping
from importlib import resources
from itertools import pairwise
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from drivers.camera.base import CameraSettings
from drivers.files import InputFileError, parse_toml, read_toml
from drivers.rig.config import BOUND_REASONS as RIG_BOUND_REASONS
from drivers.rig.config import (
    MAX_TOE_IN_DEG,
    ControllerSettings,
    QuantityMapping,
    RigConfig,
    RigConfigError,
    load_rig_config,
    rig_config_from_dict,
    with_bound_reason,
)
from drivers.sim.profile import SimSettings
from stereo_bench.geometry import (
    DEFAULT_DIST,
    DEFAULT_FOCAL_MM,
    DEFAULT_IMAGE_SIZE,
    DEFAULT_PIXEL_UM,
    CameraModel,
)
from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision.calibrate import MIN_VIEWS
from stereo_bench.vision.uncertainty import DEFAULT_BOARD_SCALE_U_REL, PRINTED_TARGET_SCALE_U_REL

if TYPE_CHECKING:
    from stereo_bench.campaign.extrinsics import ExtrinsicsSource


# cv2.stereoCalibrate through stereo_bench.vision.calibrate.calibrate_stereo needs at least this many views.
MIN_CALIBRATION_VIEWS = MIN_VIEWS  # what calibrate_stereo accepts

PRESETS: dict[str, str] = {
    "paper-exp1": "Yang et al. 2024 experiment 1: Z = 300-700 mm step 100 x B = 50-250 mm step 50, alpha = 90 deg",
    "paper-exp2": "Yang et al. 2024 experiment 2 as the paper writes alpha: Z = 500 mm, B = 100 mm, "
                  "alpha = 5-55 deg step 10 (alpha <= 45 deg: no corner in both views)",
    "paper-exp2-toe-in": "Yang et al. 2024 experiment 2 read as the pan from parallel: Z = 500 mm, B = 100 mm, "
                         "toe-in 5-55 deg step 10 (alpha = 85-35 deg)",
    "paper-exp2-measurable": "Yang et al. 2024 experiment 2, alpha = 5-55 deg step 10 as the paper writes it, made "
                             "measurable: deviates from the paper (B = 600 mm on a 1 m slide, Z = 200 mm, a 6x4 "
                             "board of 27 mm squares, nominal extrinsics) so that both views hold the whole board "
                             "at every angle by the plan (on the simulated lab bench 5 of 6 measure: the 85 deg "
                             "grazing view at alpha = 5 is not detected)",
}


BenchKind = Literal["simulated", "hardware", "bring-up"]

#: The (rig.kind, cameras.kind) combinations a campaign runs on, validated once here.
BENCH_KINDS: dict[tuple[str, str], BenchKind] = {
    ("simulated", "simulated"): "simulated",  # the GRBL emulator on a pty, cameras rendering from its axes
    ("grbl", "v4l2"): "hardware",  # the real rig and the real cameras
    # Bring-up: the real controller drives the motors while the cameras are not mounted yet; simulated
    # cameras render from the positions the controller reports.
    ("grbl", "simulated"): "bring-up",
}
UNSUPPORTED_BENCHES = {
    ("simulated", "v4l2"): "real cameras cannot film the simulated rig; set rig.kind = \"grbl\" (and rig.port) "
                           "for the real rig, or cameras.kind = \"simulated\"",
}


# rig.time_scale: below 0.1 a simulated campaign runs over ten times slower than the real rig would (1e-300 never
# ends); at 10,000 a 350 mm move already lasts under a millisecond.
TIME_SCALE_MIN, TIME_SCALE_MAX = 0.1, 10_000.0

# Bounds on what scales a campaign's work, each checked where the config enters (costs: one core of the shared
# 2-core machine, scripts/bench_input_bounds.py and its scripts/results/bench_input_bounds.json):
#: [capture] frames_per_config: a 1080p stereo frame costs 0.2-0.25 s to render, detect and encode and ~1.9 MB of
#: session; 1,000 is ~4 min and ~1.9 GB per configuration, where a measurement averages 3-20.
MAX_FRAMES_PER_CONFIG = 1_000
#: [capture] calibration_views (and ``model predict --calibration-views``): each view is a stereo frame, and the
#: joint calibration grows faster than the views (12: 0.25 s, 50: 1.5 s, 200: 17 s, 500: ~3 min); a bench collects
#: 10-50.
MAX_CALIBRATION_VIEWS = 500
#: [capture] board_retries: each retry is one more frame; a target not found 3 times is misplaced, not unlucky.
MAX_BOARD_RETRIES = 20
#: [capture] settle_s: the lab bench's heads ring for 0.24 s; a heavy camera on a long arm settles in seconds.
#: A minute is 250 times the simulated ringing, and already 14 days of waiting over a 20,000-configuration plan.
MAX_SETTLE_S = 60.0
#: [cameras.optics] exposure_s (the simulated camera's, also the plan's frame time): UVC cameras expose at most
#: 0.2-1 s (V4L2 exposure_time_absolute up to 2047-10000 in 100 us steps); every frame waits for it.
MAX_EXPOSURE_S = 1.0
#: [cameras.optics] width_px, height_px of the simulated camera: rendering grows with the pixels (a 1080p view
#: 0.06 s, a 4K one 0.16 s, an 8192x4608 one 0.74 s); no UVC camera this bench drives goes past 4K (3840x2160).
MAX_SIMULATED_SIDE_PX = 8192
#: [cameras.optics] blur_px: ``render --blur``'s bound, for the same reason (50 px: 1.5-3.6 s a pair, 200 px: 18-48 s).
MAX_BLUR_PX = 50.0
#: [plan] baseline_mm: at least the narrowest camera's width (even board cameras are ~8 mm wide): two optical centres
#: cannot come closer than their housings. At the measurement's own floor (|T| >= calibrate.MIN_BASELINE_MM, 1 mm) a
#: plan was a coin flip: B = 1 mm planned "feasible", then on the lab bench, whose cameras sit 1.8 and -2.6 mm
#: sideways of their heads' axes, the right camera came out 3 mm to the LEFT and the calibration was refused as
#: swapped, and on the ideal bench |T| = 0.998 mm was refused as one viewpoint. (1e-300 ran into "T is zero".) At
#: most 10 m (``--baseline``'s bound: a 10 m rig is no bench). Values outside the rig's soft limits are planned as such.
MIN_PLAN_BASELINE_MM = 8.0
MAX_BASELINE_MM = 10_000.0
#: [plan] distance_mm: at most 100 m (``--distance``'s bound: at 100 m a 27 mm square is under 1 px).
MAX_DISTANCE_MM = 100_000.0
#: Why each bound above is where it is, said with its refusal (with the rig's, drivers.rig.config.BOUND_REASONS).
BOUND_REASONS = {
    **RIG_BOUND_REASONS,
    "capture.frames_per_config": "a 1080p stereo frame costs ~0.2 s and ~1.9 MB of session; a measurement "
                                 "averages 3-20",
    "capture.calibration_views": "each view is a stereo frame, and 500 take ~3 min to calibrate; a bench "
                                 "collects 10-50",
    "capture.board_retries": "a target not found 3 times is misplaced",
    "capture.settle_s": "the heads ring for 0.24 s; a heavy rig settles in seconds",
    "cameras.optics.exposure_s": "UVC cameras expose at most 0.2-1 s",
    "cameras.optics.width_px": "rendering grows with the pixels; no camera of this bench is past 4K",
    "cameras.optics.height_px": "rendering grows with the pixels; no camera of this bench is past 4K",
    "cameras.optics.blur_px": "render --blur's bound: no board is found at 50 px, and 200 px renders in 18-48 s",
}


class ConfigError(ValueError):
    """A campaign configuration that cannot be used: one line, ``FILE: dotted.field: what is wrong``."""


# strict: no string-to-number or bool-to-number coercion (TOML "100" or true is not 100 mm); an integer is still
# accepted for a float field (TOML 100 for 100.0). Paths are lax (strict=False) so TOML strings load as paths.
_STRICT = ConfigDict(extra="forbid", strict=True)


def _resolve(path: Path | None, info: ValidationInfo) -> Path | None:
    """A file a campaign names, made absolute (against the campaign file's directory, else the working directory)
    and resolved: recorded in a session so that a resume matches however the plan or the cwd is spelled."""
    base = (info.context or {}).get("base_dir")
    if path is None:
        return path
    given = path if path.is_absolute() or base is None else Path(base) / path
    try:
        return given.resolve()
    except (RuntimeError, OSError) as error:  # a symlink loop: RuntimeError before Python 3.13, OSError (ELOOP) after
        raise ValueError(f"{given}: cannot be resolved ({error})") from None


# --------------------------------------------------------------------------------------------------
# Boards


class TargetConfig(BaseModel):
    """A board. Checkerboard: ``cols`` x ``rows`` INNER CORNERS; ChArUco: ``cols`` x ``rows`` SQUARES."""

    model_config = _STRICT

    kind: Literal["checkerboard", "charuco"] = "checkerboard"
    cols: int = Field(9, ge=2, description="checkerboard: inner corners per row; charuco: squares per row")
    rows: int = Field(6, ge=2, description="checkerboard: inner corners per column; charuco: squares per column")
    square_mm: float = Field(27.0, gt=0, allow_inf_nan=False, description="side of one square, mm")
    marker_mm: float | None = Field(None, gt=0, allow_inf_nan=False,
                                    description="charuco only: ArUco marker side, mm (default 0.75 * square_mm)")
    dictionary: str = Field("DICT_5X5_1000", description="charuco only: OpenCV ArUco dictionary name")
    scale_u_rel: float | None = Field(
        None, ge=0, le=0.1, allow_inf_nan=False,
        description="relative standard uncertainty of the board's square (its certificate or the printer's "
                    "tolerance): the uncertainty budget's target component. Default by role: the measured "
                    "[target] 5.8e-4 (an office laser/inkjet print is +-0.1 % in scale from the paper feed: "
                    "0.1 %/sqrt(3)); the [calibration_board] 1e-4 (the bench's length reference, a rigid "
                    "certified board: what inspection reports of precision boards state)")

    @model_validator(mode="after")
    def _check(self) -> TargetConfig:
        if self.kind == "checkerboard":
            # By value, not by "was it set": a recorded config (every field written out) must load again.
            default = type(self).model_fields["dictionary"].default
            for name, value in (("marker_mm", self.marker_mm is not None), ("dictionary", self.dictionary != default)):
                if value:
                    raise ValueError(f"{name} is only for kind = \"charuco\"")
        elif self.cols < 3 or self.rows < 3:
            raise ValueError(f"a ChArUco board of {self.cols}x{self.rows} squares has too few inner corners "
                             "(cols and rows count squares for charuco: at least 3 each)")
        try:
            self.build()
        except ValueError as error:
            raise ValueError(str(error)) from None
        return self

    def build(self) -> Checkerboard | CharucoTarget:
        """The board model (corner coordinates, texture) this config describes."""
        if self.kind == "checkerboard":
            return Checkerboard(self.cols, self.rows, self.square_mm)
        marker = self.marker_mm if self.marker_mm is not None else 0.75 * self.square_mm
        return CharucoTarget(self.cols, self.rows, self.square_mm, marker, dictionary=self.dictionary)

    def scale_u(self, role: str) -> float:
        """The board's relative scale uncertainty: stated, or the default of its ``role`` ("target": a print,
        "calibration_board": a certified board)."""
        if self.scale_u_rel is not None:
            return self.scale_u_rel
        return PRINTED_TARGET_SCALE_U_REL if role == "target" else DEFAULT_BOARD_SCALE_U_REL

    def describe(self) -> str:
        """E.g. 'checkerboard 9x6 inner corners, 27 mm squares'."""
        grid = "inner corners" if self.kind == "checkerboard" else "squares"
        return f"{self.kind} {self.cols}x{self.rows} {grid}, {self.square_mm:g} mm squares"


def _default_calibration_board() -> TargetConfig:
    return TargetConfig(cols=11, rows=8, square_mm=25.0)


# --------------------------------------------------------------------------------------------------
# Rig and cameras


class OpticsConfig(BaseModel):
    """Simulated optics; for real cameras, the nominal lens and sensor the feasibility prediction uses."""

    model_config = _STRICT

    # focal and pixel: the CLI's --focal and --pixel ranges (a 1 m lens is a telescope; pixels are 1-30 um)
    focal_mm: float = Field(DEFAULT_FOCAL_MM, gt=0, le=1000, allow_inf_nan=False, description="lens focal length, mm")
    pixel_um: float = Field(DEFAULT_PIXEL_UM, gt=0, le=100, allow_inf_nan=False,
                            description="pixel pitch, micrometres")
    width_px: int = Field(DEFAULT_IMAGE_SIZE[0], ge=2, le=MAX_SIMULATED_SIDE_PX)
    height_px: int = Field(DEFAULT_IMAGE_SIZE[1], ge=2, le=MAX_SIMULATED_SIDE_PX)
    dist: list[float] = Field(default_factory=lambda: list(DEFAULT_DIST),
                              description="OpenCV distortion coefficients (k1 k2 p1 p2 [k3 ...])")
    # an 8-bit pixel spans 255 DN: noise beyond it is no image
    noise_dn: float = Field(2.0, ge=0, le=255, allow_inf_nan=False, description="read noise, 8-bit DN (std)")
    blur_px: float = Field(0.7, ge=0, le=MAX_BLUR_PX, allow_inf_nan=False,
                           description="optical blur, Gaussian sigma, px")
    exposure_s: float = Field(0.02, gt=0, le=MAX_EXPOSURE_S, allow_inf_nan=False,
                              description="exposure time of a frame, s")

    @field_validator("dist")
    @classmethod
    def _dist_length(cls, value: list[float]) -> list[float]:
        if len(value) not in (4, 5, 8, 12, 14):
            raise ValueError(f"OpenCV takes 4, 5, 8, 12 or 14 distortion coefficients, not {len(value)}")
        if not all(math.isfinite(v) for v in value):
            raise ValueError("distortion coefficients must be finite numbers")
        return value

    @property
    def focal_px(self) -> float:
        return self.focal_mm * 1000.0 / self.pixel_um

    def camera_model(self, name: str = "camera") -> CameraModel:
        return CameraModel.from_sensor(
            focal_mm=self.focal_mm, pixel_um=self.pixel_um, image_size=(self.width_px, self.height_px),
            dist=tuple(self.dist), name=name,
        )


class RigSection(BaseModel):
    """The motorised rig: the GRBL emulator on a pty (``simulated``) or a real controller (``grbl``).

    The axis mapping and soft limits come from ``config_file`` (a RigConfig TOML), or from inline
    ``[rig.controller]`` / ``[rig.quantities.NAME]`` tables (same layout as that file), or default to
    X = baseline 1-349 mm, Y/Z = left/right toe-in 0-88 deg, tilts fixed at 0, target distance manual.
    """

    model_config = _STRICT

    kind: Literal["simulated", "grbl"] = "simulated"
    port: str | None = Field(None, description="grbl: serial device or pyserial URL of the controller")
    config_file: Path | None = Field(None, strict=False,
                                     description="rig configuration TOML, relative to the campaign file")
    controller: ControllerSettings | None = Field(None, description="inline rig config: controller settings")
    quantities: dict[str, QuantityMapping] | None = Field(
        None, description="inline rig config: quantity -> axis mapping (missing quantities keep the default)")
    time_scale: float = Field(1.0, ge=TIME_SCALE_MIN, le=TIME_SCALE_MAX, allow_inf_nan=False,
                              description="simulated rig only: simulated seconds per real second")
    homing: bool = Field(True, description="run the homing cycle ($H) before the first move; false states that the "
                                           "position the controller reports is right as it is (as `rig unlock "
                                           "--trust-position`; recorded in the session)")

    _rig_config: RigConfig | None = PrivateAttr(None)

    @field_validator("quantities")
    @classmethod
    def _check_quantities(cls, value: dict[str, QuantityMapping] | None) -> dict[str, QuantityMapping] | None:
        if value is not None:
            try:  # the cross-quantity checks (known names, one quantity per axis) are RigConfig's
                rig_config_from_dict({"quantities": value}, source="inline")
            except RigConfigError as error:
                raise ValueError(str(error).removeprefix("inline: ").removeprefix("quantities: ")) from None
        return value

    @field_validator("config_file")
    @classmethod
    def _resolve_config_file(cls, value: Path | None, info: ValidationInfo) -> Path | None:
        return _resolve(value, info)

    @model_validator(mode="after")
    def _check(self) -> RigSection:
        if self.kind == "grbl" and not self.port:
            raise ValueError("kind = \"grbl\" needs port (the controller's serial device)")
        if self.kind == "simulated" and self.port is not None:
            raise ValueError("port is set but kind is \"simulated\": set kind = \"grbl\" to use the controller "
                             "on that port, or remove port")
        if self.kind == "grbl" and self.time_scale != 1.0:
            raise ValueError("time_scale is for the simulated rig only")
        if self.config_file is not None and (self.controller is not None or self.quantities is not None):
            raise ValueError("give the rig mapping in config_file or inline ([rig.quantities]), not both")
        if self.config_file is None and (self.controller is not None or self.quantities is not None):
            self._rig_config = RigConfig(
                controller=self.controller or ControllerSettings(), quantities=self.quantities or {})
        return self

    def rig_config(self) -> RigConfig:
        """The RigConfig (mapping, limits, feeds): from config_file (read on first call), inline, or default.

        Raises :class:`drivers.rig.config.RigConfigError` for an unusable file (load_campaign has already
        checked it for configs read from a file).
        """
        if self._rig_config is None:
            self._rig_config = load_rig_config(self.config_file) if self.config_file is not None else RigConfig()
        return self._rig_config


class CamerasSection(BaseModel):
    """The stereo pair: simulated (rendered from the rig's pose) or two V4L2 cameras bound by identity."""

    model_config = _STRICT

    kind: Literal["simulated", "v4l2"] = "simulated"
    left: str | None = Field(None, description="v4l2: stable spec of the left camera, e.g. 'by-id:...', "
                                               "'usb-port:1-2', 'serial:ABC'")
    right: str | None = Field(None, description="v4l2: stable spec of the right camera")
    settings: dict[str, Any] = Field(default_factory=dict,
                                     description="CameraSettings fields applied to both cameras and read back")
    optics: OpticsConfig = Field(default_factory=OpticsConfig)
    max_skew_s: float = Field(0.02, gt=0, allow_inf_nan=False,
                              description="reject stereo pairs whose left-right grab times differ by more, s")

    @field_validator("settings")
    @classmethod
    def _check_settings(cls, value: dict[str, Any]) -> dict[str, Any]:
        try:
            CameraSettings.model_validate(value)
        except ValidationError as error:
            first = error.errors()[0]
            where = _dotted(tuple(first.get("loc", ())))
            message = first.get("msg", "invalid").removeprefix("Value error, ")
            if first.get("type") == "extra_forbidden":
                message = f"unknown camera setting; known: {', '.join(CameraSettings.model_fields)}"
            raise ValueError(f"{where}: {message}" if where != "(top level)" else message) from None
        return value

    @model_validator(mode="after")
    def _check(self) -> CamerasSection:
        if self.kind == "v4l2" and (not self.left or not self.right):
            raise ValueError("kind = \"v4l2\" needs left and right (e.g. 'by-id:usb-...', 'usb-port:1-2')")
        return self

    def camera_settings(self) -> CameraSettings:
        return CameraSettings.model_validate(self.settings)


class CaptureSection(BaseModel):
    """What is captured at each configuration, and how long the rig is left to settle first."""

    model_config = _STRICT

    settle_s: float = Field(0.3, ge=0, le=MAX_SETTLE_S, allow_inf_nan=False,
                            description="wait after a move before capturing, s")
    frames_per_config: int = Field(3, ge=1, le=MAX_FRAMES_PER_CONFIG,
                                   description="stereo frames of the target measured per configuration")
    calibration_views: int = Field(12, ge=1, le=MAX_CALIBRATION_VIEWS,
                                   description="calibration-board views per configuration (per-config)")
    board_retries: int = Field(3, ge=0, le=MAX_BOARD_RETRIES,
                               description="re-captures of a measurement frame whose target is not detected "
                                           "(calibration views without the board are dropped by the calibration "
                                           "instead)")
    keep_frames: Literal["all", "measurement", "none"] = Field(
        "all", description="frames written to the session: all; measurement (calibration views are not kept: "
                           "their detections and the calibration are, and a replay calibrates from those); "
                           "none (no frames: a replay cannot reproduce the configurations)")
    calibration_capture: Literal["auto", "enter"] | None = Field(
        None, description="how calibration views are taken: auto (the cameras stream while the operator moves the "
                          "board; a view is kept when it is still and new, until the coverage gate opens: "
                          "stereo_bench/campaign/autocapture.py) or enter (one view per press of Enter; the "
                          "simulator presents a still board per view). Default: auto for v4l2 cameras, enter for "
                          "simulated ones (auto there: the simulated hand presents the board, [sim] presenter)")
    coverage_gate: Literal["bars", "count"] = Field(
        "bars", description="auto capture: calibrate once every coverage bar is full in both cameras (bars) or once "
                            "calibration_views views are kept (count); never with fewer than calibration_views")
    max_calibration_views: int = Field(
        40, ge=1, le=MAX_CALIBRATION_VIEWS,
        description="auto capture: calibrate with this many views kept whatever the bars say (ROS calls 40 enough)")

    def calibration_capture_for(self, cameras_kind: str) -> str:
        """``calibration_capture`` or its default for ``cameras_kind`` (auto for v4l2, enter for simulated)."""
        if self.calibration_capture is not None:
            return self.calibration_capture
        return "auto" if cameras_kind == "v4l2" else "enter"


class CalibrationSection(BaseModel):
    """Which calibration views each per-configuration calibration uses beyond its own outlier rule, and whether the
    operator reviews the per-view errors first (a one-screen summary in the terminal: threshold, exclude,
    recalibrate, accept; docs/CALIBRATION.md)."""

    model_config = _STRICT

    max_view_rms_px: float | None = Field(
        None, gt=0, allow_inf_nan=False,
        description="views whose reprojection RMS (the worse of the two cameras) exceeds this are excluded and the "
                    "configuration calibrated again without them, px (None: only the calibration's own outlier rule)")
    exclude_views: list[int] = Field(
        default_factory=list, description="calibration views (indices within each configuration, from 0) left out of "
                                          "every per-configuration calibration")
    review: bool | None = Field(
        None, description="after each configuration's calibration, show the operator the per-view errors to set a "
                          "threshold, exclude views and recalibrate before measuring. Default: true with v4l2 cameras "
                          "(an operator is at the bench), false with simulated ones")

    @field_validator("exclude_views")
    @classmethod
    def _check_views(cls, value: list[int]) -> list[int]:
        if any(index < 0 for index in value):
            raise ValueError("view indices count from 0")
        return sorted(set(value))

    def review_for(self, cameras_kind: str) -> bool:
        return self.review if self.review is not None else cameras_kind == "v4l2"


def _tolerance(default: float, why: str, unit: str) -> Any:
    return Field(default, ge=0, allow_inf_nan=False, description=f"standard uncertainty, {unit}: {why}")


class RigTolerances(BaseModel):
    """The rig's stated tolerances: how far the rig as built may be from its ideal geometry (standard
    uncertainties, per camera where it applies). ``nominal`` extrinsics take R, T from the ideal geometry at the
    commanded B and alphas; these tolerances are their uncertainty (the budget's structure component,
    :func:`stereo_bench.kinematics.nominal_covariance`). The defaults describe a bench built from hobby-grade
    catalogue parts and not measured (the class of bench docs/SIMULATED_BENCH.md's ``lab`` profile simulates);
    a rig built exactly (the ``ideal`` simulated bench) states zeros.
    """

    model_config = _STRICT

    baseline_zero_mm: float = _tolerance(
        0.5, "homing switch and head plates placed at assembly to ~0.5 mm; the centres' separation at the "
             "commanded B", "mm")
    baseline_scale: float = _tolerance(
        0.001, "lead screw of accuracy class C10 (0.07 %) plus the rounding of steps/mm: separation error per mm "
               "of commanded B", "1")
    slide_direction_deg: float = _tolerance(
        0.3, "rail squared to the camera plate by eye and a try-square on an extrusion frame (+-0.3 deg), each of "
             "two directions", "deg")
    centre_forward_mm: float = _tolerance(
        23.0, "the ideal geometry turns each camera about its optical centre; an M12 lens's entrance pupil "
              "stands 15-30 mm ahead of the pan axis (the same lens and head on both sides: one offset shared "
              "by both), uncorrected: sqrt(22.5^2 + 15^2 / 12)", "mm")
    centre_forward_each_mm: float = _tolerance(
        1.0, "each camera's own forward offset about the shared one: the same head and camera mounted again "
             "land ~1 mm apart", "mm")
    centre_sideways_mm: float = _tolerance(2.0, "camera centred on the head's screw by eye: a few mm (each)", "mm")
    centre_height_mm: float = _tolerance(0.5, "head plates' thickness tolerance (each)", "mm")
    yaw_deg: float = _tolerance(
        0.3, "pan homing switch placed to 0.1-0.2 deg, camera screwed on with +-0.5 deg of play (M2 screws in "
             "clearance holes): sqrt(0.15^2 + 0.29^2)", "deg")
    pitch_deg: float = _tolerance(0.3, "camera mount, as yaw_deg (plate flatness, screw clearance)", "deg")
    roll_deg: float = _tolerance(0.3, "camera mount, as yaw_deg", "deg")
    axis_tilt_deg: float = _tolerance(
        0.3, "pan axis off vertical (bearing seat and plate perpendicularity of a hobby pan-tilt head), each of "
             "two directions", "deg")
    pan_scale: float = _tolerance(0.002, "belt reduction: effective pitch radius 0.1-0.3 % off nominal", "1")
    pan_repeat_deg: float = _tolerance(
        0.02, "half the backlash of a tensioned belt reduction (0.02-0.05 deg) and its repeatability", "deg")

    def sigmas(self) -> dict[str, float]:
        return self.model_dump()


class ExtrinsicsSection(BaseModel):
    """Where the stereo extrinsics R, T come from.

    ``per-config`` (default): re-estimated at each configuration from views of the calibration board,
    with the intrinsics refined jointly (``intrinsics = "joint"``, the default: scripts/bench_extrinsics_mode.py
    measured abs(T) errors of 0.001 vs 0.002 mm, square errors equal) or held, not refined (``"held"``: from
    ``calib_dir`` if given, else from mono calibrations of the same views; ``"fixed"``, its spelling before
    issue 21, is still accepted with a note: it read like ``mode = "fixed"``, which is R, T from a file).
    ``fixed``: R, T (and the intrinsics) read from ``calib_dir`` (OpenCV stereo_calib layout: intrinsics.yml,
    extrinsics.yml).
    ``kinematic``: R, T predicted at each configuration by the kinematic rig model
    (:mod:`stereo_bench.kinematics`) from the rig's reported axis positions and directions of approach; the
    model (with both cameras' intrinsics) is fitted once, in one joint adjustment, to calibration views at
    a design of configurations the plan chooses, or read from ``kinematic_file`` (no design visits).
    ``nominal``: R, T of the ideal geometry at the commanded B and alphas (a user who trusts the rig's
    scales); the intrinsics from ``calib_dir`` if given, else from one stereo calibration at the first
    configuration; the uncertainty of R, T is the rig's stated ``tolerances``. ``kinematic_file`` in the
    other modes adds the model's prediction as a comparison (the structure document).
    """

    model_config = _STRICT

    mode: Literal["per-config", "kinematic", "nominal", "fixed"] = "per-config"
    intrinsics: Literal["joint", "held", "fixed"] = Field(
        "joint", description="per-config: the intrinsics refined jointly with R, T (joint) or held, not refined "
                             "(held: calib_dir's, else the same views' mono calibrations); \"fixed\" is held's old "
                             "spelling (mode \"fixed\" is R, T from calib_dir)")
    calib_dir: Path | None = Field(None, strict=False,
                                   description="calibration directory, relative to the campaign file")
    lens_model: Literal["auto", "fixed-aspect", "opencv4", "opencv5", "thin-prism", "rational",
                        "legacy"] | None = Field(
        None, description="the per-configuration calibrations' lens model (stereo_bench.vision.lensmodels; "
                          "calibrate --lens-model): auto (chosen on held-out views) or a name. Default: auto for "
                          "v4l2 cameras; for simulated cameras opencv4 without a comparison (the model their "
                          "recorded numbers were calibrated with; their lens has square pixels and two radial "
                          "terms, which auto fits as fixed-aspect, equivalently). \"legacy\": that fit without a "
                          "comparison whatever the cameras, as every calibration ran before lens models were "
                          "compared (a session recorded without this key replays with it)")
    kinematic_file: Path | None = Field(
        None, strict=False,
        description="a saved kinematic rig model (TOML, stereo-bench rig calibrate-kinematics), relative to "
                    "the campaign file: kinematic mode uses it instead of visiting a design")
    repeatability_mm: float = Field(
        0.003, ge=0, le=1, allow_inf_nan=False,
        description="std of the slide's landing error per move, mm (kinematic model: prior of the fit and part of "
                    "each prediction's uncertainty). Default: a stepper lead-screw slide repeats to +-0.01 mm "
                    "(~3 sigma)")
    repeatability_deg: float = Field(
        0.002, ge=0, le=1, allow_inf_nan=False,
        description="std of each pan head's landing error per move, deg. Default: a microstepped stepper "
                    "through a tensioned belt repeats to +-0.005 deg (~2.5 sigma)")
    tolerances: RigTolerances = Field(default_factory=RigTolerances,
                                      description="the rig's stated tolerances (nominal extrinsics' uncertainty)")
    design: Literal["presented", "fixed-board"] = Field(
        "presented", description="kinematic: how the model's design is calibrated. presented: the operator presents "
                                 "the calibration board at every design visit (12 views each); fixed-board: the "
                                 "operator places the board once and the rig moves through a design of slide and pan "
                                 "positions in front of it (docs/EXTRINSICS.md)")
    fixed_board_views: int = Field(
        3, ge=1, le=50, strict=True,
        description="fixed-board design: stereo frames of the board captured at each visit (no presentation)")
    fixed_board_lens: Literal["auto", "present", "none"] = Field(
        "auto", description="fixed-board design without calib_dir: a lens calibration of capture.calibration_views "
                            "presented views before the board is placed, its intrinsics and covariance the fit's "
                            "prior. auto: when the plan's identifiability table says the fixed board alone leaves "
                            "parameters undetermined that such a prior determines; present: always; none: never "
                            "(what the board alone cannot identify is held nominal)")
    plan_corner_sigma_px: float = Field(
        0.1, gt=0, le=5, allow_inf_nan=False,
        description="fixed-board design: the corner noise (px) the plan's identifiability table and its lens plan "
                    "(fixed_board_lens = auto) assume. 0.1: a good camera; the simulated lab bench and the real "
                    "webcam sets calibrate to 0.13-0.6 px RMS (docs/SIMULATED_BENCH.md), where the table holds more "
                    "parameters nominal and auto may add a lens calibration (docs/EXTRINSICS.md)")
    design_tilt: Literal["auto", "include", "hold"] = Field(
        "auto", description="fixed-board design on a rig that drives the tilts (grblHAL's A/B): include: the design "
                            "steps them and the model has tilt joints (predictions at any tilt); hold: the design "
                            "keeps the campaign's one tilt (no joints: predictions at that tilt only); auto: include "
                            "when the plan has more than one tilt (at one tilt the joints cost the right camera's "
                            "height 2.4x its sigma, docs/EXTRINSICS.md)")

    @field_validator("calib_dir", "kinematic_file")
    @classmethod
    def _resolve_paths(cls, value: Path | None, info: ValidationInfo) -> Path | None:
        return _resolve(value, info)

    @model_validator(mode="after")
    def _check(self) -> ExtrinsicsSection:
        self.source().check(self)
        if self.design != "presented" and self.mode != "kinematic":
            raise ValueError(f"design = {self.design!r} is a kinematic model's design: it needs mode = \"kinematic\", "
                             f"not {self.mode!r}")
        return self

    @property
    def fixed_board(self) -> bool:
        """The kinematic design is fitted from one board placed once (``design = "fixed-board"``)."""
        return self.mode == "kinematic" and self.design == "fixed-board" and self.kinematic_file is None

    def lens_model_for(self, cameras_kind: str) -> str | None:
        """The lens model per-configuration calibrations fit (``lens_model`` or its default for ``cameras_kind``);
        None: the default flags without a comparison (:func:`~stereo_bench.vision.pipeline.calibrate_from_images`)."""
        if self.lens_model == "legacy":
            return None
        if self.lens_model is not None:
            return self.lens_model
        return "auto" if cameras_kind == "v4l2" else None

    @property
    def intrinsics_held(self) -> bool:
        """The stereo calibration holds the intrinsics (``held``, or its old spelling ``fixed``)."""
        return self.intrinsics in ("held", "fixed")

    def source(self) -> ExtrinsicsSource:
        """The strategy object of ``mode`` (:mod:`stereo_bench.campaign.extrinsics`): what the plan, the runner and
        the report ask instead of the name."""
        from stereo_bench.campaign.extrinsics import extrinsics_source

        return extrinsics_source(self.mode)


#: The extrinsics sources' names, in the order the report lists them (one module each in campaign/extrinsics/).
EXTRINSICS_MODES: tuple[str, ...] = get_args(ExtrinsicsSection.model_fields["mode"].annotation)


# The interval each plan value must lie in, and whether each end is allowed. The angles' ends are the rule
# drivers.rig.config.along_baseline states (alpha 0 or 180: a camera looks along the baseline).
_PLAN_BOUNDS = {
    "baseline_mm": (MIN_PLAN_BASELINE_MM, MAX_BASELINE_MM, (True, True)),
    "distance_mm": (0.0, MAX_DISTANCE_MM, (False, True)),
    "alpha_deg": (0.0, 180.0, (False, False)),
    "toe_in_deg": (-MAX_TOE_IN_DEG, MAX_TOE_IN_DEG, (False, False)),
    "tilts_deg": (-90.0, 90.0, (False, False)),
}
_ALONG = ": a camera would look along (or behind) the baseline, at the other camera, not at the target"
# Why a value beyond each end is refused, where the interval alone does not say it: (below, above).
_WHY = {"baseline_mm": (f": below {MIN_PLAN_BASELINE_MM:g} mm two cameras' optical centres would be closer than "
                        "their housings allow (even board cameras are ~8 mm wide)", ""),
        "alpha_deg": (_ALONG, _ALONG), "toe_in_deg": (_ALONG, _ALONG)}


#: The most configurations one campaign plans: a plan of 10,000 takes ~3 s to check (scripts/bench_plan.py) and its
#: run days even on the simulated bench (each configuration calibrates and measures); beyond this is a typo
#: (a step of 0.001 instead of 1) or several campaigns' work.
MAX_PLAN_CONFIGURATIONS = 20_000


#: Plan values closer than this (mm or deg) are one position (no rig resolves them): listed twice, they are refused.
PLAN_RESOLUTION = 1e-6


class PlanSection(BaseModel):
    """The grid of configurations: every combination of baseline, distance and angle.

    Give the angle as ``alpha_deg`` (between baseline and optical axis, 90 = parallel) or as
    ``toe_in_deg`` (90 - alpha, 0 = parallel), not both; neither means alpha = [90].
    """

    model_config = _STRICT

    baseline_mm: list[float] = Field(description=f"baselines B, mm ({MIN_PLAN_BASELINE_MM:g} to "
                                                 f"{MAX_BASELINE_MM:g})")
    distance_mm: list[float] = Field(description=f"target distances Z from the baseline, mm (> 0, at most "
                                                 f"{MAX_DISTANCE_MM:g})")
    alpha_deg: list[float] | None = Field(None, description="alphas, deg, in (0, 180); 90 = parallel rig")
    toe_in_deg: list[float] | None = Field(None, description="toe-ins, deg, in (-90, 90); 0 = parallel rig")
    tilt_deg: float = Field(0.0, gt=-90, lt=90, allow_inf_nan=False,
                            description="tilt of both cameras, deg (> 0 looks down)")
    tilts_deg: list[float] | None = Field(
        None, description="tilts of both cameras, deg, each a part of the grid (a rig that drives the tilts: "
                          "grblHAL's A/B); instead of tilt_deg")

    @field_validator("baseline_mm", "distance_mm", "alpha_deg", "toe_in_deg", "tilts_deg")
    @classmethod
    def _check_list(cls, values: list[float] | None, info: ValidationInfo) -> list[float] | None:
        if values is None:
            return None
        low, high, (low_in, high_in) = _PLAN_BOUNDS[info.field_name]
        if not values:
            raise ValueError("needs at least one value")
        for value in values:
            inside = (low <= value if low_in else low < value) and (value <= high if high_in else value < high)
            if not (math.isfinite(value) and inside):
                below, above = _WHY.get(info.field_name, ("", ""))
                why = "" if not math.isfinite(value) else below if value <= low else above
                raise ValueError(f"value {value:g} outside {'[' if low_in else '('}{low:g}, {high:g}"
                                 f"{']' if high_in else ')'}{why}")
        repeated = [value for value, count in Counter(values).items() if count > 1]  # linear: 10,000 values in ms
        if repeated:
            raise ValueError(f"lists {min(repeated):g} more than once")
        close = next(((a, b) for a, b in pairwise(sorted(values)) if b - a < PLAN_RESOLUTION), None)
        if close:  # two ids, one position: the rig cannot tell them apart
            raise ValueError(f"lists {close[0]!r} and {close[1]!r}, closer than {PLAN_RESOLUTION:g}: the same "
                             "position twice")
        return values

    @model_validator(mode="after")
    def _check(self) -> PlanSection:
        if self.alpha_deg is not None and self.toe_in_deg is not None:
            raise ValueError("give alpha_deg or toe_in_deg, not both")
        if self.alpha_deg is None and self.toe_in_deg is None:
            self.alpha_deg = [90.0]
        if self.tilts_deg is not None and self.tilt_deg != 0.0:  # (a recorded config holds both: tilt_deg 0)
            raise ValueError("give tilt_deg or tilts_deg, not both")
        angles = self.alpha_deg if self.toe_in_deg is None else self.toe_in_deg
        counts = (len(self.baseline_mm), len(self.distance_mm), len(angles or ()), len(self.tilts()))
        if math.prod(counts) > MAX_PLAN_CONFIGURATIONS:
            tilts = f" x {counts[3]:,} tilts" if self.tilts_deg is not None else ""
            raise ValueError(f"{math.prod(counts):,} configurations ({counts[0]:,} baselines x {counts[1]:,} distances "
                             f"x {counts[2]:,} angles{tilts}): at most {MAX_PLAN_CONFIGURATIONS:,} per campaign; split "
                             "the grid into several campaigns")
        return self

    def tilts(self) -> list[float]:
        """The tilts of the grid in the order written (``tilts_deg``, else the one ``tilt_deg``)."""
        return [float(t) for t in self.tilts_deg] if self.tilts_deg is not None else [float(self.tilt_deg)]

    def angles_deg(self) -> list[tuple[float, float]]:
        """(alpha, toe-in) pairs in the order written."""
        if self.toe_in_deg is not None:
            return [(90.0 - t, t) for t in self.toe_in_deg]
        return [(a, 90.0 - a) for a in self.alpha_deg or [90.0]]


class CampaignConfig(BaseModel):
    """A whole campaign: what to drive, what to capture, how to calibrate, and the grid of configurations."""

    model_config = _STRICT

    name: str = Field("campaign", min_length=1, description="campaign name, recorded with the session")
    description: str = ""
    # 0 .. 2^32 - 1: the simulator's random streams take the seed as one 32-bit word (drivers/sim), so a larger or
    # negative seed would silently repeat another's numbers.
    seed: int = Field(0, ge=0, le=2**32 - 1,
                      description="seed of every random choice (simulated noise, calibration poses), 0 to 4294967295")
    rig: RigSection = Field(default_factory=RigSection)
    cameras: CamerasSection = Field(default_factory=CamerasSection)
    calibration_board: TargetConfig = Field(default_factory=_default_calibration_board,
                                            description="board shown for stereo calibration (not the target)")
    target: TargetConfig = Field(default_factory=TargetConfig, description="the measured board")
    capture: CaptureSection = Field(default_factory=CaptureSection)
    calibration: CalibrationSection = Field(default_factory=CalibrationSection,
                                            description="views excluded from the per-configuration calibrations, and "
                                                        "the operator's review of their per-view errors")
    extrinsics: ExtrinsicsSection = Field(default_factory=ExtrinsicsSection)
    sim: SimSettings = Field(default_factory=SimSettings,
                             description="the simulated bench's imperfections (simulated cameras: the simulated "
                                         "bench and bring-up)")
    plan: PlanSection

    def _check_excluded_views(self) -> None:
        """[calibration] exclude_views against the views a configuration takes: an index no view has is a typo, and
        excluding all but a few leaves a calibration that cannot run; both found before any motion."""
        capture, excluded = self.capture, self.calibration.exclude_views
        enter = capture.calibration_capture_for(self.cameras.kind) == "enter"
        most = capture.calibration_views if enter else max(capture.calibration_views, capture.max_calibration_views)
        beyond = [index for index in excluded if index >= most]
        if beyond:
            raise ValueError(f"calibration.exclude_views: no view {beyond[0]}: a configuration takes views 0 to "
                             f"{most - 1} (capture.{'calibration_views' if enter else 'max_calibration_views'})")
        left = capture.calibration_views - len(excluded)
        if enter and left < MIN_CALIBRATION_VIEWS:
            raise ValueError(f"calibration.exclude_views: leaves {left} of capture.calibration_views = "
                             f"{capture.calibration_views}, fewer than the {MIN_CALIBRATION_VIEWS} a calibration needs")

    @model_validator(mode="after")
    def _check(self) -> CampaignConfig:
        if (self.rig.kind, self.cameras.kind) not in BENCH_KINDS:
            raise ValueError(f"rig.kind = \"{self.rig.kind}\" with cameras.kind = \"{self.cameras.kind}\" is not a "
                             f"bench: {UNSUPPORTED_BENCHES[self.rig.kind, self.cameras.kind]}")
        extrinsics = self.extrinsics
        if (extrinsics.source().needs_calibration_views(extrinsics)
                and self.capture.calibration_views < MIN_CALIBRATION_VIEWS):
            raise ValueError(f"capture.calibration_views: {extrinsics.mode} extrinsics need at least "
                             f"{MIN_CALIBRATION_VIEWS} calibration views, not {self.capture.calibration_views}")
        if extrinsics.source().needs_calibration_views(extrinsics) and self.calibration.exclude_views:
            self._check_excluded_views()
        if self.calibration_capture == "auto" and self.cameras.kind == "simulated" and self.sim.presenter == "still":
            raise ValueError("capture.calibration_capture = \"auto\" takes views of a board the operator moves; "
                             "[sim] presenter = \"still\" does not move it: use presenter = \"hand\" (or leave it "
                             "out)")
        if (len(set(self.plan.tilts())) > 1 and extrinsics.mode == "kinematic" and extrinsics.kinematic_file is None
                and (not extrinsics.fixed_board or extrinsics.design_tilt == "hold")):
            why = ("design_tilt = \"hold\" keeps one tilt" if extrinsics.fixed_board
                   else "the presented design's fit has no tilt joints")
            raise ValueError(f"plan.tilts_deg: a kinematic model fitted at one tilt predicts R, T at that tilt only "
                             f"({why}): use [extrinsics] design = \"fixed-board\" with design_tilt = \"auto\" on a rig "
                             "that drives the tilts, or one tilt per campaign")
        return self

    @property
    def calibration_capture(self) -> str:
        """How calibration views are taken: "auto" or "enter" (``[capture] calibration_capture`` or its default)."""
        return self.capture.calibration_capture_for(self.cameras.kind)

    @property
    def sim_presenter(self) -> str:
        """Who presents the calibration board on the simulated bench: "hand" or "still" (``[sim] presenter`` or its
        default: the hand when views are taken automatically)."""
        if self.sim.presenter is not None:
            return self.sim.presenter
        return "hand" if self.calibration_capture == "auto" else "still"

    @property
    def fully_simulated(self) -> bool:
        """True when no human is needed: simulated rig and simulated cameras."""
        return self.rig.kind == "simulated" and self.cameras.kind == "simulated"

    @property
    def bench_kind(self) -> BenchKind:
        """What the campaign runs on: "simulated", "hardware" or "bring-up" (see :data:`BENCH_KINDS`)."""
        return BENCH_KINDS[self.rig.kind, self.cameras.kind]


# --------------------------------------------------------------------------------------------------
# Loading


def _dotted(loc: tuple) -> str:
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += ("." if text else "") + str(part)
    return text or "(top level)"


def _section_model(loc: tuple) -> type[BaseModel] | None:
    """The model class whose key ``loc[-1]`` is (for naming the known keys after a typo)."""
    model: type[BaseModel] = CampaignConfig
    for part in loc[:-1]:
        field = model.model_fields.get(str(part))
        annotation = getattr(field, "annotation", None)
        candidates = getattr(annotation, "__args__", (annotation,))
        nested = [c for c in candidates if isinstance(c, type) and issubclass(c, BaseModel)]
        if not nested:
            return None
        model = nested[0]
    return model


_EXPECTED = {"float_type": "a number", "int_type": "a whole number", "bool_type": "true or false",
             "string_type": "a string"}


def strict_type_message(error: Mapping[str, Any]) -> str | None:
    """What a strict-type refusal says to a user: the value as written and what it must be (None: not one).

    E.g. ``"100" is a string, not a number: write 100 without quotes`` or ``true is a boolean, not a number``.
    """
    expected = _EXPECTED.get(str(error.get("type")))
    if expected is None:
        return None
    value = error.get("input")
    if isinstance(value, bool):
        return f"{str(value).lower()} is a boolean, not {expected}"
    if isinstance(value, str):
        hint = ""
        if expected != "true or false" and value.strip():
            hint = f": write {value.strip()} without quotes" if _is_number(value) else ""
        elif expected == "true or false" and value.strip().lower() in ("true", "false"):
            hint = f": write {value.strip().lower()} without quotes"
        return f"{value!r} is a string, not {expected}{hint}"
    if isinstance(value, float) and expected == "a whole number":
        return f"{value!r} is not {expected}"
    return None


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _one_line(error: ValidationError, source: str) -> ConfigError:
    first = error.errors()[0]
    loc = tuple(first.get("loc", ()))
    message = first.get("msg", "invalid").removeprefix("Value error, ")
    if first.get("type") == "extra_forbidden":
        model = _section_model(loc)
        known = f"; known: {', '.join(model.model_fields)}" if model is not None else ""
        message = f"unknown key{known}"
    elif first.get("type") == "missing":
        message = "missing (required)"
    elif (coerced := strict_type_message(first)) is not None:
        message = coerced
    where = _dotted(loc)
    message = with_bound_reason(message, first, where, BOUND_REASONS)
    more = f" (and {error.error_count() - 1} more)" if error.error_count() > 1 else ""
    # A cross-section check names its field at the start of its message.
    prefix = f"{where}: " if where != "(top level)" else ""
    return ConfigError(f"{source}: {prefix}{message}{more}")


def campaign_from_dict(data: Mapping[str, Any], *, source: str = "campaign config",
                       base_dir: str | Path | None = None) -> CampaignConfig:
    """Validate a campaign config from parsed TOML. Relative paths resolve against ``base_dir``.

    An old spelling (:data:`OLD_SPELLINGS`) is accepted, kept as written (the start document records what the
    user wrote) and noted on stderr in one line, once per process."""
    try:
        config = CampaignConfig.model_validate(dict(data), context={"base_dir": base_dir})
    except ValidationError as error:
        raise _one_line(error, source) from None
    _note_old_spellings(config, source)
    return config


#: Spellings a later issue renamed: (section, key, old value) -> the new value. Issue 21: ``[extrinsics]
#: intrinsics = "fixed"`` (held, not refined) read like ``mode = "fixed"`` (R, T from a file).
OLD_SPELLINGS: dict[tuple[str, str, str], str] = {("extrinsics", "intrinsics", "fixed"): "held"}
_noted: set[tuple[str, str, str]] = set()


def _note_old_spellings(config: CampaignConfig, source: str) -> None:
    for (section, key, old), new in OLD_SPELLINGS.items():
        if getattr(getattr(config, section), key) == old and (section, key, old) not in _noted:
            _noted.add((section, key, old))
            print(f"note: {source}: [{section}] {key} = \"{old}\" is now spelled \"{new}\" (the old spelling still "
                  "works)", file=sys.stderr)


# What a recorded config means by a section it lacks because the section did not exist yet: the bench
# the session was recorded on, not today's default. Before [sim] every simulated bench was the ideal one.
RECORDED_BEFORE_SECTIONS: dict[str, dict[str, Any]] = {"sim": {"profile": "ideal"}}


def recorded_campaign(data: Mapping[str, Any]) -> CampaignConfig:
    """The campaign config a session's start document recorded (raises pydantic's ``ValidationError``).

    A section the recording lacks takes the value the session ran with (:data:`RECORDED_BEFORE_SECTIONS`),
    so a session recorded before ``[sim]`` existed replays and reports as the ideal bench it was; a new
    campaign without ``[sim]`` runs on the ``lab`` bench. Likewise an ``[extrinsics]`` without ``lens_model``
    is ``"legacy"``, the fit every calibration ran before lens models were compared.
    """
    data = {**RECORDED_BEFORE_SECTIONS, **data}
    extrinsics = data.get("extrinsics")
    if isinstance(extrinsics, Mapping) and "lens_model" not in extrinsics:
        # Recorded before lens models were compared: the fit it ran with, not today's default (auto for v4l2
        # cameras), so that its replay reproduces it. A recording made since always has the key (null included).
        data["extrinsics"] = {**extrinsics, "lens_model": "legacy"}
    if "calibration" not in data:  # recorded before the operator reviewed per-view errors: no review in replay
        data["calibration"] = {"review": False}
    capture = data.get("capture")
    if isinstance(capture, Mapping) and "calibration_capture" not in capture:
        # Recorded before calibration views were taken automatically: one view per Enter (today's default for
        # v4l2 cameras is auto, whose replay serves the views the recording kept: the same views either way).
        data["capture"] = {**capture, "calibration_capture": "enter"}
    return CampaignConfig.model_validate(data)


def _check_files(config: CampaignConfig, source: str) -> None:
    """Read what the config points at (rig config file, calibration directory) so it fails now, not mid-run."""
    if config.rig.config_file is not None:
        try:
            config.rig.rig_config()
        except RigConfigError as error:
            raise ConfigError(f"{source}: rig.config_file: {error}") from None
    kinematic_file = config.extrinsics.kinematic_file
    if kinematic_file is not None:
        from stereo_bench.kinematics import KinematicFileError, load_model

        try:
            load_model(kinematic_file)
        except KinematicFileError as error:
            raise ConfigError(f"{source}: extrinsics.kinematic_file: {error}") from None
    calib_dir = config.extrinsics.calib_dir
    if calib_dir is not None:
        if not calib_dir.is_dir():
            raise ConfigError(f"{source}: extrinsics.calib_dir: no such directory: {calib_dir}")
        needed = config.extrinsics.source().calib_dir_files()
        missing = [name for name in needed if not (calib_dir / name).exists()]  # not a file: the reader says
        if missing:
            raise ConfigError(f"{source}: extrinsics.calib_dir: {calib_dir} has no {', '.join(missing)}")


def load_campaign(path: str | Path) -> CampaignConfig:
    """Read and validate a campaign TOML file, and the files it names. Errors name the file and the field.

    The file is read as every user's input file is (:func:`drivers.files.read_toml`): a FIFO, a device, a file
    over 1 MiB or TOML nested over 32 deep is refused in one line before ``tomllib`` sees it.
    """
    path = Path(path)
    try:
        data = read_toml(path, what="campaign file")
    except InputFileError as error:
        if not path.exists() and str(path) in PRESETS:
            raise ConfigError(f"{error} (a shipped preset of that name exists: --preset {path})") from None
        raise ConfigError(str(error)) from None
    config = campaign_from_dict(data, source=str(path), base_dir=path.parent)
    _check_files(config, str(path))
    return config


def preset_text(name: str) -> str:
    """The TOML text of a shipped preset."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
    return resources.files("stereo_bench.campaign").joinpath("presets", f"{name}.toml").read_text("utf-8")


def load_preset(name: str) -> CampaignConfig:
    """A shipped preset (see :data:`PRESETS`), validated like a user's file."""
    data = parse_toml(preset_text(name), f"preset {name}")
    return campaign_from_dict(data, source=f"preset {name}")


def campaign_json_schema() -> dict:
    """JSON Schema (draft 2020-12) of a campaign TOML file, as pydantic writes it."""
    schema = CampaignConfig.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "stereo-bench campaign"
    return schema


def campaign_json_schema_text() -> str:
    return json.dumps(campaign_json_schema(), indent=2)
