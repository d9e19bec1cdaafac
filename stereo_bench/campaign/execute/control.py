"""Steering a run from outside it: :class:`RunControl` (stop, pause, resume; signal-safe)."""

from __future__ import annotations

from collections.abc import Callable

from stereo_bench.campaign.runner import CampaignRunner


class RunControl:
    """Stop, pause and resume a run from outside it (signal handlers, a live page); safe before it starts.

    Signal-safe: no locks; a request made before the runner exists is applied when it attaches.
    """

    def __init__(self):
        self._runner: CampaignRunner | None = None
        self.stop_reason: str | None = None
        self._paused = False
        self._watchers: list[Callable[[CampaignRunner | None], None]] = []

    def watch(self, callback: Callable[[CampaignRunner | None], None]) -> None:
        """``callback(runner)`` when a run attaches, ``callback(None)`` when it detaches (a live page takes
        the bench's cameras for its previews from it)."""
        self._watchers.append(callback)

    def attach(self, runner: CampaignRunner) -> None:
        self._runner = runner
        for callback in self._watchers:
            callback(runner)
        if self._paused:
            runner.request_pause()
        if self.stop_reason is not None:
            runner.request_stop(self.stop_reason)

    def detach(self) -> None:
        self._runner = None
        for callback in self._watchers:
            callback(None)

    @property
    def paused(self) -> bool:
        return self._paused

    def request_stop(self, reason: str = "stopped by the operator") -> None:
        if self.stop_reason is None:
            self.stop_reason = reason
        runner = self._runner
        if runner is not None:
            runner.request_stop(reason)

    def request_pause(self) -> None:
        self._paused = True
        if self._runner is not None:
            self._runner.request_pause()

    def request_resume(self) -> None:
        self._paused = False
        if self._runner is not None:
            self._runner.request_resume()
