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
their intrinsics; a fixed-board design without one, that same intrinsics visit first where its
identifiability table says a lens calibration identifies what the board alone cannot (:mod:`.lens`).
Each visit is Move, Settle, Flush, CaptureCalibration, :class:`VisitDone`; then one
:class:`PrepareExtrinsics` fits the model (or calibrates the intrinsics) before the first measured
configuration. A visit where the calibration board cannot be shown to both cameras or outside the soft
limits is not run (the fit goes on without it, and says what it could not identify).
"""

from __future__ import annotations

from stereo_bench.campaign.plan.configurations import (
    VISIT_PURPOSES,
    Configuration,
    Visit,
    design_problem,
    design_ranges,
    expand_plan,
    format_id_value,
    plan_visits,
    visits_problem,
)
from stereo_bench.campaign.plan.duration import (
    DurationEstimate,
    estimate_duration,
    homing_estimate_s,
    predict_duration_s,
)
from stereo_bench.campaign.plan.feasibility import (
    CALIBRATION_DISTANCE_STEP_MM,
    CALIBRATION_DISTANCES_MM,
    FEASIBILITY_MARGIN_PX,
    MIN_CORNERS_IN_BOTH,
    Target,
    Visibility,
    calibration_distance_range,
    target_visibilities,
    target_visibility,
)
from stereo_bench.campaign.plan.steps import (
    PREPARE_ID,
    CaptureCalibration,
    CaptureMeasurement,
    Checkpoint,
    Flush,
    Move,
    PlaceBoard,
    PrepareExtrinsics,
    Presentations,
    PromptManual,
    PromptTarget,
    Settle,
    Step,
    StepKind,
    VisitDone,
    is_prepare_id,
    plan_steps,
    stage_id,
)
from stereo_bench.campaign.plan.summary import calibration_presentations, plan_summary
from stereo_bench.campaign.plan.timing import (
    ASSUMED_FLUSH_FRAMES,
    ASSUMED_FPS,
    OPERATOR_S_PER_CALIBRATION_VIEW,
    OPERATOR_S_PER_PROMPT,
    DurationModel,
)

__all__ = [
    "ASSUMED_FLUSH_FRAMES", "ASSUMED_FPS", "CALIBRATION_DISTANCES_MM", "CALIBRATION_DISTANCE_STEP_MM",
    "CaptureCalibration", "CaptureMeasurement", "Checkpoint", "Configuration", "DurationEstimate", "DurationModel",
    "FEASIBILITY_MARGIN_PX", "Flush", "MIN_CORNERS_IN_BOTH", "Move", "OPERATOR_S_PER_CALIBRATION_VIEW",
    "OPERATOR_S_PER_PROMPT", "PREPARE_ID", "PlaceBoard", "PrepareExtrinsics", "Presentations", "PromptManual",
    "PromptTarget",
    "Settle", "Step", "StepKind", "Target", "VISIT_PURPOSES", "Visibility", "Visit", "VisitDone",
    "calibration_distance_range", "calibration_presentations", "design_problem", "design_ranges",
    "estimate_duration", "expand_plan",
    "format_id_value", "homing_estimate_s", "is_prepare_id", "plan_steps", "plan_summary", "plan_visits",
    "predict_duration_s", "stage_id", "target_visibilities", "target_visibility", "visits_problem",
]
