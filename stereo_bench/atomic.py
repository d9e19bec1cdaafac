"""Atomic file writes: a reader sees the old file, the new file, or no file — never half of one.

Every write goes to a temporary file in the target's directory (same filesystem, so the rename is
atomic), is flushed to disk with ``fsync``, renamed into place, and the directory is fsynced so the
rename itself survives a power loss. With ``overwrite=False`` the final step is a hard link, which
fails if the target exists: recorded data is never replaced by accident.

Temporary files are named ``.<name>.<random>.tmp`` (:data:`TEMP_SUFFIX`); a crash can leave one
behind, never a torn target. :func:`is_temp_file` recognises them for clean-up.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from stereo_bench import frames

TEMP_SUFFIX = ".tmp"


def is_temp_file(path: str | Path) -> bool:
    """True for a temporary file this module creates (``.<name>.<random>.tmp``)."""
    name = Path(path).name
    return name.startswith(".") and name.endswith(TEMP_SUFFIX)


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
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
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
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    tmp = Path(tmp_name)
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
