"""Test tiers: everything runs by default except the hardware tier, which a lab opts into.

    pytest --camera /dev/v4l/by-id/usb-...-video-index0     # real V4L2 camera tests
    pytest --serial-port /dev/ttyUSB0                        # real GRBL controller tests
"""

from __future__ import annotations

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("stereo-bench hardware tier")
    group.addoption("--camera", action="append", default=[], metavar="PATH",
                    help="run camera hardware tests on this V4L2 device (repeat for a stereo pair)")
    group.addoption("--serial-port", default=None, metavar="PATH",
                    help="run rig-controller hardware tests on this GRBL serial port (the rig WILL move)")


@pytest.fixture
def camera_paths(request: pytest.FixtureRequest) -> list[str]:
    paths = request.config.getoption("--camera")
    if not paths:
        pytest.skip("hardware tier: pass --camera PATH to run")
    return paths


@pytest.fixture
def serial_port(request: pytest.FixtureRequest) -> str:
    port = request.config.getoption("--serial-port")
    if not port:
        pytest.skip("hardware tier: pass --serial-port PATH to run")
    return port
