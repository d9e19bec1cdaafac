"""`stereo-bench replay SESSION [--out DIR]`: run a recorded session through the runner again."""

from __future__ import annotations

import argparse
import json
import sys

from stereo_bench.cli import CliError


def cmd_replay(args: argparse.Namespace) -> int:
    from stereo_bench.campaign.execute import replay_session
    from stereo_bench.campaign.session import SessionError

    pipeline = {}
    if args.intrinsics:
        pipeline["extrinsics"] = {"intrinsics": args.intrinsics}
    if pipeline and not args.out:
        raise CliError("a re-analysis with changed pipeline options needs --out DIR for the new session")
    try:
        summary = replay_session(args.session, args.out, pipeline=pipeline)
    except (SessionError, KeyError) as error:
        raise CliError(str(error).strip("'\"")) from None
    report = {
        "session": args.session, "out": args.out, "compared": summary.compared, "identical": summary.identical,
        "differences": summary.differences, "carried_over": summary.carried_over, "pipeline": pipeline,
    }
    if args.json:
        json.dump(report, sys.stdout)
        print()
    else:
        print(f"replayed {summary.compared} measured configurations of {args.session}: {summary.identical} "
              f"reproduced exactly" + (f", {summary.carried_over} failed/infeasible carried over"
                                      if summary.carried_over else ""))
        for line in summary.differences:
            print(f"  differs: {line}")
        if args.out:
            print(f"new session: {args.out}")
    return 0 if pipeline or not summary.differences else 1


def register(subparsers) -> None:
    replay = subparsers.add_parser(
        "replay", help="replay a recorded session through the same runner and pipeline",
        description="Serve the recorded frames and rig telemetry through replay drivers to the campaign runner. "
                    "Without options the results must reproduce the recording exactly (exit 1 if not); with "
                    "changed pipeline options the session is re-analysed into --out.",
    )
    replay.add_argument("session", metavar="SESSION", help="recorded session directory")
    replay.add_argument("--out", metavar="DIR", help="record the replay as a new session here")
    replay.add_argument("--intrinsics", choices=("joint", "fixed"), help="re-analyse with this stereo calibration mode")
    replay.add_argument("--json", action="store_true", help="print one JSON object")
    replay.set_defaults(func=cmd_replay)
