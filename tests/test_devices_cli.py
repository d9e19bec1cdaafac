"""`stereo-bench devices` as a user runs it: an empty machine, a stereo rig, JSON, no libusb, legacy ports."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import serial.tools.list_ports
from serial.tools.list_ports_common import ListPortInfo

import drivers.camera.usb_identity as usb_identity
from stereo_bench.cli import main
from tests.test_usb_identity import FakeMachine, FakeUsbBackend, standard_rig

REPO = Path(__file__).resolve().parents[1]


def usb_serial_port() -> ListPortInfo:
    port = ListPortInfo("/dev/ttyUSB0", skip_link_detection=True)
    port.vid, port.pid, port.serial_number, port.location = 0x1A86, 0x7523, None, "1-4:1.0"
    port.description, port.product = "USB Serial", "USB Serial"
    port.hwid = port.usb_info()
    return port


def legacy_uart() -> ListPortInfo:
    port = ListPortInfo("/dev/ttyS0", skip_link_detection=True)  # description and hwid stay 'n/a'
    return port


@pytest.fixture
def ports(monkeypatch) -> list[ListPortInfo]:
    found: list[ListPortInfo] = []
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda: list(found))
    return found


@pytest.fixture
def usb_backend(monkeypatch):
    holder = {"backend": FakeUsbBackend([])}
    monkeypatch.setattr(usb_identity, "default_usb_backend", lambda: holder["backend"])
    return holder


def run(capsys, machine: FakeMachine, *argv: str) -> tuple[int, str, str]:
    code = main(["devices", "--sys-root", str(machine.sys), "--dev-root", str(machine.dev), *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_empty_machine_says_nothing_was_found(capsys, tmp_path, ports, usb_backend):
    code, out, err = run(capsys, FakeMachine(tmp_path))
    assert code == 0 and err == ""
    assert out.splitlines() == ["No cameras found.", "No serial ports found."]


def test_stereo_rig_and_controller(capsys, tmp_path, ports, usb_backend):
    machine, backend = standard_rig(tmp_path)
    usb_backend["backend"] = backend
    ports.append(usb_serial_port())
    code, out, _ = run(capsys, machine)
    assert code == 0
    lines = out.splitlines()
    assert lines[0] == "Cameras (2):"
    assert lines[1] == (f"  {machine.dev}/video0  Logitech Webcam C270  046d:0825  serial SN-LEFT  usb-port 1-2.1")
    assert f"    by-id    {machine.dev}/v4l/by-id/usb-Logitech_Webcam_C270_SN-LEFT-video-index0" in lines
    assert ("    bind as  by-id:usb-Logitech_Webcam_C270_SN-LEFT-video-index0  |  serial:SN-LEFT  |  usb-port:1-2.1"
            "  |  by-path:pci-0000:00:14.0-usb-0:2.1:1.0-video-index0") in lines
    assert f"    also     {machine.dev}/video1 (metadata, not for capture)" in lines
    assert any(line.startswith(f"  {machine.dev}/video2  Logitech Webcam C270  046d:0825  no serial") for line in lines)
    assert "Serial ports (1):" in lines
    assert "  /dev/ttyUSB0  USB Serial  USB VID:PID=1A86:7523 LOCATION=1-4:1.0" in lines
    assert not any(line.startswith("note:") for line in lines)


def test_json(capsys, tmp_path, ports, usb_backend):
    machine, backend = standard_rig(tmp_path)
    usb_backend["backend"] = backend
    ports.append(usb_serial_port())
    code, out, _ = run(capsys, machine, "--json")
    assert code == 0
    document = json.loads(out)
    left = document["cameras"][0]
    assert left["capture_node"] == f"{machine.dev}/video0"
    assert left["usb"]["vid_pid"] == "046d:0825" and left["usb"]["port_path"] == "1-2.1"
    assert left["usb"]["serial"] == "SN-LEFT" and left["usb"]["source"] == "pyusb"
    assert left["bind_as"][1:3] == ["serial:SN-LEFT", "usb-port:1-2.1"]
    assert left["other_nodes"] == [f"{machine.dev}/video1"]
    assert document["serial_ports"][0]["device"] == "/dev/ttyUSB0"
    assert document["serial_ports"][0]["vid_pid"] == "1a86:7523"
    assert document["usb_available"] is True and document["notes"] == []


def test_without_libusb_the_listing_comes_from_sysfs_and_says_so(capsys, tmp_path, ports, usb_backend):
    machine, _ = standard_rig(tmp_path)
    usb_backend["backend"] = None
    code, out, _ = run(capsys, machine)
    assert code == 0
    assert "serial SN-LEFT  usb-port 1-2.1" in out
    assert out.splitlines()[-1].startswith("note: USB details unavailable")


def test_identical_cameras_are_offered_only_port_based_names(capsys, tmp_path, ports, usb_backend):
    machine = FakeMachine(tmp_path)
    machine.add_usb_camera("1-1", {"video0": 0}, serial="0001")
    machine.add_usb_camera("1-3", {"video2": 0}, serial="0001")
    usb_backend["backend"] = None
    _, out, _ = run(capsys, machine)
    bind_lines = [line for line in out.splitlines() if "bind as" in line]
    assert bind_lines == ["    bind as  usb-port:1-1  |  by-path:pci-0000:00:14.0-usb-0:1:1.0-video-index0",
                          "    bind as  usb-port:1-3  |  by-path:pci-0000:00:14.0-usb-0:3:1.0-video-index0"]


def test_legacy_uarts_are_hidden_unless_all(capsys, tmp_path, ports, usb_backend):
    ports.append(legacy_uart())
    machine = FakeMachine(tmp_path)
    _, out, _ = run(capsys, machine)
    assert out.splitlines() == ["No cameras found.", "No serial ports found.",
                                "(1 serial port without hardware identity hidden; --all shows them)"]
    _, out, _ = run(capsys, machine, "--all")
    assert "  /dev/ttyS0  n/a  n/a" in out.splitlines()


def test_roots_from_the_environment(capsys, tmp_path, ports, usb_backend, monkeypatch):
    machine, backend = standard_rig(tmp_path)
    usb_backend["backend"] = backend
    monkeypatch.setenv("STEREO_BENCH_SYS_ROOT", str(machine.sys))
    monkeypatch.setenv("STEREO_BENCH_DEV_ROOT", str(machine.dev))
    assert main(["devices"]) == 0
    assert capsys.readouterr().out.startswith("Cameras (2):")


def test_real_process_on_an_empty_tree(tmp_path):
    env = {**os.environ, "STEREO_BENCH_SYS_ROOT": str(tmp_path / "sys"), "STEREO_BENCH_DEV_ROOT": str(tmp_path)}
    result = subprocess.run([sys.executable, "-m", "stereo_bench", "devices"], cwd=REPO, env=env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[0] == "No cameras found."
