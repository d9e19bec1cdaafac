"""The live page of a campaign: a document subscriber, an operator, previews and an HTTP server, wired once.

    page = LivePage.for_campaign(config, session_dir=out, host="127.0.0.1", port=0, control=control)
    with page:                                        # serves until the campaign has ended
        print(page.url)                               # http://127.0.0.1:PORT/?token=...
        run_campaign(config, out, operators=[TerminalOperator(), page.operator], subscribers=[page.state],
                     frame_subscribers=[page.previews.captured], control=control)

The page shows what the session records (the state folds the document stream; the previews are
the recorded frames, or while the runner waits for the operator live frames it lends the cameras
for), answers prompts as a second operator next to the terminal (the first answer wins), and steers
the run through its :class:`~stereo_bench.campaign.execute.RunControl` (pause, resume, stop).
"""

from __future__ import annotations

import secrets
import threading
from pathlib import Path

from stereo_bench.campaign.operator import ACTIONS, Ticket
from stereo_bench.live.preview import Previews
from stereo_bench.live.server import LiveApp, LiveServer, url_for
from stereo_bench.live.state import LiveState

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def prompt_json(ticket: Ticket, prompt_id: int | None = None) -> dict:
    """The prompt as the page shows it; ``id``: which offer it is (a button's answer names it, see
    :meth:`PageOperator.answer`)."""
    prompt = ticket.prompt
    return {"id": prompt_id, "kind": prompt.kind, "message": prompt.message, "config_id": prompt.config_id,
            "index": prompt.index, "quantity": prompt.quantity, "value": prompt.value,
            "actions": list(prompt.actions)}


class PageOperator:
    """The live page as an :class:`~stereo_bench.campaign.operator.Operator`: it shows the prompt as a banner
    and answers it when a button is pressed (racing the terminal: the first answer wins)."""

    name = "live page"

    def __init__(self, state: LiveState):
        self.state = state
        self._ticket: Ticket | None = None
        self._offered = 0  # the current offer's id: an answer meant for an earlier prompt must not answer this one
        self._lock = threading.Lock()

    def offer(self, ticket: Ticket) -> None:
        with self._lock:
            self._ticket = ticket
            self._offered += 1
            prompt_id = self._offered
        self.state.set_prompt(prompt_json(ticket, prompt_id))

    def withdraw(self, ticket: Ticket) -> None:
        with self._lock:
            if self._ticket is not ticket:
                return
            self._ticket = None
        self.state.set_prompt(None)

    def answer(self, action: str, value: float | None = None, prompt_id: int | None = None) -> tuple[int, str]:
        """Answer the prompt shown with ``action`` (``value``: its number, where it takes one): (HTTP status,
        message). ``prompt_id``: the ``id`` of the prompt the button was pressed on (the page sends it); when the
        prompt waiting now is another (the one pressed on was answered at the terminal and the run asked the
        next), the answer is refused rather than given to a prompt the operator has not read. None: the current
        prompt, whichever it is (a script's ``POST``)."""
        with self._lock:
            ticket, current = self._ticket, self._offered
        if ticket is None:
            return 409, "no prompt is waiting for an answer"
        if prompt_id is not None and prompt_id != current:
            return 409, "that prompt is no longer waiting (answered, or replaced by the one shown now): nothing done"
        if action not in ticket.prompt.actions:
            return 409, f"this prompt accepts {', '.join(ticket.prompt.actions)}, not {action}"
        if not ticket.answer(self.name, action, value):
            return 409, f"already answered by {ticket.answered_by}"
        self.withdraw(ticket)
        return 200, f"{action.replace('_', ' ')}" + ("" if value is None else f" {value:g}") + ": done"


class LivePage:
    """See the module docstring. ``start()``/``stop()`` or a context manager."""

    def __init__(self, *, boards: dict, image_size: tuple[int, int], session_dir: Path | None = None,
                 rig_config=None, name: str = "", host: str = "127.0.0.1", port: int = 0, control=None):
        self.token = secrets.token_urlsafe(18)
        self.host = host
        self.control_target = control
        self.app = LiveApp(self, session_dir=None if session_dir is None else Path(session_dir))
        self.state = LiveState(session_dir=session_dir, rig_config=rig_config, boards=boards, image_size=image_size,
                               name=name, on_change=self.app.notify)
        self.previews = Previews(boards, on_encoded=lambda encoded: self.state.set_preview(encoded.meta),
                                 on_views=self.state.calibration_view_detected)
        self.state.on_calibration = self.previews.set_calibration
        self.operator = PageOperator(self.state)
        self.server = LiveServer(self.app, host, port)
        self._poller: threading.Thread | None = None
        self._stopping = threading.Event()
        if control is not None:
            control.watch(self._attached)

    @classmethod
    def for_campaign(cls, config, *, session_dir: Path | None, host: str = "127.0.0.1", port: int = 0,
                     control=None) -> LivePage:
        optics = config.cameras.optics
        return cls(boards={"calibration": config.calibration_board.build(), "target": config.target.build()},
                   image_size=(optics.width_px, optics.height_px), session_dir=session_dir,
                   rig_config=config.rig.rig_config(), name=config.name, host=host, port=port, control=control)

    # -- lifecycle --------------------------------------------------------------------------------------------

    @property
    def url(self) -> str:
        assert self.server.port is not None, "start() first"
        return url_for(self.host, self.server.port, self.token)

    @property
    def exposed(self) -> bool:
        """True when the page listens beyond this machine (--ui-host): say so with a warning."""
        return self.host not in LOCAL_HOSTS

    def start(self) -> LivePage:
        self.server.start()  # first: an address it cannot serve on leaves nothing running
        self.previews.start()
        self._poller = threading.Thread(target=self._poll_transcript, name="live-transcript", daemon=True)
        self._poller.start()
        return self

    def stop(self) -> None:
        self._stopping.set()
        self.server.stop()
        self.previews.stop()
        if self._poller is not None:
            self._poller.join(timeout=2)

    def __enter__(self) -> LivePage:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _poll_transcript(self) -> None:
        while not self._stopping.wait(0.25):
            if self.state.poll_transcript():
                self.app.notify()

    def _attached(self, runner) -> None:
        self.previews.bench = None if runner is None else runner.bench

    def use_bench(self, bench) -> None:
        """Preview ``bench``'s cameras with no campaign (``stereo-bench live``): lend them for good."""
        self.previews.bench = bench

    # -- controls (from the server's thread) ------------------------------------------------------------------

    def control(self, action: str, value: float | None = None, prompt_id: int | None = None) -> tuple[int, str]:
        """Carry out a control action (``value``: a prompt answer's number; ``prompt_id``: the prompt it answers,
        :meth:`PageOperator.answer`): (HTTP status, message)."""
        if action in ACTIONS:
            return self.operator.answer(action, value, prompt_id)
        control = self.control_target
        if control is None:
            return 409, "no campaign is running: this page only previews"
        if self.state.run.get("status") not in ("running", "paused", "starting"):
            return 409, f"the campaign has ended ({self.state.run.get('status')})"
        if action == "pause":
            control.request_pause()
            self.state.requested("pause requested: the run holds at the next step (a move is feed-held)")
        elif action == "resume":
            control.request_resume()
            self.state.requested("resume requested")
        elif action == "stop":
            control.request_stop("stopped from the live page")
            self.state.requested("stop requested: the run stops at the next safe point (resumable)")
        return 200, f"{action} requested"
