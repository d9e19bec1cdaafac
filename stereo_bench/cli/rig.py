"""``stereo-bench rig`` (home / move / status / unlock / resume / reset / shell) and ``stereo-bench sim-controller``.

    stereo-bench sim-controller --link /tmp/grbl [--fault alarm:1] [--time-scale 10] [--reboot-on-open]
    stereo-bench rig --port /tmp/grbl home
    stereo-bench rig --port /tmp/grbl home move --baseline 120 --alpha 85 status    # one connection
    stereo-bench rig --port /tmp/grbl shell                                          # an interactive prompt
    stereo-bench rig --port /tmp/grbl status --json

Actions given together run in order on one connection. That matters on an Arduino-based controller: opening
its port reboots it (DTR auto-reset), so each separate call starts from machine position 0 with the
position unknown; chain the actions, use ``shell``, or disable the auto-reset (docs/RIG.md).

A controller that booted (at open, late, or mid-run) has restarted its step counters wherever the axes stand:
moves are refused until the rig is homed or ``unlock --trust-position`` states that the position is right,
whatever ``$22`` says.

Exit status: 0 done; 2 for what the user can fix (a refused move - outside the limits, or from a position
not known since a boot -, a bad rig config or action, an unreachable port, unusable controller settings);
1 for a controller fault (alarm, timeout, lost connection, nothing to resume); 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import shlex
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from drivers.rig import (
    GrblConnectionLost,
    GrblPositionUnknown,
    GrblRig,
    RigConfig,
    RigConfigError,
    RigError,
    RigReading,
    load_rig_config,
)
from drivers.rig.config import MAX_MOVE_TIMEOUT_S, along_baseline, alpha_from_toe_in, plan_move
from drivers.rig.motion import REFERENCE_HOMING
from drivers.rig.rig import physical_request
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.faults import FAULT_HELP, parse_fault
from drivers.sim.grbl.firmware import AXIS_LETTERS, AxisSpec, axis_specs_for_travel
from stereo_bench.campaign.operator import LineOperator, OperatorAbsent, OperatorDesk, move_and_ask
from stereo_bench.cli import CliError, failure, print_json, stop_on_signals
from stereo_bench.cli.args import TIME_SCALE, finite_float
from stereo_bench.paths import UnwritablePath, check_output_file

# A bound on homing or one move: positive, and at most a day (a longer wait is no bound at all), as the rig config's
# move_timeout_s (drivers/rig/config.py MAX_MOVE_TIMEOUT_S, where the reason is written).
TIMEOUT_S = finite_float(min=0, max=MAX_MOVE_TIMEOUT_S, inclusive=(False, True), unit="s")
# Move targets are checked against the rig config's soft limits before anything is sent; here only that they
# are numbers.
MOVE_VALUE = finite_float()

EXIT_FAULT = 1
ACTIONS = ("home", "unlock", "move", "status", "resume", "reset", "shell")
#: Not an action on the connection: a run of the kinematic design on a bench of its own (cli/rig_kinematics.py).
CALIBRATE_KINEMATICS = "calibrate-kinematics"
#: Actions that connect without the soft reset: looking must not disturb, and a reset would abandon a hold.
_LOOKING = ("status", "resume", "shell")

ACTIONS_HELP = """\
actions (several run in order on one connection; ACTION --help for its options):
  home                  run the homing cycle ($H)
  unlock [--trust-position]
                        leave Alarm without homing ($X); after a boot the position stays unknown (moves
                        refused) unless --trust-position states that it is right
  move OPTIONS          move to a configuration; returns once the rig has stopped there
  status [--json]       where the rig is (no soft reset on connect)
  resume                continue a move held by Ctrl-C / feed hold (waits until the hold is complete)
  reset                 soft reset: abandon a held move, end a halt after ALARM:1/2
  shell                 an interactive prompt for all of the above, on one connection
  calibrate-kinematics  visit the kinematic rig model's design, fit it, write the model (alone; simulated bench
                        without --port; calibrate-kinematics --help for its options)

Opening the port of an Arduino-based controller reboots it (DTR auto-reset) and its position is then
unknown: chain actions in one call (`rig --port P home move --baseline 100 status`) or use `shell`. Every
boot the driver sees (at open, late, or mid-run) makes the position unknown, whatever $22 says: moves are
refused until `home`, or `unlock --trust-position` if the axes really stand where the controller counts."""


def register(subparsers) -> None:
    rig = subparsers.add_parser(
        "rig", help="drive the rig's GRBL controller: home, move, status, resume, reset, shell",
        description="Drive the stereo rig through its GRBL 1.1 controller, in mm and degrees.",
        epilog=ACTIONS_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rig.add_argument("--port", metavar="PORT",
                     help="serial device or pyserial URL of the controller (e.g. /dev/ttyUSB0, a sim-controller link); "
                          "required except for calibrate-kinematics, which runs on the simulated bench without it")
    rig.add_argument("--rig-config", type=Path, metavar="FILE",
                     help="rig configuration TOML (axis mapping, limits); default: stock Grbl machine space, "
                          "X = baseline 1-349 mm at X -349..-1, Y/Z = left/right toe-in 0-88 deg at -1..-89 (one "
                          "pull-off inside $130=350, $131=$132=90)")
    rig.add_argument("--timeout", type=TIMEOUT_S, metavar="S", help="bound on homing or a move, seconds (> 0)")
    rig.add_argument("--spy-log", type=Path, metavar="FILE", help="record every byte on the link as JSON lines")
    rig.add_argument("actions", nargs=argparse.REMAINDER, metavar="ACTION [OPTIONS] ...",
                     help="home | unlock | move ... | status [--json] | resume | reset | shell | calibrate-kinematics")
    rig.set_defaults(func=_cmd_rig)

    sim = subparsers.add_parser(
        "sim-controller", help="run a GRBL 1.1h emulator on a pseudo-terminal",
        description="Serve a simulated GRBL 1.1h controller on a pty and link PATH to it, until interrupted.",
    )
    sim.add_argument("--link", required=True, type=Path, metavar="PATH", help="symlink to create to the pty")
    sim.add_argument("--fault", action="append", default=[], metavar="SPEC", help=f"inject a fault: {FAULT_HELP}")
    sim.add_argument("--rig-config", type=Path, metavar="FILE",
                     help="size the axes' travel ($13x) from a rig config's machine targets")
    sim.add_argument("--axes", default=None, help="GRBL axis letters (default XYZ, or what the rig config drives)")
    sim.add_argument("--time-scale", type=TIME_SCALE, default=1.0, metavar="X",
                     help="simulated seconds per real second, 0.1-10000 (default 1: real time)")
    sim.add_argument("--no-homing", action="store_true", help="homing disabled ($22=0): boot Idle, no soft limits")
    sim.add_argument("--hard-limits", action="store_true",
                     help="hard limits on ($21=1): a move that reaches a homing switch halts with ALARM:1")
    sim.add_argument("--reboot-on-open", action="store_true",
                     help="reboot whenever the port is opened, like an Arduino with DTR auto-reset")
    sim.add_argument("--startup-line", action="append", default=[], metavar="LINE",
                     help="a startup line ($N0, $N1) run after every reset, e.g. G20")
    sim.add_argument("--force-set-origin", action="store_true",
                     help="a HOMING_FORCE_SET_ORIGIN build: homing sets 0 (positive machine space on $23 axes)")
    sim.add_argument("--firmware", choices=("grbl", "grblhal"), default="grbl")
    sim.set_defaults(func=_cmd_sim_controller)


# ---------------------------------------------------------------------------------------------- actions


class _HelpShown(Exception):
    """An action's --help was printed: nothing to run."""


class _ActionParser(argparse.ArgumentParser):
    """Parses one action's options; errors become one-line CliErrors (the shell must not exit on them)."""

    def error(self, message: str):
        raise CliError(f"{self.prog.removeprefix('stereo-bench ')}: {message}")

    def exit(self, status: int = 0, message: str | None = None):
        if message:
            print(message, file=sys.stderr, end="")
        raise _HelpShown()


def _action_parsers() -> dict[str, _ActionParser]:
    parsers = {}
    for name, text in (("home", "run the homing cycle ($H)"),
                       ("unlock", "leave Alarm without homing ($X); after a boot moves stay refused (the position "
                                  "is unknown) unless --trust-position states that it is right"),
                       ("move", "move to a configuration; returns once the rig has stopped there"),
                       ("status", "where the rig is (does not reset the controller)"),
                       ("resume", "continue a held move: waits until the hold is complete, then '~'"),
                       ("reset", "soft reset (0x18): abandons a held move, ends a halt after ALARM:1/2"),
                       ("shell", "an interactive prompt: home, unlock, move ..., status, resume, reset, quit")):
        parsers[name] = _ActionParser(prog=f"stereo-bench rig {name}", description=text)
    move = parsers["move"]
    move.add_argument("--baseline", type=MOVE_VALUE, metavar="MM", help="baseline B, mm")
    move.add_argument("--alpha", type=MOVE_VALUE, metavar="DEG",
                      help="angle between baseline and both optical axes, deg (90 = parallel)")
    move.add_argument("--alpha-left", type=MOVE_VALUE, metavar="DEG", help="left camera's alpha, deg")
    move.add_argument("--alpha-right", type=MOVE_VALUE, metavar="DEG", help="right camera's alpha, deg")
    move.add_argument("--toe-in", type=MOVE_VALUE, metavar="DEG", help="toe-in of both cameras, deg (90 - alpha)")
    move.add_argument("--toe-in-left", type=MOVE_VALUE, metavar="DEG", help="left camera's toe-in, deg")
    move.add_argument("--toe-in-right", type=MOVE_VALUE, metavar="DEG", help="right camera's toe-in, deg")
    move.add_argument("--tilt", type=MOVE_VALUE, metavar="DEG", help="tilt of both cameras, deg (> 0 looks down)")
    move.add_argument("--target", type=MOVE_VALUE, metavar="MM", help="target distance Z from the baseline, mm")
    move.add_argument("--yes", action="store_true",
                      help="move even where a camera would look along (or behind) the baseline, at the other camera "
                           "(alpha <= 0 or >= 180 deg, |toe-in| >= 90 deg)")
    parsers["status"].add_argument("--json", action="store_true", help="print one JSON object")
    parsers["unlock"].add_argument(
        "--trust-position", action="store_true",
        help="the axes stand where the controller counts (they were not moved while it booted, or were homed "
             "and it kept counting): moves are no longer refused for a boot. Wrong, and the rig moves to wrong "
             "places, past its ends included")
    return parsers


@dataclass
class _Action:
    name: str
    options: argparse.Namespace
    request: dict[str, float | None] | None = None  # move only


def _parse_actions(tokens: list[str], config: RigConfig) -> list[_Action]:
    """Split ``home move --baseline 100 status`` into actions and parse each; moves are checked against the
    rig config here, before the port is even opened."""
    if not tokens:
        raise CliError(f"give an action: {', '.join(ACTIONS)} (several run in order on one connection)")
    groups: list[list[str]] = []
    for token in tokens:
        if token in ACTIONS or token == CALIBRATE_KINEMATICS:
            groups.append([token])
        elif not groups:
            raise CliError(f"unknown action {token!r}; actions: {', '.join(ACTIONS)}")
        else:
            groups[-1].append(token)
    parsers = _action_parsers()
    if any(group[0] == CALIBRATE_KINEMATICS for group in groups):
        raise CliError("calibrate-kinematics runs on its own: give it alone (`rig calibrate-kinematics --out DIR`)")
    actions = [_parse_action(parsers, group[0], group[1:], config) for group in groups]
    if len(actions) > 1 and any(a.name == "shell" for a in actions):
        raise CliError("shell runs on its own: give it alone (`rig --port P shell`)")
    return actions


def _parse_action(parsers: dict[str, _ActionParser], name: str, argv: list[str], config: RigConfig) -> _Action:
    if name == CALIBRATE_KINEMATICS:
        raise CliError("calibrate-kinematics runs on its own: `stereo-bench rig calibrate-kinematics --out DIR`")
    if name not in parsers:
        raise CliError(f"unknown action {name!r}; actions: {', '.join(ACTIONS)}")
    options = parsers[name].parse_args(argv)
    action = _Action(name, options)
    if name == "move":
        action.request = _move_request(options)
        try:
            physical = physical_request(**action.request)
            plan_move(config, physical)
        except RigError as error:
            raise _fail(error) from None
        if not options.yes:
            _refuse_along_baseline(physical)
    return action


def _refuse_along_baseline(physical: dict[str, float | None]) -> None:
    """A toe-in at or past 90 deg points a camera along the baseline (at the other camera) or behind it: refused
    unless confirmed. Alpha is measured on the target side (BRIEF), in (0, 180); the default soft limits reach
    toe-in 90, so the soft limits alone let ``--alpha 0`` through."""
    for side in ("left", "right"):
        toe_in = physical.get(f"toe_in_{side}_deg")
        if toe_in is not None and along_baseline(toe_in):
            raise CliError(f"move: alpha {alpha_from_toe_in(toe_in):g} deg (toe-in {toe_in:g} deg) turns the {side} "
                           "camera to look along the baseline, at the other camera, not at a target in front of the "
                           "rig (alpha lies in (0, 180) deg); add --yes to move there anyway")


def _move_request(args) -> dict[str, float | None]:
    if args.alpha is not None and any(
            v is not None for v in (args.toe_in, args.toe_in_left, args.toe_in_right, args.alpha_left,
                                    args.alpha_right)):
        raise CliError("give --alpha, or --toe-in-left/--toe-in-right (or --alpha-left/--alpha-right), not both")
    if args.toe_in is not None and any(v is not None for v in (args.toe_in_left, args.toe_in_right)):
        raise CliError("give --toe-in, or --toe-in-left/--toe-in-right, not both")
    request: dict[str, float | None] = {
        "baseline_mm": args.baseline,
        "toe_in_left_deg": args.toe_in_left if args.toe_in is None else args.toe_in,
        "toe_in_right_deg": args.toe_in_right if args.toe_in is None else args.toe_in,
        "alpha_left_deg": args.alpha_left if args.alpha is None else args.alpha,
        "alpha_right_deg": args.alpha_right if args.alpha is None else args.alpha,
        "tilt_left_deg": args.tilt, "tilt_right_deg": args.tilt, "target_distance_mm": args.target,
    }
    if all(v is None for v in request.values()):
        raise CliError("nothing to move: give --baseline, --alpha, --toe-in-left/--toe-in-right, --tilt or --target")
    return request


# ---------------------------------------------------------------------------------------------- rig


def _config(args) -> RigConfig:
    if args.rig_config is None:
        return RigConfig()
    try:
        return load_rig_config(args.rig_config)
    except RigConfigError as error:
        raise CliError(str(error)) from None


def _fail(error: RigError, rig: GrblRig | None = None) -> CliError:
    """The one-line error and exit status of a rig failure (stereo_bench.cli.failure), with the auto-reset hint."""
    mapped = failure(error) or CliError(" ".join(str(error).split()), exit_code=EXIT_FAULT)
    if isinstance(error, GrblPositionUnknown) and rig is not None and rig.controller.info.boot_detected:
        return CliError(f"{mapped} (the controller booted at connect, as an Arduino does when its port opens: chain "
                        "actions in one call, e.g. `rig --port P home move ...`, or use `rig --port P shell`; "
                        "docs/RIG.md says how to disable the auto-reset)", exit_code=mapped.exit_code)
    return mapped


def _check_spy_log(path: Path | None) -> None:
    """A spy log that cannot be created fails before the port is opened (opening may reboot the controller); one
    that exists is appended to, if it is a regular file."""
    if path is None:
        return
    try:
        check_output_file(path, option="--spy-log", exists_ok=True)
    except UnwritablePath as error:
        raise CliError(str(error)) from None


class _StderrWarnings(logging.Handler):
    """The driver's warnings (settings conflicts at connect, a boot, a recovered reply), one line each."""

    def emit(self, record: logging.LogRecord) -> None:
        print(f"stereo-bench rig: warning: {' '.join(record.getMessage().split())}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _warnings_to_stderr() -> Iterator[None]:
    logger = logging.getLogger("drivers.rig")
    handler = _StderrWarnings(level=logging.WARNING)
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)


def _cmd_rig(args) -> int:
    if args.actions and args.actions[0] == CALIBRATE_KINEMATICS:
        from stereo_bench.cli import rig_kinematics

        if args.spy_log is not None or args.timeout is not None:
            raise CliError("calibrate-kinematics records the serial transcript in its session and times moves from "
                           "the rig config: --spy-log and --timeout do not apply")
        return rig_kinematics.run(list(args.actions[1:]), port=args.port, rig_config=args.rig_config)
    config = _config(args)
    try:
        actions = _parse_actions(list(args.actions), config)  # before --port: `rig move --help` needs none
    except _HelpShown:
        return 0
    if args.port is None:
        raise CliError("rig: --port is required (the controller's serial device or a sim-controller link)")
    _check_spy_log(args.spy_log)
    first = actions[0].name
    # One soft reset at connect flushes half-received lines; not when looking, resuming a hold or in the shell.
    options = {"reset_on_open": first == "reset" or (first not in _LOOKING and config.controller.reset_on_open)}
    with _warnings_to_stderr():
        rig = GrblRig(args.port, config, spy_log=args.spy_log, **options)
        try:
            rig.open()
        except RigError as error:
            raise _fail(error) from None
        try:
            if first == "shell":
                return _shell(rig, args)
            for index, action in enumerate(actions):
                if action.name == "reset" and index == 0:
                    # The connect already reset it: report the state it is in now.
                    print(f"soft reset on connect. {_describe(rig.read())}", flush=True)
                    continue
                _run(rig, action, args, interactive=False)
        except RigError as error:
            raise _fail(error, rig) from None
        except _HelpShown:
            return 0
        finally:
            rig.close()
    return 0


def _run(rig: GrblRig, action: _Action, args, *, interactive: bool) -> None:
    """One action on an open rig. Raises RigError."""
    name = action.name
    if name == "home":
        print(f"homing the rig on {args.port} ...", flush=True)
        try:
            reading = rig.home(timeout_s=args.timeout)
        except KeyboardInterrupt:
            # A homing cycle cannot be held: only a soft reset stops it (Grbl reports ALARM:6).
            with contextlib.suppress(RigError):
                rig.reset()
            print("interrupted: homing stopped with a soft reset (ALARM:6); home again before moving",
                  file=sys.stderr, flush=True)
            raise
        print(f"homed. {_describe(reading)}", flush=True)
    elif name == "unlock":
        trust = action.options.trust_position
        reading = rig.unlock(trust_position=trust)
        if trust:
            print(f"unlocked: the position is trusted as it is. {_describe(reading)}", flush=True)
        elif rig.controller.position_unknown:
            print(f"unlocked, but the position is unknown ({rig.controller.position_unknown}): home, or unlock "
                  f"--trust-position if it is right. {_describe(reading)}", flush=True)
        else:
            print(f"unlocked: the position is used as it is. {_describe(reading)}", flush=True)
    elif name == "move":
        _move(rig, action, args, interactive=interactive)
    elif name == "status":
        _status(rig, args, as_json=action.options.json)
    elif name == "resume":
        _resume(rig, args)
    elif name == "reset":
        reading = rig.reset()
        print(f"soft reset. {_describe(reading)}", flush=True)


def _resume(rig: GrblRig, args) -> None:
    """``resume``: continue a held move; say so when there is none (a reboot at connect drops a hold)."""
    before = rig.read()
    if not before.state.startswith("Hold"):
        booted = rig.controller.info.boot_detected
        why = (f"opening {args.port} rebooted the controller, which dropped any hold and its move"
               if booted else f"the controller is not holding ({before.state})")
        if before.state == "Idle" and not booted:
            print(f"nothing to resume: {why}. {_describe(before)}", flush=True)
            return
        raise CliError(f"nothing to resume: {why}; home the rig and move again (docs/RIG.md section 4)",
                       exit_code=EXIT_FAULT)
    print("resuming ...", flush=True)
    reading = rig.resume(timeout_s=args.timeout)
    print(f"stopped. {_describe(reading)}", flush=True)


def _move(rig: GrblRig, action: _Action, args, *, interactive: bool) -> None:
    def moving(targets: dict[str, float]) -> None:
        text = " ".join(f"{axis}{value:.3f}" for axis, value in targets.items())
        print(f"moving: {text} (machine units) ...", flush=True)

    try:
        # The motors, then the operator for what the rig sets by hand: the campaign's one prompt path (a desk).
        reading = move_and_ask(rig, OperatorDesk([LineOperator()]), timeout_s=args.timeout, on_moving=moving,
                               **action.request)
    except OperatorAbsent as error:
        raise CliError(f"move: {error}") from None
    except KeyboardInterrupt:
        # The controller would carry on with the queued move: hold it before giving up.
        with contextlib.suppress(RigError):
            rig.stop()
        if interactive:
            print("interrupted: feed hold sent; the rig holds where it stopped: `resume` continues the move, "
                  "`reset` abandons it", file=sys.stderr, flush=True)
            return
        print(f"interrupted: feed hold sent; the rig holds where it stopped: `stereo-bench rig --port {args.port} "
              f"resume` continues the move, `... reset` abandons it (an Arduino that reboots when its port opens "
              "drops the hold: use `rig ... shell` there)", file=sys.stderr, flush=True)
        raise
    print(f"stopped. {_describe(reading)}", flush=True)


def _status(rig: GrblRig, args, *, as_json: bool) -> None:
    reading = rig.read()
    controller = rig.controller
    if as_json:
        data = reading.to_dict()
        data["port"] = args.port
        data["locked"] = controller.locked
        data["halted"] = controller.halted
        data["alarm"] = None if controller.alarm is None else {"code": controller.alarm.code,
                                                               "meaning": controller.alarm.meaning}
        data["firmware"] = None if controller.banner is None else controller.banner.text
        data["position_unknown"] = controller.position_unknown
        data["controller"] = rig.controller_info()
        print_json(data)
        return
    print(_describe(reading), flush=True)
    if controller.position_unknown:
        print(f"position unknown: {controller.position_unknown}: home the rig before moving", flush=True)
    elif controller.locked:
        print("controller is in Alarm: run `home` (or `unlock`) before moving", flush=True)


def _describe(reading: RigReading) -> str:
    def fmt(value: float | None, unit: str) -> str:
        return "?" if value is None else f"{value:.3f} {unit}"

    parts = [f"B = {fmt(reading.baseline_mm, 'mm')}"]
    parts.append(f"toe-in L = {fmt(reading.toe_in_left_deg, 'deg')} (alpha {fmt(reading.alpha_left_deg, 'deg')})")
    parts.append(f"R = {fmt(reading.toe_in_right_deg, 'deg')} (alpha {fmt(reading.alpha_right_deg, 'deg')})")
    parts.append(f"tilt L/R = {fmt(reading.tilt_left_deg, 'deg')} / {fmt(reading.tilt_right_deg, 'deg')}")
    parts.append(f"target Z = {fmt(reading.target_distance_mm, 'mm')}")
    machine = reading.machine_position or {}
    raw = " ".join(f"{axis}{value:.3f}" for axis, value in machine.items())
    return f"{reading.state}: " + ", ".join(parts) + (f" [machine {raw}]" if raw else "")


SHELL_HELP = """\
commands: home | unlock [--trust-position] | move OPTIONS | status [--json] | resume | reset | help | quit
  move options: --baseline MM --alpha DEG --alpha-left/--alpha-right DEG --toe-in DEG
                --toe-in-left/--toe-in-right DEG --tilt DEG --target MM   (move --help for details)
Ctrl-C during a move holds the rig: `resume` continues, `reset` abandons. quit or Ctrl-D leaves."""


def _shell(rig: GrblRig, args) -> int:
    """An interactive prompt on one connection. Errors are printed and the prompt goes on; a lost connection
    ends it with status 1."""
    parsers = _action_parsers()
    controller = rig.controller
    firmware = controller.banner.text if controller.banner else f"GRBL {controller.info.build or '(version unknown)'}"
    print(f"connected to {args.port} ({firmware}). {_describe(rig.read())}", flush=True)
    print(SHELL_HELP, flush=True)
    while True:
        try:
            line = input("rig> ")
        except EOFError:
            print(flush=True)
            return 0
        except KeyboardInterrupt:
            print("\n(quit or Ctrl-D to leave)", flush=True)
            continue
        try:
            words = shlex.split(line)
        except ValueError as error:
            print(f"error: {error}", file=sys.stderr, flush=True)
            continue
        if not words:
            continue
        if words[0] in ("quit", "exit"):
            return 0
        if words[0] == "help":
            print(SHELL_HELP, flush=True)
            continue
        try:
            if words[0] == "shell":
                raise CliError("already in the shell")
            action = _parse_action(parsers, words[0], words[1:], rig.config)
            _run(rig, action, args, interactive=True)
        except _HelpShown:
            continue
        except CliError as error:
            print(f"error: {error}", file=sys.stderr, flush=True)
        except RigError as error:
            failure = _fail(error, rig)
            print(f"error: {failure}", file=sys.stderr, flush=True)
            if isinstance(error, GrblConnectionLost):
                return failure.exit_code
        except KeyboardInterrupt:
            print(flush=True)  # Ctrl-C during homing or a prompt: the action said what it did


# ---------------------------------------------------------------------------------------------- sim


def _emulator_from_args(args) -> GrblEmulator:
    specs: dict[str, AxisSpec] = {}
    axes = args.axes
    force_set_origin = args.force_set_origin
    if args.rig_config is not None:
        config = _config(args)
        specs, needs_force = axis_specs_for_travel(config.machine_travel(), margin=REFERENCE_HOMING.pulloff)
        if needs_force and not force_set_origin:
            # A stock build: same travel, homing toward +; the driver will say which targets it refuses.
            specs = {axis: AxisSpec(max_travel=spec.max_travel, max_rate_per_min=spec.max_rate_per_min,
                                    acceleration=spec.acceleration, steps_per_unit=spec.steps_per_unit)
                     for axis, spec in specs.items()}
            print("note: the rig config has positive machine targets, which a stock Grbl refuses once homed "
                  "(--force-set-origin emulates a build that accepts them)", flush=True)
        if axes is None and config.axes:
            last = max(AXIS_LETTERS.index(a) for a in config.axes)
            axes = AXIS_LETTERS[: max(last + 1, 3)]
    axes = (axes or "XYZ").upper()
    faults = []
    for spec in args.fault:
        try:
            faults.append(parse_fault(spec))
        except ValueError as error:
            raise CliError(f"--fault: {error}") from None
    try:
        return GrblEmulator(axes=axes, axis_specs=specs, time_scale=args.time_scale,
                            homing_enabled=not args.no_homing, hard_limits=args.hard_limits,
                            firmware=args.firmware, faults=faults,
                            reboot_on_open=args.reboot_on_open, startup_lines=args.startup_line,
                            force_set_origin=force_set_origin)
    except ValueError as error:
        raise CliError(f"--axes: {error}") from None


def _link(link: Path, target: str) -> None:
    if link.is_symlink():
        link.unlink()
    elif link.exists():
        raise CliError(f"--link {link}: exists and is not a symlink; not replacing it")
    try:
        os.symlink(target, link)
    except OSError as error:
        raise CliError(f"--link {link}: {error.strerror}") from None


def _cmd_sim_controller(args) -> int:
    emulator = _emulator_from_args(args)
    stop = threading.Event()
    previous: dict[int, object] = {}
    if threading.current_thread() is threading.main_thread():
        # Ctrl-C, SIGTERM and SIGHUP just end the loop, so a second Ctrl-C cannot cut the cleanup short.
        previous = stop_on_signals(stop)
    emulator.start()
    tty_path = emulator.tty_path or ""
    try:
        _link(args.link, tty_path)
        faults = f", faults: {', '.join(args.fault)}" if args.fault else ""
        reboot = ", reboots when opened" if args.reboot_on_open else ""
        print(f"GRBL emulator ({args.firmware}, axes {emulator.axes}, time x{args.time_scale:g}{reboot}{faults}) "
              f"serving on {tty_path}, linked at {args.link}; Ctrl-C to stop", flush=True)
        try:
            while not stop.is_set():
                if not emulator.running:
                    print("the emulated port vanished (injected fault)", flush=True)
                    break
                time.sleep(0.1)
        except KeyboardInterrupt:
            pass
    finally:
        emulator.stop()
        with contextlib.suppress(OSError):
            if args.link.is_symlink() and os.readlink(args.link) == tty_path:
                args.link.unlink()
        for signum, handler in previous.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]
    print("GRBL emulator stopped", flush=True)
    return 0


__all__ = ["register"]
