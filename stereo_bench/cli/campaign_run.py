"""`stereo-bench campaign run`: run a campaign (or resume one) on the simulated or the real rig."""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from stereo_bench.cli import CliError


def _load(args: argparse.Namespace):
    from stereo_bench.campaign.config import ConfigError, load_campaign, load_preset

    if bool(args.plan) == bool(args.preset):
        raise CliError("give a PLAN.toml or --preset NAME (one of them)")
    try:
        config = load_preset(args.preset) if args.preset else load_campaign(args.plan)
    except (ConfigError, FileNotFoundError) as error:
        raise CliError(str(error)) from None
    if args.time_scale is not None:
        if config.rig.kind != "simulated":
            raise CliError("--time-scale applies to the simulated rig only")
        config = config.model_copy(update={"rig": config.rig.model_copy(update={"time_scale": args.time_scale})})
    if args.sim is not None:
        if not config.fully_simulated:
            raise CliError("--sim applies to the simulated rig and cameras only")
        config = config.model_copy(update={"sim": config.sim.model_copy(update={"profile": args.sim})})
    return config


def _format_row(row: dict) -> str:
    head = (f"{row['config_id']:>16s}  B {row['baseline_mm']:6.1f}  Z {row['distance_mm']:6.1f}  "
            f"alpha {row['alpha_deg']:5.1f}")
    if row["status"] == "measured":
        return (f"{head}  square {row['square_mean_mm']:8.4f} mm  error {row['error_mm']:+.4f} "
                f"+- {row['sigma_mm']:.4f} mm  (n {row['n_squares']}, RMS {row['rms_px']:.3f} px)")
    return f"{head}  {row['status'].upper()}: {row.get('reason')}"


def cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from stereo_bench.campaign.execute import OperatorAbsent, run_campaign
    from stereo_bench.campaign.plan import Move, expand_plan
    from stereo_bench.campaign.session import SessionError

    config = _load(args)
    out = Path(args.out)
    if args.yes and config.rig.kind != "simulated":
        raise CliError("--yes answers manual steps for the simulator only; at the real bench the operator does them")
    n_configurations = len(expand_plan(config))
    bar = tqdm(total=n_configurations, unit="config", disable=args.quiet, dynamic_ncols=True,
               desc=config.name, file=sys.stderr)
    state = {"runner": None, "stops": 0}

    def on_result(row: dict) -> None:
        bar.update(1)
        if not args.quiet:
            tqdm.write(_format_row(row), file=sys.stderr)

    def on_step(step) -> None:
        if isinstance(step, Move):
            c = step.configuration
            bar.set_postfix_str(f"moving to B {c.baseline_mm:g} mm, Z {c.distance_mm:g} mm, alpha {c.alpha_deg:g}")

    def on_sigint(signum, frame) -> None:
        state["stops"] += 1
        if state["stops"] > 1 or state["runner"] is None:
            raise KeyboardInterrupt
        tqdm.write("stopping at the next safe point (feed hold sent); Ctrl-C again to abort at once", file=sys.stderr)
        state["runner"].request_stop()

    previous = signal.signal(signal.SIGINT, on_sigint)
    started = time.monotonic()
    try:
        summary = run_campaign(config, out, resume=args.resume, yes=args.yes, on_result=on_result, on_step=on_step,
                               runner_hook=lambda runner: state.update(runner=runner))
    except SessionError as error:
        raise CliError(str(error)) from None
    except OperatorAbsent as error:
        raise CliError(str(error)) from None
    finally:
        signal.signal(signal.SIGINT, previous)
        bar.close()
    counts = summary.counts()
    elapsed = time.monotonic() - started
    parts = ", ".join(f"{n} {status}" for status, n in sorted(counts.items()))
    print(f"campaign {summary.exit_status} in {elapsed:.0f} s: {parts or 'nothing run'}"
          + (f" ({summary.skipped} already complete)" if summary.skipped else ""))
    print(f"session:  {out}/  (documents.jsonl, frames/, calib/, results.sqlite)")
    print(f"results:  {out / 'results.csv'}")
    print(f"report:   stereo-bench report {out}")
    if summary.exit_status == "interrupted":
        print(f"resume:   stereo-bench campaign run {args.plan or '--preset ' + args.preset} --out {out} --resume")
        return 130
    return 0 if counts.get("measured", 0) or not counts else 1


def register_run(subparsers) -> None:
    run = subparsers.add_parser(
        "run", help="run a campaign on the simulated or the real rig, recording a session",
        description="Drive the rig through every configuration of the plan: move, settle, flush, calibrate "
                    "(per-config extrinsics), capture and measure the square; record everything in --out. "
                    "Ctrl-C stops at the next safe point; --resume continues an interrupted session.",
    )
    run.add_argument("plan", nargs="?", metavar="PLAN.toml", help="campaign file")
    run.add_argument("--preset", metavar="NAME", help="a built-in campaign (see: stereo-bench campaign presets)")
    run.add_argument("--out", required=True, metavar="DIR", help="session directory (never overwritten)")
    run.add_argument("--resume", action="store_true", help="continue the interrupted session in --out")
    run.add_argument("--yes", action="store_true",
                     help="simulated rig: let the simulator do the manual steps (moving the target) instead of "
                          "asking")
    run.add_argument("--time-scale", type=float, metavar="X",
                     help="simulated rig: run motion and exposures X times faster than real time")
    run.add_argument("--sim", choices=("lab", "ideal"),
                     help="simulated bench: 'lab' (a bench as built: the default) or 'ideal' (perfect mechanics, "
                          "optics and boards); replaces [sim] profile, keeps its overrides")
    run.add_argument("--quiet", action="store_true", help="no progress bar or per-configuration lines")
    run.set_defaults(func=cmd_run)
