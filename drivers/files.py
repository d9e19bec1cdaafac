"""Reading a user's input file safely: the one place every config, model, calibration file and recorded frame is
opened for reading, so that a path naming something other than a file fails in one line instead of hanging or
eating memory.

    from drivers.files import InputFileError, read_regular_file, read_toml

    data = read_toml(path, what="rig configuration file")            # dict; InputFileError naming the file
    raw = read_regular_file(path, what="frame", max_bytes=None)       # bytes

What is refused, before a byte is read (each an :class:`InputFileError` ``PATH: why``):

- anything that is not a regular file: a FIFO (reading one with no writer waits for ever), a character or block
  device (``/dev/zero`` never ends: ``MemoryError``; a serial port may reboot the controller behind it), a socket,
  a directory. ``os.stat`` decides first, so such a path is never opened; the file is then opened with
  ``O_NONBLOCK`` and checked again with ``fstat``, so one swapped in between cannot block the open either;
- a file larger than ``max_bytes`` (the stated size, and what is actually read: ``/proc`` files state 0);
- a missing file, a symlink loop, one we may not read;
- for TOML: text that is not UTF-8, that is not TOML, or whose arrays and inline tables nest more than
  :data:`MAX_TOML_NESTING` deep (``tomllib`` recurses once per level: 5,000 nested inline tables end in a
  ``RecursionError``); the nesting is measured by a scan of the text before ``tomllib`` sees it.

Lives in ``drivers`` because the rig configuration is read here; ``stereo_bench`` uses the same functions.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import os
import re
import stat
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

#: The largest TOML file a user gives (a campaign, a rig configuration, a kinematic model): the shipped ones are
#: 0.5-6 kB and a plan at its 20,000-configuration limit written value by value ~200 kB; ``tomllib`` reads 1 MiB
#: in ~0.7 s (scripts/bench_input_bounds.py).
MAX_TOML_BYTES = 1 << 20
#: How deep arrays and inline tables may nest in a TOML file: a real config nests at most 4 deep (a kinematic
#: model's ``fit.design`` list of tables inside its table); ``tomllib`` recurses per level and fails near 1,000.
MAX_TOML_NESTING = 32

_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


class InputFileError(ValueError):
    """An input file that cannot be read as one: ``PATH: why`` (exit status 2 at the command line)."""

    def __init__(self, path: str | os.PathLike, reason: str):
        super().__init__(f"{path}: {reason}")
        self.path = str(path)
        self.reason = reason


def _kind(mode: int) -> str:
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a file"


def _check_mode(path: str | os.PathLike, mode: int, what: str) -> None:
    if not stat.S_ISREG(mode):
        kind = _kind(mode)
        if stat.S_ISDIR(mode):
            raise InputFileError(path, f"is a directory, not a {what}")
        raise InputFileError(path, f"not a regular file ({kind}): give a {what}")


def _os_reason(error: OSError, what: str) -> str:
    if error.errno == errno.ENOENT:
        return f"no such {what}"
    if error.errno == errno.ELOOP:
        return "a symlink loop (or a symlink where none may be)"
    if error.errno in (errno.EACCES, errno.EPERM):
        return "cannot read: permission denied"
    return f"cannot read: {error.strerror or error}"


#: The files read in the current :func:`read_once` scope (path, follow_symlinks) -> bytes; None outside one.
_READ_ONCE: contextvars.ContextVar[dict[tuple[str, bool], bytes] | None] = contextvars.ContextVar(
    "read_once", default=None)


@contextlib.contextmanager
def read_once() -> Iterator[None]:
    """Within it, each file is read from disk once: a second :func:`read_regular_file` of the same path gets the
    bytes the first read (still checked against its own ``max_bytes``). A campaign's preflight reads its input
    files this way, so every parser of a file (a config validator, a preflight check, the run) sees the same
    bytes, read once. Nested scopes share the outer one's reads; an error is never remembered."""
    token = _READ_ONCE.set({}) if _READ_ONCE.get() is None else None
    try:
        yield
    finally:
        if token is not None:
            _READ_ONCE.reset(token)


def read_regular_file(path: str | os.PathLike, *, what: str = "file", max_bytes: int | None,
                      follow_symlinks: bool = True) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``max_bytes`` (None: any size).

    ``follow_symlinks=False``: a symlink itself is refused (ELOOP), as ``O_NOFOLLOW`` refuses it.
    Raises :class:`InputFileError` naming ``path`` (``what`` says what it should be: "campaign file").
    In a :func:`read_once` scope, a file already read there is not read again.
    """
    read = _READ_ONCE.get()
    if read is None:
        return _read_from_disk(path, what=what, max_bytes=max_bytes, follow_symlinks=follow_symlinks)
    key = (os.path.abspath(path), follow_symlinks)
    if key not in read:
        # complete: a read that succeeds is the whole file (at most its max_bytes)
        read[key] = _read_from_disk(path, what=what, max_bytes=max_bytes, follow_symlinks=follow_symlinks)
    data = read[key]
    _check_size(path, len(data), max_bytes, what)
    return data


def _read_from_disk(path: str | os.PathLike, *, what: str, max_bytes: int | None, follow_symlinks: bool) -> bytes:
    """:func:`read_regular_file`'s one read of the disk."""
    try:
        info = os.stat(path, follow_symlinks=follow_symlinks)
        if not follow_symlinks and stat.S_ISLNK(info.st_mode):
            raise OSError(errno.ELOOP, "a symlink", str(path))
        _check_mode(path, info.st_mode, what)
        _check_size(path, info.st_size, max_bytes, what)
        flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow_symlinks else os.O_NOFOLLOW)
        descriptor = os.open(path, flags)
    except OSError as error:
        raise InputFileError(path, _os_reason(error, what)) from None
    try:
        _check_mode(path, os.fstat(descriptor).st_mode, what)  # swapped for a FIFO since the stat: not read
        with open(descriptor, "rb", closefd=False) as file:
            data = file.read() if max_bytes is None else file.read(max_bytes + 1)
    except OSError as error:
        raise InputFileError(path, _os_reason(error, what)) from None
    finally:
        os.close(descriptor)
    _check_size(path, len(data), max_bytes, what)
    return data


def _check_size(path: str | os.PathLike, size: int, max_bytes: int | None, what: str) -> None:
    if max_bytes is not None and size > max_bytes:
        raise InputFileError(path, f"over {max_bytes:,} bytes: too large for a {what}")


# A TOML token that may hold brackets without nesting (strings, comments), or a bracket itself.
_TOML_TOKENS = re.compile(r'"""(?:[^\\"]+|\\.|"(?!""))*+"{3,5}'  # a multi-line basic string
                          r"|'''.*?'{3,5}"  # a multi-line literal string
                          r'|"(?:[^"\\\n]+|\\.)*+"'  # a basic string
                          r"|'[^'\n]*'"  # a literal string
                          r"|#[^\n]*|[\[\]{}]", re.S)  # a comment; a bracket


def toml_nesting(text: str) -> tuple[int, int]:
    """(deepest nesting of arrays and inline tables, offset in ``text`` where it is first reached).

    Brackets inside strings and comments do not count; a table header ``[a]`` counts 1 (``[[a]]`` 2).
    Linear in the text, with no recursion: this is what may be handed to ``tomllib``.
    """
    depth = deepest = where = 0
    for match in _TOML_TOKENS.finditer(text):
        token = match.group()
        if token in ("[", "{"):
            depth += 1
            if depth > deepest:
                deepest, where = depth, match.start()
        elif token in ("]", "}"):
            depth = max(0, depth - 1)
    return deepest, where


def parse_toml(text: str, source: str | os.PathLike) -> dict[str, Any]:
    """``tomllib.loads(text)`` with its nesting bounded first; :class:`InputFileError` naming ``source``."""
    deepest, where = toml_nesting(text)
    if deepest > MAX_TOML_NESTING:
        line = text.count("\n", 0, where) + 1
        raise InputFileError(source, f"arrays or inline tables nested over {MAX_TOML_NESTING} deep (line {line}): "
                                     "a config nests a few levels at most")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise InputFileError(source, f"invalid TOML: {error}") from None
    except RecursionError:  # the scan counts what tomllib recurses on; this is the last guard, never expected
        raise InputFileError(source, "nested too deeply for the TOML parser") from None


def decode_utf8(data: bytes, source: str | os.PathLike, kind: str = "TOML files") -> str:
    """``data`` as UTF-8 text; :class:`InputFileError` naming ``source`` and the first bad byte."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise InputFileError(source, f"not UTF-8 text (byte 0x{error.object[error.start]:02x} at offset "
                                     f"{error.start}): {kind} are UTF-8") from None


def read_toml(path: str | Path, *, what: str, max_bytes: int = MAX_TOML_BYTES) -> dict[str, Any]:
    """A user's TOML file, read safely (:func:`read_regular_file`) and parsed (:func:`parse_toml`)."""
    return parse_toml(decode_utf8(read_regular_file(path, what=what, max_bytes=max_bytes), path), path)


__all__ = ["MAX_TOML_BYTES", "MAX_TOML_NESTING", "InputFileError", "decode_utf8", "parse_toml", "read_once",
           "read_regular_file", "read_toml", "toml_nesting"]
