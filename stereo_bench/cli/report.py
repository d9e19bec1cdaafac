"""`stereo-bench report SESSION [SESSION ...] [--out DIR]`: tables, figures and one HTML page from sessions."""

from __future__ import annotations

import argparse
import sys

from stereo_bench.cli import CliError, print_json
from stereo_bench.cli.args import output_dir


def cmd_report(args: argparse.Namespace) -> int:
    from stereo_bench.campaign.session import SessionError
    from stereo_bench.report.build import ReportError, build_report

    def progress(message: str) -> None:
        if not args.json:
            print(f"reporting {message}", file=sys.stderr)

    try:
        summary = build_report(args.sessions, args.out, images=not args.no_images, progress=progress)
    except (SessionError, ReportError) as error:
        raise CliError(str(error)) from None
    for warning in summary.warnings:
        print(f"stereo-bench report: warning: {warning}", file=sys.stderr)
    counts = summary.counts()
    if args.json:
        print_json({"out": str(summary.out), "index": str(summary.index), "counts": counts,
                    "sessions": [str(s.directory) for s in summary.sessions], "files": summary.files,
                    "warnings": summary.warnings})
    else:
        figures = sum(1 for f in summary.files if f.startswith("figures/"))
        tables = sum(1 for f in summary.files if f.startswith("tables/"))
        images = sum(1 for f in summary.files if f.startswith("images/"))
        print(f"report of {len(summary.sessions)} session(s), "
              + ", ".join(f"{n} {status}" for status, n in counts.items())
              + f": {figures} figures, {tables} tables, {images} images")
        print(f"open: {summary.index}")
    return 0


def register(subparsers) -> None:
    report = subparsers.add_parser(
        "report", help="write an HTML report with tables and figures from recorded sessions",
        description="Read one or more recorded sessions and write a self-contained report directory: "
                    "index.html (opens in a browser with no network), PNG figures (error +- U against Z, B and "
                    "alpha, as the paper's Figures 8, 9, 11; the normalised error error/u_c with the +-2 band; "
                    "each extrinsics source minus the truth; the structural error per extrinsics source across "
                    "all sessions given; measured error beside the rigorous prediction; calibration quality), CSV "
                    "tables (the paper's Table 1 and Table 2 layouts with error +- U, the uncertainty budget per "
                    "configuration, the extrinsics side by side, all results) and annotated images per "
                    "configuration. Sessions recorded before the budget and structure records still report and "
                    "say what they lack. A previous report in the same place is replaced atomically. "
                    "See docs/REPORTS.md.",
    )
    report.add_argument("sessions", nargs="+", metavar="SESSION", help="recorded session directory (one or more)")
    report.add_argument("--out", type=output_dir, metavar="DIR",
                        help="report directory (default: SESSION/report; required for several sessions)")
    report.add_argument("--no-images", action="store_true",
                        help="leave out the annotated images per configuration (faster)")
    report.add_argument("--json", action="store_true", help="print one JSON object")
    report.set_defaults(func=cmd_report)
