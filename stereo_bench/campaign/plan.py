"""Plans as data: a campaign config expands to configurations and to the steps a runner executes.

    configurations = expand_plan(config)          # ordered (Z, B, alpha) grid, feasibility predicted
    visits = plan_visits(config, configurations)  # kinematic design / one-off intrinsics calibration, if any
    steps = plan_steps(config, configurations, visits)  # Move, PromptTarget, Settle, Flush, Capture..., Checkpoint
    predict_duration_s(config, configurations, steps)

Nothing here moves or opens anything: feasibility is predicted from geometry and soft limits are
checked with the rig config's own check, so a plan can be listed, tested and dry-run without hardware.

Feasibility of a configuration (B, Z, alpha, tilt), predicted before moving:

- the measured target stands centred on the rig z axis at distance Z, facing the rig
  (:func:`stereo_bench.geometry.board_pose_facing_rig`); its inner corners are projected into both
  nominal cameras (``cameras.optics``), and a corner counts when it lands at least
  :data:`FEASIBILITY_MARGIN_PX` inside both images. ``fraction_in_both`` is reported for every
  configuration. Fewer than :data:`MIN_CORNERS_IN_BOTH` corners in both views is infeasible; a
  partial view is measured (the measurement core handles partial checkerboards) and flagged
  ``partial``;
- with per-configuration extrinsics, the calibration board must fit whole (with its outer squares,
  which chessboard detectors need) in both views somewhere: it is tried fronto-parallel, centred on
  the bisector of the optical axes, at :data:`CALIBRATION_DISTANCES_MM` in steps of
  :data:`CALIBRATION_DISTANCE_STEP_MM`, by the rule the presenter places boards with
  (:func:`stereo_bench.geometry.calibration_view_fits`: a ChArUco board, identified corner by corner,
  needs only half of its corners in both views);
- the move must pass the rig config's soft limits and axis mapping
  (:func:`drivers.rig.config.plan_move`); a violation is reported as ``limit_violation``.

Only runnable configurations (feasible, no limit violation) get a move and captures; the others get
a single :class:`Checkpoint` carrying the reason.

Extrinsics that need calibration views elsewhere than at the measured configurations start with
visits (:func:`plan_visits`, :class:`Visit`): ``kinematic`` extrinsics without a saved model visit the
kinematic rig model's design (:func:`stereo_bench.kinematics.kinematic_design` over the range of the
runnable configurations' B and toe-ins: 9 visits, 12 views each = 108 board presentations however many
configurations follow), ``nominal`` extrinsics without a calibration directory one configuration for
their intrinsics. Each visit is Move, Settle, Flush, CaptureCalibration, :class:`VisitDone`; then one
:class:`PrepareExtrinsics` fits the model (or calibrates the intrinsics) before the first measured
configuration. A visit where the calibration board cannot be shown to both cameras or outside the soft
limits is not run (the fit goes on without it, and says what it could not identify).
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar

import numpy as np

from drivers.rig.codec import vector_feed
from drivers.rig.config import QUANTITIES, LimitError, MoveRequestError, RigConfig, plan_move, to_machine
from drivers.rig.motion import (
    REFERENCE_AXIS_MOTION,
    REFERENCE_HOMING,
    homing_time_s,
    move_time_s,
)
from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.geometry import (
    VIEW_MARGIN_PX,
    CameraModel,
    RigPose,
    alpha_from_toe_in,
    board_pose_facing_rig,
    calibration_views_fit,
    transform_points,
)
from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision.detect import MIN_CHARUCO_MARKER_PX, MIN_SEARCH_SQUARE_PX, min_detectable_square_px
from stereo_bench.vision.pipeline import MIN_COMMON_CORNERS

MIN_CORNERS_IN_BOTH = MIN_COMMON_CORNERS  # what the measurement needs, not a planning guess
FEASIBILITY_MARGIN_PX = VIEW_MARGIN_PX
CALIBRATION_DISTANCES_MM = (250.0, 1500.0)
CALIBRATION_DISTANCE_STEP_MM = 10.0

# Duration assumptions (each estimate lists them).
OPERATOR_S_PER_PROMPT = 30.0  # move the target (or set another manual quantity) and press Enter
OPERATOR_S_PER_CALIBRATION_VIEW = 5.0  # present the calibration board in a new pose by hand
ASSUMED_FPS = 30.0  # a V4L2 camera's frame rate when the settings do not fix it
ASSUMED_FLUSH_FRAMES = 4  # frames a V4L2 flush discards when buffer_count is left to the driver

Target = Checkerboard | CharucoTarget


# --------------------------------------------------------------------------------------------------
# Geometry of feasibility (pure)


@dataclass(frozen=True)
class Visibility:
    """How many of a board's ``n_corners`` inner corners each camera, and both cameras, see."""

    n_corners: int
    in_both: int
    in_left: int
    in_right: int
    square_px_left: float = math.inf  # the smallest side of a target square the left camera sees whole, px
    square_px_right: float = math.inf

    @property
    def fraction_in_both(self) -> float:
        return self.in_both / self.n_corners


def target_visibility(
    target: Target, rig: RigPose, *, distance_mm: float, left: CameraModel, right: CameraModel,
    margin_px: float = FEASIBILITY_MARGIN_PX,
) -> Visibility:
    """Corners of ``target`` in view when it faces the rig, centred on the rig z axis at ``distance_mm``."""
    return target_visibilities(target, [rig], distance_mm=distance_mm, left=left, right=right,
                               margin_px=margin_px)[0]


def target_visibilities(
    target: Target, rigs: Sequence[RigPose], *, distance_mm: float, left: CameraModel, right: CameraModel,
    margin_px: float = FEASIBILITY_MARGIN_PX,
) -> list[Visibility]:
    """:func:`target_visibility` for several rig poses at one distance, projected together (a plan of 10,000
    configurations asks for thousands)."""
    T_rig_board = board_pose_facing_rig(distance_mm=distance_mm, board_size_mm=target.grid_size_mm)
    points = transform_points(T_rig_board, np.asarray(target.object_points, dtype=float))  # (P, 3) rig frame
    n_points = len(points)
    pairs = target.adjacent_pairs()
    out: list[list] = []  # per camera: (visible (N, P), smallest square side (N,))
    for side, camera in enumerate((left, right)):
        T = np.stack([rig.T_cameras_rig[side] for rig in rigs])  # (N, 4, 4)
        points_cam = points @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]  # (N, P, 3)
        pixels, valid = camera.project(points_cam.reshape(-1, 3))
        visible = (valid & camera.in_image(pixels, margin_px=margin_px)).reshape(len(rigs), n_points)
        pixels = pixels.reshape(len(rigs), n_points, 2)
        sides = np.linalg.norm(pixels[:, pairs[:, 0]] - pixels[:, pairs[:, 1]], axis=2)  # (N, pairs)
        whole = visible[:, pairs[:, 0]] & visible[:, pairs[:, 1]]  # both corners of a square's side in view
        out.append([visible, np.where(whole, sides, np.inf).min(axis=1)])
    (seen_left, square_left), (seen_right, square_right) = out
    in_both = (seen_left & seen_right).sum(axis=1)
    in_left, in_right = seen_left.sum(axis=1), seen_right.sum(axis=1)
    return [Visibility(n_corners=n_points, in_both=int(in_both[k]), in_left=int(in_left[k]), in_right=int(in_right[k]),
                       square_px_left=float(square_left[k]), square_px_right=float(square_right[k]))
            for k in range(len(rigs))]


def _why_too_small(vis: Visibility, need_px: float, *, distance_mm: float, target: Target) -> str | None:
    """Why the corner detector would not find the target (its squares too small in a view), or None."""
    side, smallest = min((("left", vis.square_px_left), ("right", vis.square_px_right)), key=lambda item: item[1])
    if smallest >= need_px:
        return None
    if isinstance(target, CharucoTarget):
        limit = f"ChArUco markers of {MIN_CHARUCO_MARKER_PX:g} px"
    else:
        limit = f"{MIN_SEARCH_SQUARE_PX:g} px in the checkerboard detector's reduced search image"
    return (f"target squares {smallest:.1f} px in the {side} view at Z = {distance_mm:g} mm, below the "
            f"{need_px:.1f} px the corner detector finds (minimum board size in pixels: {limit}); "
            f"a larger target or a longer lens reaches farther")


def calibration_distance_range(
    board: Target, rig: RigPose, *, left: CameraModel, right: CameraModel,
    distances_mm: tuple[float, float] = CALIBRATION_DISTANCES_MM, step_mm: float = CALIBRATION_DISTANCE_STEP_MM,
    hint: tuple[float, float] | None = None,
) -> tuple[float, float] | None:
    """(nearest, farthest) distance, mm along the bisector of the optical axes, at which the calibration
    board, fronto-parallel to that bisector and centred on it, is a usable calibration view; None if at none.

    Usable by the one rule the simulator's board poses follow too,
    :func:`stereo_bench.geometry.calibration_view_fits`, so a configuration the plan calls feasible is
    one where the presenter can place the board.

    ``hint``: the range of a nearby rig pose (a neighbouring baseline). The distances where the board fits
    form one interval (each corner's image moves monotonically along a line as the board slides along the
    bisector, and the image is convex), so the hint is the answer when both its ends fit and the grid steps
    just outside them do not: 2-4 poses tried instead of all 126. Otherwise every distance is tried.
    tests/test_campaign_plan.py checks the two agree over baselines, angles and boards.
    """
    grid = np.arange(distances_mm[0], distances_mm[1] + 1e-9, step_mm)
    bisector = rig.T_rig_left[:3, 2] + rig.T_rig_right[:3, 2]
    bisector = bisector / np.linalg.norm(bisector)
    # Board frame: z along the bisector (away from the rig), x along the baseline made orthogonal to it.
    x_axis = np.array([1.0, 0.0, 0.0]) - bisector[0] * bisector
    x_axis /= np.linalg.norm(x_axis)
    R = np.column_stack([x_axis, np.cross(bisector, x_axis), bisector])
    centre_board = np.array([board.grid_size_mm[0] / 2.0, board.grid_size_mm[1] / 2.0, 0.0])

    offset = R @ centre_board

    def fits(indices: np.ndarray) -> np.ndarray:
        poses = np.zeros((len(indices), 4, 4))
        poses[:, :3, :3] = R
        poses[:, :3, 3] = grid[indices, None] * bisector - offset
        poses[:, 3, 3] = 1.0
        return calibration_views_fit(board, poses, rig=rig, left=left, right=right)

    if hint is not None:
        low, high = (int(np.argmin(np.abs(grid - value))) for value in hint)
        probes = np.array([k for k in (low - 1, low, high, high + 1) if 0 <= k < len(grid)])
        expected = (probes >= low) & (probes <= high)
        if np.array_equal(fits(probes), expected):
            return float(grid[low]), float(grid[high])
    inside = np.flatnonzero(fits(np.arange(len(grid))))
    return (float(grid[inside[0]]), float(grid[inside[-1]])) if len(inside) else None


def _nearest_range(computed: tuple[list[float], list], baseline: float) -> tuple[float, float] | None:
    """The calibration range computed for the baseline nearest ``baseline`` (a hint; None if none or no range)."""
    baselines, ranges = computed
    k = bisect.bisect_left(baselines, baseline)
    near = [j for j in (k - 1, k) if 0 <= j < len(baselines)]
    if not near:
        return None
    return ranges[min(near, key=lambda j: abs(baselines[j] - baseline))]


def _remember(computed: tuple[list[float], list], baseline: float, found: tuple[float, float] | None) -> None:
    baselines, ranges = computed
    k = bisect.bisect_left(baselines, baseline)
    baselines.insert(k, baseline)
    ranges.insert(k, found)


def _why_too_few(vis: Visibility, *, alpha_deg: float) -> str:
    if vis.in_left == 0 and vis.in_right == 0:
        cause = "the board is outside both cameras' views"
    elif vis.in_left == 0:
        cause = "the board is outside the left camera's view"
    elif vis.in_right == 0:
        cause = "the board is outside the right camera's view"
    elif vis.in_both == 0:
        cause = "the cameras' views do not overlap on the board"
    else:
        cause = "too little of the board lies where the two views overlap"
    return (f"{vis.in_both} of {vis.n_corners} target corners in both views (left {vis.in_left}, "
            f"right {vis.in_right}; {MIN_CORNERS_IN_BOTH} needed): {cause} at alpha = {alpha_deg:g} deg")


# --------------------------------------------------------------------------------------------------
# Configurations


def format_id_value(value: float) -> str:
    """A float as a filesystem-safe token keeping every digit: 100 -> '100', 87.5 -> '87p5', -5 -> 'm5'."""
    text = repr(float(value))
    if text.endswith(".0"):
        text = text[:-2]
    return text.replace("-", "m").replace("+", "").replace(".", "p")


class _Runnable:
    """What a planned configuration or visit says about whether it runs (``feasible``, ``reason``,
    ``limit_violation``)."""

    @property
    def runnable(self) -> bool:
        return self.feasible and self.limit_violation is None

    @property
    def skip_reason(self) -> str | None:
        """Why it is not run (None if it is)."""
        reasons = [r for r in (self.reason, self.limit_violation) if r]
        return "; ".join(reasons) if reasons else None


@dataclass(frozen=True)
class Configuration(_Runnable):
    """One (B, Z, alpha, tilt) of the campaign and its predicted feasibility.

    ``feasible`` is geometric (target and, per-config, calibration board in both views; ``reason`` says
    why not); a soft-limit or axis-mapping violation is ``limit_violation``. Only :attr:`runnable`
    configurations are moved to. ``calibration_range_mm``: where the calibration board fits in both
    views (per-config extrinsics only).
    """

    index: int
    config_id: str
    baseline_mm: float
    distance_mm: float
    alpha_deg: float
    toe_in_deg: float
    tilt_deg: float
    fraction_in_both: float
    feasible: bool
    reason: str | None
    limit_violation: str | None
    corners_in_both: int = 0
    n_corners: int = 0
    calibration_range_mm: tuple[float, float] | None = None

    @property
    def status(self) -> str:
        """'infeasible', 'partial' (feasible, some target corners outside a view) or 'feasible'."""
        if not self.feasible:
            return "infeasible"
        return "partial" if self.corners_in_both < self.n_corners else "feasible"

    def rig_pose(self) -> RigPose:
        return RigPose.symmetric(self.baseline_mm, self.alpha_deg, self.tilt_deg)

    def move_request(self) -> dict[str, float]:
        """Quantity -> physical value, as :func:`drivers.rig.config.plan_move` and ``GrblRig.move_to`` take it."""
        return {
            "baseline_mm": self.baseline_mm, "toe_in_left_deg": self.toe_in_deg, "toe_in_right_deg": self.toe_in_deg,
            "tilt_left_deg": self.tilt_deg, "tilt_right_deg": self.tilt_deg, "target_distance_mm": self.distance_mm,
        }

    def as_dict(self) -> dict[str, Any]:
        # Shallow (every field a number, string or tuple): dataclasses.asdict deep-copies, ~0.1 ms a configuration.
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        data["calibration_range_mm"] = list(self.calibration_range_mm) if self.calibration_range_mm else None
        data.update(status=self.status, runnable=self.runnable)
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Configuration:
        """The configuration a recorded plan entry (:meth:`as_dict`) describes: replay and resume run the
        recorded plan, never today's re-planning of it."""
        names = {f.name for f in dataclasses.fields(cls)}
        values = {key: value for key, value in data.items() if key in names}
        if values.get("calibration_range_mm") is not None:
            values["calibration_range_mm"] = tuple(values["calibration_range_mm"])
        return cls(**values)


def _limit_violation(rig_config: RigConfig, request: Mapping[str, float]) -> str | None:
    try:
        plan_move(rig_config, request)
    except LimitError as error:
        return "; ".join(error.violations)
    except MoveRequestError as error:
        return str(error)
    return None


def _calibration_reason(config: CampaignConfig, board: Target, *, baseline_mm: float, alpha_deg: float) -> str:
    low, high = CALIBRATION_DISTANCES_MM
    need = "whole" if board.min_calibration_fraction >= 1.0 else f"{board.min_calibration_fraction:.0%} of it"
    return (f"calibration board ({config.calibration_board.describe()}) never {need} in both views fronto-parallel "
            f"at {low:g}-{high:g} mm: the views overlap too little at B = {baseline_mm:g} mm, "
            f"alpha = {alpha_deg:g} deg")


def expand_plan(config: CampaignConfig, *, margin_px: float = FEASIBILITY_MARGIN_PX) -> list[Configuration]:
    """The ordered configurations of a campaign, each with its predicted feasibility and limit check.

    The order keeps manual work and motion small: the target distance Z (set by hand by default) is
    the outer loop, in the order written; then the baseline, then the angle, both serpentine (every
    other pass runs backwards, so consecutive configurations differ by one step of one axis).
    """
    plan = config.plan
    target = config.target.build()
    calibration_board = config.calibration_board.build()
    left = config.cameras.optics.camera_model("left")
    right = config.cameras.optics.camera_model("right")
    image_size = (config.cameras.optics.width_px, config.cameras.optics.height_px)
    rig_config = config.rig.rig_config()
    per_config = config.extrinsics.source().calibrates_each_configuration
    angles = plan.angles_deg()
    calibration_ranges: dict[tuple[float, float], tuple[float, float] | None] = {}
    computed: dict[float, tuple[list[float], list]] = {}  # alpha -> (sorted baselines, their ranges): hints
    configurations: list[Configuration] = []
    sweep = 0
    poses = {(baseline, alpha): RigPose.symmetric(baseline, alpha, plan.tilt_deg)
             for baseline in plan.baseline_mm for alpha, _ in angles}
    for z_index, distance in enumerate(plan.distance_mm):
        visibility = dict(zip(poses, target_visibilities(target, list(poses.values()), distance_mm=distance,
                                                          left=left, right=right, margin_px=margin_px), strict=True))
        baselines = plan.baseline_mm if z_index % 2 == 0 else plan.baseline_mm[::-1]
        for baseline in baselines:
            ordered = angles if sweep % 2 == 0 else angles[::-1]
            sweep += 1
            for alpha, toe_in in ordered:
                rig = poses[baseline, alpha]
                vis = visibility[baseline, alpha]
                reasons = []
                if vis.in_both < MIN_CORNERS_IN_BOTH:
                    reasons.append(_why_too_few(vis, alpha_deg=alpha))
                else:  # the runner detects a view with fewer corners than the board's as partial: the same rule
                    need = min_detectable_square_px(target, image_size, partial=vis.in_both < vis.n_corners)
                    too_small = _why_too_small(vis, need, distance_mm=distance, target=target)
                    if too_small:
                        reasons.append(too_small)
                calibration_range = None
                if per_config:
                    if (baseline, alpha) not in calibration_ranges:
                        calibration_ranges[baseline, alpha] = calibration_distance_range(
                            calibration_board, rig, left=left, right=right,
                            hint=_nearest_range(computed.setdefault(alpha, ([], [])), baseline))
                        _remember(computed[alpha], baseline, calibration_ranges[baseline, alpha])
                    calibration_range = calibration_ranges[baseline, alpha]
                    if calibration_range is None:
                        reasons.append(_calibration_reason(config, calibration_board, baseline_mm=baseline,
                                                           alpha_deg=alpha))
                config_id = f"B{format_id_value(baseline)}_Z{format_id_value(distance)}_A{format_id_value(alpha)}"
                if plan.tilt_deg:
                    config_id += f"_T{format_id_value(plan.tilt_deg)}"
                configuration = Configuration(
                    index=len(configurations), config_id=config_id, baseline_mm=float(baseline),
                    distance_mm=float(distance), alpha_deg=float(alpha), toe_in_deg=float(toe_in),
                    tilt_deg=float(plan.tilt_deg), fraction_in_both=vis.fraction_in_both, feasible=not reasons,
                    reason="; ".join(reasons) or None, limit_violation=None, corners_in_both=vis.in_both,
                    n_corners=vis.n_corners, calibration_range_mm=calibration_range,
                )
                violation = _limit_violation(rig_config, configuration.move_request())
                configurations.append(dataclasses.replace(configuration, limit_violation=violation))
    ids = [c.config_id for c in configurations]
    if len(set(ids)) != len(ids):  # distinct toe-ins whose alphas (90 - t) round to the same float
        configurations = [dataclasses.replace(c, config_id=f"{c.config_id}_i{c.index}") for c in configurations]
    return configurations


# --------------------------------------------------------------------------------------------------
# Visits: calibration views for the extrinsics source (kinematic design, one-off intrinsics)

VISIT_PURPOSES = ("kinematic", "intrinsics")


@dataclass(frozen=True)
class Visit(_Runnable):
    """A visit before the measured configurations: calibration views at commanded axes, no measurement.

    ``purpose``: ``kinematic`` (a visit of the kinematic rig model's design) or ``intrinsics`` (the
    one stereo calibration whose intrinsics ``nominal`` extrinsics use). Presenters and the runner use
    it like a :class:`Configuration` (``config_id``, ``distance_mm``: where the calibration board is
    shown, ``calibration_range_mm``, :meth:`rig_pose`, :meth:`move_request`).
    """

    index: int
    config_id: str
    purpose: str
    baseline_mm: float
    toe_in_left_deg: float
    toe_in_right_deg: float
    tilt_deg: float
    distance_mm: float
    calibration_range_mm: tuple[float, float] | None
    feasible: bool
    reason: str | None = None
    limit_violation: str | None = None
    fraction_in_both: ClassVar[float] = 1.0

    def axes(self) -> dict[str, float]:
        return {"baseline_mm": self.baseline_mm, "toe_in_left_deg": self.toe_in_left_deg,
                "toe_in_right_deg": self.toe_in_right_deg}

    def rig_pose(self) -> RigPose:
        return RigPose(self.baseline_mm, alpha_from_toe_in(self.toe_in_left_deg),
                       alpha_from_toe_in(self.toe_in_right_deg), self.tilt_deg, self.tilt_deg)

    def move_request(self) -> dict[str, float]:
        return {"baseline_mm": self.baseline_mm, "toe_in_left_deg": self.toe_in_left_deg,
                "toe_in_right_deg": self.toe_in_right_deg, "tilt_left_deg": self.tilt_deg,
                "tilt_right_deg": self.tilt_deg, "target_distance_mm": self.distance_mm}

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["calibration_range_mm"] = list(self.calibration_range_mm) if self.calibration_range_mm else None
        data["runnable"] = self.runnable
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Visit:
        """The visit a recorded ``start.design`` entry describes (resume and replay run the recorded visits)."""
        names = {f.name for f in dataclasses.fields(cls)}
        values = {key: value for key, value in data.items() if key in names}
        if values.get("calibration_range_mm") is not None:
            values["calibration_range_mm"] = tuple(values["calibration_range_mm"])
        return cls(**values)


def design_ranges(configurations: Sequence[Configuration]) -> dict[str, tuple[float, float]] | None:
    """(min, max) of B and of the toe-ins over the runnable configurations: what the design must span."""
    runnable = [c for c in configurations if c.runnable]
    if not runnable:
        return None
    baselines = [c.baseline_mm for c in runnable]
    toe_ins = [c.toe_in_deg for c in runnable]
    return {"baseline_mm": (min(baselines), max(baselines)), "toe_in_deg": (min(toe_ins), max(toe_ins))}


def plan_visits(config: CampaignConfig, configurations: Sequence[Configuration]) -> list[Visit]:
    """The visits the extrinsics source needs before the measured configurations (none for most modes), as its
    strategy object says (``visits``), each visit checked like a configuration (the calibration board must fit
    both views somewhere, the move must pass the soft limits).

    ``kinematic`` without ``kinematic_file``: the design of :func:`stereo_bench.kinematics.kinematic_design`
    over :func:`design_ranges`; the board is shown around the middle of the plan's target distances.
    ``nominal`` without ``calib_dir``: the first runnable configuration at which the calibration board fits,
    for one stereo calibration whose intrinsics every configuration uses.
    """
    extrinsics = config.extrinsics
    source = extrinsics.source()
    if source.visit_purpose(extrinsics) is None:
        return []
    ranges = design_ranges(configurations)
    if ranges is None:
        return []
    board = config.calibration_board.build()
    left = config.cameras.optics.camera_model("left")
    right = config.cameras.optics.camera_model("right")
    rig_config = config.rig.rig_config()
    tilt = float(config.plan.tilt_deg)

    def visit(index: int, config_id: str, purpose: str, baseline: float, toe_left: float, toe_right: float,
              distance: float) -> Visit:
        pose = RigPose(baseline, alpha_from_toe_in(toe_left), alpha_from_toe_in(toe_right), tilt, tilt)
        fits = calibration_distance_range(board, pose, left=left, right=right)
        reason = None
        if fits is None:
            reason = (f"calibration board ({config.calibration_board.describe()}) never fits both views at "
                      f"B = {baseline:g} mm, toe-ins {toe_left:g}/{toe_right:g} deg")
        draft = Visit(index=index, config_id=config_id, purpose=purpose, baseline_mm=float(baseline),
                      toe_in_left_deg=float(toe_left), toe_in_right_deg=float(toe_right), tilt_deg=tilt,
                      distance_mm=float(distance), calibration_range_mm=fits, feasible=fits is not None,
                      reason=reason)
        return dataclasses.replace(draft, limit_violation=_limit_violation(rig_config, draft.move_request()))

    return source.visits(extrinsics, configurations, ranges, visit=visit, format_id=format_id_value)


# --------------------------------------------------------------------------------------------------
# Steps


class StepKind:
    """What every step kind declares, so that nothing outside it lists the kinds (issue 21): the configuration it
    names (``config_id``, None for one that names none: it belongs to the group before it), whether it still runs
    once its configuration failed (``closes_group``: the checkpoints), its time under a :class:`DurationModel`
    (``estimate``, each kind its own) and the calibration boards it needs presented (``present``). The runner
    executes a step through one handler per kind (``CampaignRunner._execute``)."""

    config_id: ClassVar[str | None] = None
    closes_group: ClassVar[bool] = False

    def estimate(self, model: DurationModel) -> None:
        """Add this step's time to ``model`` (every kind says its own; see :func:`estimate_duration`)."""
        raise NotImplementedError(f"{type(self).__name__} does not say how long it takes")

    def present(self, tally: Presentations) -> None:
        """Count the calibration board presentations this step needs (none by default)."""
        return None


@dataclass(frozen=True)
class Move(StepKind):
    """Move the rig to a configuration (the motors; the manual quantities are the prompt steps that follow)."""

    configuration: Configuration
    kind: ClassVar[str] = "move"

    def as_dict(self) -> dict[str, Any]:
        c = self.configuration
        return {"step": self.kind, "config_id": c.config_id, "index": c.index, "request": c.move_request()}

    @property
    def config_id(self) -> str:
        return self.configuration.config_id

    def estimate(self, model: DurationModel) -> None:
        """One straight GRBL move from where the previous one left the axes (see :func:`estimate_duration`)."""
        request = self.configuration.move_request()
        driven = {q: v for q, v in request.items() if model.rig_config.quantities[q].driven}
        targets = to_machine(model.rig_config, driven)
        deltas = {a: targets[a] - model.position[a] for a in targets}
        feed = vector_feed(deltas, model.feeds)
        model.motion_s += move_time_s(deltas, max_rate_per_min=model.rates, acceleration=model.accels,
                                      feed_per_min=feed) / model.speed_factor
        model.position.update(targets)

    def present(self, tally: Presentations) -> None:
        tally.in_visit = isinstance(self.configuration, Visit)


@dataclass(frozen=True)
class PromptTarget(StepKind):
    """The operator moves the target to ``distance_mm`` (the target distance is manual and changes here)."""

    distance_mm: float
    kind: ClassVar[str] = "prompt_target"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "distance_mm": self.distance_mm}

    def estimate(self, model: DurationModel) -> None:
        model.operator_s += OPERATOR_S_PER_PROMPT if model.real_scene else 0.0


@dataclass(frozen=True)
class PromptManual(StepKind):
    """The operator sets another manual quantity (e.g. the baseline on a rig without a motorised slide)."""

    quantity: str
    value: float
    kind: ClassVar[str] = "prompt_manual"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "quantity": self.quantity, "value": self.value}

    def estimate(self, model: DurationModel) -> None:
        model.operator_s += OPERATOR_S_PER_PROMPT if model.real_rig else 0.0


@dataclass(frozen=True)
class Settle(StepKind):
    """Wait for the rig (and the operator's hands) to be still."""

    seconds: float
    kind: ClassVar[str] = "settle"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "seconds": self.seconds}

    def estimate(self, model: DurationModel) -> None:
        model.settle_s += self.seconds


@dataclass(frozen=True)
class Flush(StepKind):
    """Discard the frames the cameras queued before and during the move."""

    kind: ClassVar[str] = "flush"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind}

    def estimate(self, model: DurationModel) -> None:
        model.flush_s += model.flush_frames * model.frame_s


@dataclass(frozen=True)
class CaptureCalibration(StepKind):
    """Capture ``n_views`` stereo views of the calibration board (R, T are estimated from them)."""

    n_views: int
    kind: ClassVar[str] = "capture_calibration"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "n_views": self.n_views}

    def estimate(self, model: DurationModel) -> None:
        model.capture_s += self.n_views * model.frame_s
        model.operator_s += self.n_views * OPERATOR_S_PER_CALIBRATION_VIEW if model.real_scene else 0.0

    def present(self, tally: Presentations) -> None:
        tally.add(self.n_views)


@dataclass(frozen=True)
class CaptureMeasurement(StepKind):
    """Capture ``n_frames`` stereo frames of the target and measure the square."""

    n_frames: int
    kind: ClassVar[str] = "capture_measurement"

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "n_frames": self.n_frames}

    def estimate(self, model: DurationModel) -> None:
        model.capture_s += self.n_frames * model.frame_s


@dataclass(frozen=True)
class Checkpoint(StepKind):
    """End of a configuration: everything before it is recorded, and a resumed run starts after it.

    ``skipped``: the configuration is not run (infeasible or outside the limits); ``reason`` says why.
    """

    config_id: str
    skipped: bool = False
    reason: str | None = None
    kind: ClassVar[str] = "checkpoint"
    closes_group: ClassVar[bool] = True

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "config_id": self.config_id, "skipped": self.skipped, "reason": self.reason}

    def estimate(self, model: DurationModel) -> None:
        return None  # bookkeeping: no time


@dataclass(frozen=True)
class VisitDone(StepKind):
    """End of a visit (:class:`Visit`): its calibration views are kept for :class:`PrepareExtrinsics`.

    ``skipped``: the visit is not run (the board does not fit, or outside the soft limits); ``reason`` says why.
    """

    config_id: str
    skipped: bool = False
    reason: str | None = None
    kind: ClassVar[str] = "visit_done"
    closes_group: ClassVar[bool] = True

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "config_id": self.config_id, "skipped": self.skipped, "reason": self.reason}

    def estimate(self, model: DurationModel) -> None:
        return None  # bookkeeping: no time


#: The config_id of the PrepareExtrinsics step's group (not a configuration: nothing is measured there).
PREPARE_ID = "extrinsics-source"


@dataclass(frozen=True)
class PrepareExtrinsics(StepKind):
    """Fit the kinematic rig model to the design's views (``kinematic``), or calibrate the intrinsics
    (``intrinsics``), before the first measured configuration; recorded, and read back by a resume."""

    purpose: str
    config_id: str = PREPARE_ID
    kind: ClassVar[str] = "prepare_extrinsics"
    closes_group: ClassVar[bool] = True

    def as_dict(self) -> dict[str, Any]:
        return {"step": self.kind, "config_id": self.config_id, "purpose": self.purpose}

    def estimate(self, model: DurationModel) -> None:
        return None  # computation (the fit, the calibration) is not counted


Step = (Move | PromptTarget | PromptManual | Settle | Flush | CaptureCalibration | CaptureMeasurement | Checkpoint
        | VisitDone | PrepareExtrinsics)


def plan_steps(config: CampaignConfig, configurations: Sequence[Configuration],
               visits: Sequence[Visit] | None = None) -> list[Step]:
    """The steps of a campaign, in order.

    First the visits (``visits``, default :func:`plan_visits`): Move, Settle, Flush, CaptureCalibration,
    VisitDone each (a visit that is not runnable: only ``VisitDone(skipped=True)``), then one
    PrepareExtrinsics. Then per runnable configuration: Move; a prompt for each manual quantity whose
    value changes (PromptTarget for the target distance, PromptManual for any other); Settle; Flush;
    CaptureCalibration (per-config extrinsics only); CaptureMeasurement; Checkpoint. A configuration
    that is not runnable gets only ``Checkpoint(skipped=True, reason=...)``.
    """
    rig_config = config.rig.rig_config()
    manual = [q for q in QUANTITIES if rig_config.quantities[q].axis == "manual"]
    last_manual: dict[str, float] = {}
    calibrates_each_configuration = config.extrinsics.source().calibrates_each_configuration
    steps: list[Step] = []
    visits = plan_visits(config, configurations) if visits is None else visits
    for visit in visits:
        if not visit.runnable:
            steps.append(VisitDone(visit.config_id, skipped=True, reason=visit.skip_reason))
            continue
        # The calibration board is shown by hand or by the simulator: no prompt for the target distance.
        steps += [Move(visit), Settle(config.capture.settle_s), Flush(),
                  CaptureCalibration(config.capture.calibration_views), VisitDone(visit.config_id)]
    if visits:
        steps.append(PrepareExtrinsics(visits[0].purpose))
    for configuration in configurations:
        if not configuration.runnable:
            steps.append(Checkpoint(configuration.config_id, skipped=True, reason=configuration.skip_reason))
            continue
        steps.append(Move(configuration))
        request = configuration.move_request()
        for quantity in manual:
            value = request[quantity]
            if last_manual.get(quantity) != value:
                steps.append(PromptTarget(value) if quantity == "target_distance_mm" else PromptManual(quantity, value))
                last_manual[quantity] = value
        steps.append(Settle(config.capture.settle_s))
        steps.append(Flush())
        if calibrates_each_configuration:
            steps.append(CaptureCalibration(config.capture.calibration_views))
        steps.append(CaptureMeasurement(config.capture.frames_per_config))
        steps.append(Checkpoint(configuration.config_id))
    return steps


# --------------------------------------------------------------------------------------------------
# Duration


@dataclass(frozen=True)
class DurationEstimate:
    """Predicted campaign time (s) by component, and the assumptions behind it."""

    homing_s: float
    motion_s: float
    settle_s: float
    flush_s: float
    capture_s: float
    operator_s: float
    assumptions: tuple[str, ...] = field(default=())

    @property
    def total_s(self) -> float:
        return self.homing_s + self.motion_s + self.settle_s + self.flush_s + self.capture_s + self.operator_s

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["assumptions"] = list(self.assumptions)
        data["total_s"] = self.total_s
        return data


def _frame_time_s(config: CampaignConfig) -> float:
    if config.cameras.kind == "simulated":
        return config.cameras.optics.exposure_s
    settings = config.cameras.camera_settings()
    period = 1.0 / (settings.fps or ASSUMED_FPS)
    return max(period, (settings.exposure_us or 0.0) / 1e6)


@dataclass
class DurationModel:
    """What a step's time depends on (the rig, the cameras, who does the manual steps), and the time counted so far
    by component: each step kind adds its own (``StepKind.estimate``), in plan order; ``position`` is where the
    last move left the axes (machine units)."""

    rig_config: RigConfig
    speed_factor: float
    rates: dict[str, float]
    accels: dict[str, float]
    feeds: dict[str, float | None]
    position: dict[str, float]
    real_scene: bool  # boards and target are moved by hand
    real_rig: bool  # a manual rig quantity is set by hand
    frame_s: float
    flush_frames: int
    motion_s: float = 0.0
    settle_s: float = 0.0
    flush_s: float = 0.0
    capture_s: float = 0.0
    operator_s: float = 0.0

    @classmethod
    def of(cls, config: CampaignConfig) -> DurationModel:
        """The model of ``config``'s bench, nothing counted yet, the axes where the emulator homes them."""
        rig_config = config.rig.rig_config()
        travel = rig_config.machine_travel()
        if config.cameras.kind == "simulated":
            flush_frames = 0
        else:
            flush_frames = config.cameras.camera_settings().buffer_count or ASSUMED_FLUSH_FRAMES
        return cls(
            rig_config=rig_config, speed_factor=config.rig.time_scale if config.rig.kind == "simulated" else 1.0,
            rates={a: REFERENCE_AXIS_MOTION[a].max_rate_per_min for a in travel},
            accels={a: REFERENCE_AXIS_MOTION[a].acceleration for a in travel},
            feeds=rig_config.axis_feeds_per_min(),
            position={a: min(max(0.0, low), high) for a, (low, high) in travel.items()},  # the emulator's home
            real_scene=config.cameras.kind != "simulated", real_rig=config.rig.kind != "simulated",
            frame_s=_frame_time_s(config), flush_frames=flush_frames)


def estimate_duration(config: CampaignConfig, configurations: Sequence[Configuration],
                      steps: Sequence[Step]) -> DurationEstimate:
    """How long the campaign should take, step by step.

    - Motion: each Move as one straight GRBL move from the previous position (the first from where
      homing leaves the axes), at the rig config's axis feeds where every moving axis has one (else a
      rapid), capped by the axis max rates and accelerations of the reference rig
      (:data:`drivers.rig.motion.REFERENCE_AXIS_MOTION`, which the simulated rig runs with; a real
      controller's $110-$125 are not known offline), timed by the model the emulator uses
      (:func:`drivers.rig.motion.move_time_s`).
    - Homing (if enabled): the firmware's sequence (:func:`homing_estimate_s`): per cycle (Z, then X and Y) a
      seek to the switches, pull-off, locate and pull-off, each with its debounce, at the reference homing
      settings (:data:`drivers.rig.motion.REFERENCE_HOMING`, the simulated rig's). The simulated rig powers up
      at machine 0; a real rig may stand anywhere: the far end of the config's range is assumed (the worst
      case). On the simulated rig, homing and motion run ``time_scale`` times faster.
    - Settle as configured. Frames: one exposure each on simulated cameras; max(exposure, 1/fps) on
      V4L2 (30 fps assumed when not set); a V4L2 flush discards ``buffer_count`` frames.
    - Operator: 30 s per prompt and 5 s per calibration view presented by hand, where a human does it:
      boards and the target stand in the cameras' world (none with simulated cameras, bring-up
      included), a manual rig quantity on the rig (none on the simulated rig).
    - Not included: computation (rendering, detection, calibration) and parking the rig at the end.
    """
    del configurations  # the steps carry what is needed; the argument keeps the documented signature
    model = DurationModel.of(config)
    travel, speed_factor = model.rig_config.machine_travel(), model.speed_factor
    real_scene, frame_s, flush_frames = model.real_scene, model.frame_s, model.flush_frames
    human = real_scene or model.real_rig

    homing = 0.0
    if config.rig.homing and travel:
        homing = homing_estimate_s(travel, simulated=config.rig.kind == "simulated") / speed_factor
    for step in steps:
        step.estimate(model)
    motion, settle, flush, capture, operator = (model.motion_s, model.settle_s, model.flush_s, model.capture_s,
                                                model.operator_s)

    assumptions = (
        "axis max rates and accelerations of the reference rig (the simulated rig's)"
        + (f", simulated rig {speed_factor:g}x faster than real time" if speed_factor != 1.0 else ""),
        f"{frame_s:g} s per stereo frame" + ("" if config.cameras.kind == "simulated"
                                              else f", {flush_frames} frames per flush"),
        (f"operator {OPERATOR_S_PER_PROMPT:g} s per prompt and {OPERATOR_S_PER_CALIBRATION_VIEW:g} s per "
         "calibration view done by hand" + ("" if real_scene else " (the scene is simulated: boards and target "
                                                                   "placed by the simulator)")
         if human else "no operator time: rig and cameras simulated"),
        "computation (rendering, detection, calibration) not included",
    ) + ((f"homing at the reference rig's $25={REFERENCE_HOMING.seek_rate_per_min:g}, "
          f"$24={REFERENCE_HOMING.feed_rate_per_min:g} mm/min, $26={REFERENCE_HOMING.debounce_ms:g} ms, "
          f"$27={REFERENCE_HOMING.pulloff:g}, from "
          + ("machine 0 (where the simulated rig powers up)" if config.rig.kind == "simulated"
             else "the far end of each axis' range (the longest seek)"),) if homing else ())
    return DurationEstimate(homing_s=homing, motion_s=motion, settle_s=settle, flush_s=flush, capture_s=capture,
                            operator_s=operator, assumptions=assumptions)


def homing_estimate_s(travel: Mapping[str, tuple[float, float]], *, simulated: bool) -> float:
    """How long ``$H`` takes (s, real time) on a rig whose config spans ``travel`` (axis -> (low, high) machine
    units, :meth:`RigConfig.machine_travel`), by the firmware's sequence (:func:`drivers.rig.motion.homing_time_s`).

    The controller is taken as the simulated bench sets it up (``$13x`` one pull-off beyond the range, the
    reference axes and homing settings): a range at or below 0 homes toward + to a switch at machine 0; one at
    or above 0 (a set-origin build) toward - to a switch one pull-off below 0. Where the axes stand first:
    ``simulated``, machine 0, where the simulated rig powers up; else the end of the range farthest from the
    switch (the longest seek).
    """
    pulloff = REFERENCE_HOMING.pulloff
    to_switch: dict[str, float] = {}
    max_travel: dict[str, float] = {}
    for axis, (low, high) in travel.items():
        if low >= 0.0 and high > 0.0:  # HOMING_FORCE_SET_ORIGIN: homes toward -, the switch at -$27
            max_travel[axis] = high + pulloff
            to_switch[axis] = pulloff if simulated else high + pulloff
        else:
            max_travel[axis] = (-low + pulloff) if high <= 0.0 else high - low
            to_switch[axis] = 0.0 if simulated else max(0.0, -low)
    return homing_time_s(to_switch, max_travel=max_travel, homing=REFERENCE_HOMING,
                         max_rate_per_min={a: REFERENCE_AXIS_MOTION[a].max_rate_per_min for a in travel},
                         acceleration={a: REFERENCE_AXIS_MOTION[a].acceleration for a in travel})


def predict_duration_s(config: CampaignConfig, configurations: Sequence[Configuration],
                       steps: Sequence[Step]) -> float:
    """Predicted campaign duration (s); :func:`estimate_duration` says what it counts and assumes."""
    return estimate_duration(config, configurations, steps).total_s


# --------------------------------------------------------------------------------------------------
# Summary


def calibration_presentations(steps: Sequence[Step]) -> dict[str, int]:
    """Board presentations the steps need: ``visits`` (design or intrinsics visits), ``configurations``
    (per-config calibration views at the measured configurations) and ``total``."""
    tally = Presentations()
    for step in steps:
        step.present(tally)
    return {**tally.counts, "total": tally.counts["visits"] + tally.counts["configurations"]}


@dataclass
class Presentations:
    """Board presentations counted so far (``StepKind.present``): at visits, or at measured configurations."""

    in_visit: bool = False  # the last move went to a visit
    counts: dict[str, int] = field(default_factory=lambda: {"visits": 0, "configurations": 0})

    def add(self, n_views: int) -> None:
        self.counts["visits" if self.in_visit else "configurations"] += n_views


def plan_summary(config: CampaignConfig, *, margin_px: float = FEASIBILITY_MARGIN_PX) -> dict[str, Any]:
    """Everything ``stereo-bench campaign plan`` reports, as one JSON-able object."""
    configurations = expand_plan(config, margin_px=margin_px)
    visits = plan_visits(config, configurations)
    steps = plan_steps(config, configurations, visits)
    estimate = estimate_duration(config, configurations, steps)
    return {
        "extrinsics_mode": config.extrinsics.mode,
        "design": [v.as_dict() for v in visits],
        "design_ranges": design_ranges(configurations) if visits else None,
        "calibration_presentations": calibration_presentations(steps),
        "name": config.name,
        "configurations": [c.as_dict() for c in configurations],
        "predicted_duration_s": estimate.total_s,
        "duration": estimate.as_dict(),
        "n_steps": len(steps),
        "steps": [s.as_dict() for s in steps],
        "n_configurations": len(configurations),
        "infeasible": sum(not c.feasible for c in configurations),
        "partial": sum(c.status == "partial" for c in configurations),
        "limit_violations": sum(c.limit_violation is not None for c in configurations),
        "runnable": sum(c.runnable for c in configurations),
        "margin_px": margin_px,
        "min_corners_in_both": MIN_CORNERS_IN_BOTH,
    }
