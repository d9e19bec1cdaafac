"""``stereo-bench rig`` (home / move / status / unlock) and ``stereo-bench sim-controller``.

    stereo-bench sim-controller --link /tmp/grbl [--fault alarm:1] [--time-scale 10]
    stereo-bench rig --port /tmp/grbl home
    stereo-bench rig --port /tmp/grbl move --baseline 120 --alpha 85
    stereo-bench rig --port /tmp/grbl status --json

Exit status: 0 done; 2 for what the user can fix (a refused move, a bad rig config, an unreachable
port); 1 for a controller fault (alarm, timeout, lost connection); 130 interrupted.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

from drivers.rig import (
    GrblConnectionError,
    GrblRig,
    LimitError,
    MoveRequestError,
    RigConfig,
    RigConfigError,
    RigError,
    RigReading,
    load_rig_config,
    wait_for_enter,
)
from drivers.rig.config import plan_move
from drivers.rig.rig import physical_request
from drivers.sim.grbl_emulator import AXIS_LETTERS, FAULT_HELP, AxisSpec, GrblEmulator, parse_fault
from stereo_bench.cli import CliError

EXIT_FAULT = 1


def register(subparsers) -> None:
    rig = subparsers.add_parser(
        "rig", help="drive the rig's GRBL controller: home, move, status",
        description="Drive the stereo rig through its GRBL 1.1 controller, in mm and degrees.",
    )
    rig.add_argument("--port", required=True, metavar="PORT",
                     help="serial device or pyserial URL of the controller (e.g. /dev/ttyUSB0, a sim-controller link)")
    rig.add_argument("--rig-config", type=Path, metavar="FILE",
                     help="rig configuration TOML (axis mapping, limits); default: X = baseline 0-350 mm, "
                          "Y/Z = left/right toe-in 0-90 deg")
    rig.add_argument("--timeout", type=float, metavar="S", help="bound on homing or a move, seconds")
    rig.add_argument("--spy-log", type=Path, metavar="FILE", help="record every byte on the link as JSON lines")
    actions = rig.add_subparsers(dest="rig_action", metavar="ACTION", required=True)

    home = actions.add_parser("home", help="run the homing cycle ($H)")
    home.set_defaults(func=_cmd_home)

    move = actions.add_parser("move", help="move to a configuration; returns once the rig has stopped there")
    move.add_argument("--baseline", type=float, metavar="MM", help="baseline B, mm")
    move.add_argument("--alpha", type=float, metavar="DEG",
                      help="angle between baseline and both optical axes, deg (90 = parallel)")
    move.add_argument("--alpha-left", type=float, metavar="DEG", help="left camera's alpha, deg")
    move.add_argument("--alpha-right", type=float, metavar="DEG", help="right camera's alpha, deg")
    move.add_argument("--toe-in", type=float, metavar="DEG", help="toe-in of both cameras, deg (90 - alpha)")
    move.add_argument("--toe-in-left", type=float, metavar="DEG", help="left camera's toe-in, deg")
    move.add_argument("--toe-in-right", type=float, metavar="DEG", help="right camera's toe-in, deg")
    move.add_argument("--tilt", type=float, metavar="DEG", help="tilt of both cameras, deg (> 0 looks down)")
    move.add_argument("--target", type=float, metavar="MM", help="target distance Z from the baseline, mm")
    move.set_defaults(func=_cmd_move)

    status = actions.add_parser("status", help="where the rig is (does not reset the controller)")
    status.add_argument("--json", action="store_true", help="print one JSON object")
    status.set_defaults(func=_cmd_status)

    unlock = actions.add_parser("unlock", help="leave Alarm without homing ($X): only if the positions are right")
    unlock.set_defaults(func=_cmd_unlock)

    sim = subparsers.add_parser(
        "sim-controller", help="run a GRBL 1.1 emulator on a pseudo-terminal",
        description="Serve a simulated GRBL 1.1 controller on a pty and link PATH to it, until interrupted.",
    )
    sim.add_argument("--link", required=True, type=Path, metavar="PATH", help="symlink to create to the pty")
    sim.add_argument("--fault", action="append", default=[], metavar="SPEC", help=f"inject a fault: {FAULT_HELP}")
    sim.add_argument("--rig-config", type=Path, metavar="FILE", help="size the axes' travel from a rig config")
    sim.add_argument("--axes", default=None, help="GRBL axis letters (default XYZ, or what the rig config drives)")
    sim.add_argument("--time-scale", type=float, default=1.0, metavar="X",
                     help="simulated seconds per real second (default 1: real time)")
    sim.add_argument("--no-homing", action="store_true", help="homing disabled: boot Idle, no soft limits")
    sim.add_argument("--firmware", choices=("grbl", "grblhal"), default="grbl")
    sim.set_defaults(func=_cmd_sim_controller)


# ---------------------------------------------------------------------------------------------- rig


def _config(args) -> RigConfig:
    if args.rig_config is None:
        return RigConfig()
    try:
        return load_rig_config(args.rig_config)
    except RigConfigError as error:
        raise CliError(str(error)) from None


def _fail(error: RigError) -> CliError:
    text = " ".join(str(error).split())
    if isinstance(error, (LimitError, MoveRequestError, RigConfigError, GrblConnectionError)):
        return CliError(text)
    return CliError(text, exit_code=EXIT_FAULT)


@contextlib.contextmanager
def _connected(args, config: RigConfig, **options):
    rig = GrblRig(args.port, config, prompt=wait_for_enter, spy_log=args.spy_log, **options)
    try:
        rig.open()
    except RigError as error:
        raise _fail(error) from None
    try:
        yield rig
    except RigError as error:
        raise _fail(error) from None
    finally:
        rig.close()


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


def _cmd_home(args) -> int:
    config = _config(args)
    with _connected(args, config) as rig:
        print(f"homing the rig on {args.port} ...", flush=True)
        reading = rig.home(timeout_s=args.timeout)
        print(f"homed. {_describe(reading)}", flush=True)
    return 0


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


def _cmd_move(args) -> int:
    config = _config(args)
    request = _move_request(args)
    # Refuse before the port is even opened: bad combinations, fixed quantities, soft limits.
    try:
        plan_move(config, physical_request(**request))
    except RigError as error:
        raise _fail(error) from None

    def moving(targets: dict[str, float]) -> None:
        text = " ".join(f"{axis}{value:.3f}" for axis, value in targets.items())
        print(f"moving: {text} (machine units) ...", flush=True)

    with _connected(args, config) as rig:
        try:
            reading = rig.move_to(timeout_s=args.timeout, on_moving=moving, **request)
        except KeyboardInterrupt:
            # The controller would carry on with the queued move: hold it before giving up.
            with contextlib.suppress(RigError):
                rig.stop()
            print("interrupted: feed hold sent; the rig is holding (resume with '~' or reset)", file=sys.stderr)
            raise
        print(f"stopped. {_describe(reading)}", flush=True)
    return 0


def _cmd_status(args) -> int:
    config = _config(args)
    # Looking must not disturb: no soft reset on connect.
    with _connected(args, config, reset_on_open=False) as rig:
        reading = rig.read()
        controller = rig.controller
        if args.json:
            data = reading.to_dict()
            data["port"] = args.port
            data["locked"] = controller.locked
            data["alarm"] = None if controller.alarm is None else {"code": controller.alarm.code,
                                                                   "meaning": controller.alarm.meaning}
            data["firmware"] = None if controller.banner is None else controller.banner.text
            print(json.dumps(data), flush=True)
        else:
            print(_describe(reading), flush=True)
            if controller.locked:
                print("controller is in Alarm: run `stereo-bench rig ... home` (or `unlock`) before moving", flush=True)
    return 0


def _cmd_unlock(args) -> int:
    config = _config(args)
    with _connected(args, config) as rig:
        reading = rig.unlock()
        print(f"unlocked. {_describe(reading)}", flush=True)
    return 0


# ---------------------------------------------------------------------------------------------- sim


def _emulator_from_args(args) -> GrblEmulator:
    specs: dict[str, AxisSpec] = {}
    axes = args.axes
    if args.rig_config is not None:
        config = _config(args)
        for axis, (low, high) in config.machine_travel().items():
            specs[axis] = AxisSpec(travel=(low, high))
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
    if args.time_scale <= 0:
        raise CliError("--time-scale must be > 0")
    try:
        return GrblEmulator(axes=axes, axis_specs=specs, time_scale=args.time_scale,
                            homing_enabled=not args.no_homing, firmware=args.firmware, faults=faults)
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
        # Ctrl-C and SIGTERM just end the loop, so a second Ctrl-C cannot cut the cleanup short.
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, lambda *_: stop.set())
    emulator.start()
    tty_path = emulator.tty_path or ""
    try:
        _link(args.link, tty_path)
        faults = f", faults: {', '.join(args.fault)}" if args.fault else ""
        print(f"GRBL emulator ({args.firmware}, axes {emulator.axes}, time x{args.time_scale:g}{faults}) "
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
