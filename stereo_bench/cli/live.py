"""`stereo-bench live`: the live page with no campaign, to aim the cameras and look at the rig.

Works on the simulated bench by default (the emulated rig homes and moves to --baseline/--alpha and
the measured target stands at --distance, so the previews show what a campaign would see), and on
the real one with --port (the GRBL controller; --rig-config for its axis mapping) and --cameras
LEFT RIGHT (stable camera names, as in a campaign file). A campaign file gives all of it at once.
Nothing is recorded; Ctrl-C ends it.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from stereo_bench.cli import stop_on_signals
from stereo_bench.cli.args import ALPHA_DEG, BASELINE_MM, DISTANCE_MM, TIME_SCALE
from stereo_bench.cli.campaign_run import add_ui_options, announce_live_page


def live_config(args: argparse.Namespace):
    """The campaign config the preview opens its bench from: a campaign file (or the defaults), the options applied."""
    from stereo_bench.campaign.config import campaign_from_dict, load_campaign
    from stereo_bench.geometry import PARALLEL_ALPHA_DEG

    base = load_campaign(Path(args.campaign)) if args.campaign else None
    data = base.model_dump(mode="json", exclude_none=True) if base is not None else {}
    rig = dict(data.get("rig", {}))
    cameras = dict(data.get("cameras", {}))
    if args.port:
        rig.update(kind="grbl", port=args.port)
    if args.rig_config:
        rig["config_file"] = str(Path(args.rig_config).resolve())
        rig.pop("quantities", None)
        rig.pop("controller", None)
    if args.time_scale is not None:
        rig["time_scale"] = args.time_scale
    if args.cameras:
        cameras.update(kind="v4l2", left=args.cameras[0], right=args.cameras[1])
    plan = dict(data.get("plan", {}))
    # The file's first angle, as alpha (the plan's own reading of alpha_deg or toe_in_deg): live sets alpha_deg, so
    # a file's toe_in_deg is dropped (both given: refused).
    first_alpha = base.plan.angles_deg()[0][0] if base is not None else PARALLEL_ALPHA_DEG
    plan.pop("toe_in_deg", None)
    plan.update(baseline_mm=[args.baseline if args.baseline is not None else (plan.get("baseline_mm") or [100.0])[0]],
                distance_mm=[args.distance if args.distance is not None else (plan.get("distance_mm") or [500.0])[0]],
                alpha_deg=[args.alpha if args.alpha is not None else first_alpha])
    data.update(rig=rig, cameras=cameras, plan=plan, name=data.get("name", "live preview"))
    for key in ("tilt_deg",):
        plan.pop(key, None)
    return campaign_from_dict(data, source=args.campaign or "live options")


def cmd_live(args: argparse.Namespace) -> int:
    from drivers.rig.config import plan_move
    from stereo_bench.campaign.bench import open_bench
    from stereo_bench.campaign.execute import CampaignPlan
    from stereo_bench.live.page import LivePage

    config = live_config(args)
    plan = CampaignPlan.of(config)
    configuration = plan.configurations[0]
    rig_config = config.rig.rig_config()
    request = {q: v for q, v in configuration.move_request().items() if rig_config.quantities[q].driven}
    plan_move(rig_config, request)  # outside the soft limits: refused (one line) before anything opens
    page = LivePage.for_campaign(config, session_dir=None, host=args.ui_host, port=args.ui_port)
    page.state.run.update(status="live preview", name=config.name)
    page.start()  # the address first: one it cannot serve on is one line (LiveServerError), before the rig moves
    stop = threading.Event()
    previous = stop_on_signals(stop)
    try:
        # The URL once the bench is open: a rig or camera that is not there is one line (exit status 2).
        with open_bench(config, operators=[], transcript=page.state.transcript) as bench:
            announce_live_page(page)
            page.use_bench(bench)
            simulated = config.cameras.kind == "simulated"
            wants_move = simulated or any(v is not None for v in (args.baseline, args.alpha))
            if wants_move and not args.no_move:
                if config.rig.homing:
                    bench.rig.home()
                elif bench.rig.capabilities.trust_position:
                    bench.rig.trust_position()  # [rig] homing = false: the position is right as it is (docs/RIG.md)
                bench.rig.move_to(**request).wait()
            if simulated:  # the measured target where the campaign would put it
                bench.presenter.begin_configuration(configuration)
                bench.presenter.present_target(0)
            print(f"previewing {configuration.config_id} ({bench.kind} bench); Ctrl-C to end", file=sys.stderr)
            with bench.camera_gate.lent():  # no runner: the cameras are the page's
                while not stop.wait(0.5):
                    with bench.camera_gate.borrowed():
                        bench.rig.read()  # a status report: the page's rig state and position
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        page.stop()
    return 0


def register(subparsers) -> None:
    live = subparsers.add_parser(
        "live", help="the live page without a campaign: aim the cameras, watch the rig",
        description=__doc__.split("\n\n")[1].replace("\n", " ") + " Prints the page's URL.",
    )
    live.add_argument("campaign", nargs="?", metavar="CAMPAIGN.toml",
                      help="take rig, cameras and boards from this campaign file (its first configuration)")
    live.add_argument("--port", metavar="PORT", help="the real rig: the GRBL controller's serial device")
    live.add_argument("--rig-config", metavar="FILE", help="rig configuration TOML (axis mapping, soft limits)")
    live.add_argument("--cameras", nargs=2, metavar=("LEFT", "RIGHT"),
                      help="the real cameras, by stable name (e.g. usb-port:1-2 usb-port:1-3, by-id:...)")
    live.add_argument("--baseline", type=BASELINE_MM, metavar="MM",
                      help="move the baseline here first (default 100 mm)")
    live.add_argument("--alpha", type=ALPHA_DEG, metavar="DEG",
                      help="turn both cameras to this alpha first (default 90)")
    live.add_argument("--distance", type=DISTANCE_MM, metavar="MM",
                      help="simulated bench: where the measured target stands (default 500 mm)")
    live.add_argument("--no-move", action="store_true", help="do not home or move the rig")
    live.add_argument("--time-scale", type=TIME_SCALE, metavar="X", help="simulated rig: motion X times faster")
    add_ui_options(live, required=True)
    live.set_defaults(func=cmd_live)
