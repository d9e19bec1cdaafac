"""``stereo-bench campaign``: plan (dry run), schema, presets; ``run`` is registered by :mod:`campaign_run`.

    stereo-bench campaign plan PLAN.toml [--json] [--steps] [--out SESSION_DIR]
    stereo-bench campaign plan --preset paper-exp1
    stereo-bench campaign schema
    stereo-bench campaign presets [--json]

``plan`` validates the config, expands the plan, predicts which configurations show the target in
both views, checks the soft limits and predicts the duration. It moves nothing and opens no port.
Exit status: 0 done; 2 for a config the user can fix (one line naming the file and the field).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from stereo_bench.campaign import presentation
from stereo_bench.campaign.config import (
    PRESETS,
    CampaignConfig,
    ConfigError,
    campaign_json_schema_text,
)
from stereo_bench.campaign.plan import plan_summary
from stereo_bench.campaign.plan.feasibility import FIXED_BOARD_PITCH_DEG, FIXED_BOARD_YAW_DEG
from stereo_bench.cli import campaign_run, print_json
from stereo_bench.cli.campaign_run import config_from_args


def register(subparsers) -> None:
    campaign = subparsers.add_parser(
        "campaign", help="measurement campaigns: plan (dry run), run, schema, presets",
        description="Campaigns over (B, Z, alpha) configurations, from a TOML config or a preset.",
    )
    actions = campaign.add_subparsers(dest="campaign_action", metavar="ACTION", required=True)

    plan = actions.add_parser(
        "plan", help="list the configurations, which are infeasible and why, limits and duration; moves nothing",
        description="Expand a campaign plan without hardware: configurations in order, the fraction of the "
                    "target in both views (predicted from geometry), infeasible ones with the reason, soft-limit "
                    "violations, the number of steps and the predicted duration. Nothing moves; no port is opened.",
    )
    plan.add_argument("plan_file", nargs="?", type=Path, metavar="PLAN.toml", help="campaign config TOML")
    plan.add_argument("--preset", metavar="NAME", help=f"a shipped preset instead of a file: {', '.join(PRESETS)}")
    plan.add_argument("--json", action="store_true",
                      help="print one JSON object {configurations, predicted_duration_s, n_steps, infeasible, ...}")
    plan.add_argument("--steps", action="store_true", help="also list every step (move, settle, capture, ...)")
    plan.add_argument("--out", type=Path, metavar="DIR",
                      help="the session directory the run will write: the seconds per board presentation that "
                           f"earlier runs measured beside it ({presentation.FILE_NAME} in its parent) replace the "
                           "assumed 5 s")
    plan.set_defaults(func=_cmd_plan)

    schema = actions.add_parser("schema", help="print the JSON Schema of a campaign config")
    schema.set_defaults(func=_cmd_schema)

    presets = actions.add_parser("presets", help="list the shipped presets")
    presets.add_argument("--json", action="store_true", help="print one JSON object {name: description}")
    presets.set_defaults(func=_cmd_presets)

    # ---- the campaign runner's CLI (``campaign run``) lives in stereo_bench/cli/campaign_run.py ----
    campaign_run.register_run(actions)


def format_duration(seconds: float) -> str:
    """Seconds as h:mm:ss (rounded to the second)."""
    total = int(round(seconds))
    return f"{total // 3600}:{total % 3600 // 60:02d}:{total % 60:02d}"


def _cmd_plan(args) -> int:
    config = config_from_args(args.plan_file, args.preset)
    measured, note = presentation.read_beside(args.out) if args.out is not None else (None, None)
    if note is not None:
        print(f"note: {note}: the assumed 5 s per presentation is used", file=sys.stderr)
    summary = plan_summary(config, presentation=measured)
    summary["presentation_time"]["file"] = str(presentation.beside(args.out)) if args.out is not None else None
    source = f"preset {args.preset}" if args.preset else str(args.plan_file)
    if args.json:
        if not args.steps:
            summary.pop("steps")
        print_json({"source": source, **summary}, indent=2)
    else:
        print(_plan_text(config, summary, source=source, with_steps=args.steps))
    if summary["design_problem"]:  # the plan is shown, with each visit's reason; run would refuse it
        raise ConfigError(f"{source}: {summary['design_problem']}")
    return 0


def _plan_text(config: CampaignConfig, summary: dict[str, Any], *, source: str, with_steps: bool) -> str:
    rows = summary["configurations"]
    lines = [
        f"campaign {config.name!r} ({source}): {summary['n_configurations']} configurations: "
        f"{summary['runnable']} to run ({summary['partial']} partial), {summary['infeasible']} infeasible, "
        f"{summary['limit_violations']} outside the soft limits",
        f"rig {config.rig.kind}, cameras {config.cameras.kind}, target {config.target.describe()}, "
        f"extrinsics {config.extrinsics.mode}"
        + (f" (calibration board {config.calibration_board.describe()})"
           if config.extrinsics.source().calibrates_each_configuration else ""),
        f"in both = target corners at least {summary['margin_px']:g} px inside both images, predicted from "
        f"geometry; infeasible below {summary['min_corners_in_both']}",
        "",
    ]
    # Columns as wide as their longest entry (a plan of 87.25 mm baselines and toe-ins has ids past 18 characters),
    # and values to 10 digits: two values the plan tells apart never print alike (100 and 100.0001).
    ids = max([18] + [len(row["config_id"]) for row in rows])
    cells = [tuple(f"{row[key]:.10g}" for key in ("baseline_mm", "distance_mm", "alpha_deg", "toe_in_deg"))
             for row in rows]
    widths = [max([7, 7, 6, 6][i], *(len(c[i]) for c in cells)) for i in range(4)]
    lines.append(f"{'#':>3}  {'config_id':<{ids}} {'B mm':>{widths[0]}} {'Z mm':>{widths[1]}} "
                 f"{'alpha':>{widths[2]}} {'toe-in':>{widths[3]}}  {'in both':>12}  status")
    for row, cell in zip(rows, cells, strict=True):
        in_both = f"{row['corners_in_both']}/{row['n_corners']} {row['fraction_in_both']:4.0%}"
        status = row["status"] + ("" if row["limit_violation"] is None else ", outside limits")
        values = " ".join(f"{text:>{width}}" for text, width in zip(cell, widths, strict=True))
        lines.append(f"{row['index']:>3}  {row['config_id']:<{ids}} {values}  {in_both:>12}  {status}")
        if row["reason"]:
            lines.append(f"{'':>5}why: {row['reason']}")
        if row["limit_violation"]:
            lines.append(f"{'':>5}limits: {row['limit_violation']}")
    lines += _extrinsics_text(config, summary)
    duration = summary["duration"]
    parts = ", ".join(f"{name} {format_duration(duration[name + '_s'])}"
                      for name in ("homing", "motion", "settle", "flush", "capture", "operator"))
    lines += [
        "",
        f"steps: {summary['n_steps']}",
        f"predicted duration: {format_duration(summary['predicted_duration_s'])} ({parts})",
        "assumed: " + "; ".join(duration["assumptions"]),
    ]
    if config.cameras.kind != "simulated":  # boards presented by hand: where their time comes from
        lines.append(_presentation_text(summary["presentation_time"]))
    if with_steps:
        lines += ["", "steps:"]
        lines += [f"{i:>5}  " + _step_text(step) for i, step in enumerate(summary["steps"])]
    lines.append("dry run: nothing moved, no port opened")
    return "\n".join(lines)


def _presentation_text(figure: dict[str, Any]) -> str:
    """Where the seconds per board presentation come from: measured by an earlier run (which file), or assumed."""
    others = "".join(f"; {what}: measured, {figure[key]:.1f} s, from {figure['file']}"
                     for what, key, source in (("target move", "s_per_target_move", "target_move_source"),
                                               ("board placement", "s_per_placement", "placement_source"))
                     if figure.get(source) == "measured")
    if figure["source"] == "measured":
        return (f"presentation time: measured, {figure['s_per_calibration_view']:.2f} s per view, from "
                f"{figure['file']}" + others)
    where = (f"no measured figure in {figure['file']}" if figure.get("file")
             else "pass --out SESSION_DIR to use the figure earlier runs measured beside it")
    return f"presentation time: assumed, {figure['s_per_calibration_view']:g} s per view ({where})" + others


def _extrinsics_text(config: CampaignConfig, summary: dict[str, Any]) -> list[str]:
    """Where R, T come from, the visits that prepare it (the kinematic design) and the board presentations."""
    mode = config.extrinsics.mode
    extrinsics = config.extrinsics.source()
    counts = summary["calibration_presentations"]
    lines = ["", f"extrinsics {mode}: {extrinsics.describe(config.extrinsics)}"]
    design = summary["design"]
    if design:
        ranges = summary["design_ranges"]
        # The last stage's visits (a fixed-board design's lens calibration, if any, comes before them)
        last = [v for v in design if v["purpose"] == design[-1]["purpose"]]
        title = ("kinematic design" if last[0]["purpose"] == "kinematic" else "intrinsics calibration")
        span = (f" over B {ranges['baseline_mm'][0]:g}-{ranges['baseline_mm'][1]:g} mm, toe-in "
                f"{ranges['toe_in_deg'][0]:g}-{ranges['toe_in_deg'][1]:g} deg" if ranges else "")
        before = len(design) - len(last)
        lines.append(f"{title}: {sum(v['runnable'] for v in last)} of {len(last)} visits to run{span}"
                     + (f", after {before} intrinsics visit{'s' if before > 1 else ''} (a lens calibration)"
                        if before else ""))
        if summary.get("design_tilt"):
            lines.append(f"design tilts: {summary['design_tilt']}")
        fixed = last[0].get("fixed_board_pose")
        if fixed:
            T = np.array(fixed, float).reshape(4, 4)
            centre = T[:3, :3] @ np.array([*config.calibration_board.build().grid_size_mm, 0.0]) / 2.0 + T[:3, 3]
            lines.append(f"fixed board: placed once, centred {centre[2]:.0f} mm in front of the rig "
                         f"({centre[0]:+.0f} mm across), turned {FIXED_BOARD_YAW_DEG:g} deg about the vertical and "
                         f"{FIXED_BOARD_PITCH_DEG:g} deg about the horizontal; captured "
                         f"{config.extrinsics.fixed_board_views} times at each visit, never moved")
        for visit in design:
            where = ("fixed board" if visit.get("fixed_board_pose") else
                     f"board at {visit['calibration_range_mm'][0]:g}-{visit['calibration_range_mm'][1]:g} mm"
                     if visit["calibration_range_mm"] else "")
            why = "; ".join(r for r in (visit["reason"], visit["limit_violation"]) if r)
            status = where if visit["runnable"] else f"NOT RUN: {why}"
            tilts = (f"  tilt {visit['tilt_left_deg']:g}/{visit['tilt_right_deg']:g} deg"
                     if visit.get("tilt_left_deg") is not None and visit.get("tilt_right_deg") is not None else "")
            lines.append(f"{'':>5}{visit['config_id']:<24} B {visit['baseline_mm']:>6g} mm  toe-in "
                         f"{visit['toe_in_left_deg']:g}/{visit['toe_in_right_deg']:g} deg{tilts}  {status}")
    table = summary.get("identifiability")
    if table:
        held = [row for row in table if not row["identified"]]
        corners = config.extrinsics.plan_corner_sigma_px
        lines.append(f"identifiability (the design's views on the nominal rig, {corners:g} px corners "
                     "([extrinsics] plan_corner_sigma_px), "
                     f"intrinsics {table[0]['intrinsics']}): {len(table) - len(held)} of {len(table)} parameters "
                     "identified")
        for row in table:
            sigma = f"sigma {row['sigma']:.3g} {row['unit']}" if row["identified"] else f"held nominal: {row['note']}"
            lines.append(f"{'':>5}{row['name']:<24} {sigma}")
    predicted = summary.get("predicted_extrinsics")
    if predicted:
        corners = predicted["corner_sigma_px"]
        lines += predicted_extrinsics_text(predicted, f"the planned fit to first order, {corners:g} px corners, "
                                                      f"intrinsics {predicted['intrinsics']}")
    per_configuration = " (one set per configuration)" if extrinsics.calibrates_each_configuration else ""
    note = " (adding configurations adds none)" if counts["visits"] and not counts["configurations"] else ""
    lines.append(f"calibration board presentations: {counts['total']}: {counts['visits']} at visits{note}, "
                 f"{counts['configurations']} at the configurations{per_configuration}")
    lens = summary.get("lens_calibration")
    if lens is not None:  # a fixed-board design: whether it starts with a lens calibration, and why
        where = f" at {lens['visit']}, before the board is placed" if lens["visit"] else ""
        lines.append(f"{'':>5}lens calibration: {lens['presentations']} presentations{where} ({lens['reason']})"
                     + (f"; held nominal all the same: {', '.join(lens['held'])}" if lens["held"] else ""))
    actions = summary["operator_actions"]
    lines.append(f"calibration board placements: {counts['placements']}")
    lines.append(f"operator actions: {actions['total']} ({actions['presentations']} board presentations, "
                 f"{actions['placements']} board placements, {actions['target_moves']} target moves"
                 + (f", {actions['manual_settings']} other manual settings" if actions["manual_settings"] else "")
                 + ")")
    capture = config.capture
    if counts["total"] and config.calibration_capture == "auto":
        gate = ("every coverage bar full" if capture.coverage_gate == "bars" else "the count")
        lines.append(f"calibration views taken automatically when the board is still and new, until {gate} (at "
                     f"least {capture.calibration_views}, at most "
                     f"{max(capture.max_calibration_views, capture.calibration_views)} per set; Enter ends a set early)"
                     + (": the simulated hand presents the board" if config.cameras.kind == "simulated" else ""))
    elif counts["total"] and config.cameras.kind != "simulated":
        lines.append("calibration views taken one per Enter ([capture] calibration_capture = \"enter\")")
    return lines


def predicted_extrinsics_text(predicted: dict[str, Any], source: str) -> list[str]:
    """The sigma of R, T a kinematic model predicts at the measured configurations
    (:func:`stereo_bench.campaign.plan.summary.extrinsics_prediction`): the range, the RMS and where it is worst;
    what it does not count. ``source``: which model, for the first line's brackets."""
    rows = predicted["configurations"]

    def spread(key: str, unit: str, rms: str) -> str:
        values = [r[key] for r in rows]
        if f"{min(values):.3g}" == f"{max(values):.3g}":
            return f"{max(values):.3g} {unit}" + (" at every configuration" if len(values) > 1 else "")
        worst = max(rows, key=lambda r: r[key])["config_id"]
        return f"{min(values):.3g}-{max(values):.3g} {unit} (RMS {predicted[rms]:.3g}, worst at {worst})"

    baseline = max(r["structure"]["baseline_mm"] for r in rows)
    alphas = max(max(r["structure"]["alpha_left_deg"], r["structure"]["alpha_right_deg"]) for r in rows)
    where = "the measured configuration" if len(rows) == 1 else f"the {len(rows)} measured configurations"
    most = "" if len(rows) == 1 else "up to "
    lines = [f"predicted R, T at {where} ({source}): "
             f"sigma |T| {spread('sigma_T_mm', 'mm', 'rms_sigma_T_mm')}, "
             f"sigma angle(R) {spread('sigma_R_deg', 'deg', 'rms_sigma_R_deg')}; "
             f"the optical baseline's sigma {most}{baseline:.3g} mm, the alphas' {most}{alphas:.3g} deg"]
    held = predicted["held"]
    if held:
        plural = "s" if len(held) > 1 else ""
        lines.append(f"{'':>5}not counted: the build tolerance of the {len(held)} parameter{plural} held nominal "
                     f"({', '.join(held)})")
    return lines


def _step_text(step: dict[str, Any]) -> str:
    kind = step["step"]
    if kind == "move":
        request = step["request"]
        return (f"move to {step['config_id']}: B = {request['baseline_mm']:g} mm, toe-in "
                f"{request['toe_in_left_deg']:g}/{request['toe_in_right_deg']:g} deg")
    if kind == "prompt_target":
        return f"operator: move the target to Z = {step['distance_mm']:g} mm"
    if kind == "prompt_manual":
        return f"operator: set {step['quantity']} = {step['value']:g}"
    if kind == "settle":
        return f"settle {step['seconds']:g} s"
    if kind == "flush":
        return "flush camera buffers"
    if kind == "capture_calibration":
        return f"capture {step['n_views']} calibration views"
    if kind == "capture_measurement":
        return f"capture {step['n_frames']} measurement frames"
    if kind == "visit_done":
        return (f"visit {step['config_id']} done" if not step["skipped"]
                else f"visit {step['config_id']} (skipped: {step['reason']})")
    if kind == "prepare_extrinsics":
        return ("fit the kinematic rig model to the design's views" if step["purpose"] == "kinematic"
                else "calibrate the intrinsics from the visit's views")  # (a fixed-board design's lens, or nominal's)
    if step["skipped"]:
        return f"checkpoint {step['config_id']} (skipped: {step['reason']})"
    return f"checkpoint {step['config_id']}"


def _cmd_schema(args) -> int:
    print(campaign_json_schema_text())
    return 0


def _cmd_presets(args) -> int:
    if args.json:
        print(json.dumps(PRESETS, indent=2))
        return 0
    width = max(len(name) for name in PRESETS)
    for name, description in PRESETS.items():
        print(f"{name:<{width}}  {description}")
    return 0
