"""Small campaigns the campaign tests share (simulated rig, half-resolution cameras: seconds, not minutes)."""

from __future__ import annotations

import csv
import json
import tomllib
from functools import cache
from pathlib import Path

import numpy as np

from stereo_bench.campaign.config import CampaignConfig, campaign_from_dict
from stereo_bench.frames import decode_frame

SAMPLE_SESSION = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"


@cache
def sample_session_frames(every: int) -> tuple[np.ndarray, ...]:
    """Every ``every``-th frame file of the shipped sample session (sorted paths), decoded as a replay decodes
    it; shared by the tests, so never write into them."""
    paths = sorted((SAMPLE_SESSION / "frames").rglob("*.png"))[::every]
    return tuple(decode_frame(path.read_bytes(), str(path)) for path in paths)

# Two baselines x two angles at one distance: alpha = 90 measured, alpha = 35 infeasible.
SMALL = """
name = "small"
seed = 7
[rig]
time_scale = 50
[cameras.optics]
width_px = 960
height_px = 540
pixel_um = 6.0
[calibration_board]
cols = 9
rows = 6
square_mm = 25
[capture]
calibration_views = 6
frames_per_config = 2
settle_s = 0.1
[sim]
profile = "ideal"  # the nominal geometry; the lab bench reproduces as exactly (LAB below)
[plan]
baseline_mm = [100, 150]
distance_mm = [450]
alpha_deg = [90, 35]
"""


# The small campaign on the lab bench (backlash, landing errors, ringing for 0.24 s after a move, placement errors),
# with a settle shorter than the ringing: four measured configurations at one distance (one target placement),
# visited B100/A90, B100/A87, B150/A87, B150/A90, so that a resume must re-approach the slide and the heads.
LAB = (SMALL.replace('profile = "ideal"  # the nominal geometry; the lab bench reproduces as exactly (LAB below)',
                     'profile = "lab"')
       .replace("seed = 7", "seed = 1").replace("alpha_deg = [90, 35]", "alpha_deg = [90, 87]"))


def lab_config(**sections) -> CampaignConfig:
    """:data:`LAB` with ``sections`` merged in (as :func:`small_config`)."""
    return small_config(_text=LAB, **sections)


def small_config(_text: str = SMALL, **sections) -> CampaignConfig:
    data = tomllib.loads(_text)
    for name, values in sections.items():
        data[name] = {**data.get(name, {}), **values} if isinstance(values, dict) else values
    return campaign_from_dict(data)


def results_csv(session: Path) -> list[dict]:
    with open(session / "results.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def numbers(session: Path) -> dict[str, tuple]:
    """What must be identical between two recordings of the same campaign, per configuration."""
    return {row["config_id"]: (row["status"], row["square_mean_mm"], row["square_std_mm"], row["sigma_mm"],
                               row["rms_px"]) for row in results_csv(session)}


def recorded_outcome(session: Path, *, clock: bool = True) -> tuple[dict, dict]:
    """What a run of a campaign on a simulated bench must reproduce: per configuration every results.csv column
    but when and in which attempt it was recorded, and the bench's truth at its measurement (``clock``: with
    the bench time it was taken at, which a resume reaches by another way)."""
    from stereo_bench.campaign.session import SessionReader

    rows = {row["config_id"]: {k: v for k, v in row.items() if k not in ("time", "attempt")}
            for row in results_csv(session)}
    truths = {event.config_id: {k: v for k, v in event.data.model_dump().items() if clock or k != "sim_time_s"}
              for event in SessionReader(session).events(kind="truth")}
    return rows, truths


def motion_commands(path: Path) -> list[str]:
    """The lines of a session's serial transcript that move the rig (homing, G0/G1): queries such as
    ``$I``/``$$``/``$N`` at connect move nothing."""
    return [line for line in transcript_commands(path)
            if line.startswith("$H") or any(word in line.split() for word in ("G0", "G1"))]


def transcript_commands(path: Path) -> list[str]:
    """The lines a session's serial transcript sent to the controller (real-time bytes left out)."""
    sent = []
    for line in path.read_text().splitlines():
        record = json.loads(line)
        if record.get("dir") == "tx" and record["data"].endswith("\n"):
            sent.append(record["data"].strip())
    return sent



def act_at_move(number: int, action):
    """A bench factory (``run_campaign(bench_factory=...)``) whose rig calls ``action()`` at the end of its
    ``number``-th move, as an operator's Stop or Pause button would. Deterministic where a subscriber is not:
    the runner publishes documents on the recorder's thread, so a subscriber may see a move only after the
    run has gone past it (and, on a loaded machine, after the last configuration)."""
    from stereo_bench.campaign.bench import simulated_bench

    def factory(config, **options):
        bench = simulated_bench(config, **options)
        move_to, moves = bench.rig.move_to, []

        def counted(**targets):
            moves.append(targets)
            result = move_to(**targets)
            result.wait()  # the action comes once the move has ended (move_to returns its status at once)
            if len(moves) == number:
                action()
            return result

        bench.rig.move_to = counted
        return bench

    return factory


def stop_at_move(control, number: int):
    """:func:`act_at_move` asking ``control`` to stop."""
    return act_at_move(number, control.request_stop)


def interrupt_at_presentation(control, method: str, number: int):
    """A bench factory whose presenter, at the ``number``-th call of ``method`` (e.g. "present_target",
    "present_calibration_view"), asks ``control`` to stop and then raises KeyboardInterrupt: a Ctrl-C and,
    while that stop is pending, the second one that stops at once."""
    from stereo_bench.campaign.bench import simulated_bench

    def factory(config, **options):
        bench = simulated_bench(config, **options)
        presenter, calls = bench.presenter, []
        present = getattr(presenter, method)

        def interrupted(index):
            calls.append(index)
            if len(calls) == number:
                control.request_stop("stopped by SIGINT")
                raise KeyboardInterrupt
            present(index)

        setattr(presenter, method, interrupted)
        return bench

    return factory
