"""Opt-in hardware tier: the real GRBL controller of the rig. Skipped unless ``--serial-port`` is given.

    pytest tests/test_hw_serial.py --serial-port /dev/ttyUSB0
    STEREO_BENCH_HW_HOME=1 pytest tests/test_hw_serial.py --serial-port /dev/ttyUSB0      # also home
    STEREO_BENCH_RIG_CONFIG=rig.toml pytest ...                                          # the rig's mapping

Gentle on purpose: read status; home only when asked; one small baseline move (1 mm) and back.
The rig WILL move in the last test: keep clear of it.
"""

from __future__ import annotations

import os

import pytest

from drivers.rig import GrblController, GrblRig, RigConfig, load_rig_config
from drivers.rig.codec import STATES

pytestmark = pytest.mark.hardware


def _config() -> RigConfig:
    path = os.environ.get("STEREO_BENCH_RIG_CONFIG")
    return load_rig_config(path) if path else RigConfig()


def test_status_without_reset(serial_port):
    with GrblController(serial_port, reset_on_open=False, connect_timeout_s=5.0) as grbl:
        reading = grbl.status(timeout=2.0)
        assert reading.state in STATES
        assert reading.machine_position is not None and set(reading.machine_position) >= set("XYZ")
        assert grbl.axes is not None and len(grbl.axes) >= 3


def test_connect_with_soft_reset_sees_the_banner(serial_port):
    with GrblController(serial_port, connect_timeout_s=5.0) as grbl:
        assert grbl.banner is not None and grbl.banner.version.startswith("1.1")
        assert grbl.send("$I", timeout=2.0)[0].startswith("[VER:")


def test_home_when_asked(serial_port):
    if os.environ.get("STEREO_BENCH_HW_HOME") != "1":
        pytest.skip("homing moves every axis to its switch: set STEREO_BENCH_HW_HOME=1 to run it")
    config = _config()
    with GrblRig(serial_port, config) as rig:
        reading = rig.home()
        assert reading.state == "Idle"


def test_small_baseline_move_and_back(serial_port):
    config = _config()
    with GrblRig(serial_port, config) as rig:
        start = rig.read()
        if rig.controller.locked:
            pytest.skip("controller is in Alarm: home it first (STEREO_BENCH_HW_HOME=1)")
        mapping = config.quantities["baseline_mm"]
        if not mapping.driven or start.baseline_mm is None:
            pytest.skip("the baseline is not motorised in this rig config")
        step = 1.0 if start.baseline_mm + 1.0 <= mapping.max else -1.0  # type: ignore[operator]
        moved = rig.move_to(baseline_mm=start.baseline_mm + step, timeout_s=30.0).wait()
        assert moved.state == "Idle"
        assert moved.baseline_mm == pytest.approx(start.baseline_mm + step, abs=mapping.tolerance)
        back = rig.move_to(baseline_mm=start.baseline_mm, timeout_s=30.0).wait()
        assert back.baseline_mm == pytest.approx(start.baseline_mm, abs=mapping.tolerance)
