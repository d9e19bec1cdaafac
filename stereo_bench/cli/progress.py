"""The campaign's progress on the terminal: one status line at the bottom, lines written above it, and the
operator's prompt, which suspends the line.

While the runner waits for the operator the prompt is the last thing on the screen: the progress line is
erased when the prompt is shown and nothing redraws it until the prompt is answered; a result line that
arrives meanwhile is written above the prompt, which is drawn again under it. Where stderr is not a
terminal (a log, a pipe) no line is drawn at all (a redrawn line would be text there); the result lines
and the prompts are written as lines, and a prompt is written again under a line that arrives while it waits.

    line = ProgressLine(sys.stderr, draw=sys.stderr.isatty(), render=lambda: "paper-exp1 3/25 ...")
    line.refresh()               # redraw (a ticker thread also redraws it every second: elapsed, ETA)
    line.write("B100 ... error +0.021 mm")   # a line above
    line.show_prompt("move the target to Z = 400 mm, then press Enter")
    line.end_prompt()            # answered by Enter here; end_prompt("answered by live-page") otherwise
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import IO

CLEAR_LINE = "\r\x1b[K"  # to the line's start, erase it (VT100; every terminal emulator in use)
PROMPT_MARK = ">>> "


def terminal_columns(stream: IO[str], default: int = 80) -> int:
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return default


def is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or replaced stream
        return False


class ProgressLine:
    """A status line (``render()``'s text, cut to the terminal's width) that prompts suspend (module docstring).

    Thread-safe: the recorder thread, the terminal operator's reader and the ticker all write through one lock.
    ``draw``: draw the line at all (a terminal); ``refresh_s``: the ticker's period (None: no ticker).
    """

    def __init__(self, stream: IO[str], *, draw: bool, render: Callable[[], str], refresh_s: float | None = 1.0):
        self.stream = stream
        self.draw = draw
        self._render = render
        self._lock = threading.RLock()
        self._prompt: str | None = None
        self._drawn = False  # the status line is on the screen (the cursor at its end)
        self._at_line_start = True  # where nothing is drawn: whether the last text written ended its line
        self._closed = threading.Event()
        self._ticker = None
        if draw and refresh_s:
            self._ticker = threading.Thread(target=self._tick, args=(refresh_s,), name="progress-line", daemon=True)
            self._ticker.start()

    @property
    def prompting(self) -> bool:
        return self._prompt is not None

    def _tick(self, period_s: float) -> None:
        while not self._closed.wait(period_s):
            try:
                self.refresh()
            except (OSError, ValueError):  # the terminal went away: the run notices on its own writes
                return

    def _emit(self, text: str) -> None:
        self.stream.write(text)
        self.stream.flush()

    def _line(self) -> str:
        return self._render()[: max(terminal_columns(self.stream) - 1, 10)]

    def refresh(self) -> None:
        """Redraw the status line (not while a prompt waits: the prompt stays the last thing on the screen)."""
        with self._lock:
            if not self.draw or self._prompt is not None or self._closed.is_set():
                return
            self._emit(CLEAR_LINE + self._line())
            self._drawn = True

    def _erase(self) -> str:
        """What erases the status line, or a prompt however many rows it takes (wrapped, or of several lines: the
        per-view review), the cursor left where it began."""
        if self._prompt is None:
            return CLEAR_LINE
        columns = max(terminal_columns(self.stream), 1)
        rows = sum(max(1, math.ceil(len(line) / columns)) for line in (PROMPT_MARK + self._prompt + " ").split("\n"))
        return "\r" + (f"\x1b[{rows - 1}A" if rows > 1 else "") + "\x1b[J"

    def write(self, text: str) -> None:
        """A line above the status line (and above a prompt that waits, drawn again under it)."""
        with self._lock:
            if self.draw:
                self._emit(self._erase() + text + "\n")
                self._drawn = False
                if self._prompt is not None:
                    self._emit(PROMPT_MARK + self._prompt + " ")
                elif not self._closed.is_set():
                    self._emit(self._line())
                    self._drawn = True
                return
            self._emit(("" if self._at_line_start else "\n") + text + "\n")
            self._at_line_start = True
            if self._prompt is not None:
                self._emit(PROMPT_MARK + self._prompt + " ")
                self._at_line_start = False

    def show_prompt(self, message: str) -> None:
        """The operator's prompt, the last thing on the screen until :meth:`end_prompt`."""
        with self._lock:
            self._prompt = message
            if self.draw:
                self._emit(CLEAR_LINE + PROMPT_MARK + message + " ")
                self._drawn = False
                return
            self._emit(("" if self._at_line_start else "\n") + PROMPT_MARK + message + " ")
            self._at_line_start = False

    def end_prompt(self, note: str | None = None) -> None:
        """The prompt was answered: by Enter here (``note`` None: the terminal echoed the newline), or elsewhere
        (``note`` says by whom, written after the prompt); the status line comes back."""
        with self._lock:
            if self._prompt is None:
                return
            self._prompt = None
            if note is not None:
                self._emit(f"({note})\n")
                self._at_line_start = True
            elif not self.draw and not self._at_line_start:
                self._emit("\n")  # a log: the answer's newline was not echoed into it
                self._at_line_start = True
        self.refresh()

    def close(self, *, clear: bool = False) -> None:
        """Stop the ticker; leave the line's last state on the screen (``clear``: erase it, e.g. before an error)."""
        with self._lock:
            if self._closed.is_set():
                return
            if self.draw and self._drawn:
                if clear:
                    self._emit(CLEAR_LINE)
                else:
                    self._emit(CLEAR_LINE + self._line() + "\n")
                self._drawn = False
            self._closed.set()


def _uncertainty(row: dict) -> str:
    """The expanded uncertainty U (k=2) where the budget is known; else the image-noise sigma, said so (a
    bare +- sigma beside a calibration- or structure-dominated error reads as a false precision)."""
    expanded = row.get("U_expanded_mm")
    if expanded is not None and math.isfinite(expanded):
        return f"+- {expanded:.4f} mm (U, k=2)"
    return f"+- {row['sigma_mm']:.4f} mm (sigma of image noise only)"


def format_row(row: dict) -> str:
    head = (f"{row['config_id']:>16s}  B {row['baseline_mm']:6.1f}  Z {row['distance_mm']:6.1f}  "
            f"alpha {row['alpha_deg']:5.1f}")
    if row["status"] == "measured":
        # A fixed calibration from a file that records no RMS (OpenCV's sample, an imported one) stores none.
        rms = row.get("rms_px")
        rms_text = f"RMS {rms:.3f} px" if rms is not None and math.isfinite(rms) else "RMS not recorded"
        return (f"{head}  square {row['square_mean_mm']:8.4f} mm  error {row['error_mm']:+.4f} "
                f"{_uncertainty(row)}  (n {row['n_squares']}, {rms_text})")
    return f"{head}  {row['status'].upper()}: {row.get('reason')}"


def format_duration(seconds: float | None) -> str:
    """``1:02:03`` or ``2:03``; ``?`` when unknown."""
    if seconds is None or not seconds == seconds or seconds == float("inf"):
        return "?"
    whole = int(round(max(seconds, 0.0)))
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def bar(fraction: float, width: int = 20) -> str:
    filled = int(round(min(max(fraction, 0.0), 1.0) * width))
    return "#" * filled + "-" * (width - filled)


class Progress:
    """A subscriber (a document router): the status line over the configurations with the time elapsed and the
    ETA of :mod:`stereo_bench.campaign.eta`, one line per result (stderr); and the terminal operator's prompt
    display (:class:`stereo_bench.campaign.operator.PromptDisplay`), which suspends the line.

    ``clock``: monotonic seconds (the wall clock; a test may pass another).
    """

    def __init__(self, plan, config, *, quiet: bool, stream: IO[str] | None = None,
                 clock: Callable[[], float] = time.monotonic, refresh_s: float | None = 1.0, presentation=None):
        from stereo_bench.campaign.documents import (
            CalibrationSelectionEvent,
            CalibrationViewEvent,
            MoveEvent,
            PromptEvent,
            ResultDocument,
            ResumeDocument,
        )
        from stereo_bench.campaign.eta import EtaTracker, forecast_groups
        from stereo_bench.campaign.router import DocumentRouter

        self._router = (DocumentRouter().on(ResumeDocument, self._resumed).on(MoveEvent, self._moved)
                        .on(PromptEvent, self._prompted).on(ResultDocument, self._result)
                        .on(CalibrationViewEvent, self._view_kept).on(CalibrationSelectionEvent, self._selected))
        self.name, self.total, self.done = config.name, len(plan.configurations), 0
        self.quiet = quiet
        self.status = ""
        self.clock = clock
        self.started_s = clock()
        self._epoch_offset_s = time.time() - self.started_s  # epoch time stamps (a rig reading's) on this clock
        self.eta = EtaTracker(forecast_groups(config, plan.steps, presentation=presentation), start_s=self.started_s)
        self.etas: list[tuple[float, float]] = []  # (elapsed, ETA) at every marker: what the line showed
        stream = stream or sys.stderr
        self.line = ProgressLine(stream, draw=not quiet and is_terminal(stream), render=self.render,
                                 refresh_s=refresh_s)

    def __call__(self, document) -> None:
        self._router(document)

    def render(self) -> str:
        now = self.clock()
        fraction = self.done / self.total if self.total else 1.0
        return (f"{self.name} {self.done}/{self.total} [{bar(fraction)}] {fraction:4.0%}  "
                f"{format_duration(now - self.started_s)} elapsed, ETA {format_duration(self.eta.shown(now))}"
                + (f"  {self.status}" if self.status else ""))

    def _resumed(self, document) -> None:
        self.done += len(document.completed)
        self.line.refresh()

    def _moved(self, document) -> None:
        now = self.clock()
        rig = document.data.rig
        # When the rig arrived, from its reading's time stamp (epoch seconds): the event reaches this subscriber
        # after the frames recorded before it, late on a loaded machine, and a late marker skews the ETA.
        arrived = now if rig.timestamp is None else min(now, max(rig.timestamp - self._epoch_offset_s,
                                                                  self.started_s))
        self.eta.moved(document.config_id, arrived)
        self.etas.append((now - self.started_s, self.eta.shown(now)))
        self.status = f"at {document.config_id}: B {rig.baseline_mm:g} mm"
        self.line.refresh()

    def _prompted(self, document) -> None:
        self.eta.prompt_answered(document.data.waited_s)
        if document.data.answered_by != "simulator":
            self.status = f"{document.data.prompt} done by {document.data.answered_by}"
        self.line.refresh()

    def _view_kept(self, document) -> None:
        """A view taken automatically: a line (above the operator's prompt while it waits: the operator presents
        the board and wants to know a pose was taken; the event may arrive just after the prompt ended)."""
        auto = document.data.auto
        if auto is None:
            return
        speed = "" if auto.speed_px_s is None else f", corners at {auto.speed_px_s:.0f} px/s"
        new = "" if auto.novelty is None else f", new by {auto.novelty:.2f}"
        text = f"calibration view {document.data.index + 1} kept ({document.config_id}{speed}{new})"
        if self.quiet:
            self.status = text
            self.line.refresh()
        else:
            self.line.write(text)

    def _selected(self, document) -> None:
        data = document.data
        rejected = ", ".join(f"{why} {n}" for why, n in data.tally.items() if why != "kept" and n)
        text = (f"{document.config_id}: {data.kept} calibration views kept of {data.offered} pairs"
                + (f" ({rejected})" if rejected else "") + f"; {data.ended_by} ended it")
        if self.quiet:
            return
        self.line.write(text)

    def _result(self, document) -> None:
        self.done += 1
        if not self.quiet:
            self.line.write(format_row(document.row.stored()))
        else:
            self.line.refresh()

    # PromptDisplay (the terminal operator's)
    def show_prompt(self, message: str) -> None:
        self.eta.prompt_shown(self.clock())
        self.line.show_prompt(message)

    def end_prompt(self, note: str | None = None) -> None:
        self.eta.prompt_ended()
        self.line.end_prompt(note)

    def write(self, text: str) -> None:
        self.line.write(text)

    def close(self, *, clear: bool = False) -> None:
        """End the line; ``clear``: erase it (a failure's one-line error follows, clean, as the last line)."""
        self.line.close(clear=clear)
