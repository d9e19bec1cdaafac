"""A rig's move returns a RigStatus (issue 21): it finishes by itself, says how, runs callbacks, and ``wait`` is the
blocking convenience; every rig the runner drives states its capabilities instead of being probed with getattr."""

from __future__ import annotations

import threading

import pytest

from drivers.replay import ReplayRig
from drivers.rig import GrblRig, Rig, RigCapabilities, RigStatus, StatusTimeout
from drivers.rig.config import MoveRequestError
from drivers.sim.grbl.emulator import GrblEmulator


def test_a_status_finishes_by_itself_and_says_how():
    release = threading.Event()
    status = RigStatus.running(lambda: (release.wait(5.0), "there")[1])
    seen: list[RigStatus] = []
    status.add_callback(seen.append)
    assert not status.done and status.reading is None
    with pytest.raises(StatusTimeout, match="not ended after 0.05 s"):
        status.wait(0.05)
    release.set()
    assert status.wait(5.0) == "there"
    assert status.done and status.success and status.exception is None and seen == [status]
    late: list[RigStatus] = []
    status.add_callback(late.append)  # already finished: at once
    assert late == [status]


def test_a_failed_status_raises_its_error_to_every_waiter():
    def fail():
        raise MoveRequestError("refused")

    status = RigStatus.running(fail)
    for _ in range(2):
        with pytest.raises(MoveRequestError, match="refused"):
            status.wait(5.0)
    assert status.done and not status.success and isinstance(status.exception, MoveRequestError)
    with pytest.raises(RuntimeError, match="already finished"):
        status.set_finished("again")


def test_grbl_rig_move_returns_before_the_rig_has_stopped():
    with GrblEmulator(time_scale=2.0) as emulator, GrblRig(emulator.tty_path, connect_timeout_s=3.0) as rig:
        assert isinstance(rig, Rig) and rig.capabilities == RigCapabilities(True, True, True)
        rig.home(timeout_s=30.0)
        done = threading.Event()
        status = rig.move_to(baseline_mm=150.0)  # 199 mm of travel: well over a second at 2x
        status.add_callback(lambda _: done.set())
        assert not status.done
        assert done.wait(60.0)  # nobody waited: it finished by itself
        assert status.success and status.reading.baseline_mm == 150.0
        assert status.wait() is status.reading


def test_the_replay_rig_conforms_and_has_no_controller():
    rig = ReplayRig([{"baseline_mm": 100.0, "state": "Idle"}])
    assert isinstance(rig, Rig)
    assert rig.capabilities == RigCapabilities()
    status = rig.move_to(baseline_mm=100.0)
    assert status.done and status.wait().baseline_mm == 100.0
    assert rig.controller_info() == {} and rig.warnings == [] and rig.homing_approach() == {}
    assert rig.resume().baseline_mm == 100.0
