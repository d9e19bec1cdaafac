"""How long one presentation of the calibration board takes, measured by a run and read by the next plan.

At a real bench the operator is most of the campaign (``paper-exp1``: 300 presentations); the plan assumed 5 s each
(:data:`~stereo_bench.campaign.plan.timing.OPERATOR_S_PER_CALIBRATION_VIEW`). A run records, per configuration, how
long the presentations took (a ``presentation_time`` event: from the first view asked for to the last one taken,
on the operator's wall clock at a real bench, on the bench clock on the simulated one, where the simulated hand
presents), and at its end writes their total to ``presentation_time.json`` **beside the session directory** (in
the directory that holds the sessions, ``--out``'s parent). The next ``campaign plan ... --out DIR`` and ``campaign
run`` (its ETA) read the file beside their ``--out`` and use its seconds per view instead of the assumed 5 s, and
say where the figure came from.

The same file carries the operator's other hand work a real bench timed (prompts answered by a person, not the
simulator, with real cameras: on the simulated bench the scene is placed by the simulator and a prompt's wait
says nothing about a bench): seconds per target move (``target`` prompts) and per fixed-board placement
(``fixed_board`` prompts), which replace the plan's assumed 30 s and 20 s. A run that presented no view by hand
but timed a placement (a fixed-board campaign) writes the file with ``seconds_per_view`` null.

    measured = PresentationTime.of_events(events, session="2026-11-21")   # None: nothing presented by hand
    write_beside(session_dir, measured)                                   # -> session_dir.parent / FILE_NAME
    found = read_beside(out_dir)                                          # (PresentationTime | None, note | None)
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from stereo_bench import atomic

FILE_NAME = "presentation_time.json"
#: Larger files are not a presentation-time record (it is ~300 bytes): refused before parsing.
MAX_FILE_BYTES = 64 * 1024


class PresentationTime(BaseModel):
    """Seconds per calibration-board presentation, measured by one run (``presentation_time.json``)."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    schema_version: Literal[1] = 1
    seconds_per_view: float | None = Field(gt=0, description="seconds per view presented, s (null: none presented)")
    views: int = Field(ge=0, description="views presented in the run it was measured in")
    seconds: float = Field(ge=0, description="their presentation time in total, s")
    seconds_per_target_move: float | None = Field(None, gt=0, description="seconds per target move done by a "
                                                  "person at a real bench, s (null: none timed)")
    target_moves: int = Field(0, ge=0, description="target moves timed")
    seconds_per_placement: float | None = Field(None, gt=0, description="seconds per fixed-board placement done by "
                                                "a person at a real bench, s (null: none timed)")
    placements: int = Field(0, ge=0, description="fixed-board placements timed")
    capture: Literal["auto", "enter", "mixed"] = Field(description="how the views were taken")
    clock: Literal["bench", "wall", "mixed"] = Field(
        description="whose seconds: the operator's wall clock (a real bench) or the simulated bench's clock")
    session: str = Field(description="the session directory it was measured in (its name)")
    measured_at: str = Field(description="when the run ended (UTC, ISO 8601)")

    @classmethod
    def of_events(cls, events: Iterable, *, session: str, prompts: Iterable = (),
                  real_scene: bool = False) -> PresentationTime | None:
        """The total of a run's ``presentation_time`` events (:class:`PresentationTimeEvent`) and, with
        ``real_scene`` (real cameras), the waits of its ``target`` and ``fixed_board`` prompts (``PromptEvent``)
        that a person answered; None when nothing was timed."""
        data = [event.data for event in events]
        views = sum(d.views for d in data)
        seconds = sum(d.seconds for d in data)
        timed: dict[str, list[float]] = {"target": [], "fixed_board": []}
        if real_scene:
            for event in prompts:
                prompt = event.data
                if prompt.prompt in timed and prompt.answered_by != "simulator" and prompt.waited_s > 0:
                    timed[prompt.prompt].append(prompt.waited_s)
        presented = views > 0 and seconds > 0
        if not presented and not any(timed.values()):
            return None
        captures, clocks = {d.capture for d in data}, {d.clock for d in data}
        if any(timed.values()):
            clocks.add("wall")
        moves, placed = timed["target"], timed["fixed_board"]
        return cls(seconds_per_view=seconds / views if presented else None, views=views, seconds=seconds,
                   seconds_per_target_move=sum(moves) / len(moves) if moves else None, target_moves=len(moves),
                   seconds_per_placement=sum(placed) / len(placed) if placed else None, placements=len(placed),
                   capture=captures.pop() if len(captures) == 1 else ("mixed" if captures else "enter"),
                   clock=clocks.pop() if len(clocks) == 1 else "mixed", session=session,
                   measured_at=datetime.now(UTC).isoformat(timespec="seconds"))

    def describe(self) -> str:
        """Where the figure comes from, for the plan's assumptions: 'measured 2.31 s per view (auto, bench clock)
        over 96 views of session x on 2026-12-03T08:10:00+00:00'."""
        clock = {"bench": "the simulated bench's clock", "wall": "the operator's wall clock",
                 "mixed": "bench and wall clocks"}[self.clock]
        if self.seconds_per_view is None:
            return f"no calibration view presented by hand in session {self.session} at {self.measured_at}"
        return (f"{self.seconds_per_view:.2f} s per calibration view presented by hand, measured over {self.views} "
                f"views ({self.capture} capture, {clock}) in session {self.session} at {self.measured_at}")

    def describe_prompts(self) -> list[str]:
        """The operator's other hand work this run timed: ['31.2 s per target move, measured over 5 moves in
        session x', ...]; [] when none was timed."""
        out = []
        for what, seconds, count, noun in (("target move", self.seconds_per_target_move, self.target_moves, "moves"),
                                           ("fixed-board placement", self.seconds_per_placement, self.placements,
                                            "placements")):
            if seconds is not None:
                out.append(f"{seconds:.1f} s per {what}, measured over {count} {noun} in session {self.session}")
        return out


def beside(out_dir: str | Path) -> Path:
    """Where the runs writing into ``out_dir`` keep the figure: ``out_dir``'s parent / :data:`FILE_NAME`."""
    return Path(out_dir).absolute().parent / FILE_NAME


def write_beside(session_dir: str | Path, measured: PresentationTime) -> Path:
    """Write ``measured`` beside ``session_dir`` (atomically: a reader sees the old file or the new one)."""
    path = beside(session_dir)
    atomic.write_text(path, json.dumps(measured.model_dump(), indent=1) + "\n")
    return path


def read(path: str | Path) -> tuple[PresentationTime | None, str | None]:
    """(the figure in ``path``, None) or (None, a one-line note saying why it is not used); (None, None): no file."""
    path = Path(path)
    if not path.exists():
        return None, None
    try:
        if not path.is_file() or path.stat().st_size > MAX_FILE_BYTES:
            return None, f"{path}: not a presentation-time file (a regular file under {MAX_FILE_BYTES} bytes)"
        return PresentationTime.model_validate(json.loads(path.read_text("utf-8"))), None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        return None, f"{path}: unreadable ({error})"
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first.get("loc", ())) or "(top level)"
        return None, f"{path}: {where}: {first.get('msg')}"


def read_beside(out_dir: str | Path) -> tuple[PresentationTime | None, str | None]:
    """:func:`read` of the file beside ``out_dir`` (see :func:`beside`)."""
    return read(beside(out_dir))


__all__ = ["FILE_NAME", "PresentationTime", "beside", "read", "read_beside", "write_beside"]
