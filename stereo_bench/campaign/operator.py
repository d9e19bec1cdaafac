"""Operators: who does the manual steps of a campaign, and how several of them race for one prompt.

The runner executes every operator step itself (move the target, present the calibration board,
put the measured target back) by asking an :class:`OperatorDesk`; the desk offers the
:class:`Prompt` to every :class:`Operator` at once, the first answer wins and the others are told
to withdraw it. Today's operators are the terminal (Enter on stdin) and the simulator (``--yes``:
the simulated scene is set by the presenter, so there is nothing to do); a live web page is a
second operator next to the terminal::

    desk = OperatorDesk([TerminalOperator(), web_page])
    answer = desk.ask(Prompt("target", "move the target to Z = 400 mm, then press Enter"), stop=stop_event)
    answer.operator, answer.waited_s      # who answered, after how long (recorded as a 'prompt' event)
    answer.action                         # 'continue' (Enter), or one of the prompt's other actions

A prompt lists the answers it accepts (``Prompt.actions``): every prompt accepts ``continue``; a
calibration view at the bench also ``capture_now`` (take this view now) and ``discard_last_view``
(drop the view kept last and take it again), which a live page offers as buttons.

An operator's :meth:`Operator.offer` must not block: it shows the prompt and later calls
``ticket.answer(name)`` (or ``ticket.give_up(name, why)`` when it cannot answer, e.g. stdin closed).
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import IO, Any, Protocol, runtime_checkable

from drivers.rig.rig import manual_instruction, physical_request
from stereo_bench.campaign.documents import PromptKind

CONTINUE = "continue"
CAPTURE_NOW = "capture_now"
DISCARD_LAST_VIEW = "discard_last_view"
# The per-view error review (runner: after a configuration's calibration): with a value (px; a view's index).
SET_THRESHOLD = "set_threshold"
EXCLUDE_VIEW = "exclude_view"
RECALIBRATE = "recalibrate"
#: Every answer an operator can give; a prompt accepts a subset (always ``continue``).
ACTIONS = (CONTINUE, CAPTURE_NOW, DISCARD_LAST_VIEW, SET_THRESHOLD, EXCLUDE_VIEW, RECALIBRATE)
#: What a terminal line answers (its first word; a number after it is the value), where the prompt accepts it.
TERMINAL_KEYS = {"d": DISCARD_LAST_VIEW, "discard": DISCARD_LAST_VIEW, "t": SET_THRESHOLD, "x": EXCLUDE_VIEW,
                 "r": RECALIBRATE}


class OperatorAbsent(RuntimeError):
    """A manual step needs an operator but none can answer (e.g. no terminal)."""


class StopRequested(Exception):
    """Raised inside the runner when the operator asked it to stop."""


@dataclass(frozen=True)
class Prompt:
    """One operator step: what to do (``message``), and for a manual quantity which one and its value."""

    kind: PromptKind
    message: str
    config_id: str | None = None
    quantity: str | None = None
    value: float | None = None
    index: int | None = None
    actions: tuple[str, ...] = (CONTINUE,)  # the answers this prompt accepts (see ACTIONS)
    # Shown while the runner works (views taken automatically); an answer ends that work early. Operators with
    # nothing to do there (the simulator, a replay) leave it unanswered: the work ends by itself.
    background: bool = False


class Ticket:
    """One prompt offered to several operators: the first :meth:`answer` wins, later ones return False."""

    def __init__(self, prompt: Prompt, n_operators: int):
        self.prompt = prompt
        self.asked_at = time.monotonic()
        self.answered_by: str | None = None
        self.answered_at: float | None = None
        self.action: str = CONTINUE
        self.value: float | None = None  # the action's number, where it takes one (a threshold, a view)
        self.gave_up: dict[str, str] = {}
        self.withdraw_reason: str | None = None  # why it was withdrawn unanswered (OperatorDesk.close)
        self._n_operators = n_operators
        self._lock = threading.Lock()
        self._done = threading.Event()

    def answer(self, operator: str, action: str = CONTINUE, value: float | None = None) -> bool:
        """``operator`` has done the step (``action``: one of the prompt's actions, ``value`` its number where it
        takes one); True if it was the first.

        Raises ValueError for an action the prompt does not accept.
        """
        if action not in self.prompt.actions:
            raise ValueError(f"this prompt accepts {', '.join(self.prompt.actions)}, not {action!r}")
        with self._lock:
            if self._done.is_set():
                return False
            self.answered_by, self.answered_at, self.action = operator, time.monotonic(), action
            self.value = value
            self._done.set()
            return True

    def give_up(self, operator: str, reason: str) -> None:
        """``operator`` cannot answer (e.g. its input closed); when every operator has given up, nobody can."""
        with self._lock:
            self.gave_up[operator] = reason
            if len(self.gave_up) >= self._n_operators:
                self._done.set()

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout: float) -> bool:
        return self._done.wait(timeout)


@runtime_checkable
class Operator(Protocol):
    """Somebody (or something) that can do a campaign's manual steps."""

    name: str

    def offer(self, ticket: Ticket) -> None:
        """Show ``ticket.prompt`` and return at once; call ``ticket.answer(self.name)`` when it is done."""

    def withdraw(self, ticket: Ticket) -> None:
        """The prompt was answered by another operator, or the run stopped: stop showing it."""


@dataclass(frozen=True)
class Answer:
    operator: str
    waited_s: float
    action: str = CONTINUE
    value: float | None = None


class OperatorDesk:
    """Asks every operator at once; the first to answer wins (see the module docstring)."""

    def __init__(self, operators: Sequence[Operator]):
        self.operators = list(operators)

    def ask(self, prompt: Prompt, *, stop: threading.Event, poll_s: float = 0.05,
            while_waiting: Callable[[], None] | None = None) -> Answer:
        """Block until an operator answers ``prompt``; ``while_waiting()`` is called every ``poll_s`` meanwhile.

        Raises StopRequested when ``stop`` is set first, OperatorAbsent when no operator can answer.
        """
        if not self.operators:
            raise OperatorAbsent(f"the campaign needs an operator here ({prompt.message!r}) but none is connected")
        ticket = self.open(prompt)
        try:
            while not ticket.wait(poll_s):
                if stop.is_set():
                    raise StopRequested()
                if while_waiting is not None:
                    while_waiting()
        finally:
            self.close(ticket)
        if ticket.answered_by is None:
            reasons = "; ".join(f"{name}: {why}" for name, why in ticket.gave_up.items())
            raise OperatorAbsent(f"the campaign needs the operator here ({prompt.message!r}) but nobody can "
                                 f"answer ({reasons})")
        assert ticket.answered_at is not None
        return Answer(operator=ticket.answered_by, waited_s=ticket.answered_at - ticket.asked_at, action=ticket.action,
                      value=ticket.value)


    def open(self, prompt: Prompt) -> Ticket:
        """Offer ``prompt`` to every operator and return at once (a :attr:`Prompt.background` prompt: the runner
        works meanwhile and looks at ``ticket.done``); :meth:`close` withdraws it."""
        ticket = Ticket(prompt, len(self.operators))
        for operator in self.operators:
            operator.offer(ticket)
            if ticket.done:
                break
        return ticket

    def close(self, ticket: Ticket, *, reason: str | None = None) -> None:
        """Withdraw ``ticket`` from every operator but the one that answered it (``reason``: why, when unanswered)."""
        ticket.withdraw_reason = reason
        for operator in self.operators:
            if operator.name != ticket.answered_by:
                operator.withdraw(ticket)


def manual_prompt(quantity: str, value: float, *, config_id: str | None = None) -> Prompt:
    """The one prompt for a quantity set by hand (the runner's PromptTarget/PromptManual steps, ``rig move``)."""
    return Prompt("target" if quantity == "target_distance_mm" else "manual", manual_instruction(quantity, value),
                  config_id=config_id, quantity=quantity, value=value)


def move_and_ask(rig: Any, desk: OperatorDesk, *, stop: threading.Event | None = None, **request: Any) -> Any:
    """Move a :class:`~drivers.rig.rig.GrblRig` and have the operators set what it sets by hand: the motors first
    (``rig.move_to(**request)``, waited on), then one :func:`manual_prompt` per manual quantity whose value changes,
    each recorded on the rig once answered (``rig.set_by_hand``). Returns the reading then. What ``rig move`` does;
    a campaign has these prompts as steps of its plan instead.

    Raises what the move raises (refused: before anything moves), OperatorAbsent, StopRequested.
    """
    options = {key: request.pop(key) for key in ("timeout_s", "on_moving") if key in request}
    manual = rig.manual_steps(**request)
    motors = {q: (None if q in manual else v) for q, v in physical_request(**request).items()}
    reading = rig.move_to(**motors, **options).wait()
    for quantity, value in manual.items():
        desk.ask(manual_prompt(quantity, value), stop=stop or threading.Event())
        rig.set_by_hand(quantity, value)
    return rig.read() if manual else reading


class SimulatedOperator:
    """Answers every prompt at once: on the simulated bench the presenter sets the scene (``--yes``)."""

    def __init__(self, name: str = "simulator"):
        self.name = name
        self.prompts: list[Prompt] = []

    def offer(self, ticket: Ticket) -> None:
        self.prompts.append(ticket.prompt)
        if not ticket.prompt.background:  # a background prompt's work (the simulated hand) ends by itself
            ticket.answer(self.name)

    def withdraw(self, ticket: Ticket) -> None:
        return None


class LineOperator:
    """The operator at a terminal for a desk of one (``rig move``, its shell): the prompt is printed and one line
    read in :meth:`offer` itself. It blocks, unlike :class:`TerminalOperator`, so that nothing is left reading
    standard input after the answer (the shell's next ``input()`` gets the next line); end of input gives up."""

    name = "terminal"

    def __init__(self, stream_in: IO[str] | None = None, stream_out: IO[str] | None = None):
        self._in = stream_in
        self._out = stream_out

    def offer(self, ticket: Ticket) -> None:
        out = self._out or sys.stderr
        out.write(ticket.prompt.message + " ")
        out.flush()
        if (self._in or sys.stdin).readline() == "":
            ticket.give_up(self.name, "no operator answer (end of input)")
        else:
            ticket.answer(self.name)

    def withdraw(self, ticket: Ticket) -> None:
        return None


def terminal_answer(line: str) -> tuple[str, float | None]:
    """(action, value) a line typed at the terminal answers: its first word by :data:`TERMINAL_KEYS` ("t 0.4": set the
    threshold to 0.4 px, "x 3": exclude view 3, "r", "d"), anything else Enter (continue). A key whose number is
    missing or not one comes with None (the runner shows its prompt again and says so)."""
    words = line.strip().lower().split()
    action = TERMINAL_KEYS.get(words[0]) if words else None
    if action is None:
        return CONTINUE, None
    if action in (SET_THRESHOLD, EXCLUDE_VIEW):
        try:
            return action, float(words[1])
        except (IndexError, ValueError):
            return action, None
    return action, None


@runtime_checkable
class PromptDisplay(Protocol):
    """Where a terminal operator shows its prompt: the CLI's progress line suspends itself for it
    (``stereo_bench/cli/progress.py``), so that the prompt stays the last thing on the screen."""

    def show_prompt(self, message: str) -> None:
        """Show ``message`` as the prompt (the cursor after it)."""

    def end_prompt(self, note: str | None = None) -> None:
        """The prompt was answered: by Enter (``note`` None) or elsewhere (``note``, e.g. 'done: answered by ...')."""


class StreamPromptDisplay:
    """A prompt written to a stream as it is (no progress line to suspend)."""

    def __init__(self, stream_out: IO[str] | None = None):
        self._out = stream_out

    def show_prompt(self, message: str) -> None:
        out = self._out or sys.stderr
        out.write(f"\n>>> {message} ")
        out.flush()

    def end_prompt(self, note: str | None = None) -> None:
        if note is not None:
            out = self._out or sys.stderr
            out.write(f"({note})\n")
            out.flush()


class TerminalOperator:
    """The operator at the terminal: the prompt is printed, Enter on standard input answers it.

    ``d`` + Enter discards the last calibration view where the prompt accepts that; any other line is Enter.

    One reader thread owns standard input for the whole run, so a prompt answered elsewhere (a live
    page) leaves no blocked ``input()`` behind; a line typed while no prompt is shown is ignored.
    End of input means nobody is at the terminal: the prompt is given up with advice.
    """

    name = "terminal"

    def __init__(self, stream_in: IO[str] | None = None, stream_out: IO[str] | None = None, *,
                 absent_advice: str = "run it in a terminal, or pass --yes on the simulated bench",
                 display: PromptDisplay | None = None):
        self._in = stream_in
        self.display = display or StreamPromptDisplay(stream_out)
        self.absent_advice = absent_advice
        self._lock = threading.Lock()
        self._ticket: Ticket | None = None
        self._closed = False
        self._reader: threading.Thread | None = None

    def offer(self, ticket: Ticket) -> None:
        with self._lock:
            if self._closed:
                ticket.give_up(self.name, f"standard input is closed: {self.absent_advice}")
                return
            self._ticket = ticket
            if self._reader is None:
                self._reader = threading.Thread(target=self._read, name="terminal-operator", daemon=True)
                self._reader.start()
            self.display.show_prompt(ticket.prompt.message)

    def withdraw(self, ticket: Ticket) -> None:
        with self._lock:
            if self._ticket is ticket:
                self._ticket = None
                self.display.end_prompt(f"done: answered by {ticket.answered_by}" if ticket.answered_by is not None
                                        else ticket.withdraw_reason or "no longer needed: the run stopped")

    def _read(self) -> None:
        stream = self._in or sys.stdin
        while True:
            try:
                line = stream.readline()
            except (OSError, ValueError):
                line = ""
            with self._lock:
                ticket = self._ticket
                if line == "":
                    self._closed = True
                    self._ticket = None
            if line == "":
                if ticket is not None:
                    ticket.give_up(self.name, f"standard input is closed: {self.absent_advice}")
                return
            action, value = terminal_answer(line)
            if ticket is not None and action not in ticket.prompt.actions:
                action, value = CONTINUE, None
            if ticket is not None and ticket.answer(self.name, action, value):
                with self._lock:
                    if self._ticket is ticket:
                        self._ticket = None
                        self.display.end_prompt()
