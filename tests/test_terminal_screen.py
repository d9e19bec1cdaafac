"""What the operator sees in a terminal (issue 24): the real CLI on a real pseudo-terminal, its byte stream rendered
into a screen (pyte), and assertions on that screen: while the runner waits for the operator the prompt is the
last non-empty line, and the progress line returns after Enter.

Set ``STEREO_BENCH_SCREENS=DIR`` to keep the screens captured (docs/screens/ holds one).
"""

from __future__ import annotations

import io
import os
import sys
import time
from pathlib import Path

import pexpect
import pyte
import pytest

from stereo_bench.cli.progress import ProgressLine
from tests.campaigns import SMALL

ROWS, COLUMNS = 30, 120
STEREO_BENCH = [sys.executable, "-m", "stereo_bench"]

# The shared small campaign with two distances: the target is moved by hand twice (Z = 400, then Z = 500).
CAMPAIGN = (SMALL.replace("distance_mm = [450]", "distance_mm = [400, 500]")
            .replace("alpha_deg = [90, 35]", "alpha_deg = [90]"))
assert "distance_mm = [400, 500]" in CAMPAIGN and "alpha_deg = [90]" in CAMPAIGN


class Terminal:
    """A command on a pty of ROWS x COLUMNS, its output rendered as a VT100 screen."""

    def __init__(self, argv: list[str], cwd: Path):
        self.screen = pyte.Screen(COLUMNS, ROWS)
        self.stream = pyte.ByteStream(self.screen)
        self.child = pexpect.spawn(argv[0], argv[1:], cwd=str(cwd), dimensions=(ROWS, COLUMNS), timeout=5,
                                   env={**os.environ, "TERM": "xterm", "PYTHONUNBUFFERED": "1"})
        self.ended = False

    def pump(self, seconds: float) -> None:
        """Read what the command writes for ``seconds`` (or until it exits)."""
        end = time.monotonic() + seconds
        while not self.ended and time.monotonic() < end:
            try:
                self.stream.feed(self.child.read_nonblocking(65536, timeout=0.05))
            except pexpect.TIMEOUT:
                pass
            except pexpect.EOF:
                self.ended = True

    def lines(self) -> list[str]:
        return [line.rstrip() for line in self.screen.display if line.strip()]

    def last_line(self) -> str:
        lines = self.lines()
        return lines[-1] if lines else ""

    def text(self) -> str:
        return "\n".join(line.rstrip() for line in self.screen.display).rstrip() + "\n"

    def until(self, condition, *, timeout_s: float = 120.0, what: str) -> None:
        """Pump until ``condition(self)`` holds; fails naming ``what`` with the screen."""
        end = time.monotonic() + timeout_s
        while not condition(self):
            if self.ended or time.monotonic() > end:
                pytest.fail(f"never saw {what}; the screen:\n{self.text()}")
            self.pump(0.05)

    def exit_status(self) -> int | None:
        self.until(lambda t: t.ended, what="the command exit")
        self.child.close()
        return self.child.exitstatus


def _keep(name: str, terminal: Terminal) -> None:
    where = os.environ.get("STEREO_BENCH_SCREENS")
    if where:
        Path(where).mkdir(parents=True, exist_ok=True)
        (Path(where) / name).write_text(terminal.text())


def _prompt_for(distance: int):
    # The campaign marks its prompts with '>>> ' (among result lines); rig move writes the bare instruction.
    text = f"move the target to Z = {distance} mm, then press Enter"
    return lambda t: t.last_line().removeprefix(">>> ") == text


def _prompt_stays_last(terminal: Terminal, distance: int) -> None:
    # The progress line redraws every second and result lines arrive meanwhile: none of it may cover the prompt.
    terminal.pump(2.5)
    assert _prompt_for(distance)(terminal), f"the prompt is not the last line:\n{terminal.text()}"


@pytest.mark.slow
def test_campaign_prompt_is_the_last_line_and_progress_returns(tmp_path):
    (tmp_path / "c.toml").write_text(CAMPAIGN)
    terminal = Terminal([*STEREO_BENCH, "campaign", "run", "c.toml", "--out", "s"], tmp_path)
    terminal.until(_prompt_for(400), what="the prompt for Z = 400 mm as the last line")
    _prompt_stays_last(terminal, 400)
    assert not any("elapsed, ETA" in line for line in terminal.lines()), "a progress line left on the screen"
    _keep("campaign-run-prompt.txt", terminal)

    terminal.child.send("\r")
    terminal.until(lambda t: "small" in t.last_line() and "elapsed, ETA" in t.last_line(),
                   what="the progress line back as the last line after Enter")
    assert any(line.startswith(">>> move the target to Z = 400 mm") for line in terminal.lines())
    _keep("campaign-run-after-enter.txt", terminal)

    terminal.until(_prompt_for(500), what="the prompt for Z = 500 mm as the last line")
    _prompt_stays_last(terminal, 500)
    # The results of Z = 400 mm arrive while the operator is asked for Z = 500 (analysed meanwhile, published when
    # done: a loaded machine takes longer than any fixed wait): above the prompt, which stays the last line.
    terminal.until(lambda t: any("B100_Z400_A90" in line and "square" in line for line in t.lines())
                   and _prompt_for(500)(t), what="the result of B100_Z400_A90 above the prompt for Z = 500 mm")
    _keep("campaign-run-second-prompt.txt", terminal)
    terminal.child.send("\r")
    assert terminal.exit_status() == 0, terminal.text()
    assert "campaign success" in terminal.text()
    assert terminal.text().count(">>> move the target") == 2, terminal.text()


@pytest.mark.slow
def test_rig_move_prompt_is_the_last_line(tmp_path):
    link = tmp_path / "grbl"
    controller = pexpect.spawn(sys.executable, ["-m", "stereo_bench", "sim-controller", "--link", str(link),
                                                "--time-scale", "50"], timeout=30)
    try:
        deadline = time.monotonic() + 30
        while not link.exists():
            assert time.monotonic() < deadline, "the emulator never linked its pty"
            time.sleep(0.05)
        terminal = Terminal([*STEREO_BENCH, "rig", "--port", str(link), "home", "move", "--baseline", "120",
                             "--target", "400"], tmp_path)
        terminal.until(_prompt_for(400), what="rig move's prompt as the last line")
        _prompt_stays_last(terminal, 400)
        terminal.child.send("\r")
        assert terminal.exit_status() == 0, terminal.text()
        assert "stopped. Idle: B = 120.000 mm" in terminal.text() and "target Z = 400.000 mm" in terminal.text()
    finally:
        controller.terminate(force=True)


# ---------------------------------------------------------------------------------------------- the line itself


class _Tty(io.StringIO):
    """A terminal stand-in for the renderer (what it writes is rendered by pyte below)."""

    def isatty(self) -> bool:
        return True


def _render(text: str) -> list[str]:
    screen = pyte.Screen(80, 10)
    pyte.Stream(screen).feed(text.replace("\n", "\r\n"))  # the tty's onlcr
    return [line.rstrip() for line in screen.display if line.strip()]


def test_a_line_written_during_a_prompt_goes_above_it():
    out = _Tty()
    status = {"text": "run 1/4 [#---] 25%"}
    line = ProgressLine(out, draw=True, render=lambda: status["text"], refresh_s=None)
    line.refresh()
    line.show_prompt("move the target to Z = 500 mm, then press Enter")
    line.write("B100_Z400_A90 measured")
    status["text"] = "run 2/4 [##--] 50%"
    line.refresh()  # what the ticker does: nothing while the prompt waits
    assert _render(out.getvalue()) == ["B100_Z400_A90 measured",
                                       ">>> move the target to Z = 500 mm, then press Enter"]
    out.write("\n")  # the terminal echoes the operator's Enter
    line.end_prompt()
    assert _render(out.getvalue())[-1] == "run 2/4 [##--] 50%"
    line.close()
    assert _render(out.getvalue())[-1] == "run 2/4 [##--] 50%"


def test_without_a_terminal_lines_and_prompts_are_plain_lines():
    out = io.StringIO()
    line = ProgressLine(out, draw=False, render=lambda: "never drawn", refresh_s=None)
    line.refresh()
    line.show_prompt("move the target to Z = 400 mm, then press Enter")
    line.write("a result")
    line.end_prompt()
    line.show_prompt("again")
    line.end_prompt("done: answered by live-page")
    line.close()
    assert out.getvalue() == (">>> move the target to Z = 400 mm, then press Enter \na result\n"
                              ">>> move the target to Z = 400 mm, then press Enter \n"
                              ">>> again (done: answered by live-page)\n")
    assert "\x1b" not in out.getvalue() and "\r" not in out.getvalue()
