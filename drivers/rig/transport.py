"""Byte transports for the rig controller: a pyserial port, a spy that records every byte, and a script.

The driver above sees only :class:`Transport`: ``open``/``close``, ``write(bytes)`` and ``read()``
returning whatever arrived within a short timeout. That is the lowest layer, so the fakes here
(:class:`ScriptedTransport`) and the pty emulator (drivers/sim) run all of the driver's logic.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import threading
import time
from collections import deque
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Protocol, runtime_checkable

import serial


class TransportError(OSError):
    """The port could not be opened, or it went away (unplugged, emulator stopped)."""


@runtime_checkable
class Transport(Protocol):
    """What the GRBL driver needs from a byte link."""

    name: str

    @property
    def is_open(self) -> bool: ...

    def open(self) -> None: ...

    def close(self) -> None: ...

    def write(self, data: bytes) -> None:
        """Send all of ``data``; raise :class:`TransportError` if the link is gone."""

    def read(self) -> bytes:
        """Return the bytes that arrived, waiting at most the transport's read timeout for the first one.

        ``b""`` means nothing arrived; :class:`TransportError` means the link is gone.
        """

    def cancel_read(self) -> None:
        """Make a blocked :meth:`read` return early (best effort)."""


class SerialTransport:
    """A pyserial port, from a path/URL (opened by :meth:`open`) or an already-open ``serial.SerialBase``.

    Args:
        port: device path (``/dev/ttyUSB0``, a pty path), a pyserial URL (``loop://``, ``spy://...``,
            ``socket://host:port``), or a ``serial.SerialBase`` the caller made (its settings are kept,
            except that the read timeout is set to ``read_timeout_s``).
        baudrate: bits per second (GRBL 1.1 default 115200).
        read_timeout_s: how long :meth:`read` waits for the first byte (s). Short, so that a reader
            thread notices a close promptly.
    """

    def __init__(self, port: str | serial.SerialBase, *, baudrate: int = 115200, read_timeout_s: float = 0.05):
        self._given = port if isinstance(port, serial.SerialBase) else None
        self._url = None if self._given is not None else str(port)
        self.name = self._url if self._url is not None else str(getattr(port, "port", None) or port)
        self.baudrate = baudrate
        self.read_timeout_s = read_timeout_s
        self._serial: serial.SerialBase | None = self._given

    @property
    def serial(self) -> serial.SerialBase | None:
        return self._serial

    @property
    def is_open(self) -> bool:
        return self._serial is not None and bool(self._serial.is_open)

    def open(self) -> None:
        if self.is_open:
            return
        try:
            if self._serial is None:
                self._serial = serial.serial_for_url(
                    self._url, baudrate=self.baudrate, timeout=self.read_timeout_s, write_timeout=2.0,
                    do_not_open=True,
                )
            else:
                self._serial.timeout = self.read_timeout_s
            if not self._serial.is_open:
                self._serial.open()
        except (serial.SerialException, OSError, ValueError) as error:
            self._serial = self._given
            raise TransportError(errno.ENODEV, f"cannot open serial port {self.name}: {_reason(error)}") from error

    def close(self) -> None:
        if self._serial is not None:
            with contextlib.suppress(Exception):
                self._serial.close()
        if self._given is None:
            self._serial = None

    def write(self, data: bytes) -> None:
        port = self._require_open()
        try:
            port.write(data)
        except (serial.SerialException, OSError) as error:
            raise TransportError(errno.EIO, f"write to {self.name} failed: {_reason(error)}") from error

    def read(self) -> bytes:
        port = self._require_open()
        try:
            data = port.read(1)
            if data:
                waiting = port.in_waiting
                if waiting:
                    data += port.read(waiting)
            return bytes(data)
        except (serial.SerialException, OSError, TypeError, AttributeError) as error:
            # TypeError/AttributeError: pyserial's posix read after a concurrent close (fd is None).
            raise TransportError(errno.EIO, f"read from {self.name} failed: {_reason(error)}") from error

    def cancel_read(self) -> None:
        port = self._serial
        if port is not None and hasattr(port, "cancel_read"):
            with contextlib.suppress(Exception):
                port.cancel_read()

    def reset_input_buffer(self) -> None:
        port = self._require_open()
        with contextlib.suppress(serial.SerialException, OSError):
            port.reset_input_buffer()

    def pulse_dtr(self, low_s: float = 0.1) -> bool:
        """Pulse DTR low then high, which resets an Arduino-based controller. Returns False where the
        port has no modem lines (a pty raises ENOTTY, errno 25; ``loop://`` ignores it)."""
        port = self._require_open()
        try:
            port.dtr = False
            time.sleep(low_s)
            port.dtr = True
            return True
        except OSError as error:
            if error.errno in (errno.ENOTTY, errno.EINVAL):
                return False
            raise TransportError(errno.EIO, f"DTR pulse on {self.name} failed: {_reason(error)}") from error
        except serial.SerialException:
            return False

    def _require_open(self) -> serial.SerialBase:
        if self._serial is None or not self._serial.is_open:
            raise TransportError(errno.EBADF, f"serial port {self.name} is not open")
        return self._serial


def _reason(error: BaseException) -> str:
    """A short reason: 'No such file or directory' rather than pyserial's nested repetition of the path."""
    code = getattr(error, "errno", None)
    if isinstance(code, int) and code > 0:
        return os.strerror(code)
    text = str(error).strip() or type(error).__name__
    return text.splitlines()[0]


class SpyTransport:
    """Wraps a transport and logs every byte each way, with ``time.monotonic()`` timestamps, as JSON lines.

    Each record is ``{"t": seconds, "dir": "tx"|"rx", "data": text}`` where ``data`` is the bytes decoded
    as latin-1 (lossless; JSON escapes control bytes such as 0x18). The first record is
    ``{"t": ..., "event": "open", "port": ..., "wall_time": unix seconds}`` so a log can be placed in time.
    The log is flushed after each record: a crash loses nothing already seen on the wire.
    """

    def __init__(self, inner: Transport, log: str | Path | IO[str]):
        self.inner = inner
        self.name = inner.name
        self._log_path = None if hasattr(log, "write") else Path(log)
        self._log: IO[str] | None = log if hasattr(log, "write") else None  # type: ignore[assignment]
        self._lock = threading.Lock()

    @property
    def is_open(self) -> bool:
        return self.inner.is_open

    def open(self) -> None:
        if self._log is None and self._log_path is not None:
            self._log = self._log_path.open("a", encoding="utf-8")
        self._record({"event": "open", "port": self.name, "wall_time": time.time()})
        try:
            self.inner.open()
        except TransportError as error:
            self._record({"event": "error", "message": str(error)})
            raise

    def close(self) -> None:
        self.inner.close()
        self._record({"event": "close"})
        if self._log_path is not None and self._log is not None:
            with self._lock:
                self._log.close()
                self._log = None

    def write(self, data: bytes) -> None:
        self._record({"dir": "tx", "data": data.decode("latin-1")})
        self.inner.write(data)

    def read(self) -> bytes:
        try:
            data = self.inner.read()
        except TransportError as error:
            self._record({"event": "error", "message": str(error)})
            raise
        if data:
            self._record({"dir": "rx", "data": data.decode("latin-1")})
        return data

    def cancel_read(self) -> None:
        self.inner.cancel_read()

    def _record(self, record: dict) -> None:
        with self._lock:
            if self._log is None:
                return
            self._log.write(json.dumps({"t": time.monotonic(), **record}) + "\n")
            self._log.flush()


def read_spy_log(path: str | Path) -> list[dict]:
    """The records of a :class:`SpyTransport` log, in order."""
    with Path(path).open(encoding="utf-8") as f:
        return [json.loads(line) for line in f if line.strip()]


def script_from_spy_log(path: str | Path) -> list[tuple[bytes | None, bytes]]:
    """Turn a spy log into request/reply pairs for :class:`ScriptedTransport`.

    Each write becomes a request; the bytes received after it (until the next write) become its reply.
    Bytes received before the first write become an unsolicited ``(None, reply)`` pair.
    """
    pairs: list[tuple[bytes | None, bytes]] = []
    request: bytes | None = None
    reply = bytearray()
    started = False
    for record in read_spy_log(path):
        direction = record.get("dir")
        if direction == "tx":
            if started or reply:
                pairs.append((request, bytes(reply)))
            request, reply, started = record["data"].encode("latin-1"), bytearray(), True
        elif direction == "rx":
            reply += record["data"].encode("latin-1")
    if started or reply:
        pairs.append((request, bytes(reply)))
    return pairs


class ScriptedTransport:
    """A transport that plays a script of request/reply pairs, in the manner of pymeasure's ``expected_protocol``.

    ``pairs`` is a sequence of ``(request, reply)``: when the driver writes exactly ``request`` the
    transport makes ``reply`` readable. A pair whose request is ``None`` is emitted unsolicited as soon
    as the pairs before it have been used (a banner, a pushed ``ALARM:N``). A write that is not the next
    expected request is recorded as a mismatch. :meth:`check` raises if anything went wrong or if a pair
    was never used; :func:`expected_protocol` calls it for you.
    """

    def __init__(self, pairs: Iterable[tuple[bytes | None, bytes | None]], *, name: str = "scripted",
                 read_timeout_s: float = 0.01):
        self.name = name
        self._pairs: deque[tuple[bytes | None, bytes | None]] = deque(pairs)
        self._total = len(self._pairs)
        self._rx = bytearray()
        self._cond = threading.Condition()
        self._open = False
        self._cancel = False
        self.read_timeout_s = read_timeout_s
        self.mismatches: list[str] = []
        self.written: list[bytes] = []

    @property
    def is_open(self) -> bool:
        return self._open

    def open(self) -> None:
        with self._cond:
            self._open = True
            self._release_unsolicited()

    def close(self) -> None:
        with self._cond:
            self._open = False
            self._cond.notify_all()

    def write(self, data: bytes) -> None:
        with self._cond:
            if not self._open:
                raise TransportError(errno.EBADF, f"{self.name} is not open")
            self.written.append(bytes(data))
            if not self._pairs:
                self.mismatches.append(f"unexpected write {bytes(data)!r}: the script is finished")
                return
            request, reply = self._pairs[0]
            if request != bytes(data):
                self.mismatches.append(f"wrote {bytes(data)!r}, expected {request!r}")
                return
            self._pairs.popleft()
            if reply:
                self._rx += reply
            self._release_unsolicited()
            self._cond.notify_all()

    def read(self) -> bytes:
        with self._cond:
            if not self._open:
                raise TransportError(errno.EBADF, f"{self.name} is not open")
            if not self._rx and not self._cancel:
                self._cond.wait(self.read_timeout_s)
            self._cancel = False
            data, self._rx = bytes(self._rx), bytearray()
            return data

    def cancel_read(self) -> None:
        with self._cond:
            self._cancel = True
            self._cond.notify_all()

    def push(self, data: bytes) -> None:
        """Make ``data`` readable now, outside the script (e.g. an alarm at a chosen moment)."""
        with self._cond:
            self._rx += data
            self._cond.notify_all()

    @property
    def unused(self) -> list[tuple[bytes | None, bytes | None]]:
        with self._cond:
            return list(self._pairs)

    def _release_unsolicited(self) -> None:
        while self._pairs and self._pairs[0][0] is None:
            _, reply = self._pairs.popleft()
            if reply:
                self._rx += reply

    def check(self) -> None:
        problems = list(self.mismatches)
        if self._pairs:
            problems.append(f"{len(self._pairs)} of {self._total} scripted pair(s) unused, next: {self._pairs[0]!r}")
        if problems:
            raise AssertionError("protocol mismatch on " + self.name + ":\n  " + "\n  ".join(problems))


@contextlib.contextmanager
def expected_protocol(pairs: Iterable[tuple[bytes | None, bytes | None]], **kwargs) -> Iterator[ScriptedTransport]:
    """Yield a :class:`ScriptedTransport`; on exit, fail if a write was unexpected or a pair went unused."""
    transport = ScriptedTransport(pairs, **kwargs)
    yield transport
    transport.check()
