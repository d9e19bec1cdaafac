"""How long one presentation of the calibration board takes, measured by a run and read by the next plan.

At a real bench the operator is most of the campaign (``paper-exp1``: 300 presentations); the plan assumed 5 s each
(:data:`~stereo_bench.campaign.plan.timing.OPERATOR_S_PER_CALIBRATION_VIEW`). A run records, per configuration, how
long the presentations took (a ``presentation_time`` event: from the first view asked for to the last one taken,
on the operator's wall clock at a real bench, on the bench clock on the simulated one, where the simulated hand
presents), and at its end writes their total to ``presentation_time.json`` **beside the session directory** (in
the directory that holds the sessions, ``--out``'s parent). The next ``campaign plan ... --out DIR`` and ``campaign
run`` (its ETA) read the file beside their ``--out`` and use its seconds per view instead of the assumed 5 s, and
say where the figure came from.

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
    seconds_per_view: float = Field(gt=0, description="seconds per view presented, s")
    views: int = Field(ge=1, description="views presented in the run it was measured in")
    seconds: float = Field(ge=0, description="their presentation time in total, s")
    capture: Literal["auto", "enter", "mixed"] = Field(description="how the views were taken")
    clock: Literal["bench", "wall", "mixed"] = Field(
        description="whose seconds: the operator's wall clock (a real bench) or the simulated bench's clock")
    session: str = Field(description="the session directory it was measured in (its name)")
    measured_at: str = Field(description="when the run ended (UTC, ISO 8601)")

    @classmethod
    def of_events(cls, events: Iterable, *, session: str) -> PresentationTime | None:
        """The total of a run's ``presentation_time`` events (:class:`PresentationTimeEvent`); None without one."""
        data = [event.data for event in events]
        if not data:
            return None
        views = sum(d.views for d in data)
        seconds = sum(d.seconds for d in data)
        if seconds <= 0:
            return None
        captures, clocks = {d.capture for d in data}, {d.clock for d in data}
        return cls(seconds_per_view=seconds / views, views=views, seconds=seconds,
                   capture=captures.pop() if len(captures) == 1 else "mixed",
                   clock=clocks.pop() if len(clocks) == 1 else "mixed", session=session,
                   measured_at=datetime.now(UTC).isoformat(timespec="seconds"))

    def describe(self) -> str:
        """Where the figure comes from, for the plan's assumptions: 'measured 2.31 s per view (auto, bench clock)
        over 96 views of session x on 2026-12-03T08:10:00+00:00'."""
        clock = {"bench": "the simulated bench's clock", "wall": "the operator's wall clock",
                 "mixed": "bench and wall clocks"}[self.clock]
        return (f"{self.seconds_per_view:.2f} s per calibration view presented by hand, measured over {self.views} "
                f"views ({self.capture} capture, {clock}) in session {self.session} at {self.measured_at}")


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
