"""Paths confined to their roots: the one rule for names used in file names, and the checks that keep every
read and write of a session, report or replay inside its directory (symlinks resolved).

A *name* (a configuration id, a side file's or transcript's name, a report's session key) becomes one
path component, so it must be one: letters, digits, ``.``, ``_``, ``+``, ``-``, starting with a letter or
digit (so never ``.``, ``..`` or a hidden file), at most :data:`NAME_MAX` characters, no ``/``. The
session writer refuses to record a bad name, the reader refuses a session whose documents carry one, and
the report and replay build file names only from names that pass.
"""

from __future__ import annotations

import os
import re
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

    Raises :class:`OutsideRoot` naming the path and where it leads.
    """
    resolved_root = Path(root).resolve()
    target = Path(path)
    resolved = (target if target.is_absolute() else Path(root) / target).resolve()
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


__all__ = ["NAME_MAX", "NAME_RULE", "OutsideRoot", "UnsafeName", "check_name", "confined", "is_inside",
           "is_safe_name", "symlinks_leaving"]
