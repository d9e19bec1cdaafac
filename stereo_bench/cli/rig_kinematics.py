"""``stereo-bench rig calibrate-kinematics``: visit the kinematic rig model's design only, fit it, write the model.

    stereo-bench rig calibrate-kinematics --out sessions/kin --yes                     # the simulated lab bench
    stereo-bench rig calibrate-kinematics --preset paper-exp2-toe-in --out s --yes     # the design a campaign needs
    stereo-bench rig calibrate-kinematics --design fixed-board --calib-dir lens/ --out s --yes  # a board placed once
    stereo-bench rig --port /dev/ttyUSB0 --rig-config rig.toml calibrate-kinematics --config bench.toml --out s

It is a campaign of visits only (recorded as a session: every view, the rig's telemetry, the fitted model),
over the design :func:`stereo_bench.campaign.plan.plan_visits` chooses for the campaign's plan (or for
``--baseline-range`` / ``--toe-in-range``). The model is written to ``--model`` (default
``OUT/kinematic_model.toml``), ready for a campaign's ``[extrinsics] kinematic_file``. On the simulated
bench by default; ``--port`` drives a real controller (cameras from the config: ``[cameras] kind = "v4l2"``
at the real bench, where the operator presents the calibration board).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from pathlib import Path

from stereo_bench.cli import EXIT_FAILED, EXIT_INTERRUPTED, STOP_SIGNALS, CliError, failure, hung_up
from stereo_bench.cli.args import BASELINE_MM, DISTANCE_MM, TILT_DEG, TIME_SCALE, TOE_IN_DEG, check_range, output_dir
from stereo_bench.paths import UnwritablePath, check_output_file, is_inside


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise CliError(f"rig calibrate-kinematics: {message}")


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog="stereo-bench rig calibrate-kinematics",
                description="Visit the kinematic rig model's design (9 configurations x the calibration views), fit "
                            "the model in one joint adjustment and write it (every parameter with its sigma) for "
                            "[extrinsics] kinematic_file. Records a session in --out. Simulated bench unless "
                            "`rig --port` is given.")
    p.add_argument("--config", type=Path, metavar="FILE", help="campaign file: its plan's range, boards, cameras")
    p.add_argument("--preset", metavar="NAME", help="a built-in campaign instead of --config")
    p.add_argument("--baseline-range", type=BASELINE_MM, nargs=2, metavar=("MIN", "MAX"),
                   help="baselines the model must cover, mm (default: the campaign's, else 50 250)")
    p.add_argument("--toe-in-range", type=TOE_IN_DEG, nargs=2, metavar=("MIN", "MAX"),
                   help="toe-ins the model must cover, deg (default: the campaign's, else 0 20)")
    p.add_argument("--tilt-range", type=TILT_DEG, nargs=2, metavar=("MIN", "MAX"),
                   help="fixed-board on a rig that drives the tilts (grblHAL's A/B): tilts the model must cover, deg "
                        "(default: the campaign's; a span under 10 deg is widened to 10 about its middle). The design "
                        "steps them and the model has tilt joints unless the campaign says [extrinsics] design_tilt = "
                        "\"hold\"")
    p.add_argument("--distance", type=DISTANCE_MM, metavar="MM",
                   help="where the calibration board is shown, mm (default: the middle of the campaign's distances)")
    p.add_argument("--design", choices=("presented", "fixed-board"),
                   help="presented: the board presented at every design visit; fixed-board: placed once, the rig "
                        "moves in front of it (default: the campaign's [extrinsics] design, else presented)")
    p.add_argument("--calib-dir", type=Path, metavar="DIR",
                   help="fixed-board: a lens calibration (intrinsics.yml with its covariance) as the fit's prior")
    p.add_argument("--out", required=True, type=lambda text: Path(output_dir(text)), metavar="DIR",
                   help="session directory (never overwritten)")
    p.add_argument("--model", type=Path, metavar="FILE",
                   help="where to write the model (default OUT/kinematic_model.toml)")
    p.add_argument("--yes", action="store_true", help="simulated cameras: the simulator presents the boards")
    p.add_argument("--time-scale", type=TIME_SCALE, metavar="X", help="simulated rig: X times faster than real time")
    p.add_argument("--sim", choices=("lab", "ideal"), help="simulated cameras: the bench's profile")
    p.add_argument("--json", action="store_true", help="print one JSON object (the model's summary) on stdout")
    return p


def _config(args, port: str | None, rig_config: Path | None):
    """The campaign config of the design: the file's or preset's, extrinsics kinematic, the ranges applied."""
    from drivers.files import InputFileError, parse_toml, read_toml
    from stereo_bench.campaign.config import campaign_from_dict, preset_text

    if args.config is not None and args.preset is not None:
        raise CliError("rig calibrate-kinematics: give --config FILE or --preset NAME, not both")
    try:
        if args.config is not None:
            data = read_toml(args.config, what="campaign file")
        elif args.preset is not None:
            data = parse_toml(preset_text(args.preset), f"preset {args.preset}")
        else:
            data = {}
    except InputFileError as error:
        raise CliError(f"--config {error}") from None
    base = bool(data)
    plan = dict(data.get("plan") or {"distance_mm": [500.0]})
    if not base or args.baseline_range:
        plan["baseline_mm"] = sorted(set(args.baseline_range or (50.0, 250.0)))
    if not base or args.toe_in_range:
        plan.pop("alpha_deg", None)
        plan["toe_in_deg"] = sorted(set(args.toe_in_range or (0.0, 20.0)))
    if args.distance is not None:
        plan["distance_mm"] = [args.distance]
    if args.tilt_range:
        plan.pop("tilt_deg", None)
        plan["tilts_deg"] = sorted(set(args.tilt_range))
    data["plan"] = plan
    extrinsics = {key: value for key, value in (data.get("extrinsics") or {}).items() if key != "kinematic_file"}
    data["extrinsics"] = {**extrinsics, "mode": "kinematic"}
    if extrinsics.get("design_tilt") != "hold":
        # A model file serves later campaigns at any tilt: on a rig that drives the tilts, fit their joints.
        data["extrinsics"]["design_tilt"] = "include"
    if args.design is not None:
        data["extrinsics"]["design"] = args.design
    if args.calib_dir is not None:
        data["extrinsics"]["calib_dir"] = str(os.path.abspath(args.calib_dir))
    data.setdefault("name", "calibrate-kinematics")
    rig = dict(data.get("rig") or {})
    if port is not None:
        rig.update(kind="grbl", port=port)
        rig.pop("time_scale", None)
    if rig_config is not None:
        rig["config_file"] = str(rig_config)
        rig.pop("controller", None)
        rig.pop("quantities", None)
    if args.time_scale is not None:
        rig["time_scale"] = args.time_scale
    data["rig"] = rig
    if args.sim is not None:
        data["sim"] = {**(data.get("sim") or {}), "profile": args.sim}
    source = str(args.config) if args.config is not None else f"preset {args.preset}" if args.preset else \
        "rig calibrate-kinematics"
    return campaign_from_dict(data, source=source, base_dir=args.config.parent if args.config is not None else None)


def _model_path(args) -> Path:
    """Where the model will be written, checked before the first move or presentation (the design is 9 visits of
    boards presented by hand at a real rig: a path that cannot be written must fail now, not after them)."""
    model_path = args.model or args.out / "kinematic_model.toml"
    try:
        check_output_file(model_path, option="--model", will_create=args.out)
    except UnwritablePath as error:
        raise CliError(str(error)) from None
    out = Path(os.path.abspath(args.out))
    if is_inside(out, Path(os.path.abspath(model_path))) and (
            Path(os.path.abspath(model_path.parent)) != out or model_path.suffix != ".toml"):
        raise CliError(f"--model {model_path}: lies inside the session --out {args.out} records; give a .toml file "
                       "directly in it (the default kinematic_model.toml) or outside it")
    return model_path


def run(argv: list[str], *, port: str | None, rig_config: Path | None) -> int:
    """``rig calibrate-kinematics`` with its own options ``argv``; ``port``/``rig_config``: the rig group's."""
    from drivers.camera.base import CameraError
    from drivers.rig.config import RigError
    from stereo_bench.campaign.documents import KinematicModelEvent
    from stereo_bench.campaign.execute import CampaignPlan, RunControl, run_campaign
    from stereo_bench.campaign.extrinsics_run import recorded_sources
    from stereo_bench.campaign.plan import visits_problem
    from stereo_bench.campaign.plan.summary import extrinsics_prediction
    from stereo_bench.campaign.session import SessionReader
    from stereo_bench.cli.campaign import predicted_extrinsics_text
    from stereo_bench.cli.campaign_run import stopped_note
    from stereo_bench.kinematics import save_model

    args = parser().parse_args(argv)
    for option in ("baseline_range", "toe_in_range", "tilt_range"):
        check_range(getattr(args, option), "--" + option.replace("_", "-"))
    config = _config(args, port, rig_config)
    model_path = _model_path(args)
    if args.yes and config.cameras.kind != "simulated":
        raise CliError("--yes lets the simulator present the boards, for simulated cameras only")
    full = CampaignPlan.of(config)
    if not any(visit.runnable for visit in full.visits):
        problem = visits_problem(config, full.visits) or "no design visit: no runnable configuration in the plan"
        raise CliError(f"rig calibrate-kinematics: {problem}")
    plan = CampaignPlan.design_only(full)
    control = RunControl()

    def on_signal(signum, frame) -> None:
        if signum == signal.SIGHUP:
            hung_up()
        control.request_stop(f"stopped by {signal.Signals(signum).name}")

    previous = {sig: signal.signal(sig, on_signal) for sig in STOP_SIGNALS}
    started = time.monotonic()
    fixed = config.extrinsics.fixed_board
    views = config.extrinsics.fixed_board_views if fixed else config.capture.calibration_views
    design = [v for v in plan.visits if v.purpose == "kinematic"]
    lens = [v for v in plan.visits if v.purpose == "intrinsics"]  # a fixed-board design's lens calibration first
    print(f"kinematic design{' (fixed board: placed once)' if fixed else ''}: {sum(v.runnable for v in design)} "
          f"visits x {views} views on the {config.bench_kind} bench"
          + (f", after a lens calibration of {config.capture.calibration_views} presented views at "
             f"{lens[0].config_id}" if lens else "") + f"; recording {args.out}", file=sys.stderr, flush=True)
    try:
        summary = run_campaign(config, args.out, yes=args.yes, control=control, plan=plan)
    except (RigError, CameraError) as error:  # as campaign run: a port or camera not there 2, a fault in work 1
        mapped = failure(error)
        raise CliError(f"{mapped} ({stopped_note(args.out, None)})", exit_code=mapped.exit_code) from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if summary.exit_status == "interrupted":
        print(f"interrupted: {summary.reason}; the design's views are in {args.out}", file=sys.stderr)
        return EXIT_INTERRUPTED
    if summary.exit_status == "failed" and summary.reason:  # the rig failed and could not be recovered
        raise CliError(f"{summary.reason} (session {args.out} stopped as failed)", exit_code=EXIT_FAILED)
    reader = SessionReader(args.out)
    optics = config.cameras.optics
    size = (optics.width_px, optics.height_px)
    model = recorded_sources(reader, sources=("design",), image_size=size).kinematic_model
    if model is None:
        errors = [e.data.error for e in reader.events(kind=KinematicModelEvent, attempt=None)]
        raise CliError(f"kinematic fit failed: {errors[-1] if errors else 'no model recorded'} (session {args.out})",
                       exit_code=1)
    save_model(model, model_path)
    fit = model.fit
    # What the model's R, T are worth where the campaign will measure (the fit's covariance, its own corner noise).
    predicted = extrinsics_prediction(model, full.steps)
    summary_out = {"model": str(model_path), "session": str(args.out), "views": fit.n_views,
                   "visits": fit.n_configurations, "rms_px": fit.rms_px, "elapsed_s": time.monotonic() - started,
                   "parameters": {name: {"value": p.value, "sigma": p.sigma, "unit": p.unit,
                                         "identifiable": p.identifiable} for name, p in model.parameters.items()},
                   "predicted_extrinsics": predicted}
    if args.json:
        print(json.dumps(summary_out))
    else:
        print(f"kinematic model fitted to {fit.n_views} views at {fit.n_configurations} visits (RMS {fit.rms_px:.3f} "
              f"px) in {summary_out['elapsed_s']:.0f} s")
        for name, p in model.parameters.items():
            held = f"({p.note})" if p.note else "(held nominal: not identifiable by this design)"
            sigma = f"+- {p.sigma:.3g}" if p.sigma is not None else held
            print(f"  {name:<24} {p.value:12.5g} {p.unit:<4} {sigma}")
        if predicted:
            for line in predicted_extrinsics_text(predicted, f"the fitted model, its {fit.pixel_sigma_px:.3g} px "
                                                              "corner sigma"):
                print(line)
        print(f"model:   {model_path}  (use it: [extrinsics] mode = \"kinematic\", kinematic_file = \"{model_path}\")")
        print(f"session: {args.out}/")
    return 0


__all__ = ["parser", "run"]
