"""Side files of a session: the directories they live in, reading them back confined, the attempts on disk."""

from __future__ import annotations

import re
from pathlib import Path

from drivers.files import InputFileError, read_regular_file
from stereo_bench.campaign.session.errors import SessionError

RECOVERED_DIR = "recovered"
SESSION_LEVEL = "_session"  # the directory of side files of events that belong to no configuration

_ATTEMPT_DIR = re.compile(r"a(\d+)(?:-\d+)?")
_ATTEMPT_IN_NAME = re.compile(r"-a(\d+)(?:\.|$)")


def _read_no_follow(path: Path) -> bytes:
    """The bytes of ``path``; :class:`InputFileError` if it is a symlink (ELOOP), not a regular file (a FIFO is
    never opened: a replay would wait for its writer for ever) or cannot be read.

    O_NOFOLLOW is POSIX, as the ``fcntl`` locks of the writer are (resume opens the stream with it too).
    """
    return read_regular_file(path, what="frame", max_bytes=None, follow_symlinks=False)


def _read_side_file(path: Path, what: str = "side file") -> bytes:
    try:
        return read_regular_file(path, what=what, max_bytes=None)
    except InputFileError as error:
        reason = "side file missing" if error.reason.startswith("no such") else error.reason
        raise SessionError(f"{path}: {reason}") from None



def _attempts_on_disk(root: Path) -> int:
    """The highest attempt number that any side-file directory or transcript of ``root`` uses."""
    highest = 0
    for area in ("frames", "files", "calib"):
        for path in (root / area).glob("*/*"):
            match = _ATTEMPT_DIR.fullmatch(path.name)
            if match:
                highest = max(highest, int(match.group(1)))
    for area in ("transcripts", RECOVERED_DIR):
        for path in (root / area).glob("*"):
            match = _ATTEMPT_IN_NAME.search(path.name)
            if match:
                highest = max(highest, int(match.group(1)))
    return highest

