"""Who may grab from the bench's cameras: the runner always, a preview only while the runner lends them.

The runner owns the cameras: what it captures is what is recorded. While it waits for the operator
(a prompt) or is paused it captures nothing, and lends the cameras to a preview (the live page aims
and watches through them at several frames a second). Taking them back waits for a preview grab in
flight to end, so a preview never overlaps a capture and never changes what is captured::

    gate = CameraGate()
    with gate.lent():                      # runner: waiting for the operator
        answer = desk.ask(prompt, stop=stop)
    with gate.borrowed() as allowed:       # preview thread
        if allowed:
            pair = cameras.capture_pair()
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager


class CameraGate:
    """See the module docstring. Thread-safe; a bench that nobody previews never lends anything out."""

    def __init__(self):
        self._lock = threading.Lock()
        self._lent = 0  # nested lends (a prompt while paused) count

    @property
    def lent_out(self) -> bool:
        """True while the runner lends the cameras (a hint: :meth:`borrowed` decides)."""
        return self._lent > 0

    @contextmanager
    def lent(self) -> Iterator[None]:
        """Runner: the cameras may be borrowed inside; leaving waits for a borrowed grab to end."""
        with self._lock:
            self._lent += 1
        try:
            yield
        finally:
            with self._lock:  # held by a borrower while it grabs
                self._lent -= 1

    @contextmanager
    def borrowed(self) -> Iterator[bool]:
        """Preview: yields True when the cameras may be used inside (the runner waits until this ends)."""
        with self._lock:
            yield self._lent > 0
