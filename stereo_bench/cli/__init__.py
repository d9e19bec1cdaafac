"""``stereo-bench`` command line: one subcommand per job, each registered by its own module.

Every error a user can cause ends in :class:`CliError`: one line on stderr naming the field, file or
device, and exit status 2. Tracebacks are for bugs.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from stereo_bench import __version__

# Each module defines ``register(subparsers)``; its subparsers set ``func(args) -> int``.
COMMAND_MODULES = (
    "stereo_bench.cli.vision",
    "stereo_bench.cli.devices",
    "stereo_bench.cli.rig",
    "stereo_bench.cli.model",
    "stereo_bench.cli.campaign",
    "stereo_bench.cli.replay",
    "stereo_bench.cli.session",
    "stereo_bench.cli.report",
    "stereo_bench.cli.live",
)

EXIT_USAGE = 2


class CliError(Exception):
    """A failure the user can fix; printed as one line, exit status 2 unless ``exit_code`` says otherwise."""

    def __init__(self, message: str, exit_code: int = EXIT_USAGE):
        super().__init__(message)
        self.exit_code = exit_code


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stereo-bench",
        description="Drive a motorised stereo rig, calibrate, triangulate and measure a checkerboard square.",
    )
    parser.add_argument("--version", action="version", version=f"stereo-bench {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        return int(args.func(args) or 0)
    except CliError as error:
        print(f"stereo-bench {args.command}: error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        print(f"stereo-bench {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
