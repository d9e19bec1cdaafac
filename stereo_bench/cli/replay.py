"""`stereo-bench replay SESSION [SESSION ...] [--out DIR]`: run recorded sessions through the runner again.

Each session's numbers are compared with the recording by the rule of docs/REPLAY.md
(``stereo_bench.campaign.reproduce``): identical, reproduced within tolerance, or differs (exit 1)."""

from __future__ import annotations

import argparse
from pathlib import Path

from stereo_bench.cli import CliError, print_json
from stereo_bench.cli.args import output_dir
from stereo_bench.cli.model import _add_executor_options, _executor


def cmd_replay(args: argparse.Namespace) -> int:
    from stereo_bench.campaign.execute import replay_job

    pipeline = {}
    if args.intrinsics:
        pipeline["extrinsics"] = {"intrinsics": args.intrinsics}
    if pipeline and not args.out:
        raise CliError("a re-analysis with changed pipeline options needs --out DIR for the new session(s)")
    sessions = [str(Path(s)) for s in args.session]
    if len(set(Path(s).name for s in sessions)) != len(sessions) and args.out and len(sessions) > 1:
        raise CliError("sessions with the same directory name cannot share one --out root")
    if len(sessions) == 1:
        jobs = [(sessions[0], args.out, pipeline)]
        reports = [replay_job(jobs[0])]  # one session: in this process, no pool to start
    else:
        # A batch re-analysis: one job per session, through the executor (process pool or Dask).
        jobs = [(s, str(Path(args.out) / Path(s).name) if args.out else None, pipeline) for s in sessions]
        with _executor(args) as executor:
            reports = executor.map(replay_job, jobs)
    errors = [r for r in reports if "error" in r]
    if len(sessions) == 1 and errors:
        raise CliError(errors[0]["error"])
    if args.json:
        print_json(reports[0] if len(reports) == 1 else {"sessions": reports})
    else:
        for report in reports:
            if "error" in report:
                print(f"{report['session']}: error: {report['error']}")
                continue
            carried = f", {report['carried_over']} failed/infeasible carried over" if report["carried_over"] else ""
            if pipeline:
                print(f"re-analysed {report['compared']} measured configurations of {report['session']}: "
                      f"{report['measured']} measured again, {report['identical']} unchanged{carried}")
            else:
                print(f"replayed {report['compared']} measured configurations of {report['session']}: "
                      f"{_outcome(report)}{carried}")
            print(f"  {_environment(report['numeric_environment'])}")
            if report.get("from_detections"):
                print(f"  calibrated from the recorded detections of their calibration views (frames not kept): "
                      f"{_listing(report['from_detections'], report['compared'])}")
            by_reason: dict[str, list[str]] = {}
            for config_id, reason in report.get("not_reproducible", {}).items():
                by_reason.setdefault(reason, []).append(config_id)
            for reason, config_ids in by_reason.items():
                print(f"  cannot reproduce, {reason}: {_listing(config_ids, len(report['not_reproducible']))}")
            if report.get("plan_drift"):
                print(f"  note: the recorded plan was replayed; {report['plan_drift']}")
            for warning in report.get("warnings", []):
                print(f"  note: {warning}")
            for line in report["differences"]:
                print(f"  differs: {line}")
            if report["out"]:
                print(f"  new session: {report['out']}")
    if errors:
        return 2
    # A session that kept too few frames to reproduce any measured configuration ([capture] keep_frames =
    # "none") fails its replay; configurations it cannot reproduce beside ones it can are listed, not failed.
    if any(r["not_reproducible"] and not r["compared"] for r in reports):
        return 1
    if pipeline:  # a re-analysis may change numbers, but one that measures nothing has failed
        return 0 if all(r["measured"] or not r["compared"] for r in reports) else 1
    return 0 if all(not r["differences"] for r in reports) else 1


def _outcome(report: dict) -> str:
    """'0 identical, 2 reproduced within tolerance (largest deviation: ...), 0 differ' (docs/REPLAY.md)."""
    largest = report.get("largest_deviation")
    detail = ""
    if largest is not None:  # the number nearest its tolerance: beside the verdict it has
        unit = f" {largest['unit']}" if largest["unit"] else ""
        size = (f"|Δ| = {largest['abs']:.2g}{unit}" if largest["abs"] is not None
                else f"{largest['recorded']!r} -> {largest['replayed']!r}")
        if largest["relative_to_scale"] is not None:
            size += f" = {largest['relative_to_scale']:.2g} of its scale"
        if largest["abs"] is not None:
            size += f", {largest['relative_to_u']:.2g} u" if largest["relative_to_u"] is not None else ", u unknown"
        detail = f" (largest deviation: {largest['column']} of {largest['where']}, {size})"
    differ = report["compared"] - report["identical"] - report["reproduced"]
    model = f"; kinematic model fitted again: {report['kinematic_model']}" if report.get("kinematic_model") else ""
    reproduced_detail = detail if largest is not None and largest["verdict"] == "reproduced" else ""
    differ_detail = detail if largest is not None and largest["verdict"] == "differs" else ""
    return (f"{report['identical']} identical, {report['reproduced']} reproduced within tolerance{reproduced_detail}, "
            f"{differ} differ{differ_detail}{model}")


def _environment(environment: dict) -> str:
    """One line: where today's numeric environment differs from the recording's, or that it has none."""
    from stereo_bench.campaign.environment import describe_differences

    if environment["recorded"] is None:
        return "numeric environment: the recording has none (recorded before stereo-bench kept it)"
    differences = [(d["field"], d["recorded"], d["today"]) for d in environment["differences"]]
    if not differences:
        return "numeric environment: as recorded"
    return f"numeric environment differs from the recording: {describe_differences(differences)}"


def _listing(config_ids: list[str], of: int) -> str:
    listed = ", ".join(config_ids)
    return f"all {of} ({listed})" if len(config_ids) == of and of > 1 else listed


def register(subparsers) -> None:
    replay = subparsers.add_parser(
        "replay", help="replay recorded sessions through the same runner and pipeline",
        description="Serve the recorded frames and rig telemetry through replay drivers to the campaign runner, "
                    "over the recorded plan. Without options every recorded number is compared (docs/REPLAY.md): "
                    "identical when bit-equal, reproduced when within a tolerance derived from the numerics "
                    "(|d| <= 1e-9 of the size of its operands) and negligible against its own uncertainty "
                    "(|d| <= 1e-6 u; a kinematic model fitted again, and what is measured with it: both within "
                    "the fit's resolution), differs beyond (exit 1). The largest deviation is named, and where "
                    "today's numeric environment (BLAS kernels and threads, library versions, CPU) differs from "
                    "the recording's. With changed pipeline options each session is re-analysed into --out "
                    "(exit 1 if a session's re-analysis measures nothing). A session recorded with [capture] "
                    "keep_frames = \"measurement\" is calibrated from its recorded detections; configurations "
                    "whose frames were not kept are listed as not reproducible, and a session that can "
                    "reproduce none of its measured configurations (keep_frames = \"none\") exits 1. Exit 2: "
                    "a session cannot be read. Exit 130: stopped by Ctrl-C, SIGTERM or SIGHUP (nothing is "
                    "compared, and no --out is left: a partial one would look like a good session). Several "
                    "sessions are replayed in parallel through the executor (a local process pool, or Dask).",
    )
    replay.add_argument("session", nargs="+", metavar="SESSION", help="recorded session directory")
    replay.add_argument("--out", type=output_dir, metavar="DIR",
                        help="record the replay as a new session here (several sessions: one subdirectory each)")
    replay.add_argument("--intrinsics", choices=("joint", "held", "fixed"),
                        help="re-analyse with this stereo calibration mode (held: the intrinsics not refined; fixed: "
                             "held's old spelling)")
    replay.add_argument("--json", action="store_true", help="print one JSON object")
    _add_executor_options(replay)
    replay.set_defaults(func=cmd_replay)
