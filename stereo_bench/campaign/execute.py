"""Wiring: build the rig, cameras and presenter a campaign config asks for, run it, record it, replay it.

``run_campaign`` is what ``stereo-bench campaign run`` does; ``replay_session`` what ``stereo-bench
replay`` does. Both put the same :class:`~stereo_bench.campaign.runner.CampaignRunner` to work;
only the drivers behind the protocols differ (simulated bench, real hardware, recorded session).
"""

from __future__ import annotations

import contextlib
import math
import platform
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereo_bench import __version__
from stereo_bench.campaign.config import CampaignConfig
from stereo_bench.campaign.plan import expand_plan, plan_steps
from stereo_bench.campaign.presenters import OperatorPresenter, SimulatedPresenter
from stereo_bench.campaign.runner import CampaignRunner, RunnerOptions, group_steps
from stereo_bench.campaign.session import SessionReader, SessionWriter

RESULT_FIELDS_COMPARED = ("status", "square_mean_mm", "square_std_mm", "n_squares", "error_mm", "sigma_mm",
                          "rms_px", "epipolar_rms_px")


class OperatorAbsent(RuntimeError):
    """A manual step needs the operator but nobody can answer (no terminal)."""


def software_versions() -> dict:
    return {"stereo_bench": __version__, "opencv": cv2.__version__, "numpy": np.__version__,
            "python": platform.python_version()}


def terminal_prompt(message: str) -> None:
    """Ask the operator and wait for Enter."""
    try:
        input(f"\n>>> {message} ")
    except EOFError:
        raise OperatorAbsent(f"the campaign needs the operator here ({message!r}) but standard input is closed: "
                             "run it in a terminal, or pass --yes on the simulated rig") from None


@dataclass
class RunSummary:
    session: Path
    exit_status: str
    rows: list[dict] = field(default_factory=list)
    skipped: int = 0

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for row in self.rows:
            counts[row["status"]] = counts.get(row["status"], 0) + 1
        return counts


def _options(config: CampaignConfig, time_scale: float) -> RunnerOptions:
    from stereo_bench.vision.calibio import read_calibration, read_intrinsics

    extrinsics = config.extrinsics
    options = RunnerOptions(settle_s=config.capture.settle_s, board_retries=config.capture.board_retries,
                            time_scale=time_scale, intrinsics_mode=extrinsics.intrinsics)
    if extrinsics.mode == "fixed":
        optics = config.cameras.optics
        options.fixed_calibration = read_calibration(extrinsics.calib_dir, image_size=(optics.width_px,
                                                                                        optics.height_px))
    elif extrinsics.calib_dir is not None:
        options.intrinsics = read_intrinsics(extrinsics.calib_dir)[:4]
    return options


def run_campaign(
    config: CampaignConfig, out_dir: str | Path, *, resume: bool = False, yes: bool = False,
    prompt: Callable[[str], None] = terminal_prompt, on_result: Callable[[dict], None] | None = None,
    on_step: Callable | None = None, runner_hook: Callable[[CampaignRunner], None] | None = None,
) -> RunSummary:
    """Run (or resume) ``config`` into the session directory ``out_dir``."""
    configurations = expand_plan(config)
    steps = plan_steps(config, configurations)
    summary = RunSummary(session=Path(out_dir), exit_status="failed")
    with SessionWriter(out_dir, resume=resume) as writer:
        writer.start(config=config.model_dump(mode="json"), plan=[c.as_dict() for c in configurations],
                     software=software_versions())
        done = writer.completed_config_ids()
        summary.skipped = len(done)
        with contextlib.ExitStack() as stack:
            rig, cameras, presenter, time_scale = _hardware(config, writer, stack, yes=yes, prompt=prompt)
            options = _options(config, time_scale)

            def collect(row: dict) -> None:
                summary.rows.append(row)
                if on_result:
                    on_result(row)

            runner = CampaignRunner(config, configurations, steps, rig=rig, cameras=cameras, presenter=presenter,
                                    writer=writer, options=options, on_result=collect, on_step=on_step)
            if runner_hook:
                runner_hook(runner)
            if config.rig.homing:
                writer.event("home", data={"rig": rig.home().to_dict()})
            try:
                summary.exit_status = runner.run(skip=done)
            except BaseException as error:
                writer.stop(exit_status="failed", reason=f"{type(error).__name__}: {error}")
                raise
        writer.stop(exit_status=summary.exit_status,
                    reason="stopped by the operator" if summary.exit_status == "interrupted" else None)
    return summary


def _hardware(config: CampaignConfig, writer: SessionWriter, stack: contextlib.ExitStack, *, yes: bool,
              prompt: Callable[[str], None]):
    """(rig, stereo cameras, presenter, time_scale) for the config's rig and camera kinds, opened on ``stack``."""
    from drivers.camera.stereo import StereoCamera
    from drivers.rig.rig import GrblRig

    rig_config = config.rig.rig_config()
    optics = config.cameras.optics
    if config.rig.kind == "simulated":
        from drivers.sim.bench import SimulatedBench
        from drivers.sim.render import Optics

        bench = stack.enter_context(SimulatedBench(
            rig_config=rig_config, left=optics.camera_model("left"), right=optics.camera_model("right"),
            optics=Optics(noise_sigma_dn=optics.noise_dn, blur_sigma_px=optics.blur_px),
            time_scale=config.rig.time_scale, exposure_s=optics.exposure_s, homing_enabled=config.rig.homing,
            profile=config.sim.resolve(), seed=config.seed,
        ))
        rig_prompt = bench.operator_prompt if yes else prompt
        rig = stack.enter_context(GrblRig(bench.tty_path, rig_config, prompt=rig_prompt,
                                          spy_log=writer.transcript_path()))
        cameras = stack.enter_context(StereoCamera(*bench.cameras(), max_skew_s=config.cameras.max_skew_s))
        presenter = SimulatedPresenter(bench, config.calibration_board.build(), config.target.build(),
                                       seed=config.seed)
        return rig, cameras, presenter, config.rig.time_scale
    # The real bench.
    from drivers.camera.usb_identity import resolve_camera
    from drivers.camera.v4l2 import V4L2Camera

    rig = stack.enter_context(GrblRig(config.rig.port, rig_config, prompt=prompt, spy_log=writer.transcript_path()))
    settings = config.cameras.camera_settings()
    left = V4L2Camera(resolve_camera(config.cameras.left).capture_node, settings, name="left")
    right = V4L2Camera(resolve_camera(config.cameras.right).capture_node, settings, name="right")
    cameras = stack.enter_context(StereoCamera(left, right, max_skew_s=config.cameras.max_skew_s))
    presenter = OperatorPresenter(prompt, image_size=(optics.width_px, optics.height_px),
                                  target_description=config.target.describe())
    return rig, cameras, presenter, 1.0


# -- replay -------------------------------------------------------------------------------------------------------


class _ReplayPresenter:
    """Queues the recorded pair the runner is about to capture."""

    def __init__(self, cameras):
        self.cameras = cameras
        self.config_id = ""
        self.retries: Counter = Counter()

    def begin_configuration(self, config_id, pose, distance_mm, n_views, *, calibration_range_mm=None) -> None:
        self.config_id = config_id

    def present_calibration_view(self, index: int) -> None:
        self.cameras.expect(f"{self.config_id}/calibration_view/{index}")

    def calibration_view_captured(self, index, left, right) -> None:
        return None

    def present_target(self, frame_index: int) -> None:
        # The runner asks again for a frame whose target was not found: serve the recorded retries in turn.
        retry = self.retries[(self.config_id, frame_index)]
        self.retries[(self.config_id, frame_index)] += 1
        self.cameras.expect(f"{self.config_id}/measurement_frame/{frame_index}/{retry}")


class _MemoryWriter:
    """A writer that keeps results in memory: replay without --out records nothing."""

    attempt = 1

    def __init__(self):
        self.rows: dict[str, dict] = {}

    def event(self, *args, **kwargs) -> dict:
        return {}

    def write_calibration(self, *args, **kwargs) -> dict:
        return {}

    def result(self, config_id: str, row: dict) -> None:
        self.rows[config_id] = row


@dataclass
class ReplaySummary:
    compared: int
    identical: int
    differences: list[str]
    rows: list[dict]
    carried_over: int
    out: Path | None


def replay_session(session_dir: str | Path, out_dir: str | Path | None = None, *,
                   pipeline: dict | None = None) -> ReplaySummary:
    """Run a recorded session's frames and telemetry through the runner again.

    Without ``out_dir`` nothing is written and the results are compared with the recorded ones; with
    it, a new session is recorded there (frames copied, so it stands alone). ``pipeline`` overrides
    pipeline settings (e.g. ``{"extrinsics": {"intrinsics": "fixed"}}``) for a re-analysis.
    """
    from drivers.replay import ReplayRig, ReplayStereoCamera

    reader = SessionReader(session_dir)
    start = reader.start()
    recorded_config = dict(start["config"])
    for section, values in (pipeline or {}).items():
        recorded_config[section] = {**recorded_config.get(section, {}), **values}
    config = CampaignConfig.model_validate(recorded_config)
    configurations = expand_plan(config)
    recorded_rows = {row["config_id"]: row for row in reader.results()}
    measured = {cid for cid, row in recorded_rows.items() if row.get("status") == "measured"}
    steps = [s for cid, group in group_steps(plan_steps(config, configurations)) if cid in measured for s in group]

    frames: dict[str, dict] = {}
    readings = []
    for event in reader.events():
        cid = event.get("config_id")
        if cid not in measured:
            continue
        if event["kind"] == "move":
            readings.append(event["data"]["rig"])
        elif event["kind"] == "calibration_view":
            frames[f"{cid}/calibration_view/{event['data']['index']}"] = event
        elif event["kind"] == "measurement_frame":
            frames[f"{cid}/measurement_frame/{event['data']['index']}/{event['data'].get('retry', 0)}"] = event

    def load_pair(key: str):
        event = frames.get(key)
        if event is None:
            raise KeyError(f"{reader.directory}: recording holds no {key}")
        return reader.frame(event["frames"]["left"]), reader.frame(event["frames"]["right"]), event["data"]

    cameras = ReplayStereoCamera(load_pair)
    writer_context = SessionWriter(out_dir) if out_dir is not None else contextlib.nullcontext(_MemoryWriter())
    with writer_context as writer, ReplayRig(readings) as rig, cameras:
        if out_dir is not None:
            writer.start(config=config.model_dump(mode="json"), plan=[c.as_dict() for c in configurations],
                         software=software_versions(), extra={"replay_of": str(Path(session_dir).resolve())})
        options = _options(config, time_scale=math.inf)
        runner = CampaignRunner(config, configurations, steps, rig=rig, cameras=cameras,
                                presenter=_ReplayPresenter(cameras), writer=writer, options=options,
                                sleep=lambda s: None)
        status = runner.run()
        if out_dir is not None:
            for cid, row in recorded_rows.items():
                if cid not in measured:
                    writer.result(cid, {k: v for k, v in row.items() if not k.startswith("_")})
            writer.stop(exit_status=status)
            new_rows = {row["config_id"]: row for row in SessionReader(out_dir).results()}
        else:
            new_rows = writer.rows
    differences, identical = [], 0
    for cid in sorted(measured):
        new = new_rows.get(cid)
        if new is None:
            differences.append(f"{cid}: not reproduced")
            continue
        changed = [f"{key} {recorded_rows[cid].get(key)!r} -> {new.get(key)!r}" for key in RESULT_FIELDS_COMPARED
                   if not _same(recorded_rows[cid].get(key), new.get(key))]
        if changed:
            differences.append(f"{cid}: " + ", ".join(changed))
        else:
            identical += 1
    return ReplaySummary(compared=len(measured), identical=identical, differences=differences,
                         rows=list(new_rows.values()), carried_over=len(recorded_rows) - len(measured),
                         out=None if out_dir is None else Path(out_dir))


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def replay_job(job: tuple[str, str | None, dict]) -> dict:
    """One replay as a picklable job for an executor: (session, out or None, pipeline) -> JSON-ready summary.

    Errors come back as data (``error``) so one bad session does not sink a batch.
    """
    from stereo_bench.campaign.session import SessionError

    session, out, pipeline = job
    try:
        summary = replay_session(session, out, pipeline=pipeline)
    except (SessionError, KeyError, OSError) as error:
        return {"session": session, "out": out, "error": str(error).strip("'\"")}
    return {"session": session, "out": out, "compared": summary.compared, "identical": summary.identical,
            "differences": summary.differences, "carried_over": summary.carried_over, "pipeline": pipeline}
