"""What a campaign visits: its configurations (:func:`expand_plan`, feasibility predicted) and the visits of its
extrinsics source (:func:`plan_visits`: the kinematic design, a one-off intrinsics calibration)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from drivers.rig.config import LimitError, MoveRequestError, RigConfig, plan_move
from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan.feasibility import (
    CALIBRATION_DISTANCES_MM,
    FEASIBILITY_MARGIN_PX,
    MIN_CORNERS_IN_BOTH,
    Target,
    _nearest_range,
    _remember,
    _why_too_few,
    _why_too_small,
    calibration_distance_range,
    target_visibilities,
)
from stereo_bench.geometry import RigPose, alpha_from_toe_in
from stereo_bench.vision.detect import min_detectable_square_px


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
        for key in ("calibration_range_mm", "fixed_board_pose"):
            if values.get(key) is not None:
                values[key] = tuple(values[key])
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
    calibration_ranges: dict[tuple[float, float, float], tuple[float, float] | None] = {}
    computed: dict[tuple[float, float], tuple[list[float], list]] = {}  # (alpha, tilt) -> (baselines, ranges): hints
    configurations: list[Configuration] = []
    sweep = tilt_sweep = 0
    tilts = plan.tilts()
    poses = {(baseline, alpha, tilt): RigPose.symmetric(baseline, alpha, tilt)
             for baseline in plan.baseline_mm for alpha, _ in angles for tilt in tilts}
    for z_index, distance in enumerate(plan.distance_mm):
        visibility = dict(zip(poses, target_visibilities(target, list(poses.values()), distance_mm=distance,
                                                          left=left, right=right, margin_px=margin_px), strict=True))
        baselines = plan.baseline_mm if z_index % 2 == 0 else plan.baseline_mm[::-1]
        for baseline in baselines:
            ordered = angles if sweep % 2 == 0 else angles[::-1]
            sweep += 1
            for alpha, toe_in in ordered:
                # Tilts (a rig that drives them) innermost, serpentine too: one step of one axis at a time.
                for tilt in tilts if tilt_sweep % 2 == 0 else tilts[::-1]:
                    configurations.append(_configuration(
                        config, len(configurations), baseline=baseline, distance=distance, alpha=alpha,
                        toe_in=toe_in, tilt=tilt, rig=poses[baseline, alpha, tilt],
                        vis=visibility[baseline, alpha, tilt], per_config=per_config, target=target,
                        calibration_board=calibration_board, left=left, right=right, image_size=image_size,
                        rig_config=rig_config, calibration_ranges=calibration_ranges, computed=computed))
                tilt_sweep += 1
    ids = [c.config_id for c in configurations]
    if len(set(ids)) != len(ids):  # distinct toe-ins whose alphas (90 - t) round to the same float
        configurations = [dataclasses.replace(c, config_id=f"{c.config_id}_i{c.index}") for c in configurations]
    return configurations


def _configuration(config: CampaignConfig, index: int, *, baseline: float, distance: float, alpha: float,
                   toe_in: float, tilt: float, rig: RigPose, vis, per_config: bool, target: Target,
                   calibration_board: Target, left, right, image_size: tuple[int, int], rig_config: RigConfig,
                   calibration_ranges: dict, computed: dict) -> Configuration:
    """One configuration of :func:`expand_plan`, its feasibility and limit check."""
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
        key = (baseline, alpha, tilt)
        if key not in calibration_ranges:
            calibration_ranges[key] = calibration_distance_range(
                calibration_board, rig, left=left, right=right,
                hint=_nearest_range(computed.setdefault((alpha, tilt), ([], [])), baseline))
            _remember(computed[alpha, tilt], baseline, calibration_ranges[key])
        calibration_range = calibration_ranges[key]
        if calibration_range is None:
            reasons.append(_calibration_reason(config, calibration_board, baseline_mm=baseline, alpha_deg=alpha))
    config_id = f"B{format_id_value(baseline)}_Z{format_id_value(distance)}_A{format_id_value(alpha)}"
    if tilt:
        config_id += f"_T{format_id_value(tilt)}"
    configuration = Configuration(
        index=index, config_id=config_id, baseline_mm=float(baseline), distance_mm=float(distance),
        alpha_deg=float(alpha), toe_in_deg=float(toe_in), tilt_deg=float(tilt), fraction_in_both=vis.fraction_in_both,
        feasible=not reasons, reason="; ".join(reasons) or None, limit_violation=None, corners_in_both=vis.in_both,
        n_corners=vis.n_corners, calibration_range_mm=calibration_range,
    )
    violation = _limit_violation(rig_config, configuration.move_request())
    return dataclasses.replace(configuration, limit_violation=violation)


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
    # A fixed-board design (issue 25): the calibration board stands where the operator placed it once, requested
    # at this T_rig_board (16 numbers, row-major); None: presented by hand at this visit.
    fixed_board_pose: tuple[float, ...] | None = None
    # A design that steps the tilts (a rig that drives them, issue 25): each camera's commanded tilt at this visit,
    # a part of the kinematic model's axes; None: both at ``tilt_deg``, the campaign's, not in the model.
    tilt_left_deg: float | None = None
    tilt_right_deg: float | None = None
    fraction_in_both: ClassVar[float] = 1.0

    @property
    def board_fixed(self) -> bool:
        return self.fixed_board_pose is not None

    def fixed_board_matrix(self) -> np.ndarray | None:
        return None if self.fixed_board_pose is None else np.array(self.fixed_board_pose, float).reshape(4, 4)

    @property
    def tilts_in_design(self) -> tuple[str, ...]:
        """The tilts this visit steps for the kinematic model (``tilt_left_deg``, ``tilt_right_deg``; none: held)."""
        return tuple(axis for axis in ("tilt_left_deg", "tilt_right_deg") if getattr(self, axis) is not None)

    def tilt(self, side: str) -> float:
        """The commanded tilt of camera ``side`` ("left" or "right") at this visit."""
        value = getattr(self, f"tilt_{side}_deg")
        return self.tilt_deg if value is None else value

    def axes(self) -> dict[str, float]:
        out = {"baseline_mm": self.baseline_mm, "toe_in_left_deg": self.toe_in_left_deg,
               "toe_in_right_deg": self.toe_in_right_deg}
        out.update({axis: getattr(self, axis) for axis in self.tilts_in_design})
        return out

    def rig_pose(self) -> RigPose:
        return RigPose(self.baseline_mm, alpha_from_toe_in(self.toe_in_left_deg),
                       alpha_from_toe_in(self.toe_in_right_deg), self.tilt("left"), self.tilt("right"))

    def move_request(self) -> dict[str, float]:
        return {"baseline_mm": self.baseline_mm, "toe_in_left_deg": self.toe_in_left_deg,
                "toe_in_right_deg": self.toe_in_right_deg, "tilt_left_deg": self.tilt("left"),
                "tilt_right_deg": self.tilt("right"), "target_distance_mm": self.distance_mm}

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["calibration_range_mm"] = list(self.calibration_range_mm) if self.calibration_range_mm else None
        if self.fixed_board_pose is None:
            del data["fixed_board_pose"]  # as recorded before fixed boards existed
        else:
            data["fixed_board_pose"] = list(self.fixed_board_pose)
        for axis in ("tilt_left_deg", "tilt_right_deg"):
            if data[axis] is None:
                del data[axis]  # as recorded before designs stepped the tilts
        data["runnable"] = self.runnable
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Visit:
        """The visit a recorded ``start.design`` entry describes (resume and replay run the recorded visits)."""
        names = {f.name for f in dataclasses.fields(cls)}
        values = {key: value for key, value in data.items() if key in names}
        for key in ("calibration_range_mm", "fixed_board_pose"):
            if values.get(key) is not None:
                values[key] = tuple(values[key])
        return cls(**values)


def design_ranges(configurations: Sequence[Configuration]) -> dict[str, tuple[float, float]] | None:
    """(min, max) of B and of the toe-ins over the runnable configurations: what the design must span."""
    runnable = [c for c in configurations if c.runnable]
    if not runnable:
        return None
    baselines = [c.baseline_mm for c in runnable]
    toe_ins = [c.toe_in_deg for c in runnable]
    return {"baseline_mm": (min(baselines), max(baselines)), "toe_in_deg": (min(toe_ins), max(toe_ins))}


@dataclass(frozen=True)
class DesignTilt:
    """Whether the kinematic design steps the tilts (:func:`design_tilt`): ``ranges`` per driven tilt the span of
    the campaign's tilts (None: held at the campaign's tilt, no tilt joints in the model); ``note`` says which and
    why, for ``campaign plan`` (None: the rig drives no tilt)."""

    ranges: dict[str, tuple[float, float]] | None
    note: str | None


def design_tilt(config: CampaignConfig, configurations: Sequence[Configuration]) -> DesignTilt:
    """Whether the fixed-board design steps the tilts the rig drives (``[extrinsics] design_tilt``).

    ``auto`` steps them when the runnable configurations use more than one tilt: a model with tilt joints is the
    only one that predicts R, T at another tilt. At one tilt it holds them: measured on the lab mechanics
    (scripts/bench_tilt_identifiability.py), the joints' 12 parameters from the same views cost the right camera's
    height (T_y) 2.4x its sigma and give the principal points 2-10 %, and a model fitted at the campaign's tilt
    needs no joint there. ``include`` steps them anyway (a model file for later campaigns at other tilts)."""
    from stereo_bench.kinematics.model import TILT_AXES

    extrinsics = config.extrinsics
    driven = [axis for axis in TILT_AXES if axis in config.rig.rig_config().driven]
    if not driven:
        return DesignTilt(None, None)
    tilts = sorted({c.tilt_deg for c in configurations if c.runnable}) or [float(config.plan.tilts()[0])]
    at = f"{tilts[0]:g} deg" if len(tilts) == 1 else f"{tilts[0]:g}-{tilts[-1]:g} deg"
    if not extrinsics.fixed_board:
        return DesignTilt(None, f"tilts held at {at}: the presented design's fit has no tilt joints")
    if extrinsics.design_tilt == "hold" or (extrinsics.design_tilt == "auto" and len(tilts) == 1):
        why = ("design_tilt = \"hold\"" if extrinsics.design_tilt == "hold" else
               "one campaign tilt: tilt joints would cost the right camera's height 2.4x its sigma, "
               "docs/EXTRINSICS.md")
        return DesignTilt(None, f"tilts held at {at} ({why}); the model predicts at that tilt only")
    why = "design_tilt = \"include\"" if extrinsics.design_tilt == "include" else f"the campaign tilts {at}"
    return DesignTilt({axis: (tilts[0], tilts[-1]) for axis in driven},
                      f"tilts stepped ({', '.join(driven)}; {why}): the model has tilt joints")


def _visit_maker(config: CampaignConfig):
    """``visit(index, config_id, purpose, baseline, toe_left, toe_right, distance, tilts=None)``: one :class:`Visit`,
    checked like a configuration (the calibration board must fit both views somewhere, the move must pass the soft
    limits)."""
    board = config.calibration_board.build()
    left = config.cameras.optics.camera_model("left")
    right = config.cameras.optics.camera_model("right")
    rig_config = config.rig.rig_config()
    tilt = float(config.plan.tilts()[0])

    def visit(index: int, config_id: str, purpose: str, baseline: float, toe_left: float, toe_right: float,
              distance: float, *, tilts: Mapping[str, float] | None = None) -> Visit:
        tilts = tilts or {}
        pose = RigPose(baseline, alpha_from_toe_in(toe_left), alpha_from_toe_in(toe_right),
                       tilts.get("tilt_left_deg", tilt), tilts.get("tilt_right_deg", tilt))
        fits = calibration_distance_range(board, pose, left=left, right=right)
        reason = None
        if fits is None:
            reason = (f"calibration board ({config.calibration_board.describe()}) never fits both views at "
                      f"B = {baseline:g} mm, toe-ins {toe_left:g}/{toe_right:g} deg")
        draft = Visit(index=index, config_id=config_id, purpose=purpose, baseline_mm=float(baseline),
                      toe_in_left_deg=float(toe_left), toe_in_right_deg=float(toe_right), tilt_deg=tilt,
                      distance_mm=float(distance), calibration_range_mm=fits, feasible=fits is not None,
                      reason=reason, **{axis: float(value) for axis, value in tilts.items()})
        return dataclasses.replace(draft, limit_violation=_limit_violation(rig_config, draft.move_request()))

    return visit


def plan_visits(config: CampaignConfig, configurations: Sequence[Configuration]) -> list[Visit]:
    """The visits the extrinsics source needs before the measured configurations: :func:`plan_visits_and_lens`'s."""
    return plan_visits_and_lens(config, configurations)[0]


def plan_visits_and_lens(config: CampaignConfig, configurations: Sequence[Configuration]) -> tuple[list[Visit], object]:
    """(visits, the fixed-board design's :class:`~stereo_bench.campaign.plan.lens.LensPlan` or None): the lens plan
    that decided whether the design starts with presentations, for ``campaign plan`` to print without deciding
    again (for paper-exp1 that saved 0.1-0.2 s of 0.83-0.95 warm, ~0.5 s on the first, cold call).

    The visits the extrinsics source needs before the measured configurations (none for most modes), as its
    strategy object says (``visits``), each visit checked like a configuration (the calibration board must fit
    both views somewhere, the move must pass the soft limits).

    ``kinematic`` without ``kinematic_file``: the design of :func:`stereo_bench.kinematics.kinematic_design`
    over :func:`design_ranges`; the board is shown around the middle of the plan's target distances; a
    fixed-board design steps the tilts too where :func:`design_tilt` says so (``ranges["tilt_ranges_deg"]``).
    ``nominal`` without ``calib_dir``: the first runnable configuration at which the calibration board fits,
    for one stereo calibration whose intrinsics every configuration uses.
    """
    extrinsics = config.extrinsics
    source = extrinsics.source()
    if source.visit_purpose(extrinsics) is None:
        return [], None
    ranges = design_ranges(configurations)
    if ranges is None:
        return [], None
    tilt_ranges = design_tilt(config, configurations).ranges
    if tilt_ranges:
        ranges = {**ranges, "tilt_ranges_deg": tilt_ranges}
    board = config.calibration_board.build()
    left = config.cameras.optics.camera_model("left")
    right = config.cameras.optics.camera_model("right")
    visit = _visit_maker(config)

    visits = source.visits(extrinsics, configurations, ranges, visit=visit, format_id=format_id_value)
    lens = None
    if extrinsics.fixed_board and visits:
        visits = _with_fixed_board(visits, board, left, right, config.calibration_board.describe())
        lens, lens_visit = fixed_board_lens(config, configurations, visits, visit=visit)
        if lens is not None and lens.n_views:
            # The presentations first, at the measured configuration where a presented board fits: the fixed
            # board is placed after them (a presented board would hide it, or move it).
            visits = [lens_visit, *(dataclasses.replace(v, index=v.index + 1) for v in visits)]
    return visits, lens


def design_problem(config: CampaignConfig, configurations: Sequence[Configuration], visits: Sequence[Visit]
                   ) -> str | None:
    """Why the visits the extrinsics source needs cannot give it (None when they can, or when nothing is to be
    measured anyway), as :func:`visits_problem` says it. Every configuration would then fail on its extrinsics after
    the rig had moved through the plan, so ``campaign plan`` says so and ``campaign run`` refuses before anything
    moves."""
    if not any(c.runnable for c in configurations):
        return None
    problem = _visits_problem(config, visits)
    if problem is None:
        return None
    what, fixes = problem
    return f"extrinsics: {what} and no configuration could be measured; use {fixes}"


def visits_problem(config: CampaignConfig, visits: Sequence[Visit]) -> str | None:
    """One line (None if there is none to say): a stage of ``visits`` (the kinematic design, the one intrinsics
    calibration) none of whose visits can run, its first visit's reason and what to change."""
    problem = _visits_problem(config, visits)
    return None if problem is None else f"extrinsics: {problem[0]}; use {problem[1]}"


def _visits_problem(config: CampaignConfig, visits: Sequence[Visit]) -> tuple[str, str] | None:
    """(what cannot be prepared and why, what to change) of :func:`visits_problem`."""
    extrinsics = config.extrinsics
    charuco = 'a ChArUco board counts partial views: [calibration_board] kind = "charuco"'
    for purpose in VISIT_PURPOSES:
        stage = [v for v in visits if v.purpose == purpose]
        if not stage or any(v.runnable for v in stage):
            continue
        why = f"{stage[0].config_id}: {stage[0].skip_reason or 'not runnable'}"
        if purpose == "kinematic":
            fixes = [f"a calibration board that fits both views there ({charuco})"]
            if extrinsics.fixed_board:
                fixes.append('design = "presented"')
            fixes.append("extrinsics.kinematic_file (a model fitted before)")
            what = (f"no visit of the kinematic design ({extrinsics.design}) can run ({why}), so the kinematic "
                    "model cannot be fitted")
        else:
            fixes = [f"a calibration board that fits both views ({charuco})",
                     "extrinsics.calib_dir (a lens calibration made before)"]
            what = (f"the intrinsics calibration visit cannot run ({why}), so the {extrinsics.mode} extrinsics have "
                    "no intrinsics")
        return what, ", or ".join(fixes)
    return None


def fixed_board_lens(config: CampaignConfig, configurations: Sequence[Configuration], design: Sequence[Visit], *,
                     visit):
    """(:class:`~stereo_bench.campaign.plan.lens.LensPlan` or None, the intrinsics visit it presents at): whether a
    fixed-board ``design`` starts with a lens calibration of presented views (:func:`.lens.lens_plan`). ``visit``:
    plan_visits' visit maker."""
    from stereo_bench.campaign.extrinsics.base import intrinsics_visit
    from stereo_bench.campaign.plan.lens import lens_plan

    design = [v for v in design if v.purpose == "kinematic"]
    if not config.extrinsics.fixed_board or config.extrinsics.calib_dir is not None or not design:
        return None, None
    candidate = intrinsics_visit(configurations, visit)
    candidate = candidate if candidate is not None and candidate.runnable else None
    return lens_plan(config, design, candidate), candidate


def _with_fixed_board(visits: Sequence[Visit], board, left, right, board_name: str) -> list[Visit]:
    """The fixed-board design's visits with where the operator is asked to place the board once
    (:func:`~stereo_bench.campaign.plan.feasibility.fixed_board_placement`); a visit where it does not fit both
    views is not run, with the reason."""
    from stereo_bench.campaign.plan.feasibility import fixed_board_placement

    T, fits = fixed_board_placement(board, [v.rig_pose() for v in visits], left=left, right=right)
    pose = None if T is None else tuple(float(x) for x in np.asarray(T).ravel())
    out = []
    for v, ok in zip(visits, fits, strict=True):
        reason = v.reason
        if not ok and v.feasible:
            reason = (f"calibration board ({board_name}) placed once for the fixed-board design does not fit both "
                      f"views at B = {v.baseline_mm:g} mm, toe-ins {v.toe_in_left_deg:g}/{v.toe_in_right_deg:g} deg")
        out.append(dataclasses.replace(v, fixed_board_pose=pose, feasible=v.feasible and ok, reason=reason,
                                       distance_mm=float(T[2, 3]) if T is not None else v.distance_mm))
    return out
