"""Stable camera identity: pyusb through a fake ``usb.backend.IBackend`` and a fake sysfs + /dev tree.

Both fakes sit at the lowest layer: pyusb's own ``usb.core.find``/``Device``/string-descriptor code and the
registry's real sysfs walking, symlink resolution and matching all run. ``FakeUsbBackend`` and ``FakeMachine`` are
also used by the ``stereo-bench devices`` tests.
"""

from __future__ import annotations

import array
import errno
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import pytest
import usb.backend
import usb.core

from drivers.camera import (
    AmbiguousCameraSpec,
    CameraError,
    CameraGone,
    CameraNotFound,
    CameraRegistry,
    UnstableCameraName,
    list_cameras,
)
from drivers.camera.usb_identity import (
    NO_BACKEND_NOTE,
    V4L2_CAP_META_CAPTURE,
    V4L2_CAP_VIDEO_CAPTURE,
    default_usb_backend,
    query_device_caps,
)

# --- fake pyusb backend -------------------------------------------------------------------------------------------


@dataclass
class FakeUsbDevice:
    vendor_id: int
    product_id: int
    bus: int
    address: int
    port_numbers: tuple[int, ...]
    serial: str | None = None
    manufacturer: str | None = None
    product: str | None = None
    device_class: int = 0xEF  # miscellaneous + interface association, as UVC cameras report
    interface_classes: tuple[int, ...] = (0x0E, 0x0E)  # video control + video streaming
    open_errno: int | None = None
    reset_errno: int | None = None
    resets: int = 0
    strings: dict[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for index, text in enumerate((self.manufacturer, self.product, self.serial), start=1):
            if text is not None:
                self.strings[index] = text


class FakeUsbBackend(usb.backend.IBackend):
    """Enough of a libusb backend for usb.core.find, descriptor iteration, string descriptors and reset."""

    def __init__(self, devices: list[FakeUsbDevice]):
        self.devices = devices
        self.open_handles = 0

    def enumerate_devices(self):
        yield from self.devices

    def get_device_descriptor(self, dev: FakeUsbDevice):
        return SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=dev.device_class, bDeviceSubClass=2,
            bDeviceProtocol=1, bMaxPacketSize0=64, idVendor=dev.vendor_id, idProduct=dev.product_id,
            bcdDevice=0x0100, iManufacturer=1 if dev.manufacturer else 0, iProduct=2 if dev.product else 0,
            iSerialNumber=3 if dev.serial else 0, bNumConfigurations=1, address=dev.address, bus=dev.bus,
            port_number=dev.port_numbers[-1], port_numbers=dev.port_numbers, speed=3)

    def get_configuration_descriptor(self, dev: FakeUsbDevice, config: int):
        if config != 0:
            raise IndexError(config)
        return SimpleNamespace(bLength=9, bDescriptorType=2, wTotalLength=9 + 9 * len(dev.interface_classes),
                               bNumInterfaces=len(dev.interface_classes), bConfigurationValue=1, iConfiguration=0,
                               bmAttributes=0x80, bMaxPower=250, extra_descriptors=[])

    def get_interface_descriptor(self, dev: FakeUsbDevice, intf: int, alt: int, config: int):
        if config != 0 or alt != 0 or intf >= len(dev.interface_classes):
            raise IndexError((intf, alt, config))
        return SimpleNamespace(bLength=9, bDescriptorType=4, bInterfaceNumber=intf, bAlternateSetting=0,
                               bNumEndpoints=1, bInterfaceClass=dev.interface_classes[intf],
                               bInterfaceSubClass=intf + 1, bInterfaceProtocol=0, iInterface=0,
                               extra_descriptors=[])

    def open_device(self, dev: FakeUsbDevice):
        if dev.open_errno is not None:
            raise usb.core.USBError("Access denied (insufficient permissions)", errno=dev.open_errno)
        self.open_handles += 1
        return dev

    def close_device(self, dev_handle: FakeUsbDevice) -> None:
        self.open_handles -= 1

    def ctrl_transfer(self, dev_handle: FakeUsbDevice, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        descriptor_type, index = wValue >> 8, wValue & 0xFF
        assert (bmRequestType, bRequest, descriptor_type) == (0x80, 6, 3), "only GET_DESCRIPTOR(string) is faked"
        if index == 0:
            payload = bytes([4, 3, 0x09, 0x04])  # LANGID en-US
        else:
            assert wIndex == 0x0409
            text = dev_handle.strings[index].encode("utf-16-le")
            payload = bytes([2 + len(text), 3]) + text
        count = min(len(payload), len(data))
        data[:count] = array.array("B", payload[:count])
        return count

    def reset_device(self, dev_handle: FakeUsbDevice) -> None:
        if dev_handle.reset_errno is not None:
            raise usb.core.USBError("reset failed", errno=dev_handle.reset_errno)
        dev_handle.resets += 1


# --- fake sysfs and /dev ------------------------------------------------------------------------------------------


class FakeMachine:
    """A sysfs + /dev tree laid out like the kernel's and udev's, under tmp_path."""

    PCI = "devices/pci0000:00/0000:00:14.0"

    def __init__(self, root: Path):
        self.sys = root / "sys"
        self.dev = root / "dev"
        (self.sys / "class" / "video4linux").mkdir(parents=True)
        (self.dev / "v4l" / "by-id").mkdir(parents=True)
        (self.dev / "v4l" / "by-path").mkdir(parents=True)

    def registry(self, backend=None, **kwargs) -> CameraRegistry:
        return CameraRegistry(sys_root=self.sys, dev_root=self.dev, usb_backend=backend, **kwargs)

    def add_usb_camera(self, port: str, nodes: dict[str, int], *, vid: int = 0x046D, pid: int = 0x0825,
                       serial: str | None = None, product: str = "Webcam C270", manufacturer: str = "Logitech",
                       devnum: int = 5) -> None:
        bus = int(port.split("-")[0])
        device = self.sys / self.PCI / f"usb{bus}" / port
        interface = device / f"{port}:1.0"
        interface.mkdir(parents=True)
        attributes = {"idVendor": f"{vid:04x}", "idProduct": f"{pid:04x}", "busnum": str(bus), "devnum": str(devnum),
                      "product": product, "manufacturer": manufacturer, "devpath": port.split("-", 1)[1]}
        if serial is not None:
            attributes["serial"] = serial
        for name, value in attributes.items():
            (device / name).write_text(value + "\n")
        (interface / "bInterfaceClass").write_text("0e\n")
        id_name = f"usb-{manufacturer}_{product.replace(' ', '_')}" + (f"_{serial}" if serial else "")
        path_name = f"pci-0000:00:14.0-usb-0:{port.split('-', 1)[1]}:1.0"
        for node, index in nodes.items():
            self._add_node(interface / "video4linux" / node, node, f"{product}: {product}", index)
            by_id = self.dev / "v4l" / "by-id" / f"{id_name}-video-index{index}"
            if by_id.is_symlink():  # identical cameras: udev keeps one link, for the last one to appear
                by_id.unlink()
            os.symlink(f"../../{node}", by_id)
            os.symlink(f"../../{node}", self.dev / "v4l" / "by-path" / f"{path_name}-video-index{index}")

    def add_platform_camera(self, node: str, name: str = "unicam") -> None:
        parent = self.sys / "devices/platform/soc/fe801000.csi"
        parent.mkdir(parents=True, exist_ok=True)
        self._add_node(parent / "video4linux" / node, node, name, 0)

    def _add_node(self, directory: Path, node: str, name: str, index: int) -> None:
        directory.mkdir(parents=True)
        (directory / "name").write_text(name + "\n")
        (directory / "index").write_text(f"{index}\n")
        (directory / "dev").write_text("81:0\n")
        os.symlink("../..", directory / "device")
        os.symlink(os.path.relpath(directory, self.sys / "class" / "video4linux"),
                   self.sys / "class" / "video4linux" / node)
        (self.dev / node).write_text("")


def standard_rig(tmp_path: Path) -> tuple[FakeMachine, FakeUsbBackend]:
    """Left camera with a serial on port 1-2.1, right camera without one on 1-2.2, plus a USB-serial adapter."""
    machine = FakeMachine(tmp_path)
    machine.add_usb_camera("1-2.1", {"video0": 0, "video1": 1}, serial="SN-LEFT", devnum=5)
    machine.add_usb_camera("1-2.2", {"video2": 0, "video3": 1}, devnum=6)
    backend = FakeUsbBackend([
        FakeUsbDevice(0x046D, 0x0825, 1, 5, (2, 1), serial="SN-LEFT", manufacturer="Logitech", product="Webcam C270"),
        FakeUsbDevice(0x046D, 0x0825, 1, 6, (2, 2), manufacturer="Logitech", product="Webcam C270"),
        FakeUsbDevice(0x1A86, 0x7523, 1, 7, (4,), product="USB Serial", device_class=0xFF, interface_classes=(0xFF,)),
    ])
    return machine, backend


# --- pyusb through the fake backend -------------------------------------------------------------------------------


def test_fake_backend_serves_pyusb_find_by_serial(tmp_path):
    _, backend = standard_rig(tmp_path)
    device = usb.core.find(backend=backend, serial_number="SN-LEFT")
    assert device is not None and (device.bus, device.port_numbers) == (1, (2, 1))
    assert backend.open_handles == 1
    usb.util.dispose_resources(device)
    assert backend.open_handles == 0


def test_scan_joins_sysfs_nodes_with_pyusb_identity(tmp_path):
    machine, backend = standard_rig(tmp_path)
    scan = machine.registry(backend).scan()
    assert scan.usb_available and scan.notes == []
    left, right = scan.cameras
    assert left.capture_node == str(machine.dev / "video0")
    assert left.other_nodes == (str(machine.dev / "video1"),)
    assert left.name == "Webcam C270: Webcam C270"
    assert [Path(p).name for p in left.by_id] == ["usb-Logitech_Webcam_C270_SN-LEFT-video-index0"]
    assert [Path(p).name for p in left.by_path] == ["pci-0000:00:14.0-usb-0:2.1:1.0-video-index0"]
    assert left.usb.source == "pyusb"
    assert (left.usb.vid_pid, left.usb.serial, left.usb.port_path, left.usb.bus, left.usb.address) == (
        "046d:0825", "SN-LEFT", "1-2.1", 1, 5)
    assert (left.usb.manufacturer, left.usb.product) == ("Logitech", "Webcam C270")
    assert right.capture_node == str(machine.dev / "video2") and right.usb.serial is None
    assert left.stable_specs() == ["by-id:usb-Logitech_Webcam_C270_SN-LEFT-video-index0", "serial:SN-LEFT",
                                   "usb-port:1-2.1", "by-path:pci-0000:00:14.0-usb-0:2.1:1.0-video-index0"]
    assert left.to_dict()["usb"]["vid_pid"] == "046d:0825"


def test_unreadable_usb_strings_fall_back_to_sysfs(tmp_path):
    machine, backend = standard_rig(tmp_path)
    for device in backend.devices:
        device.open_errno = errno.EACCES  # a normal user may not open USB devices
    left = machine.registry(backend).scan().cameras[0]
    assert (left.usb.serial, left.usb.product, left.usb.source) == ("SN-LEFT", "Webcam C270", "pyusb")


def test_without_libusb_listing_works_from_sysfs_and_says_so(tmp_path):
    machine, _ = standard_rig(tmp_path)
    scan = machine.registry(backend=None).scan()
    assert not scan.usb_available
    assert scan.notes == [NO_BACKEND_NOTE] and "USB details unavailable" in NO_BACKEND_NOTE
    left = scan.cameras[0]
    assert (left.usb.source, left.usb.serial, left.usb.port_path, left.usb.vid_pid) == (
        "sysfs", "SN-LEFT", "1-2.1", "046d:0825")


def test_default_backend_is_the_bundled_libusb_when_installed():
    pytest.importorskip("libusb_package")
    assert default_usb_backend() is not None


def test_usb_camera_without_a_v4l2_node_is_reported(tmp_path):
    machine, backend = standard_rig(tmp_path)
    backend.devices.append(FakeUsbDevice(0x0C45, 0x6366, 2, 3, (1,), product="USB Camera"))
    scan = machine.registry(backend).scan()
    orphan = [camera for camera in scan.cameras if camera.capture_node is None]
    assert len(orphan) == 1 and orphan[0].usb.port_path == "2-1"
    assert "uvcvideo" in scan.notes[0]


def test_non_usb_camera_is_listed_without_usb_identity(tmp_path):
    machine = FakeMachine(tmp_path)
    machine.add_platform_camera("video0")
    (camera,) = machine.registry().scan().cameras
    assert camera.capture_node == str(machine.dev / "video0") and camera.usb is None and camera.name == "unicam"


def test_empty_machine(tmp_path):
    scan = list_cameras(sys_root=tmp_path / "sys", dev_root=tmp_path / "dev", usb_backend=FakeUsbBackend([]))
    assert scan.cameras == [] and scan.notes == []


# --- capture node vs metadata node --------------------------------------------------------------------------------


def test_querycap_decides_when_the_node_answers(tmp_path):
    machine, backend = standard_rig(tmp_path)
    # A camera that registered its metadata node first: only QUERYCAP gets it right.
    caps = {"video0": V4L2_CAP_META_CAPTURE, "video1": V4L2_CAP_VIDEO_CAPTURE}
    registry = machine.registry(backend, probe_caps=lambda node: caps.get(Path(node).name))
    left = registry.scan().cameras[0]
    assert left.capture_node == str(machine.dev / "video1")
    assert left.other_nodes == (str(machine.dev / "video0"),)


def test_querycap_on_something_that_is_not_a_v4l2_node_returns_none(tmp_path):
    plain = tmp_path / "video9"
    plain.write_text("")
    assert query_device_caps(str(plain)) is None
    assert query_device_caps(str(tmp_path / "missing")) is None


# --- resolving specs ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("spec, node", [
    ("by-id:usb-Logitech_Webcam_C270_SN-LEFT-video-index0", "video0"),
    ("/dev/v4l/by-id/usb-Logitech_Webcam_C270_SN-LEFT-video-index0", "video0"),
    ("serial:SN-LEFT", "video0"),
    ("usb-port:1-2.2", "video2"),
    ("by-path:pci-0000:00:14.0-usb-0:2.2:1.0-video-index0", "video2"),
    ("/dev/v4l/by-path/pci-0000:00:14.0-usb-0:2.1:1.0-video-index0", "video0"),
])
def test_resolve_stable_specs(tmp_path, spec, node):
    machine, backend = standard_rig(tmp_path)
    camera = machine.registry(backend).resolve(spec)
    assert camera.capture_node == str(machine.dev / node)


def test_resolve_a_labs_own_udev_symlink(tmp_path):
    machine, backend = standard_rig(tmp_path)
    os.symlink("video2", machine.dev / "cam-right")
    assert machine.registry(backend).resolve(str(machine.dev / "cam-right")).capture_node.endswith("video2")


@pytest.mark.parametrize("spec", ["/dev/video0", "video0", "0"])
def test_bare_video_index_is_refused_with_the_stable_alternatives(tmp_path, spec):
    machine, backend = standard_rig(tmp_path)
    with pytest.raises(UnstableCameraName) as caught:
        machine.registry(backend).resolve(spec)
    message = str(caught.value)
    assert "change across reboots" in message and "\n" not in message
    assert "by-id:usb-Logitech_Webcam_C270_SN-LEFT-video-index0 or serial:SN-LEFT or usb-port:1-2.1" in message


def test_video_index_under_the_dev_root_is_refused_too(tmp_path):
    machine, backend = standard_rig(tmp_path)
    with pytest.raises(UnstableCameraName, match="usb-port:1-2.2"):
        machine.registry(backend).resolve(str(machine.dev / "video2"))


def test_shared_serial_is_ambiguous_and_not_offered(tmp_path):
    machine = FakeMachine(tmp_path)
    machine.add_usb_camera("1-1", {"video0": 0}, serial="0001")
    machine.add_usb_camera("1-3", {"video2": 0}, serial="0001")
    registry = machine.registry()
    with pytest.raises(AmbiguousCameraSpec, match="usb-port:1-1, usb-port:1-3"):
        registry.resolve("serial:0001")
    with pytest.raises(AmbiguousCameraSpec, match="identical cameras share this by-id name"):
        registry.resolve("by-id:usb-Logitech_Webcam_C270_0001-video-index0")
    with pytest.raises(UnstableCameraName) as caught:
        registry.resolve("/dev/video0")
    message = str(caught.value)
    assert "serial:" not in message and "by-id:" not in message
    assert "use usb-port:1-1 or by-path:pci-0000:00:14.0-usb-0:1:1.0-video-index0" in message


@pytest.mark.parametrize("spec, message", [
    ("serial:NOPE", r"no such camera; present: .*video0 usb-port:1-2.1 serial:SN-LEFT"),
    ("usb-port:9-9", "no such camera"),
    ("usb-port:left", "looks like '1-2.3'"),
    ("by-id:usb-Nothing-video-index0", "no such camera link; present: usb-Logitech"),
    ("by-id:usb-Logitech_Webcam_C270_SN-LEFT-video-index1", "metadata node"),
    ("left", "not a camera spec"),
])
def test_specs_that_match_nothing_say_what_is_there(tmp_path, spec, message):
    machine, backend = standard_rig(tmp_path)
    with pytest.raises(CameraNotFound, match=message):
        machine.registry(backend).resolve(spec)


def test_by_id_link_without_sysfs_is_trusted(tmp_path):
    machine = FakeMachine(tmp_path)
    (machine.dev / "video4").write_text("")
    os.symlink("../../video4", machine.dev / "v4l" / "by-id" / "usb-X-video-index0")
    camera = machine.registry().resolve("by-id:usb-X-video-index0")
    assert camera.capture_node == str(machine.dev / "video4") and camera.usb is None


# --- USB reset ----------------------------------------------------------------------------------------------------


def test_usb_reset_resets_the_camera_at_that_port(tmp_path):
    machine, backend = standard_rig(tmp_path)
    identity = machine.registry(backend).usb_reset("usb-port:1-2.2")
    assert identity.port_path == "1-2.2"
    assert [device.resets for device in backend.devices] == [0, 1, 0]
    assert backend.open_handles == 0


def test_usb_reset_permission_denied_names_the_bus_node(tmp_path):
    machine, backend = standard_rig(tmp_path)
    backend.devices[0].open_errno = errno.EACCES
    with pytest.raises(CameraError, match="write access to /dev/bus/usb/001/005"):
        machine.registry(backend).usb_reset("serial:SN-LEFT")


def test_usb_reset_of_a_vanished_camera(tmp_path):
    machine, backend = standard_rig(tmp_path)
    registry = machine.registry(backend)
    camera = registry.resolve("usb-port:1-2.1")
    backend.devices.pop(0)
    with pytest.raises(CameraGone, match="no USB device at that port"):
        registry.usb_reset(camera)
    backend.devices[0].reset_errno = errno.ENODEV
    with pytest.raises(CameraGone, match="vanished during reset"):
        registry.usb_reset("usb-port:1-2.2")


def test_usb_reset_without_libusb_says_how_to_get_it(tmp_path):
    machine, _ = standard_rig(tmp_path)
    with pytest.raises(CameraError, match="pip install libusb-package"):
        machine.registry(backend=None).usb_reset("usb-port:1-2.1")


def test_usb_reset_of_a_non_usb_camera(tmp_path):
    machine = FakeMachine(tmp_path)
    machine.add_platform_camera("video0")
    registry = machine.registry()
    with pytest.raises(CameraError, match="not a USB camera"):
        registry.usb_reset(registry.scan().cameras[0])


def test_construction_does_no_io(tmp_path):
    class Exploding(FakeUsbBackend):
        def enumerate_devices(self):
            raise AssertionError("USB touched during construction")

    CameraRegistry(sys_root=tmp_path / "nowhere", dev_root=tmp_path / "nowhere", usb_backend=Exploding([]),
                   probe_caps=lambda node: pytest.fail("probed during construction"))


def test_a_camera_with_two_capture_streams(tmp_path):
    """An RGB+IR camera: one USB device, capture nodes at index 0 and 2, each with a metadata node."""
    machine = FakeMachine(tmp_path)
    machine.add_usb_camera("1-4", {"video4": 0, "video5": 1, "video6": 2, "video7": 3}, serial="RGBIR")
    capture = {"video4", "video6"}
    registry = machine.registry(
        probe_caps=lambda node: V4L2_CAP_VIDEO_CAPTURE if Path(node).name in capture else V4L2_CAP_META_CAPTURE)
    scan = registry.scan()
    rgb, ir = scan.cameras
    assert (Path(rgb.capture_node).name, Path(ir.capture_node).name) == ("video4", "video6")
    assert rgb.primary and not ir.primary
    assert not scan.has_twin(rgb) and scan.serial_is_unique("RGBIR")
    assert registry.resolve("serial:RGBIR", scan) is rgb
    assert registry.resolve("usb-port:1-4", scan) is rgb
    assert registry.resolve("by-id:usb-Logitech_Webcam_C270_RGBIR-video-index2", scan) is ir
    assert ir.stable_specs(scan) == ["by-id:usb-Logitech_Webcam_C270_RGBIR-video-index2",
                                     "by-path:pci-0000:00:14.0-usb-0:4:1.0-video-index2"]
