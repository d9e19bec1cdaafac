"""``stereo-bench devices``: the cameras and serial ports on this machine, with the stable names to bind them by.

Cameras come from ``drivers.camera.usb_identity`` (sysfs + pyusb); serial ports from pyserial's
``serial.tools.list_ports``. Legacy on-board UARTs that report no hardware identity (``/dev/ttyS*`` with hwid
'n/a': placeholders the kernel registers whether or not a port is wired) are hidden unless ``--all``: a GRBL rig
controller is a USB serial device.

For tests the camera roots can be moved with the hidden ``--sys-root``/``--dev-root`` options or the
``STEREO_BENCH_SYS_ROOT``/``STEREO_BENCH_DEV_ROOT`` environment variables.
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import serial.tools.list_ports

from drivers.camera.base import CameraError
from drivers.camera.usb_identity import CameraDevice, CameraRegistry, DeviceScan
from stereo_bench.cli import CliError, print_json


def serial_ports(include_all: bool) -> tuple[list[dict[str, Any]], int]:
    """(ports as dicts, number hidden because they have no hardware identity)."""
    shown, hidden = [], 0
    for port in sorted(serial.tools.list_ports.comports(), key=lambda p: p.device):
        if not include_all and (port.hwid in (None, "", "n/a")):
            hidden += 1
            continue
        shown.append({
            "device": port.device,
            "description": port.description,
            "hwid": port.hwid,
            "vid_pid": f"{port.vid:04x}:{port.pid:04x}" if port.vid is not None and port.pid is not None else None,
            "serial_number": port.serial_number,
            "location": port.location,
            "manufacturer": port.manufacturer,
            "product": port.product,
        })
    return shown, hidden


def camera_label(camera: CameraDevice) -> str:
    if camera.usb is not None and (camera.usb.product or camera.usb.manufacturer):
        return " ".join(part for part in (camera.usb.manufacturer, camera.usb.product) if part)
    return camera.name or "(unnamed)"


def camera_lines(camera: CameraDevice, scan: DeviceScan) -> list[str]:
    head = [camera.capture_node or "(no V4L2 capture node)", camera_label(camera)]
    if camera.usb is not None:
        head.append(camera.usb.vid_pid)
        head.append(f"serial {camera.usb.serial}" if camera.usb.serial else "no serial")
        if camera.usb.port_path:
            head.append(f"usb-port {camera.usb.port_path}")
    lines = ["  " + "  ".join(head)]
    lines += [f"    by-id    {link}" for link in camera.by_id]
    lines += [f"    by-path  {link}" for link in camera.by_path]
    specs = camera.stable_specs(scan)
    if specs and camera.capture_node:
        lines.append(f"    bind as  {'  |  '.join(specs)}")
    if camera.other_nodes:
        lines.append(f"    also     {', '.join(camera.other_nodes)} (metadata, not for capture)")
    return lines


def cmd_devices(args: argparse.Namespace) -> int:
    registry = CameraRegistry(sys_root=args.sys_root, dev_root=args.dev_root)
    try:
        scan = registry.scan()
    except (CameraError, OSError) as error:
        raise CliError(f"listing cameras failed: {error}") from None
    ports, hidden = serial_ports(args.all)

    if args.json:
        print_json({
            "cameras": [{**camera.to_dict(), "bind_as": camera.stable_specs(scan)} for camera in scan.cameras],
            "serial_ports": ports,
            "hidden_serial_ports": hidden,
            "usb_available": scan.usb_available,
            "notes": scan.notes,
        }, indent=2)
        return 0

    lines: list[str] = []
    if scan.cameras:
        lines.append(f"Cameras ({len(scan.cameras)}):")
        for camera in scan.cameras:
            lines += camera_lines(camera, scan)
    else:
        lines.append("No cameras found.")
    if ports:
        lines.append(f"Serial ports ({len(ports)}):")
        for port in ports:
            lines.append(f"  {port['device']}  {port['description']}  {port['hwid']}")
    else:
        lines.append("No serial ports found.")
    if hidden:
        lines.append(f"({hidden} serial port{'s' if hidden != 1 else ''} without hardware identity hidden; "
                     f"--all shows them)")
    lines += [f"note: {note}" for note in scan.notes]
    print("\n".join(lines))
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "devices", help="list cameras and serial ports, with the stable names to bind them by",
        description="List V4L2 cameras (capture node, /dev/v4l/by-id and by-path links, USB VID:PID, serial "
                    "number, port path) and serial ports. Bind cameras in the config by by-id:, serial: or "
                    "usb-port: names, never by /dev/videoN, whose numbers change across reboots.",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--all", action="store_true",
                        help="also list serial ports without hardware identity (legacy /dev/ttyS*)")
    parser.add_argument("--sys-root", default=os.environ.get("STEREO_BENCH_SYS_ROOT", "/sys"),
                        help=argparse.SUPPRESS)
    parser.add_argument("--dev-root", default=os.environ.get("STEREO_BENCH_DEV_ROOT", "/dev"),
                        help=argparse.SUPPRESS)
    parser.set_defaults(func=cmd_devices)
