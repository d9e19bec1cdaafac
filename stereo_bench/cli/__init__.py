"""``stereo-bench`` command line: one subcommand per job, each registered by its own module.

Every failure a user or the bench can cause ends in one line on stderr naming the field, file or device,
and the exit status docs/EXIT_STATUS.md documents. That happens in one place, :func:`main`, through
:func:`failure`; tracebacks are for bugs (exit status 70). The API a command module uses:

- :class:`CliError` ``(message, exit_code=EXIT_USAGE)``: raise it for a failure with a message of your own.
- Raise, or let through, the project's own exceptions (``ConfigError``, ``SessionError``, ``RigError``,
  ``CameraError``, ``CalibrationFileError``, ``ReplayMismatch``, pydantic's ``ValidationError``, ``OSError``,
  ...): :func:`failure` turns each into its line and status, so a command catches only what it can say
  better (an ``OSError`` already names its file; a ``UnicodeDecodeError`` does not: name the file).
- :func:`print_json` for every ``--json`` output: always valid JSON (NaN and infinities become null,
  with the reason under ``"null_reasons"``).
- :mod:`stereo_bench.cli.args`: the argparse types (``finite_float``, ``int_in``, ``board_pattern`` ...)
  that check every number where it enters.

Exit statuses: ``EXIT_OK`` 0; ``EXIT_FAILED`` 1 (the job ran and failed: a controller or camera fault, a
campaign that measured nothing, a replay that does not reproduce); ``EXIT_USAGE`` 2 (the user can fix
it: an argument, a file, a config, a device that is not there, a path that cannot be written, a
measurement refused as physically meaningless); ``EXIT_INTERNAL`` 70 (a bug: the traceback is printed);
``EXIT_INTERRUPTED`` 130 (Ctrl-C, SIGTERM, or SIGHUP: a closed terminal or ssh session); ``EXIT_BROKEN_PIPE`` 141
(the reader of stdout went away).

Signals: :func:`main` turns SIGTERM and SIGHUP into ``KeyboardInterrupt``, as Python does SIGINT, so every command
stops on them as on Ctrl-C (its cleanup runs, and the status is 130); a command with stops of its own (``campaign
run`` stops at a safe point) installs its own handlers for :data:`STOP_SIGNALS` and calls :func:`hung_up` first on
SIGHUP.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import json
import math
import os
import signal
import sys
import threading
import traceback
from typing import Any, TextIO

from stereo_bench import __version__

# Each module defines ``register(subparsers)``; its subparsers set ``func(args) -> int``.
COMMAND_MODULES = (
    "stereo_bench.cli.vision",
    "stereo_bench.cli.formats",
    "stereo_bench.cli.devices",
    "stereo_bench.cli.rig",
    "stereo_bench.cli.model",
    "stereo_bench.cli.campaign",
    "stereo_bench.cli.replay",
    "stereo_bench.cli.session",
    "stereo_bench.cli.report",
    "stereo_bench.cli.live",
)

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 70  # sysexits.h EX_SOFTWARE: an internal software error
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a Ctrl-C
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE: the reader of stdout went away (``... --json | head -1``)

#: What stops a command as Ctrl-C does: Ctrl-C, SIGTERM (systemd, ``docker stop``, ``kill``) and SIGHUP (the terminal
#: closed: an ssh session ended, a terminal window was closed).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class CliError(Exception):
    """A failure with its one-line message; exit status 2 (the user can fix it) unless ``exit_code`` says otherwise."""

    def __init__(self, message: str, exit_code: int = EXIT_USAGE):
        super().__init__(message)
        self.exit_code = exit_code


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``PROG: error: MESSAGE (PROG --help)``, exit status 2.

    argparse's own form prints the whole usage first, which is several lines for most commands.
    """

    def error(self, message: str):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="stereo-bench",
        description="Drive a motorised stereo rig, calibrate, triangulate and measure a checkerboard square.",
        epilog="Exit status: 0 done, 1 the job failed (controller or camera fault, nothing measured, replay "
               "differs), 2 a usage, input or setup error, 70 an internal error (a bug), 130 interrupted (Ctrl-C, "
               "SIGTERM, SIGHUP), 141 stdout closed. "
               "docs/EXIT_STATUS.md says more.",
    )
    parser.add_argument("--version", action="version", version=f"stereo-bench {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")  # subparsers inherit _Parser
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


# ---------------------------------------------------------------------------------------------- failures


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _os_error(error: OSError) -> str:
    """``FILE: reason`` (both files of a rename); the reason in words a user knows."""
    reason = error.strerror or _one_line(error) or type(error).__name__
    if error.errno == errno.ENOSPC:
        reason += " (the disk is full: free space, or choose another --out)"
    elif error.errno == errno.EROFS:
        reason += " (a read-only file system: choose a writable --out)"
    elif error.errno in (errno.EACCES, errno.EPERM):
        reason += " (check the permissions, or choose another path)"
    names = [str(n) for n in (error.filename, error.filename2) if n is not None]
    return f"{' -> '.join(names)}: {reason}" if names else reason


def _validation_error(error) -> str:
    """pydantic's multi-line ValidationError as ``dotted.field: message (and N more)``."""
    first = error.errors()[0]
    where = ".".join(str(part) for part in first.get("loc", ()))
    message = first.get("msg", "invalid").removeprefix("Value error, ")
    if first.get("type") == "extra_forbidden":
        message = "unknown key"
    more = f" (and {error.error_count() - 1} more)" if error.error_count() > 1 else ""
    return f"{error.title}: {where + ': ' if where else ''}{message}{more}"


def _cv2_error(error) -> str:
    """OpenCV's multi-line ``cv2.error`` as one line: what it refused and in which function."""
    detail = getattr(error, "err", None) or _one_line(error)
    func = getattr(error, "func", None)
    return f"OpenCV refused the input: {detail}" + (f" (in {func})" if func else "")


def failure(error: BaseException) -> CliError | None:
    """The one line and exit status of an exception a user or the bench can cause; None for a bug.

    The one mapping of the exception types of ``drivers/`` and ``stereo_bench/`` to exit statuses: what the
    user can fix is 2 (a damaged recording included), a fault of the controller or a camera during work is 1.
    Imports are lazy: ``--help`` stays fast.
    """
    if isinstance(error, CliError):
        return error
    import cv2
    from pydantic import ValidationError

    from drivers.camera.base import CameraError, CameraGone, CaptureFailed
    from drivers.camera.stereo import StereoSkewError
    from drivers.files import InputFileError
    from drivers.replay import ReplayMismatch
    from drivers.rig.config import RigConfigError, RigError
    from drivers.rig.grbl import GrblConnectionError, GrblConnectionLost, GrblSettingsError
    from stereo_bench.campaign.config import ConfigError
    from stereo_bench.campaign.documents import DocumentError
    from stereo_bench.campaign.operator import OperatorAbsent
    from stereo_bench.campaign.session import SessionError
    from stereo_bench.campaign.store import StoreError
    from stereo_bench.executors import ExecutorUnavailable
    from stereo_bench.frames import FrameError
    from stereo_bench.kinematics import KinematicFileError
    from stereo_bench.live.server import LiveServerError
    from stereo_bench.report.build import ReportError
    from stereo_bench.vision.calibio import CalibrationFileError
    from stereo_bench.vision.detect import AmbiguousViewError
    from stereo_bench.vision.pipeline import BoardNotFoundError, ImplausibleMeasurement

    text = _one_line(error)
    if isinstance(error, RigError):
        # What the user can fix (a refused move - outside the limits, or from a position not known since a boot -,
        # a bad rig config, a port that is not there, unusable controller settings) is 2; the controller failing
        # during work (alarm, timeout, lost connection, lock) is 1.
        from drivers.rig.config import LimitError, MoveRequestError
        from drivers.rig.grbl import GrblPositionUnknown

        user = (LimitError, MoveRequestError, RigConfigError, GrblSettingsError, GrblConnectionError,
                GrblPositionUnknown)
        fault = isinstance(error, GrblConnectionLost) or not isinstance(error, user)
        return CliError(text, EXIT_FAILED if fault else EXIT_USAGE)
    if isinstance(error, CameraError):
        # A camera that is not there, not allowed, busy, ambiguously named, refusing a setting, or sharing a USB
        # bus without bandwidth for both streams: 2. One that stops delivering during work: 1.
        fault = isinstance(error, CameraGone | CaptureFailed | StereoSkewError)
        return CliError(text, EXIT_FAILED if fault else EXIT_USAGE)
    if isinstance(error, ReplayMismatch):  # a recording that does not hold what its plan asks: damaged input
        return CliError(f"the recording cannot be replayed: {text}")
    if isinstance(error, ConfigError | SessionError | DocumentError | StoreError | ReportError | FrameError
                  | CalibrationFileError | KinematicFileError | InputFileError | OperatorAbsent | ExecutorUnavailable
                  | BoardNotFoundError | AmbiguousViewError | ImplausibleMeasurement | LiveServerError):
        return CliError(text)
    if isinstance(error, ValidationError):
        return CliError(_validation_error(error))
    if isinstance(error, UnicodeDecodeError):
        return CliError(f"an input file is not UTF-8 text (byte {error.object[error.start:error.start + 1]!r} at "
                        f"offset {error.start}); save it as UTF-8")
    if isinstance(error, OSError):
        return CliError(_os_error(error))
    if isinstance(error, cv2.error):
        return CliError(_cv2_error(error))
    return None


def _stdout_is_closed(error: BaseException) -> bool:
    """A broken pipe naming no file: the reader of our output went away (files, the serial link and sockets
    fail otherwise, or name their file)."""
    return isinstance(error, BrokenPipeError) and error.filename is None


def output_gone(error: BaseException) -> bool:
    """Whether writing stdout or stderr failed because its reader is gone: a closed pipe, or a hung-up terminal
    (EIO: an ssh session that ended)."""
    return _stdout_is_closed(error) or (isinstance(error, OSError) and error.errno == errno.EIO
                                        and error.filename is None)


def _to_devnull(fd: int) -> None:
    with contextlib.suppress(OSError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)


def silence_stdout() -> None:
    """Point stdout at /dev/null: its reader went away, so nothing more is said there, and Python's flush of the
    unwritten buffer at exit cannot fail (it would change the exit status to 120)."""
    with contextlib.suppress(OSError, ValueError):  # ValueError: a replaced stdout without a file descriptor
        _to_devnull(sys.stdout.fileno())


# The standard streams that were a terminal when main() started: after SIGHUP the ones still pointing at it, now
# hung up, are pointed at /dev/null (see hung_up()).
_terminal_fds: set[int] = set()


def hung_up() -> None:
    """On SIGHUP: stdout and stderr that were a terminal that has now hung up go to /dev/null, so that the command
    can still stop cleanly (record its stop, remove its temporary files) and return its status: every write to a
    hung-up terminal fails (EIO). A SIGHUP sent by hand, with the terminal still there, leaves them as they are."""
    for fd in sorted(_terminal_fds):
        if not _isatty(fd):  # a hung-up terminal is no longer one (its tcgetattr fails with EIO)
            _to_devnull(fd)


def stop_on_signals(stop: threading.Event) -> dict:
    """Set ``stop`` on each of :data:`STOP_SIGNALS` (SIGHUP: after :func:`hung_up`), for a command that serves until
    told to end (``sim-controller``, ``live``); returns the previous handlers, to restore with ``signal.signal``."""
    def on_signal(signum, frame) -> None:
        if signum == signal.SIGHUP:
            hung_up()
        stop.set()

    return {signum: signal.signal(signum, on_signal) for signum in STOP_SIGNALS}


def _raise_interrupt(signum, frame) -> None:
    if signum == signal.SIGHUP:
        hung_up()
    raise KeyboardInterrupt


@contextlib.contextmanager
def _stop_signals_interrupt():
    """SIGTERM and SIGHUP raise KeyboardInterrupt (as SIGINT does) while a command runs; only in the main thread,
    where Python runs signal handlers (a test calling main() from another thread keeps its handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _terminal_fds.update(fd for fd in (1, 2) if _isatty(fd))  # stdout, stderr
    previous = {signum: signal.signal(signum, _raise_interrupt) for signum in STOP_SIGNALS if signum != signal.SIGINT}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _isatty(fd: int) -> bool:
    try:
        return os.isatty(fd)
    except OSError:
        return False


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args, unknown = parser.parse_known_args(argv)
    except SystemExit as done:  # --help, --version, or a usage error already printed in one line
        return EXIT_OK if done.code is None else done.code if isinstance(done.code, int) else EXIT_USAGE
    if unknown:  # said by the command that got them (argparse would name only 'stereo-bench')
        where = " ".join(["stereo-bench"] + [str(getattr(args, name)) for name in ("command", *sorted(
            name for name in vars(args) if name.endswith("_action"))) if getattr(args, name, None)])
        print(f"{where}: error: unrecognized arguments: {' '.join(unknown)} (see {where} --help)", file=sys.stderr)
        return EXIT_USAGE
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    prog = f"stereo-bench {args.command}"
    try:
        with _stop_signals_interrupt():
            code = int(args.func(args) or 0)
            sys.stdout.flush()  # here, not at exit: a reader gone meanwhile is a broken pipe (141), not status 120
            return code
    except KeyboardInterrupt:
        with contextlib.suppress(OSError):  # a hung-up terminal, or a closed pipe
            print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as error:  # noqa: BLE001 - the one place every failure becomes one line
        if output_gone(error):
            # The reader went away: say nothing more on a pipe that is gone, and keep Python from
            # complaining about the unflushed buffer at exit. A terminal that hung up (EIO before its SIGHUP
            # came) is the hangup: 130, as after SIGHUP.
            silence_stdout()
            hung_up()
            return EXIT_BROKEN_PIPE if _stdout_is_closed(error) else EXIT_INTERRUPTED
        known = failure(error)
        with contextlib.suppress(OSError):  # stderr's reader gone too: the status still says it
            if known is None:
                traceback.print_exc()
                print(f"{prog}: internal error (a bug; please report it with the traceback above): "
                      f"{type(error).__name__}: {_one_line(error)}", file=sys.stderr)
                return EXIT_INTERNAL
            print(f"{prog}: error: {_one_line(known)}", file=sys.stderr)
        return EXIT_INTERNAL if known is None else known.exit_code


# ---------------------------------------------------------------------------------------------- JSON output


def json_ready(obj: Any) -> tuple[Any, dict[str, str]]:
    """(obj with every non-finite float replaced by None, {dotted.path: reason}) for strict JSON.

    JSON has no NaN or infinity; Python's ``json`` writes them anyway (``NaN``), which no strict reader
    accepts. Numpy scalars and arrays become plain numbers and lists.
    """
    reasons: dict[str, str] = {}

    def walk(value: Any, path: str) -> Any:
        if isinstance(value, dict):
            return {key: walk(item, f"{path}.{key}" if path else str(key)) for key, item in value.items()}
        if isinstance(value, list | tuple):
            return [walk(item, f"{path}[{i}]") for i, item in enumerate(value)]
        if hasattr(value, "tolist") and not isinstance(value, str):  # numpy scalar or array
            return walk(value.tolist(), path)
        if isinstance(value, float) and not math.isfinite(value):
            reasons[path or "(value)"] = ("not a number (NaN): undefined for these inputs" if math.isnan(value)
                                          else f"{'+' if value > 0 else '-'}infinity: unbounded for these inputs")
            return None
        return value

    return walk(obj, ""), reasons


def print_json(obj: Any, *, file: TextIO | None = None, indent: int | None = None) -> None:
    """Print ``obj`` as strict JSON: non-finite numbers become null and a top-level object gains
    ``"null_reasons": {dotted.path: why}`` (only when there are any)."""
    clean, reasons = json_ready(obj)
    if reasons and isinstance(clean, dict):
        clean["null_reasons"] = reasons
    print(json.dumps(clean, indent=indent, allow_nan=False), file=file or sys.stdout, flush=True)


if __name__ == "__main__":
    sys.exit(main())
