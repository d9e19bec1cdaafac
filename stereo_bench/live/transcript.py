"""The last lines of the rig's serial transcript, its latest status report and its alarms, for the live page.

The GRBL driver's spy log (``drivers/rig/transport.py`` SpyTransport) writes every chunk of bytes
each way as a JSON line ``{"t", "dir": "tx"|"rx", "data"}``. During a campaign the session records
it (``transcripts/serial-a<N>.jsonl``, named by the stream's ``transcript`` event): the page tails
that file. Without a session (``stereo-bench live``) the rig's spy log is this object itself
(it has ``write``/``flush``). Received chunks are reassembled into lines; status reports (``<...>``)
update the state and position but are not listed (they come several times a second).
"""

from __future__ import annotations

import json
import threading
from collections import deque
from pathlib import Path

from drivers.rig.codec import LineSplitter, ParseError, machine_position, parse_status, split_axes
from drivers.rig.config import RigConfig, to_physical


class TranscriptTail:
    """Keeps the last ``max_lines`` lines of a spy log, the latest status and every alarm line."""

    def __init__(self, rig_config: RigConfig | None = None, *, max_lines: int = 40):
        self.rig_config = rig_config
        self.lines: deque[str] = deque(maxlen=max_lines)
        self.alarms: list[str] = []
        self.state: str | None = None
        self.position: dict[str, float] = {}  # physical units, from the latest status report
        self._splitter = LineSplitter()
        self._wco: tuple[float, ...] | None = None
        self._partial = ""  # a record cut in the middle by a read of a growing file
        self._path: Path | None = None
        self._offset = 0
        self._lock = threading.Lock()
        self.changed = 0  # counts updates (for a reader that wants to know whether to re-read)

    # -- sources ----------------------------------------------------------------------------------------------

    def follow(self, path: Path) -> None:
        """Tail ``path`` from its start (poll with :meth:`poll`)."""
        with self._lock:
            self._path, self._offset, self._partial = Path(path), 0, ""

    def poll(self) -> bool:
        """Read what was appended to the followed file; True if anything was."""
        path = self._path
        if path is None:
            return False
        try:
            with path.open("rb") as handle:
                handle.seek(self._offset)
                data = handle.read(1 << 20)
        except OSError:
            return False
        if not data:
            return False
        self._offset += len(data)
        self.write(data.decode("utf-8", errors="replace"))
        return True

    def write(self, text: str) -> int:
        """Take spy-log JSON lines (also the IO interface a spy log writes to)."""
        with self._lock:
            text = self._partial + text
            *complete, self._partial = text.split("\n")
            for line in complete:
                if line.strip():
                    self._record(line)
            self.changed += 1
        return len(text)

    def flush(self) -> None:
        return None

    # -- parsing ----------------------------------------------------------------------------------------------

    def _record(self, line: str) -> None:
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            return
        direction = record.get("dir")
        if direction == "tx":
            data = record.get("data", "")
            shown = data.strip() or {"?": "?", "!": "!", "~": "~", "\x18": "^X"}.get(data, repr(data))
            if shown != "?":  # status polls are many and say nothing
                self.lines.append(f"> {shown}")
        elif direction == "rx":
            for text in self._splitter.feed(record.get("data", "").encode("latin-1")):
                self._received(text)
        elif record.get("event") in ("open", "close", "error"):
            detail = record.get("port") or record.get("message") or ""
            self.lines.append(f"-- {record['event']} {detail}".rstrip())

    def _received(self, text: str) -> None:
        if text.startswith("<") and text.endswith(">"):
            try:
                report = parse_status(text)
            except ParseError:
                self.lines.append(f"< {text}")
                return
            self.state = report.full_state
            if report.wco is not None:
                self._wco = report.wco
            position = machine_position(report, self._wco)
            if position is not None and self.rig_config is not None:
                self.position = to_physical(self.rig_config, split_axes(position))
            return
        self.lines.append(f"< {text}")
        if text.startswith("ALARM:"):
            self.alarms.append(text)
            self.state = "Alarm"

    def snapshot(self) -> dict:
        with self._lock:
            return {"state": self.state, "position": dict(self.position), "alarms": list(self.alarms[-10:]),
                    "lines": list(self.lines)}
