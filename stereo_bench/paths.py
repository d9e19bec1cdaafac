"""Paths confined to their roots: the one rule for names used in file names, and the checks that keep every
read and write of a session, report or replay inside its directory (symlinks resolved).

A *name* (a configuration id, a side file's or transcript's name, a report's session key) becomes one
path component, so it must be one: letters, digits, ``.``, ``_``, ``+``, ``-``, starting with a letter or
digit (so never ``.``, ``..`` or a hidden file), at most :data:`NAME_MAX` characters, no ``/``. The
session writer refuses to record a bad name, the reader refuses a session whose documents carry one, and
the report and replay build file names only from names that pass.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import stat
from pathlib import Path

NAME_MAX = 100  # leaves room for the suffixes added to it ("_rectified.jpg", "-a12.jsonl") within 255 bytes
NAME_RULE = f"letters, digits, '.', '_', '+', '-', starting with a letter or digit, at most {NAME_MAX} characters"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")


class UnsafeName(ValueError):
    """A name that cannot be used as one path component."""


class OutsideRoot(ValueError):
    """A path that is, or resolves (through a symlink) to, somewhere outside the directory it must stay in."""


def is_safe_name(value: object) -> bool:
    return isinstance(value, str) and len(value) <= NAME_MAX and _NAME.fullmatch(value) is not None


def check_name(value: object, what: str) -> str:
    """``value`` if it is a safe name (see the module docstring); else :class:`UnsafeName` saying ``what`` it is."""
    if not is_safe_name(value):
        raise UnsafeName(f"{what} {value!r} is not a valid name ({NAME_RULE})")
    return value  # type: ignore[return-value]


def is_inside(root: Path, path: Path) -> bool:
    """True if ``path`` is ``root`` or below it, both as given (resolve them first to follow symlinks)."""
    return path.is_relative_to(root)


def confined(root: str | Path, path: str | Path) -> Path:
    """``path`` resolved (symlinks followed, also for a file that does not exist yet), if it lies inside ``root``.

    Raises :class:`OutsideRoot` naming the path and where it leads (or that it leads nowhere: a symlink loop).
    """
    target = Path(path)
    try:
        resolved_root = Path(root).resolve()
        resolved = (target if target.is_absolute() else Path(root) / target).resolve()
    except (RuntimeError, OSError) as error:  # a symlink loop (RuntimeError before Python 3.13): leads nowhere
        raise OutsideRoot(f"{path} cannot be resolved ({error})") from None
    if not is_inside(resolved_root, resolved):
        raise OutsideRoot(f"{path} resolves to {resolved}, outside {root} (a symlink?)")
    return resolved


def symlinks_leaving(root: str | Path) -> list[Path]:
    """Every symlink under ``root`` (not followed) that resolves outside it, or dangles outside it, sorted.

    One ``scandir`` per directory and no ``stat`` per file (a session holds thousands of frames).
    """
    resolved_root = Path(root).resolve()
    found, pending = [], [Path(root)]
    while pending:
        with os.scandir(pending.pop()) as entries:
            for entry in entries:
                if entry.is_symlink():
                    if not is_inside(resolved_root, Path(entry.path).resolve()):
                        found.append(Path(entry.path))
                elif entry.is_dir(follow_symlinks=False):
                    pending.append(Path(entry.path))
    return sorted(found)


# -- where an action will write: checked before it starts ---------------------------------------------------------

#: The file every session directory holds (campaign.session.DOCUMENTS_FILE): what makes a directory a recording.
SESSION_MARKER = "documents.jsonl"


class UnwritablePath(ValueError):
    """An output path an action could not write, or must not (it would overwrite a recording); one line naming it."""


def _kind(mode: int) -> str:
    return ("a FIFO" if stat.S_ISFIFO(mode) else "a character device" if stat.S_ISCHR(mode)
            else "a block device" if stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a file")


def nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists (symlinks followed), made absolute."""
    current = Path(os.path.abspath(path))
    while not os.path.lexists(current) and current != current.parent:
        current = current.parent
    return current


def recording_holding(path: Path) -> Path | None:
    """The recorded session directory ``path`` lies in (itself or an ancestor holding :data:`SESSION_MARKER`)."""
    current = nearest_existing(path)
    for directory in (current, *current.parents):
        if (directory / SESSION_MARKER).is_file():
            return directory
    return None


def probe_writable(directory: Path) -> str | None:
    """None if a new file can be created in ``directory`` (tried: one is created and removed), else why not.

    ``os.access`` cannot tell: it says yes to root everywhere, and about ``/proc`` or a read-only mount it says
    nothing true.
    """
    probe = directory / f".stereo-bench-probe-{secrets.token_hex(6)}.tmp"
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600))
    except OSError as error:
        reason = error.strerror or str(error)
        if error.errno in (errno.ENOENT, errno.EROFS):
            reason += " (a read-only or virtual file system)"
        return reason
    os.unlink(probe)
    return None


def check_output_file(path: str | Path, *, option: str, exists_ok: bool = False,
                      will_create: str | Path | None = None) -> Path:
    """``path`` if an action can write it as a new file (or append to it: ``exists_ok``); else :class:`UnwritablePath`.

    Checked before the action starts (before a rig moves or an operator presents a board), so that a path it
    cannot write fails in one line up front, not after the work: ``path`` is not a directory or a special file,
    exists only if ``exists_ok``, does not lie inside a recorded session (a recording is never written into), and
    its directory exists (or lies inside ``will_create``, a directory the action makes first) and a file can be
    created there.
    """
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        info = None
    except OSError as error:
        raise UnwritablePath(f"{option} {path}: {error.strerror or error}") from None
    if info is not None:
        if stat.S_ISDIR(info.st_mode):
            raise UnwritablePath(f"{option} {path}: is a directory; give a file name")
        if not stat.S_ISREG(info.st_mode):
            raise UnwritablePath(f"{option} {path}: exists and is not a regular file ({_kind(info.st_mode)})")
        if not exists_ok:
            raise UnwritablePath(f"{option} {path}: exists; not overwriting it (choose another path)")
    recording = recording_holding(path.parent)
    if recording is not None:
        raise UnwritablePath(f"{option} {path}: lies inside the recorded session {recording}: a recording is never "
                             "written into (choose a path outside it)")
    parent = Path(os.path.abspath(path.parent))
    existing = nearest_existing(parent)
    if not existing.is_dir():
        raise UnwritablePath(f"{option} {path}: {existing} is not a directory")
    if existing != parent and not (will_create is not None and is_inside(Path(os.path.abspath(will_create)), parent)):
        raise UnwritablePath(f"{option} {path}: directory {parent} does not exist")
    reason = probe_writable(existing)
    if reason is not None:
        raise UnwritablePath(f"{option} {path}: cannot create a file in {existing}: {reason}")
    return path


__all__ = ["NAME_MAX", "NAME_RULE", "SESSION_MARKER", "OutsideRoot", "UnsafeName", "UnwritablePath", "check_name",
           "check_output_file", "confined", "is_inside", "is_safe_name", "nearest_existing", "probe_writable",
           "recording_holding", "symlinks_leaving"]
