"""Whether a fixed-board design starts with a lens calibration of presented views (issue 25 item 1: "the plan adds
presentations only for what it cannot [identify]").

Without ``calib_dir`` the fixed-board fit takes both cameras' intrinsics from its own views, which all see one board
at one depth: what they cannot separate from the focal lengths (a pan axis' depth, the slide scale...) the fit holds
nominal. :func:`lens_plan` reads that off the plan's identifiability table (:func:`design_table`: the board projected
exactly through the nominal chain at every visit) twice: with the intrinsics from the design's views alone, and with
the prior a stereo calibration of ``capture.calibration_views`` presented views would give
(:func:`stereo_bench.vision.planned.planned_stereo_calibration`: its views planned like the simulated presenter's,
at the table's corner noise, ``[extrinsics] plan_corner_sigma_px``, 0.1 px by default). The presentations are
planned when the prior identifies a parameter the board alone does not; what neither identifies (an axis held at one
value, one approach direction) is held nominal either way, and no presentation is added for it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from stereo_bench.campaign.config import CampaignConfig

if TYPE_CHECKING:
    from stereo_bench.kinematics.fixed_board import PlannedFit


@dataclass(frozen=True)
class LensPlan:
    """What :func:`lens_plan` decided: ``n_views`` presentations (0: none) and why (``reason``, for ``campaign
    plan``); ``gains``: the parameters the lens prior identifies that the fixed board alone does not; ``held``: those
    held nominal in the table the fit will have (``fit``: the planned fit, with the predicted prior when presentations
    are planned, else without; ``table`` its rows); ``covariance``: the predicted prior (16 x 16 over
    ``fixed_board.INTRINSIC_NAMES``), None when none is planned."""

    n_views: int
    reason: str
    gains: tuple[str, ...]
    held: tuple[str, ...]
    fit: PlannedFit
    covariance: np.ndarray | None = None

    @property
    def table(self) -> list:
        return self.fit.rows


def design_table(config: CampaignConfig, design: Sequence, *, intrinsics: tuple | None = None,
                 covariance: np.ndarray | None = None) -> PlannedFit:
    """The planned fit (:func:`stereo_bench.kinematics.fixed_board.planned_fit`: the identifiability rows and the
    planned model) of the fixed-board ``design`` (runnable visits with the board fixed), the nominal cameras'
    intrinsics (or ``intrinsics``) with ``covariance`` as their prior (None: from the design's views alone)."""
    from stereo_bench.kinematics.design import DesignConfiguration
    from stereo_bench.kinematics.fixed_board import planned_fit

    optics = config.cameras.optics
    left, right = optics.camera_model("left"), optics.camera_model("right")
    # The tilts where the design steps them (the table then has the tilt joints' rows).
    configurations = [DesignConfiguration(v.baseline_mm, v.toe_in_left_deg, v.toe_in_right_deg, v.tilt_left_deg,
                                          v.tilt_right_deg) for v in design]
    return planned_fit(configurations, config.calibration_board.build().object_points, design[0].fixed_board_matrix(),
                       intrinsics or (left.K, left.dist, right.K, right.dist),
                       pixel_sigma_px=config.extrinsics.plan_corner_sigma_px, intrinsics_covariance=covariance,
                       repeatability_mm=config.extrinsics.repeatability_mm,
                       repeatability_deg=config.extrinsics.repeatability_deg, image_size=left.image_size)


def predicted_lens_prior(config: CampaignConfig, visit, n_views: int) -> np.ndarray:
    """(16, 16) covariance of ``fixed_board.INTRINSIC_NAMES`` that a joint stereo calibration of ``n_views`` views
    presented at ``visit`` would have (views planned as the simulated presenter shows them,
    :func:`stereo_bench.vision.planned.planned_board_poses`, at 0.6-1.3 x the visit's distance within the range
    where the board fits both views; the plan's corners, ``[extrinsics] plan_corner_sigma_px``). ValueError if the views
    cannot be planned there."""
    from stereo_bench.geometry import RigPose, alpha_from_toe_in
    from stereo_bench.kinematics.fixed_board import INTRINSIC_NAMES
    from stereo_bench.vision.planned import planned_board_poses, planned_stereo_calibration

    if n_views < 5:
        raise ValueError(f"a stereo calibration needs at least 5 views, not {n_views}")
    optics = config.cameras.optics
    left, right = optics.camera_model("left"), optics.camera_model("right")
    board = config.calibration_board.build()
    # The presenter's range for a target at Z (the error model's CalibrationPlan rule), within where the board fits.
    near, far = max(250.0, 0.6 * visit.distance_mm), 1.3 * visit.distance_mm
    if visit.calibration_range_mm:
        lo, hi = visit.calibration_range_mm
        near, far = (max(near, lo), min(far, hi)) if max(near, lo) <= min(far, hi) else (lo, hi)
    rig = RigPose(visit.baseline_mm, alpha_from_toe_in(visit.toe_in_left_deg),
                  alpha_from_toe_in(visit.toe_in_right_deg), visit.tilt_deg, visit.tilt_deg)
    poses = planned_board_poses(rig, board, left, right, n_views=n_views, distance_mm=(near, far))
    covariance = planned_stereo_calibration(rig, board, left, right, poses,
                                            pixel_sigma_px=config.extrinsics.plan_corner_sigma_px).covariance
    index = covariance.index(INTRINSIC_NAMES)
    return np.asarray(covariance.matrix, float)[np.ix_(index, index)]


def lens_plan(config: CampaignConfig, design: Sequence, lens_visit) -> LensPlan | None:
    """Whether the fixed-board ``design`` (its visits, the board placed) starts with ``capture.calibration_views``
    presentations at ``lens_visit`` (an intrinsics visit where a presented board fits both views; None: there is
    none), by ``[extrinsics] fixed_board_lens``. None where it does not apply: not a fixed-board design, a
    ``calib_dir`` given (its lens calibration is the prior), or fewer than 3 runnable visits."""
    from stereo_bench.vision.covariance import CovarianceUnavailable

    extrinsics = config.extrinsics
    runnable = [v for v in design if v.runnable and v.board_fixed]
    if not extrinsics.fixed_board or extrinsics.calib_dir is not None or len(runnable) < 3:
        return None
    n_views = config.capture.calibration_views
    alone = design_table(config, runnable)
    held_alone = tuple(r.name for r in alone.rows if not r.identified)
    choice = extrinsics.fixed_board_lens

    def without(reason: str) -> LensPlan:
        return LensPlan(0, reason, (), held_alone, alone)

    if choice == "none":
        return without('fixed_board_lens = "none": the intrinsics from the design\'s views alone')
    if choice == "auto" and not held_alone:
        return without("the fixed board alone identifies every parameter")
    if lens_visit is None:
        return without("no configuration where a presented calibration board fits both views")
    try:
        covariance = predicted_lens_prior(config, lens_visit, n_views)
        prior = design_table(config, runnable, covariance=covariance)
    except (ValueError, CovarianceUnavailable, np.linalg.LinAlgError) as error:
        return without(f"a lens calibration of {n_views} presented views cannot be planned: {error}")
    held = tuple(r.name for r in prior.rows if not r.identified)
    gains = tuple(name for name in held_alone if name not in held)
    if choice == "auto" and not gains:
        return without(f"a lens calibration would identify none of {', '.join(held_alone)}: they stay nominal")
    # The sigmas the prior sharpens most (the table's, at the plan's corners): what presentations buy beyond the gains.
    ratios = sorted(((a.sigma / b.sigma, a) for a, b in zip(alone.rows, prior.rows, strict=True)
                     if a.identified and b.identified and b.sigma), key=lambda item: -item[0])[:3]
    by_name = {r.name: r for r in prior.rows}
    sharper = ", ".join(f"{a.name} {a.sigma:.3g} -> {by_name[a.name].sigma:.3g} {a.unit}" for _, a in ratios)
    reason = ("a lens calibration: the fixed board alone does not separate " + ", ".join(gains)
              + " from the focal lengths" if gains else 'a lens calibration: fixed_board_lens = "present"')
    return LensPlan(n_views, reason + (f"; sigmas {sharper}" if sharper else ""), gains, held, prior, covariance)


__all__ = ["LensPlan", "design_table", "lens_plan", "predicted_lens_prior"]
