"""`stereo-bench campaign run`: run a campaign (or resume one) on the simulated, bring-up or real bench.

Stopping: Ctrl-C, SIGTERM (what systemd and ``docker stop`` send) or SIGHUP (the terminal closed: an ssh
session ended) feed-holds the rig and stops at the next safe point, recording a 'stop' document and
leaving the session resumable (exit status 130); a second one stops at once, still recording
"interrupted" and printing the command that resumes. The reader of ``--json`` going away (``| head -1``)
stops it the same way, with exit status 141. A rig that fails and cannot be recovered (soft reset, then
homing) ends it as failed: exit status 1, one line naming the fault, and the session resumes once fixed.
A run refused before anything moved (a port that is not there) leaves ``--out`` as it was.

``--resume`` without a campaign file continues with the config the session recorded: the printed resume
command is ``stereo-bench campaign run --out DIR --resume`` (with ``--yes`` if the simulator did the
manual steps), whatever options went into that config.

``--ui`` serves the live page (``stereo_bench/live``) for the run's duration and prints its URL.
"""

from __future__ import annotations

import argparse
import contextlib
import shlex
import signal
import sys
import time
from pathlib import Path

from stereo_bench.campaign import presentation
from stereo_bench.cli import (
    EXIT_BROKEN_PIPE,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    STOP_SIGNALS,
    CliError,
    failure,
    hung_up,
    output_gone,
    silence_stdout,
)
from stereo_bench.cli.args import TIME_SCALE, finite_float, int_in, output_dir
from stereo_bench.cli.progress import Progress


def config_from_args(plan_file: Path | None, preset: str | None, *, time_scale: float | None = None,
                     sim: str | None = None, session: Path | None = None):
    """The campaign config named by a file or a preset (exactly one) or, with neither, the one ``session`` recorded
    (``run --resume``); ``time_scale`` and the ``sim`` profile applied, and checked as ``run`` checks it before
    moving (:func:`preflight_from_args`); errors -> CliError, ConfigError or SessionError (one line, exit status 2).

    The one way the CLI loads a campaign (``campaign plan`` and ``campaign run``).
    """
    return preflight_from_args(plan_file, preset, time_scale=time_scale, sim=sim, session=session).config


def preflight_from_args(plan_file: Path | None, preset: str | None, *, time_scale: float | None = None,
                        sim: str | None = None, session: Path | None = None, calibration: dict | None = None):
    """:func:`config_from_args`'s config with what its preflight read (:class:`stereo_bench.campaign.preflight.
    Preflight`): ``campaign run`` hands it to ``run_campaign``, which then reads no input file again.
    ``calibration``: ``[calibration]`` keys given as options (--max-view-rms-px, --exclude-views, --no-review)."""
    from drivers.files import read_once

    with read_once():  # the campaign file, the files it names: each read once, by the loader and the preflight
        return _preflight_from_args(plan_file, preset, time_scale=time_scale, sim=sim, session=session,
                                    calibration=calibration or {})


def _preflight_from_args(plan_file: Path | None, preset: str | None, *, time_scale: float | None,
                         sim: str | None, session: Path | None, calibration: dict):
    if plan_file is not None and preset is not None:
        raise CliError("give a campaign file or --preset NAME, not both")
    if plan_file is None and preset is None and session is None:
        raise CliError("give a campaign file or --preset NAME")
    from stereo_bench.campaign.config import load_campaign, load_preset

    if preset is not None:
        config, source = load_preset(preset), f"preset {preset}"
    elif plan_file is not None:
        config, source = load_campaign(plan_file), str(plan_file)
    else:
        from stereo_bench.campaign.execute import recorded_config

        config, source = recorded_config(session), f"{session}: the recorded campaign config"
    if time_scale is not None:
        if config.rig.kind != "simulated":
            raise CliError("--time-scale applies to the simulated rig only")
        config = _override(config, "rig", "time_scale", time_scale, "--time-scale")
    if sim is not None:
        if config.cameras.kind != "simulated":
            raise CliError("--sim applies to simulated cameras only (the simulated bench or bring-up)")
        config = _override(config, "sim", "profile", sim, "--sim")
    for key, (value, option) in calibration.items():
        config = _override(config, "calibration", key, value, option)
    from stereo_bench.campaign.preflight import preflight

    # What run checks before moving, checked for plan too; run_campaign takes it (it checks only when not given one).
    return preflight(config, source=source)


def _override(config, section: str, field: str, value, option: str):
    """``config`` with ``section.field = value``, validated as if the file said so (``model_copy`` would not)."""
    from pydantic import ValidationError

    shown = ",".join(map(str, value)) if isinstance(value, list) else value  # as the option takes it
    current = getattr(config, section)
    try:
        replaced = type(current).model_validate({**current.model_dump(exclude_unset=True), field: value})
    except ValidationError as error:
        message = error.errors()[0].get("msg", "invalid").removeprefix("Value error, ")
        raise CliError(f"{option} {shown}: {message}") from None
    updated = config.model_copy(update={section: replaced})
    try:  # the checks across sections (exclude_views against the views captured, ...), as loading runs them
        updated._check()
    except ValueError as error:
        raise CliError(f"{option} {shown}: {error}") from None
    return updated


def start_live_page(page, *, write=None):
    """Serve ``page`` (a :class:`~stereo_bench.live.page.LivePage`, for ``--ui``) and print its URL (see
    :func:`announce_live_page`). An address it cannot serve on raises ``LiveServerError``: one line naming
    host:port, exit status 2 through ``failure``."""
    page.start()
    return announce_live_page(page, write=write)


def announce_live_page(page, *, write=None):
    """Print a started page's URL, with a warning first when it listens beyond this machine."""
    write = write or (lambda text: print(text, file=sys.stderr, flush=True))
    if page.exposed:
        write(f"warning: the live page listens on {page.host}, beyond this machine: anyone on that network can "
              "watch; only the URL's token can control the run")
    write(f"live page: {page.url}")
    return page


DEFAULT_UI_HOST = "127.0.0.1"
DEFAULT_UI_PORT = 8765
UI_PORT = int_in(min=0, max=65535)  # a TCP port; 0 asks the system for a free one


def add_ui_options(parser: argparse.ArgumentParser, *, required: bool = False) -> None:
    """--ui-host and --ui-port (and --ui, unless the command always serves the page: ``required``)."""
    if not required:
        parser.add_argument("--ui", action="store_true",
                            help="serve the live page (cameras, coverage, rig, plan, results, prompts and controls) "
                                 "while the campaign runs; prints its URL")
    needs = "" if required else "with --ui: "
    parser.add_argument("--ui-host", default=DEFAULT_UI_HOST if required else None, metavar="HOST",
                        help=f"{needs}address the live page listens on (default {DEFAULT_UI_HOST}: this machine "
                             "only; 0.0.0.0 exposes it on the lab network, with a warning)")
    parser.add_argument("--ui-port", type=UI_PORT, default=DEFAULT_UI_PORT if required else None, metavar="PORT",
                        help=f"{needs}port of the live page, 0 to 65535 (default {DEFAULT_UI_PORT}; 0 picks a "
                             "free one)")


def _view_list(text: str) -> list[int]:
    """--exclude-views: 'N,N,...' (view indices from 0)."""
    try:
        views = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give view indices separated by commas, e.g. 0,3") from None
    if not views or min(views) < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: give view indices from 0 separated by commas, e.g. 0,3")
    return views


def _resume_command(args: argparse.Namespace, out: Path) -> str:
    """The command that continues the session in ``out``: no campaign file, so the config is the one the session
    recorded, with every option that went into it (``--time-scale``, ``--sim``, the file's own values); ``--yes``
    when the simulator did the manual steps (not part of the config: who does them)."""
    return shlex.join(["stereo-bench", "campaign", "run", "--out", str(out), "--resume", *(["--yes"] if args.yes
                                                                                          else [])])


def stopped_note(out: Path, resume_command: str | None) -> str:
    """How a run that raised left its session: stopped and resumable, or (refused before anything moved) not there."""
    if (out / "documents.jsonl").is_file():
        return f"session {out} stopped as failed" + (f"; once fixed: {resume_command}" if resume_command else "")
    return f"nothing was recorded: --out {out} is as it was"


class _UntilOutputGone:
    """A subscriber that stops the run once its stream's reader is gone, instead of failing it: :attr:`gone` is
    then "closed" (a closed pipe: ``--json | head -1``) or "hung up" (a terminal that hung up: SIGHUP follows)."""

    def __init__(self, subscriber, name: str, control):
        self.subscriber, self.name, self.control = subscriber, name, control
        self.gone: str | None = None

    def __call__(self, document) -> None:
        if self.gone is not None:
            return
        try:
            self.subscriber(document)
        except OSError as error:
            if not output_gone(error):
                raise
            self.gone = "closed" if isinstance(error, BrokenPipeError) else "hung up"
            self.control.request_stop(f"stopped: the reader of {self.name} went away" if self.gone == "closed"
                                      else f"stopped: the terminal of {self.name} hung up")


def cmd_run(args: argparse.Namespace) -> int:
    from drivers.camera.base import CameraError
    from drivers.rig.config import RigError
    from stereo_bench.campaign.execute import (
        CampaignPlan,
        RunControl,
        default_operators,
        run_campaign,
    )
    from stereo_bench.campaign.stream import JsonLines

    out = Path(args.out)
    calibration = {key: (value, option) for key, value, option in (
        ("max_view_rms_px", args.max_view_rms_px, "--max-view-rms-px"),
        ("exclude_views", args.exclude_views, "--exclude-views"),
        ("review", False if args.no_review else None, "--no-review")) if value is not None}
    checked = preflight_from_args(Path(args.plan) if args.plan else None, args.preset, time_scale=args.time_scale,
                                  sim=args.sim, session=out if args.resume else None, calibration=calibration)
    config = checked.config
    if args.yes and config.cameras.kind != "simulated":
        raise CliError("--yes lets the simulator do the manual steps, for simulated cameras only; at the real "
                       "bench the operator does them")
    if not args.ui and (args.ui_host is not None or args.ui_port is not None):
        given = " and ".join(name for name, value in (("--ui-host", args.ui_host), ("--ui-port", args.ui_port))
                             if value is not None)
        raise CliError(f"{given} {'apply' if ' and ' in given else 'applies'} to the live page: add --ui to serve it")
    plan = CampaignPlan.of(config)  # expanded once: the progress bar and the run share it
    resume_command = _resume_command(args, out)
    control = RunControl()
    # The seconds per board presentation earlier runs measured beside this session (campaign/presentation.py).
    measured, note = presentation.read_beside(out)
    if note is not None:
        print(f"note: {note}: the ETA assumes 5 s per presentation", file=sys.stderr)
    progress = Progress(plan, config, quiet=args.quiet, presentation=measured)
    # The terminal's prompts suspend the progress line: the prompt is the last thing on the screen.
    operators, frame_subscribers, page = default_operators(config, yes=args.yes, display=progress), [], None
    if args.ui:  # before the progress bar: an address it cannot serve on is one line
        from stereo_bench.live.page import LivePage

        page = start_live_page(LivePage.for_campaign(
            config, session_dir=out, host=args.ui_host or DEFAULT_UI_HOST,
            port=DEFAULT_UI_PORT if args.ui_port is None else args.ui_port, control=control))
        operators = operators + [page.operator]  # the first answer wins
    # Outputs whose reader may go away: stopped at a safe point (as by a signal) rather than failed.
    outputs = [_UntilOutputGone(progress, "stderr", control)]
    if args.json:
        outputs.append(_UntilOutputGone(JsonLines(sys.stdout), "stdout", control))
    subscribers = list(outputs)
    if page is not None:
        subscribers.append(page.state)
        frame_subscribers.append(page.previews.captured)
    signals = {"count": 0}

    def on_signal(signum, frame) -> None:
        if signum == signal.SIGHUP:
            hung_up()  # before anything is written to a terminal that may be gone
        if signals.get("finished"):  # the run has ended and recorded its stop: nothing left to stop
            return
        signals["count"] += 1
        if signals["count"] > 1:
            raise KeyboardInterrupt
        name = signal.Signals(signum).name
        with contextlib.suppress(OSError):  # stderr's reader gone too: the stop still happens
            progress.write(f"{name}: stopping at the next safe point (feed hold sent); again to stop at once")
        control.request_stop(f"stopped by {name}")

    previous = {sig: signal.signal(sig, on_signal) for sig in STOP_SIGNALS}
    started = time.monotonic()
    ended = False  # True once the summary is printed; otherwise an error line follows and the bar is erased
    try:
        summary = run_campaign(config, out, resume=args.resume, yes=args.yes, subscribers=subscribers,
                               control=control, plan=plan, resume_command=resume_command, operators=operators,
                               preflight=checked,
                               frame_subscribers=frame_subscribers)
        signals["finished"] = True
        progress.close()
        ended = True
        if any(output.name == "stdout" and output.gone == "closed" for output in outputs):
            # The reader went away: nothing more on stdout; one line on stderr (unless that is gone too).
            silence_stdout()
            with contextlib.suppress(OSError):
                print(f"stereo-bench campaign: stdout closed (its reader went away): "
                      f"{_stop_line(summary, out, resume_command)}", file=sys.stderr, flush=True)
            return EXIT_BROKEN_PIPE
        return _summarise(args, summary, out, resume_command, time.monotonic() - started)
    except (RigError, CameraError) as error:  # recorded as 'failed' in the session; one line here
        mapped = failure(error)  # a port or camera that is not there: 2; a fault during the run: 1
        raise CliError(f"{mapped} ({stopped_note(out, resume_command)})", exit_code=mapped.exit_code) from None
    except OSError as error:  # a full or read-only disk: what is recorded stays, and the session resumes
        if output_gone(error):
            raise
        mapped = failure(error)
        resumable = (out / "documents.jsonl").is_file()
        raise CliError(f"{mapped}" + (f" (session {out} stopped; once fixed: {resume_command})" if resumable
                                      else "")) from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        progress.close(clear=not ended)
        if page is not None:
            if page.previews.watched:
                time.sleep(0.5)  # let the browsers get the final state before the page goes away
            page.stop()


def _stop_line(summary, out: Path, resume_command: str) -> str:
    """Where a run stopped by its reader going away left its session (the one line left for stderr)."""
    if summary.exit_status == "success":  # it went away as the last configuration was recorded
        return f"session {out} complete"
    return f"session {out} {summary.exit_status} at a safe point; resume: {resume_command}"


def _summarise(args: argparse.Namespace, summary, out: Path, resume_command: str, elapsed: float) -> int:
    from stereo_bench.campaign.documents import campaign_outcome

    counts = summary.counts()
    parts = ", ".join(f"{n} {status}" for status, n in sorted(counts.items()))
    report = sys.stderr if args.json else sys.stdout  # --json: stdout holds only the documents
    if summary.plan_drift:
        print(f"note: the recorded plan runs; {summary.plan_drift}", file=report)
    # The word and the exit status agree (docs/EXIT_STATUS.md): success 0, partial 0 (some planned configurations
    # not measured: the word says so, the report lists each with its reason), interrupted 130, failed 1, and a run
    # that measured nothing (every configuration infeasible, outside the limits or failed) is failed, not success.
    status, reason = campaign_outcome(summary.exit_status, counts)
    code, why = 0, f" ({reason})" if reason else ""
    if status == "interrupted":
        code = EXIT_INTERRUPTED
    elif status not in ("success", "partial"):
        code = EXIT_FAILED
    print(f"campaign {status} in {elapsed:.0f} s: {parts or 'nothing run'}"
          + (f" ({summary.skipped} already complete)" if summary.skipped else "") + why, file=report)
    print(f"session:  {out}/  (documents.jsonl, frames/, calib/, results.sqlite)", file=report)
    print(f"results:  {out / 'results.csv'}", file=report)
    print(f"report:   stereo-bench report {out}", file=report)
    if code == EXIT_INTERRUPTED:
        print(f"resume:   {resume_command}", file=report)
    elif summary.exit_status == "failed" and summary.reason:  # the rig unrecoverable: the one error line says it
        report.flush()
        raise CliError(f"{summary.reason} (session {out} stopped as failed; once fixed: {resume_command})",
                       exit_code=EXIT_FAILED)
    elif code:
        print(f"exit status {code}: {why.strip(' ()') or 'the campaign ' + status}", file=report)
    return code


def register_run(subparsers) -> None:
    run = subparsers.add_parser(
        "run", help="run a campaign on the simulated, bring-up or real bench, recording a session",
        description="Drive the rig through every configuration of the plan: move, settle, flush, calibrate "
                    "(per-config extrinsics), capture and measure the square; record everything in --out. "
                    "Ctrl-C, SIGTERM or SIGHUP (a closed terminal or ssh session) stops at the next safe point "
                    "(again: at once); so does the reader of --json going away. A rig fault is recovered by a soft "
                    "reset and homing (the configuration fails, the campaign goes on); if that fails the campaign "
                    "stops as failed. A run refused before anything moved (a port that is not there) leaves --out "
                    "as it was. --resume continues a stopped session with the config it recorded (no campaign file "
                    "needed: the printed resume command). Exit status: 0 done, 1 nothing measured or a rig/camera "
                    "fault, 2 a usage or config error, 130 interrupted (resumable), 141 stdout closed (resumable).",
    )
    run.add_argument("plan", nargs="?", metavar="PLAN.toml",
                     help="campaign file; with --resume it may be left out (the config the session recorded "
                          "continues; a file given must match it)")
    run.add_argument("--preset", metavar="NAME", help="a built-in campaign (see: stereo-bench campaign presets)")
    run.add_argument("--out", required=True, type=output_dir, metavar="DIR",
                     help="session directory (never overwritten)")
    run.add_argument("--resume", action="store_true",
                     help="continue the interrupted or failed session in --out (with the config it recorded)")
    run.add_argument("--yes", action="store_true",
                     help="simulated cameras: let the simulator do the manual steps (moving the target in the "
                          "simulated scene) instead of asking")
    run.add_argument("--time-scale", type=TIME_SCALE, metavar="X",
                     help="simulated rig: run motion and exposures X times faster than real time")
    run.add_argument("--sim", choices=("lab", "ideal"),
                     help="simulated cameras: the simulated bench's profile, 'lab' (a bench as built: the default) or "
                          "'ideal' (perfect mechanics, optics and boards); replaces [sim] profile, keeps its overrides")
    run.add_argument("--max-view-rms-px", type=finite_float(min=0.0, inclusive=(False, True), unit="px"), metavar="PX",
                     help="leave out of each configuration's calibration the views whose RMS (the worse camera's) "
                          "exceeds PX and calibrate again without them; replaces [calibration] max_view_rms_px")
    run.add_argument("--exclude-views", type=_view_list, metavar="N,N,...",
                     help="calibration views (indices within each configuration, from 0) left out of every "
                          "per-configuration calibration; replaces [calibration] exclude_views")
    run.add_argument("--no-review", action="store_true",
                     help="do not stop after each configuration's calibration for the operator's review of its "
                          "per-view errors (the default with v4l2 cameras); replaces [calibration] review")
    run.add_argument("--json", action="store_true",
                     help="print every document (start, events, results, stop) as one JSON line on stdout, as it "
                          "is recorded; the summary goes to stderr")
    run.add_argument("--quiet", action="store_true", help="no progress bar or per-configuration lines")
    add_ui_options(run)
    run.set_defaults(func=cmd_run)
