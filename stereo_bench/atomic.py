"""Atomic file writes: a reader sees the old file, the new file, or no file — never half of one.

Every write goes to a temporary file in the target's directory (same filesystem, so the rename is
atomic), is flushed to disk with ``fsync``, renamed into place, and the directory is fsynced so the
rename itself survives a power loss. With ``overwrite=False`` the final step is a hard link, which
fails if the target exists: recorded data is never replaced by accident.

Temporary files are named ``.<name>.<random>.tmp`` (:data:`TEMP_SUFFIX`); a crash can leave one
behind, never a torn target. :func:`is_temp_file` recognises them for clean-up.

Files and directories are created with the ordinary modes (0o666 and 0o777) less the user's umask, as
``open`` and ``mkdir`` make them — not ``mkstemp``'s 0600 / ``mkdtemp``'s 0700 — so a session or report
is as readable by colleagues as anything else the user writes.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from stereo_bench import frames

TEMP_SUFFIX = ".tmp"


def is_temp_file(path: str | Path) -> bool:
    """True for a temporary file this module creates (``.<name>.<random>.tmp``)."""
    name = Path(path).name
    return name.startswith(".") and name.endswith(TEMP_SUFFIX)


def _temp_name(directory: Path, prefix: str) -> Path:
    return directory / f"{prefix}{secrets.token_hex(6)}{TEMP_SUFFIX}"


def make_temp_file(directory: str | Path, prefix: str) -> tuple[int, Path]:
    """Create a new, empty temporary file ``<prefix><random>.tmp`` in ``directory``, mode 0o666 less the umask.

    Returns (an open write descriptor, its path). Like ``tempfile.mkstemp`` (O_EXCL, never an existing file)
    but with the mode every other file of the user gets.
    """
    for _ in range(100):
        path = _temp_name(Path(directory), prefix)
        try:
            return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC | os.O_NOFOLLOW, 0o666), path
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(directory))


def make_temp_dir(directory: str | Path, prefix: str) -> Path:
    """Create a new temporary directory ``<prefix><random>.tmp`` in ``directory``, mode 0o777 less the umask."""
    for _ in range(100):
        path = _temp_name(Path(directory), prefix)
        try:
            os.mkdir(path, 0o777)
            return path
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(directory))


def fsync_dir(directory: str | Path) -> None:
    """Flush a directory entry change (create, rename, unlink) to disk."""
    fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    except OSError as error:  # some filesystems cannot fsync a directory; the rename is still atomic
        if error.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def _commit(tmp: Path, path: Path, *, overwrite: bool) -> None:
    if overwrite:
        os.replace(tmp, path)
    else:
        os.link(tmp, path)  # FileExistsError if the target exists; never replaces it
        os.unlink(tmp)
    fsync_dir(path.parent)


@contextlib.contextmanager
def atomic_path(path: str | Path, *, overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on a clean exit fsync it and rename it to ``path``.

    For writers that want a file name (``cv2.FileStorage``, ``sqlite3``, ``cv2.imwrite``). The
    temporary file exists (empty) when the block starts; on an exception it is removed and ``path``
    is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not overwrite and path.exists():
        raise FileExistsError(errno.EEXIST, "refusing to overwrite", str(path))
    fd, tmp = make_temp_file(path.parent, prefix=f".{path.name}.")
    os.close(fd)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        _commit(tmp, path, overwrite=overwrite)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def write_bytes(path: str | Path, data: bytes, *, overwrite: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file + fsync + rename + directory fsync)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not overwrite and path.exists():
        raise FileExistsError(errno.EEXIST, "refusing to overwrite", str(path))
    fd, tmp = make_temp_file(path.parent, prefix=f".{path.name}.")
    try:
        view = memoryview(data)
        while view:
            written = os.write(fd, view)
            view = view[written:]
        os.fsync(fd)
        os.close(fd)
        fd = -1
        _commit(tmp, path, overwrite=overwrite)
    except OSError as error:  # os.write names no file: a full disk must say which file it could not write
        if error.filename is None:
            error.filename = str(path)
        raise
    finally:
        if fd >= 0:
            os.close(fd)
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return path


def write_text(path: str | Path, text: str, *, encoding: str = "utf-8", overwrite: bool = True) -> Path:
    """Write ``text`` to ``path`` atomically."""
    return write_bytes(path, text.encode(encoding), overwrite=overwrite)


def write_png(path: str | Path, image: np.ndarray, *, overwrite: bool = True) -> Path:
    """Write ``image`` as a lossless PNG atomically (:func:`stereo_bench.frames.encode_frame`, then
    :func:`write_bytes`).

    Raises:
        ValueError: the image cannot be stored losslessly (:class:`stereo_bench.frames.FrameError`).
    """
    return write_bytes(path, frames.encode_frame(image), overwrite=overwrite)
