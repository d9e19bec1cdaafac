"""A slow rig action in progress: :class:`RigStatus`, what :meth:`Rig.move_to <drivers.rig.rig.Rig.move_to>` returns.

In the manner of ophyd's ``Status``/``MoveStatus`` and ophyd-async's ``AsyncStatus``: the action finishes by
itself (on a thread of its own, or at once), whoever waits; ``done``, ``success``, ``reading`` and ``exception``
say how it ended; ``add_callback`` runs a function when it does; ``wait(timeout)`` blocks and returns the reading
(or raises the action's error)::

    status = rig.move_to(baseline_mm=120.0)   # validated and queued: returns at once
    status.add_callback(lambda s: print("there", s.reading))
    reading = status.wait()                   # the blocking convenience (``rig move`` on the CLI)
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from drivers.rig.config import RigError


class StatusTimeout(RigError):
    """:meth:`RigStatus.wait` gave up before the action ended (the action itself goes on)."""


class Outcome:
    """How an action ended, once: ``done``, ``success``, ``reading``, ``exception`` and callbacks run when it does.
    The part :class:`RigStatus` and the controller's :class:`~drivers.rig.grbl.MoveStatus` share; each says
    itself how the action is waited for."""

    description = "move"

    def __init__(self) -> None:
        self._lock = threading.Lock()  # guards the callbacks and the outcome
        self._done = threading.Event()
        self._reading: Any = None
        self._exception: BaseException | None = None
        self._callbacks: list[Callable[[Any], None]] = []

    def _finish(self, reading: Any, error: BaseException | None) -> None:
        with self._lock:
            if self._done.is_set():
                raise RuntimeError(f"the {self.description} has already finished")
            self._reading, self._exception = reading, error
            self._done.set()
            callbacks, self._callbacks = self._callbacks, []
        for callback in callbacks:
            callback(self)

    @property
    def done(self) -> bool:
        return self._done.is_set()

    @property
    def success(self) -> bool:
        return self._done.is_set() and self._exception is None

    @property
    def reading(self) -> Any:
        """The reading where the action ended (a :class:`~drivers.rig.rig.RigReading` or the controller's
        report); None until it has."""
        return self._reading

    @property
    def exception(self) -> BaseException | None:
        return self._exception

    def add_callback(self, callback: Callable[[Any], None]) -> None:
        """Call ``callback(status)`` once the action has ended (at once if it has)."""
        with self._lock:
            if not self._done.is_set():
                self._callbacks.append(callback)
                return
        callback(self)


class RigStatus(Outcome):
    """One rig action in progress (a move); finished by :meth:`set_finished` / :meth:`set_exception`, once."""

    def __init__(self, description: str = "move"):
        super().__init__()
        self.description = description

    # -- construction -----------------------------------------------------------------------------------------

    @classmethod
    def finished(cls, reading: Any, description: str = "move") -> RigStatus:
        """An action that ended at once (a replay serves what was recorded)."""
        status = cls(description)
        status.set_finished(reading)
        return status

    @classmethod
    def running(cls, work: Callable[[], Any], description: str = "move") -> RigStatus:
        """Run ``work()`` (blocking until the action has ended, returning its reading) on a thread of its own;
        the status finishes with what it returns or raises."""
        status = cls(description)

        def run() -> None:
            try:
                reading = work()
            except BaseException as error:  # noqa: BLE001 - handed to whoever waits on the status
                status.set_exception(error)
            else:
                status.set_finished(reading)

        threading.Thread(target=run, name=f"rig-{description}", daemon=True).start()
        return status

    def set_finished(self, reading: Any) -> None:
        self._finish(reading, None)

    def set_exception(self, error: BaseException) -> None:
        self._finish(None, error)

    def wait(self, timeout: float | None = None) -> Any:
        """Block until the action has ended and return its reading, or raise its error.

        ``timeout`` (s): give up waiting after it (:class:`StatusTimeout`; the action goes on). None: the action's
        own bound (a GRBL move's ``move_timeout_s``) applies."""
        if not self._done.wait(timeout):
            raise StatusTimeout(f"the {self.description} has not ended after {timeout:g} s")
        if self._exception is not None:
            raise self._exception
        return self._reading

    def __repr__(self) -> str:
        state = "running" if not self.done else ("done" if self.success else f"failed: {self._exception}")
        return f"RigStatus({self.description!r}, {state})"


__all__ = ["Outcome", "RigStatus", "StatusTimeout"]
