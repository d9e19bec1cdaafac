"""Stable camera identity: which ``/dev/videoN`` is the left camera today.

``/dev/videoN`` numbers follow probe order and change across reboots and replugs, so cameras are bound by

* ``by-id:NAME`` or a ``/dev/v4l/by-id/...`` path: udev's link built from vendor, product and serial;
* ``serial:XXXX``: the USB serial number (cheap identical cameras often have none, or all share one);
* ``usb-port:1-2.3``: the physical USB port path (bus 1, root port 2, hub port 3), stable while the cables stay;
* ``by-path:NAME`` or a ``/dev/v4l/by-path/...`` path: udev's port-based link;
* any other udev symlink to a video node (a lab's own rule, e.g. ``/dev/cam-left``).

``serial:`` and ``usb-port:`` name a USB device; for a device with several capture streams (RGB + IR) they mean
its first stream, and the others are bound by their ``-video-indexN`` links. Identical cameras share serial
numbers and by-id names (udev keeps one link, for whichever appeared last): such specs are refused as ambiguous
and ``stable_specs()`` leaves them out.

A bare ``/dev/videoN`` (or ``videoN``, or an index) is refused with the stable names of that node in the message:
accepting it "with a warning" would let a rig silently swap left and right after a reboot, which corrupts every
stereo calibration without any error.

Where the facts come from:

* sysfs: ``/sys/class/video4linux/videoN/device`` is the USB *interface* (``1-2.3:1.0``); its parent directory is
  the USB device, named by its port path, with ``idVendor``, ``idProduct``, ``serial``, ``product``...
* pyusb: enumerates USB devices with a video-class (0x0E) interface and reads their string descriptors; it is
  also the only way to USB-reset a hung camera. Its backend is the libusb bundled by ``libusb-package`` when that
  is installed, else pyusb's default search. Without any libusb, listing still works from sysfs alone and says
  that USB details (and reset) are unavailable.
* Capture vs metadata node: since Linux 4.16 uvcvideo registers two nodes per camera, the capture node and a
  metadata node, with the same ``name``. The authoritative test is VIDIOC_QUERYCAP's device capabilities
  (``V4L2_CAP_VIDEO_CAPTURE``), used when the node can be opened. Otherwise the sysfs ``index`` attribute decides:
  uvcvideo registers the capture node first, so it has ``index`` 0 (udev's ``-video-index0`` links rely on the
  same fact). ``name`` cannot tell them apart. A camera with several capture streams is only fully seen when
  QUERYCAP works.

All filesystem roots are parameters so tests run the real code on a fake tree.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import re
import struct
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import usb.core
import usb.util

from drivers.camera.base import CameraError, CameraGone, CameraNotFound

log = logging.getLogger(__name__)

USB_CLASS_VIDEO = 0x0E
V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_VIDEO_CAPTURE_MPLANE = 0x00001000
V4L2_CAP_META_CAPTURE = 0x00800000
V4L2_CAP_DEVICE_CAPS = 0x80000000
# _IOR('V', 0, struct v4l2_capability): 104-byte struct (driver[16] card[32] bus_info[32] version capabilities
# device_caps reserved[3]).
VIDIOC_QUERYCAP = 0x80685600
_V4L2_CAPABILITY_SIZE = 104

NO_BACKEND_NOTE = ("USB details unavailable: pyusb found no libusb backend (pip install libusb-package); "
                   "identity read from sysfs only, USB reset unavailable")


class UnstableCameraName(CameraError, ValueError):
    """A ``/dev/videoN`` index was given where a stable camera name is required."""


class AmbiguousCameraSpec(CameraError, ValueError):
    """A spec matches more than one camera (e.g. two cameras sharing a serial number)."""


# --- records ------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UsbIdentity:
    """A USB device: ``port_path`` is the kernel name, e.g. '1-2.3' (bus 1, port 2, hub port 3)."""

    vendor_id: int
    product_id: int
    bus: int | None
    port_path: str | None
    serial: str | None = None
    manufacturer: str | None = None
    product: str | None = None
    address: int | None = None
    source: str = "sysfs"  # 'pyusb' when the descriptors were read through libusb

    @property
    def vid_pid(self) -> str:
        return f"{self.vendor_id:04x}:{self.product_id:04x}"

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "vid_pid": self.vid_pid}


@dataclass(frozen=True)
class CameraDevice:
    """One camera: its capture node, udev links, USB identity and any other (metadata) nodes.

    ``primary`` is False for the second and later capture streams of one USB device (e.g. the IR stream of an
    RGB+IR camera): ``serial:`` and ``usb-port:`` name the device, and so its first (lowest-index) stream only.
    """

    capture_node: str | None
    name: str | None = None
    by_id: tuple[str, ...] = ()
    by_path: tuple[str, ...] = ()
    usb: UsbIdentity | None = None
    other_nodes: tuple[str, ...] = ()
    primary: bool = True

    def stable_specs(self, scan: DeviceScan | None = None) -> list[str]:
        """Specs that will find this camera again after a reboot, best first.

        With ``scan``, names shared with an identical camera are left out: a serial number two cameras report,
        and the by-id link (udev builds it from vendor, product and serial, so identical cameras share one name
        and udev keeps a single link for whichever appeared last).
        """
        twins = scan is not None and scan.has_twin(self)
        specs = [] if twins else [f"by-id:{Path(link).name}" for link in self.by_id]
        usb_dev = self.usb if self.primary else None
        if usb_dev is not None and usb_dev.serial and (scan is None or scan.serial_is_unique(usb_dev.serial)):
            specs.append(f"serial:{usb_dev.serial}")
        if usb_dev is not None and usb_dev.port_path:
            specs.append(f"usb-port:{usb_dev.port_path}")
        specs += [f"by-path:{Path(link).name}" for link in self.by_path]
        return specs

    def to_dict(self) -> dict[str, Any]:
        return {
            "capture_node": self.capture_node,
            "name": self.name,
            "by_id": list(self.by_id),
            "by_path": list(self.by_path),
            "usb": self.usb.to_dict() if self.usb else None,
            "other_nodes": list(self.other_nodes),
            "primary": self.primary,
        }


@dataclass
class DeviceScan:
    """Result of one look at the machine; ``notes`` say what could not be determined and why."""

    cameras: list[CameraDevice] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    usb_available: bool = False

    def serial_is_unique(self, serial: str | None) -> bool:
        """Exactly one USB device reports this serial number."""
        return bool(serial) and len({cam.usb.port_path for cam in self.cameras
                                     if cam.usb and cam.usb.serial == serial}) == 1

    def has_twin(self, camera: CameraDevice) -> bool:
        """Another USB device with the same VID:PID and serial (or lack of one): udev gives both one by-id name."""
        if camera.usb is None:
            return False
        key = (camera.usb.vendor_id, camera.usb.product_id, camera.usb.serial)
        return any(other.usb is not None and other.usb.port_path != camera.usb.port_path
                   and (other.usb.vendor_id, other.usb.product_id, other.usb.serial) == key
                   for other in self.cameras)


# --- low-level probes ---------------------------------------------------------------------------------------------


def query_device_caps(node: str) -> int | None:
    """V4L2 device capabilities of ``node`` via VIDIOC_QUERYCAP, or ``None`` if it cannot be asked.

    Opens read-only and non-blocking: allowed while another program streams, and does not start streaming.
    """
    try:
        fd = os.open(node, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        buffer = bytearray(_V4L2_CAPABILITY_SIZE)
        fcntl.ioctl(fd, VIDIOC_QUERYCAP, buffer)
    except OSError:
        return None
    finally:
        os.close(fd)
    _version, capabilities, device_caps = struct.unpack_from("<III", buffer, 80)
    return device_caps if capabilities & V4L2_CAP_DEVICE_CAPS else capabilities


def default_usb_backend() -> Any | None:
    """The pyusb backend to use: libusb-package's bundled libusb if installed, else pyusb's own search."""
    try:
        import libusb_package
    except ImportError:
        libusb_package = None
    if libusb_package is not None:
        try:
            backend = libusb_package.get_libusb1_backend()
        except Exception as error:  # a broken wheel must not stop listing from sysfs
            log.debug("libusb-package backend failed: %s", error)
            backend = None
        if backend is not None:
            return backend
    import usb.backend.libusb0
    import usb.backend.libusb1
    import usb.backend.openusb

    for module in (usb.backend.libusb1, usb.backend.openusb, usb.backend.libusb0):
        try:
            backend = module.get_backend()
        except Exception:
            backend = None
        if backend is not None:
            return backend
    return None


def _read_attr(directory: Path, name: str) -> str | None:
    try:
        return (directory / name).read_text(errors="replace").strip() or None
    except OSError:
        return None


def _int_attr(directory: Path, name: str, base: int = 10) -> int | None:
    text = _read_attr(directory, name)
    try:
        return int(text, base) if text is not None else None
    except ValueError:
        return None


_PORT_PATH = re.compile(r"^\d+-\d+(\.\d+)*$")
_VIDEO_INDEX = re.compile(r"^(?:/dev/)?video(\d+)$|^\d+$")


@dataclass
class _SysNode:
    name: str  # 'video0'
    node: str  # dev_root/video0
    card: str | None
    index: int | None
    usb_dir: Path | None  # the USB device directory (named by port path), or None for non-USB nodes
    parent_key: str  # groups the nodes of one physical device


# --- the registry -------------------------------------------------------------------------------------------------

_UNSET: Any = object()


class CameraRegistry:
    """Finds cameras and resolves stable specs to capture nodes. Constructing it does no I/O.

    ``sys_root``/``dev_root``: where sysfs and /dev are (tests pass a fake tree). ``usb_backend``: a pyusb
    backend, ``None`` to skip pyusb entirely, or unset for ``default_usb_backend()``. ``probe_caps``: returns a
    node's V4L2 device capabilities or ``None`` (default: VIDIOC_QUERYCAP).
    """

    def __init__(
        self,
        *,
        sys_root: str | os.PathLike[str] = "/sys",
        dev_root: str | os.PathLike[str] = "/dev",
        usb_backend: Any = _UNSET,
        probe_caps: Callable[[str], int | None] = query_device_caps,
    ):
        self.sys_root = Path(sys_root)
        self.dev_root = Path(dev_root)
        self._usb_backend = usb_backend
        self._probe_caps = probe_caps

    # -- public ----------------------------------------------------------------------------------------------------

    def scan(self) -> DeviceScan:
        """Every camera on the machine: V4L2 nodes from sysfs joined with USB video devices from pyusb."""
        scan = DeviceScan()
        nodes = self._sysfs_nodes()
        links = self._udev_links()
        usb_devices = self._pyusb_devices(scan)

        groups: dict[str, list[_SysNode]] = {}
        for node in nodes:
            groups.setdefault(node.parent_key, []).append(node)

        seen_ports: set[str] = set()
        for group in groups.values():
            capture, other = self._split_capture(group)
            usb_dir = group[0].usb_dir
            port = usb_dir.name if usb_dir is not None else None
            identity = None
            if port is not None:
                seen_ports.add(port)
                identity = self._merge_identity(usb_devices.get(port), self._sysfs_identity(usb_dir))
            capture.sort(key=lambda n: (n.index if n.index is not None else 0, _natural_key(n.name)))
            for position, node in enumerate(capture or [None]):
                key = node.name if node else None
                scan.cameras.append(CameraDevice(
                    capture_node=node.node if node else None,
                    name=(node or group[0]).card,
                    by_id=tuple(links.get(key, ((), ()))[0]),
                    by_path=tuple(links.get(key, ((), ()))[1]),
                    usb=identity,
                    other_nodes=tuple(n.node for n in other),
                    primary=position == 0,
                ))
        for port, identity in usb_devices.items():
            if port not in seen_ports:
                scan.cameras.append(CameraDevice(capture_node=None, name=identity.product, usb=identity))
                scan.notes.append(f"USB video device {identity.vid_pid} at port {port} has no V4L2 node: "
                                  f"is the uvcvideo driver loaded (sudo modprobe uvcvideo)?")
        scan.cameras.sort(key=_camera_sort_key)
        return scan

    def resolve(self, spec: str, scan: DeviceScan | None = None) -> CameraDevice:
        """The camera a stable spec names; see the module docstring for the spec forms.

        Raises ``UnstableCameraName`` for ``/dev/videoN``, ``CameraNotFound`` when nothing matches (the message
        lists what is there), ``AmbiguousCameraSpec`` when several cameras match.
        """
        spec = spec.strip()
        if is_unstable_name(spec, dev_root=self.dev_root):
            raise self._unstable(spec, scan)
        kind, _, value = spec.partition(":")
        if spec.startswith("/"):
            return self._resolve_link(self._map_dev_path(spec), spec, scan)
        if kind == "by-id" and value:
            return self._resolve_link(self.dev_root / "v4l" / "by-id" / value, spec, scan)
        if kind == "by-path" and value:
            return self._resolve_link(self.dev_root / "v4l" / "by-path" / value, spec, scan)
        if kind == "serial" and value:
            return self._pick(spec, scan, lambda cam: cam.usb is not None and cam.usb.serial == value)
        if kind == "usb-port" and value:
            if not _PORT_PATH.match(value):
                raise CameraNotFound(f"{spec}: a USB port path looks like '1-2.3' (bus-port.port...)", device=spec)
            return self._pick(spec, scan, lambda cam: cam.usb is not None and cam.usb.port_path == value)
        raise CameraNotFound(
            f"{spec!r}: not a camera spec; use by-id:NAME, serial:XXXX, usb-port:1-2.3, by-path:NAME "
            f"or a /dev/v4l/by-id/... path", device=spec)

    def usb_reset(self, target: CameraDevice | str) -> UsbIdentity:
        """USB-reset a hung camera (same effect as replugging it); returns the identity that was reset.

        The camera re-enumerates afterwards, possibly on a new /dev/videoN: resolve its spec again.
        """
        camera = self.resolve(target) if isinstance(target, str) else target
        if camera.usb is None or not camera.usb.port_path:
            raise CameraError(f"{camera.capture_node}: not a USB camera, cannot USB-reset it",
                              device=camera.capture_node)
        backend = self._backend()
        if backend is None:
            raise CameraError(f"{camera.usb.port_path}: USB reset needs libusb; pip install libusb-package",
                              device=camera.capture_node)
        port = camera.usb.port_path
        try:
            device = usb.core.find(backend=backend, custom_match=lambda dev: _port_path(dev) == port)
        except (usb.core.NoBackendError, usb.core.USBError) as error:
            raise CameraError(f"usb-port:{port}: cannot enumerate USB devices ({error})", device=port) from error
        if device is None:
            raise CameraGone(f"usb-port:{port}: no USB device at that port any more; replug the camera", device=port)
        try:
            device.reset()
        except usb.core.USBError as error:
            if error.errno in (errno.EACCES, errno.EPERM):
                bus_dev = f"/dev/bus/usb/{device.bus:03d}/{device.address:03d}"
                raise CameraError(f"usb-port:{port}: permission denied resetting the camera; it needs write access "
                                  f"to {bus_dev} (a udev rule or root)", device=port) from error
            if error.errno == errno.ENODEV:
                raise CameraGone(f"usb-port:{port}: camera vanished during reset; replug it", device=port) from error
            raise CameraError(f"usb-port:{port}: USB reset failed ({error})", device=port) from error
        finally:
            usb.util.dispose_resources(device)
        return camera.usb

    # -- sysfs -----------------------------------------------------------------------------------------------------

    def _sysfs_nodes(self) -> list[_SysNode]:
        class_dir = self.sys_root / "class" / "video4linux"
        try:
            names = sorted(os.listdir(class_dir), key=_natural_key)
        except OSError:
            return []
        nodes = []
        for name in names:
            entry = class_dir / name
            card = _read_attr(entry, "name")
            index = _int_attr(entry, "index")
            device = Path(os.path.realpath(entry / "device"))
            usb_dir = self._usb_device_dir(device)
            parent_key = str(usb_dir) if usb_dir is not None else str(device)
            nodes.append(_SysNode(name, str(self.dev_root / name), card, index, usb_dir, parent_key))
        return nodes

    @staticmethod
    def _usb_device_dir(device: Path) -> Path | None:
        # `device` is the USB interface ('1-2.3:1.0'); its parent is the USB device ('1-2.3').
        for candidate in (device.parent, device):
            if _PORT_PATH.match(candidate.name) and (candidate / "idVendor").exists():
                return candidate
        return None

    def _split_capture(self, group: list[_SysNode]) -> tuple[list[_SysNode], list[_SysNode]]:
        capture, other = [], []
        for node in group:
            caps = self._probe_caps(node.node)
            if caps is not None:
                is_capture = bool(caps & (V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_VIDEO_CAPTURE_MPLANE))
            else:
                is_capture = node.index == 0 or (node.index is None and len(group) == 1)
            (capture if is_capture else other).append(node)
        return capture, other

    def _udev_links(self) -> dict[str, tuple[list[str], list[str]]]:
        links: dict[str, tuple[list[str], list[str]]] = {}
        for slot, kind in enumerate(("by-id", "by-path")):
            directory = self.dev_root / "v4l" / kind
            try:
                entries = sorted(os.listdir(directory))
            except OSError:
                continue
            for entry in entries:
                try:
                    target = os.readlink(directory / entry)
                except OSError:
                    continue
                links.setdefault(Path(target).name, ([], []))[slot].append(str(directory / entry))
        return links

    @staticmethod
    def _sysfs_identity(usb_dir: Path) -> UsbIdentity | None:
        vendor, product = _int_attr(usb_dir, "idVendor", 16), _int_attr(usb_dir, "idProduct", 16)
        if vendor is None or product is None:
            return None
        return UsbIdentity(
            vendor_id=vendor, product_id=product, bus=_int_attr(usb_dir, "busnum"), port_path=usb_dir.name,
            serial=_read_attr(usb_dir, "serial"), manufacturer=_read_attr(usb_dir, "manufacturer"),
            product=_read_attr(usb_dir, "product"), address=_int_attr(usb_dir, "devnum"), source="sysfs")

    @staticmethod
    def _merge_identity(from_usb: UsbIdentity | None, from_sysfs: UsbIdentity | None) -> UsbIdentity | None:
        if from_usb is None:
            return from_sysfs
        if from_sysfs is None:
            return from_usb
        # String descriptors need the device opened, which a normal user often may not do; sysfs has copies.
        return UsbIdentity(
            vendor_id=from_usb.vendor_id, product_id=from_usb.product_id, bus=from_usb.bus,
            port_path=from_usb.port_path, serial=from_usb.serial or from_sysfs.serial,
            manufacturer=from_usb.manufacturer or from_sysfs.manufacturer,
            product=from_usb.product or from_sysfs.product, address=from_usb.address, source="pyusb")

    # -- pyusb -----------------------------------------------------------------------------------------------------

    def _backend(self) -> Any | None:
        if self._usb_backend is _UNSET:
            self._usb_backend = default_usb_backend()
        return self._usb_backend

    def _pyusb_devices(self, scan: DeviceScan) -> dict[str, UsbIdentity]:
        backend = self._backend()
        if backend is None:
            scan.notes.append(NO_BACKEND_NOTE)
            return {}
        try:
            devices = list(usb.core.find(find_all=True, backend=backend, custom_match=_is_video_device))
        except usb.core.NoBackendError:
            scan.notes.append(NO_BACKEND_NOTE)
            return {}
        except usb.core.USBError as error:
            scan.notes.append(f"USB details unavailable: enumerating USB devices failed ({error}); "
                              f"identity read from sysfs only")
            return {}
        scan.usb_available = True
        found = {}
        for device in devices:
            port = _port_path(device)
            if port is None:
                continue
            serial, manufacturer, product = (_usb_string(device, attr) for attr in
                                             ("serial_number", "manufacturer", "product"))
            usb.util.dispose_resources(device)
            found[port] = UsbIdentity(
                vendor_id=device.idVendor, product_id=device.idProduct, bus=device.bus, port_path=port,
                serial=serial, manufacturer=manufacturer, product=product, address=device.address, source="pyusb")
        return found

    # -- resolution helpers ----------------------------------------------------------------------------------------

    def _map_dev_path(self, path: str) -> Path:
        """'/dev/v4l/by-id/x' under an injected dev root."""
        if path.startswith("/dev/") and str(self.dev_root) != "/dev":
            return self.dev_root / path[len("/dev/"):]
        return Path(path)

    def _resolve_link(self, link: Path, spec: str, scan: DeviceScan | None) -> CameraDevice:
        """A udev symlink (by-id, by-path, or a lab's own rule such as /dev/cam-left) to its camera."""
        if not os.path.islink(link):
            if os.path.exists(link) and _VIDEO_INDEX.match(link.name):
                raise self._unstable(spec, scan)
            if os.path.exists(link):
                raise CameraNotFound(f"{spec}: not a udev camera link; use a stable name from `stereo-bench devices`",
                                     device=spec)
            scan = scan or self.scan()
            known = [Path(p).name for cam in scan.cameras for p in (cam.by_id + cam.by_path)]
            hint = f"; present: {', '.join(known)}" if known else "; no cameras are connected"
            raise CameraNotFound(f"{spec}: no such camera link{hint}", device=spec)
        # Only the node name matters: udev links are relative ('../../video0') and the dev root may be injected.
        node_name = Path(os.readlink(link)).name
        scan = scan or self.scan()
        for camera in scan.cameras:
            if camera.capture_node and Path(camera.capture_node).name == node_name:
                if link.parent.name == "by-id" and scan.has_twin(camera):
                    ports = ", ".join(f"usb-port:{cam.usb.port_path}" for cam in scan.cameras
                                      if cam.usb and cam.capture_node and (cam is camera or (
                                          cam.usb.vendor_id, cam.usb.product_id, cam.usb.serial) == (
                                          camera.usb.vendor_id, camera.usb.product_id, camera.usb.serial)))
                    raise AmbiguousCameraSpec(
                        f"{spec}: identical cameras share this by-id name and udev points it at whichever appeared "
                        f"last; bind by port instead: {ports}", device=spec)
                return camera
            if any(Path(other).name == node_name for other in camera.other_nodes):
                raise CameraNotFound(f"{spec}: points to {node_name}, a metadata node, not the capture node; "
                                     f"use the camera's '-video-index0' link", device=spec)
        # udev made the link but sysfs shows no such node (a container without /sys): trust the link.
        kind = link.parent.name
        return CameraDevice(capture_node=str(self.dev_root / node_name),
                            by_id=(str(link),) if kind == "by-id" else (),
                            by_path=(str(link),) if kind == "by-path" else ())

    def _pick(self, spec: str, scan: DeviceScan | None, match: Callable[[CameraDevice], bool]) -> CameraDevice:
        scan = scan or self.scan()
        matches = [cam for cam in scan.cameras if match(cam)]
        # serial: and usb-port: name a USB device; a device with several capture streams means its first one.
        with_node = [cam for cam in matches if cam.capture_node and cam.primary]
        if len(with_node) == 1:
            return with_node[0]
        if len(with_node) > 1:
            ports = ", ".join(f"usb-port:{cam.usb.port_path}" for cam in with_node if cam.usb)
            raise AmbiguousCameraSpec(f"{spec}: matches {len(with_node)} cameras (identical serial numbers?); "
                                      f"bind by port instead: {ports}", device=spec)
        if matches:
            raise CameraNotFound(f"{spec}: the USB device is there but has no V4L2 capture node; "
                                 f"is the uvcvideo driver loaded?", device=spec)
        raise CameraNotFound(f"{spec}: no such camera; {_inventory(scan)}", device=spec)

    def _unstable(self, spec: str, scan: DeviceScan | None) -> UnstableCameraName:
        number = re.search(r"(\d+)$", spec)
        node_name = f"video{number.group(1)}" if number else spec
        alternatives: list[str] = []
        try:
            scan = scan or self.scan()
            for camera in scan.cameras:
                if camera.capture_node and Path(camera.capture_node).name == node_name:
                    alternatives = camera.stable_specs(scan)
        except OSError:
            pass
        use = f"use {' or '.join(alternatives)}" if alternatives else "use by-id:, serial: or usb-port: names " \
            "from `stereo-bench devices`"
        return UnstableCameraName(f"{spec}: /dev/videoN numbers change across reboots and replugs (left and right "
                                  f"could swap); {use}", device=spec)


# --- module helpers -----------------------------------------------------------------------------------------------


def is_unstable_name(spec: str, *, dev_root: str | Path = "/dev") -> bool:
    """True for a bare ``/dev/videoN``, ``videoN`` or index: a name :meth:`CameraRegistry.resolve` refuses. Pure (no
    device is looked at), so a campaign plan refuses it offline, as ``run`` does."""
    spec = spec.strip()
    return bool(_VIDEO_INDEX.match(spec) or re.match(rf"^{re.escape(str(dev_root))}/video\d+$", spec))


UNSTABLE_NAME_REASON = ("/dev/videoN numbers change across reboots and replugs (left and right could swap); use "
                        "by-id:, serial: or usb-port: names from `stereo-bench devices`")


def spec_key(spec: str) -> str:
    """One spelling of a camera spec, for telling whether two name the same camera without looking at devices:
    ``by-id:NAME`` and ``/dev/v4l/by-id/NAME`` (and ``by-path:``) are one name."""
    spec = spec.strip()
    kind, _, value = spec.partition(":")
    if kind in ("by-id", "by-path") and value:
        return f"/dev/v4l/{kind}/{value}"
    return spec


def _is_video_device(device: usb.core.Device) -> bool:
    if device.bDeviceClass == USB_CLASS_VIDEO:
        return True
    try:
        for configuration in device:
            for interface in configuration:
                if interface.bInterfaceClass == USB_CLASS_VIDEO:
                    return True
    except (usb.core.USBError, NotImplementedError, IndexError):
        return False
    return False


def _port_path(device: usb.core.Device) -> str | None:
    ports = getattr(device, "port_numbers", None)
    if device.bus is None or not ports:
        return None
    return f"{device.bus}-{'.'.join(str(p) for p in ports)}"


def _usb_string(device: usb.core.Device, attribute: str) -> str | None:
    try:
        value = getattr(device, attribute)
    except (usb.core.USBError, ValueError, NotImplementedError) as error:
        # Typically EACCES: reading strings opens the device; sysfs supplies them instead.
        log.debug("USB %s of %04x:%04x unreadable: %s", attribute, device.idVendor, device.idProduct, error)
        return None
    return value.strip() if isinstance(value, str) and value.strip() else None


def _natural_key(name: str) -> tuple[Any, ...]:
    return tuple(int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name))


def _camera_sort_key(camera: CameraDevice) -> tuple[Any, ...]:
    port = camera.usb.port_path if camera.usb and camera.usb.port_path else ""
    return (_natural_key(port), _natural_key(camera.capture_node or ""))


def _inventory(scan: DeviceScan) -> str:
    if not scan.cameras:
        return "no cameras are connected"
    described = []
    for camera in scan.cameras:
        parts = [camera.capture_node or "(no node)"]
        if camera.usb:
            parts.append(f"usb-port:{camera.usb.port_path}")
            if camera.usb.serial:
                parts.append(f"serial:{camera.usb.serial}")
        described.append(" ".join(parts))
    return "present: " + "; ".join(described)


# --- convenience functions ----------------------------------------------------------------------------------------


def list_cameras(**roots: Any) -> DeviceScan:
    """``CameraRegistry(**roots).scan()``."""
    return CameraRegistry(**roots).scan()


def resolve_camera(spec: str, **roots: Any) -> CameraDevice:
    """``CameraRegistry(**roots).resolve(spec)``: the camera a stable spec names."""
    return CameraRegistry(**roots).resolve(spec)


def usb_reset(target: CameraDevice | str, **roots: Any) -> UsbIdentity:
    """``CameraRegistry(**roots).usb_reset(target)``."""
    return CameraRegistry(**roots).usb_reset(target)

