"""Calibration files in the layout of OpenCV's ``stereo_calib`` sample.

``intrinsics.yml``: M1, D1, M2, D2. ``extrinsics.yml``: R, T, R1, R2, P1, P2, Q. We add what produced
them as extra keys (image size, RMS, board, mode, date, software); OpenCV's sample ignores extra
keys and a file the sample wrote (no extra keys) loads here.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import cv2
import numpy as np

from stereo_bench import __version__
from stereo_bench.atomic import atomic_path
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.rectify import Rectification

INTRINSICS_FILE = "intrinsics.yml"
EXTRINSICS_FILE = "extrinsics.yml"


class CalibrationFileError(ValueError):
    """A calibration file is missing, unreadable or lacks a key; the message names the file and key."""


def _write_storage(path: Path, items: dict[str, object]) -> None:
    """Write one FileStorage YAML atomically (temporary file beside it, fsync, rename, directory fsync)."""
    with atomic_path(path) as tmp:
        # The temporary name does not end in .yml: name the format explicitly.
        storage = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
        for key, value in items.items():
            if value is None:
                continue
            if isinstance(value, np.ndarray):
                storage.write(key, np.asarray(value, np.float64))
            elif isinstance(value, bool):
                storage.write(key, int(value))
            elif isinstance(value, int | float | str):
                storage.write(key, value)
            else:
                raise TypeError(f"cannot write {key}={value!r} to {path}")
        storage.release()


def write_calibration(
    out_dir: str | Path, calib: StereoCalibration, rect: Rectification | None = None, *, board: str = "",
    extra: dict[str, object] | None = None,
) -> tuple[Path, Path]:
    """Write ``intrinsics.yml`` and ``extrinsics.yml`` into ``out_dir``; returns their paths."""
    out_dir = Path(out_dir)
    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    common = {
        "image_width": int(calib.image_size[0]), "image_height": int(calib.image_size[1]),
        "rms_px": float(calib.rms_px), "board": board, "mode": calib.mode, "date": date,
        "software": f"stereo-bench {__version__}", **(extra or {}),
    }
    intrinsics = out_dir / INTRINSICS_FILE
    extrinsics = out_dir / EXTRINSICS_FILE
    _write_storage(intrinsics, {"M1": calib.K1, "D1": calib.D1, "M2": calib.K2, "D2": calib.D2, **common})
    rect_items = {} if rect is None else {"R1": rect.R1, "R2": rect.R2, "P1": rect.P1, "P2": rect.P2, "Q": rect.Q}
    _write_storage(extrinsics, {"R": calib.R, "T": np.asarray(calib.T).reshape(3, 1), **rect_items, **common})
    return intrinsics, extrinsics


def _open(path: Path) -> cv2.FileStorage:
    if not path.is_file():
        raise CalibrationFileError(f"{path}: calibration file not found")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:  # OpenCV's parser error surfaces as SystemError in Python
        reason = getattr(error, "err", None) or getattr(error.__cause__, "err", None) or "parse error"
        raise CalibrationFileError(f"{path}: not a readable OpenCV YAML/XML file ({reason})") from None
    if not storage.isOpened():
        raise CalibrationFileError(f"{path}: not a readable OpenCV YAML/XML file")
    return storage


def _matrix(storage: cv2.FileStorage, path: Path, key: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    node = storage.getNode(key)
    value = None if node.empty() else node.mat()
    if value is None:
        raise CalibrationFileError(f"{path}: missing key {key!r}")
    value = np.asarray(value, np.float64)
    if shape is not None and value.size != int(np.prod(shape)):
        raise CalibrationFileError(f"{path}: key {key!r} has shape {value.shape}, expected {shape}")
    return value.reshape(shape) if shape is not None else value


def _image_size(storage: cv2.FileStorage) -> tuple[int, int] | None:
    width, height = storage.getNode("image_width"), storage.getNode("image_height")
    if width.empty() or height.empty():
        return None
    return int(width.real()), int(height.real())


def _resolve(path: str | Path, name: str) -> Path:
    path = Path(path)
    return path / name if path.is_dir() else path


def read_intrinsics(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[int, int] | None]:
    """(M1, D1, M2, D2, image_size or None) from a calibration directory or an intrinsics file."""
    path = _resolve(path, INTRINSICS_FILE)
    storage = _open(path)
    try:
        return (
            _matrix(storage, path, "M1", (3, 3)), _matrix(storage, path, "D1").reshape(1, -1),
            _matrix(storage, path, "M2", (3, 3)), _matrix(storage, path, "D2").reshape(1, -1),
            _image_size(storage),
        )
    finally:
        storage.release()


def read_calibration(calib_dir: str | Path, *, image_size: tuple[int, int] | None = None) -> StereoCalibration:
    """Load ``intrinsics.yml`` + ``extrinsics.yml`` from ``calib_dir``.

    ``image_size`` is needed when the files do not record it (OpenCV's own sample does not).
    """
    calib_dir = Path(calib_dir)
    if not calib_dir.is_dir():
        raise CalibrationFileError(f"{calib_dir}: calibration directory not found")
    K1, D1, K2, D2, stored_size = read_intrinsics(calib_dir)
    path = calib_dir / EXTRINSICS_FILE
    storage = _open(path)
    try:
        R = _matrix(storage, path, "R", (3, 3))
        T = _matrix(storage, path, "T", (3,))
        stored_size = stored_size or _image_size(storage)
        rms_node = storage.getNode("rms_px")
        rms_px = float("nan") if rms_node.empty() else float(rms_node.real())
        mode_node = storage.getNode("mode")
        mode = "given" if mode_node.empty() else mode_node.string()
    finally:
        storage.release()
    size = stored_size or image_size
    if size is None:
        raise CalibrationFileError(f"{calib_dir}: files do not record the image size (image_width, image_height)")
    return StereoCalibration(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=size, rms_px=rms_px, mode=mode)
