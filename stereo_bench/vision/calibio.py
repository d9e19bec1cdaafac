"""Calibration files in the layout of OpenCV's ``stereo_calib`` sample.

``intrinsics.yml``: M1, D1, M2, D2. ``extrinsics.yml``: R, T, R1, R2, P1, P2, Q. We add what produced
them as extra keys (image size, RMS, board, mode, date, software); OpenCV's sample ignores extra
keys and a file the sample wrote (no extra keys) loads here.

The calibration's covariance (:mod:`stereo_bench.vision.covariance`) is written as more keys:
``covariance_parameters`` (the parameter names, space-separated, in the matrix's order),
``covariance`` (P x P; px, unitless, rad, mm as the names say), ``covariance_sigma_px`` (the corner
noise it is scaled by), ``covariance_dof`` and ``pixel_locking_px`` (1 x 2: the detector's fitted
pixel locking, sin and cos coefficients, when estimated). ``extrinsics.yml`` holds the whole matrix (both
cameras' intrinsics, rvec, T and their correlations); ``intrinsics.yml`` the intrinsics' block, so
that intrinsics reused alone (``--intrinsics``) keep their uncertainty. A file without these keys
loads with the covariance None: unknown, not zero (``covariance_note`` says why).

The lens model (:mod:`stereo_bench.vision.lensmodels`) is recorded in both files: ``lens_model`` (its name; the
length of D1/D2 follows from it: 5, 8 or 12), and, when it was chosen from a comparison, ``lens_model_requested``
("auto" or a name), ``lens_model_reason``, ``lens_model_choice_z``, ``lens_model_diagonal_fov_deg``,
``lens_model_candidates`` (names, space-separated) and ``lens_model_comparison`` (one row per candidate: free
intrinsics per camera, fit RMS px, held-out RMS px, held-out square RMS mm; NaN where no held-out estimate). A
file without them (older, or OpenCV's) loads with ``lens_model`` "" (not recorded).
"""

from __future__ import annotations

import datetime as _dt
import re
from pathlib import Path

import cv2
import numpy as np

from drivers.files import InputFileError, read_regular_file
from stereo_bench import __version__
from stereo_bench.atomic import write_text
from stereo_bench.vision.calibrate import StereoCalibration, calibration_problems, camera_problems
from stereo_bench.vision.covariance import CalibrationCovariance
from stereo_bench.vision.rectify import Rectification

INTRINSICS_FILE = "intrinsics.yml"
EXTRINSICS_FILE = "extrinsics.yml"
NO_COVARIANCE_NOTE = "the calibration file has no covariance: its uncertainty is unknown"


class CalibrationFileError(ValueError):
    """A calibration file is missing, unreadable or lacks a key; the message names the file and key."""


def _write_storage(path: Path, items: dict[str, object]) -> None:
    """Write one FileStorage YAML atomically (temporary file beside it, fsync, rename, directory fsync).

    OpenCV composes the text in memory and Python writes it: OpenCV's own file writer ignores write errors,
    so on a full disk it left empty calibration files and reported success.
    """
    storage = cv2.FileStorage(".yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
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
    write_text(path, storage.releaseAndGetString())


def _covariance_items(covariance: CalibrationCovariance | None, note: str) -> dict[str, object]:
    if covariance is None:
        return {"covariance_note": note or "not computed"}
    locking = None if covariance.pixel_locking_px is None else np.array([covariance.pixel_locking_px])
    return {
        "covariance_parameters": " ".join(covariance.names), "covariance": covariance.matrix,
        "covariance_sigma_px": float(covariance.sigma_px), "covariance_dof": int(covariance.dof),
        "pixel_locking_px": locking,
        # (n_views, P) the views' linearised leave-one-out changes: the jackknife of CalibrationCovariance.variance_of
        "covariance_view_deltas": covariance.view_deltas,
    }


#: The model-adequacy keys of extrinsics.yml (uncertainty.ModelAdequacy's fields; absent when not computed).
_ADEQUACY_KEYS = {"u_rel": "adequacy_u_rel", "dof": "adequacy_dof", "n_views": "adequacy_views",
                  "rms_rel": "adequacy_rms_rel", "predicted_rel": "adequacy_predicted_rel",
                  "bias_rel": "adequacy_bias_rel", "corner_px": "adequacy_corner_px"}
#: Written since the check separated the noise's lengthening of the held-out squares; a file without it reads 0.
_ADEQUACY_OPTIONAL_KEYS = {"lengthening_rel": "adequacy_lengthening_rel"}


def _adequacy_items(adequacy) -> dict[str, object]:
    if adequacy is None:
        return {}
    values = adequacy.as_dict()
    return {key: (int(values[name]) if name == "n_views" else float(values[name]))
            for name, key in {**_ADEQUACY_KEYS, **_ADEQUACY_OPTIONAL_KEYS}.items()}


def _lens_items(calib: StereoCalibration) -> dict[str, object]:
    if not calib.lens_model:
        return {}
    items: dict[str, object] = {"lens_model": calib.lens_model}
    choice = calib.lens_choice
    if choice is not None:
        items.update({
            "lens_model_requested": choice.requested, "lens_model_reason": choice.reason,
            "lens_model_choice_z": float(choice.as_dict()["choice_z"]),
            "lens_model_diagonal_fov_deg": float(choice.diagonal_fov_deg),
            "lens_model_candidates": " ".join(h.model for h in choice.comparison),
            "lens_model_comparison": np.array([[h.n_free, h.fit_rms_px, h.reprojection_rms_px, h.square_rms_mm]
                                               for h in choice.comparison], float),
        })
    return items


def recorded_lens_choice(calib_dir: str | Path) -> dict | None:
    """The lens model and its comparison as a calibration recorded them (``lens_model*`` keys), or None.

    ``{"chosen", "requested", "reason", "diagonal_fov_deg", "comparison": [{"model", "free_intrinsics_per_camera",
    "fit_rms_px", "held_out_rms_px", "held_out_square_rms_mm"}, ...]}``; "requested" etc. None when only the
    model's name was recorded.
    """
    path = _resolve(calib_dir, EXTRINSICS_FILE)
    storage = _open(path)
    try:
        node = storage.getNode("lens_model")
        if node.empty():
            return None
        result: dict = {"chosen": node.string(), "requested": None, "reason": None, "diagonal_fov_deg": None,
                        "comparison": []}
        for key, field in (("lens_model_requested", "requested"), ("lens_model_reason", "reason")):
            if not storage.getNode(key).empty():
                result[field] = storage.getNode(key).string()
        if not storage.getNode("lens_model_diagonal_fov_deg").empty():
            result["diagonal_fov_deg"] = float(storage.getNode("lens_model_diagonal_fov_deg").real())
        names_node = storage.getNode("lens_model_candidates")
        if not names_node.empty():
            names = names_node.string().split()
            table = storage.getNode("lens_model_comparison").mat()
            table = np.zeros((0, 4)) if table is None else np.asarray(table, float).reshape(-1, 4)
            if len(table) != len(names):
                raise CalibrationFileError(f"{path}: key 'lens_model_comparison' has {len(table)} rows for the "
                                           f"{len(names)} lens_model_candidates")
            result["comparison"] = [
                {"model": name, "free_intrinsics_per_camera": int(row[0]), "fit_rms_px": float(row[1]),
                 "held_out_rms_px": float(row[2]), "held_out_square_rms_mm": float(row[3])}
                for name, row in zip(names, table, strict=True)]
        return result
    finally:
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
    cov = calib.covariance
    intrinsic_cov = None if cov is None else cov.subset([n for n in cov.names if n.startswith(("left.", "right."))])
    common.update(_lens_items(calib))
    _write_storage(intrinsics, {"M1": calib.K1, "D1": calib.D1, "M2": calib.K2, "D2": calib.D2, **common,
                                **_covariance_items(intrinsic_cov, calib.covariance_note)})
    rect_items = {} if rect is None else {"R1": rect.R1, "R2": rect.R2, "P1": rect.P1, "P2": rect.P2, "Q": rect.Q}
    _write_storage(extrinsics, {"R": calib.R, "T": np.asarray(calib.T).reshape(3, 1), **rect_items, **common,
                                **_covariance_items(cov, calib.covariance_note),
                                **_adequacy_items(getattr(calib, "adequacy", None))})
    return intrinsics, extrinsics


#: The largest calibration file read: one with the whole covariance of a joint calibration is ~20 kB.
MAX_CALIBRATION_FILE_BYTES = 16 << 20


def _open(path: Path) -> cv2.FileStorage:
    """The file as an OpenCV FileStorage, read as every input file is (:func:`drivers.files.read_regular_file`:
    a FIFO or a device is refused, not opened) and parsed from memory."""
    try:
        data = read_regular_file(path, what="calibration file", max_bytes=MAX_CALIBRATION_FILE_BYTES)
    except InputFileError as error:
        reason = "calibration file not found" if error.reason.startswith("no such") else error.reason
        raise CalibrationFileError(f"{path}: {reason}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise CalibrationFileError(f"{path}: not a readable OpenCV YAML/XML file (not UTF-8 text at byte "
                                   f"{error.start})") from None
    if not text.strip():
        raise CalibrationFileError(f"{path}: not a readable OpenCV YAML/XML file (empty)")
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
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
    if not np.all(np.isfinite(value)):
        raise CalibrationFileError(f"{path}: key {key!r} has non-finite entries (.nan or .inf)")
    return value.reshape(shape) if shape is not None else value


def _image_size(storage: cv2.FileStorage) -> tuple[int, int] | None:
    width, height = storage.getNode("image_width"), storage.getNode("image_height")
    if width.empty() or height.empty():
        return None
    return int(width.real()), int(height.real())


def _covariance(storage: cv2.FileStorage, path: Path) -> tuple[CalibrationCovariance | None, str]:
    """(covariance, note) from the covariance keys; (None, why) when the file has none."""
    names_node = storage.getNode("covariance_parameters")
    if names_node.empty():
        note_node = storage.getNode("covariance_note")
        return None, NO_COVARIANCE_NOTE if note_node.empty() else note_node.string()
    names = tuple(names_node.string().split())
    matrix = _matrix(storage, path, "covariance")
    if matrix.shape != (len(names), len(names)):
        raise CalibrationFileError(f"{path}: key 'covariance' has shape {matrix.shape}, expected "
                                   f"{(len(names), len(names))} for its {len(names)} covariance_parameters")
    if not np.all(np.isfinite(matrix)) or np.any(np.diag(matrix) < 0) or not np.allclose(matrix, matrix.T, rtol=1e-9,
                                                                                          atol=0):
        raise CalibrationFileError(f"{path}: key 'covariance' is not a finite symmetric matrix with a "
                                   "non-negative diagonal")
    sigma_node, dof_node = storage.getNode("covariance_sigma_px"), storage.getNode("covariance_dof")
    locking = None
    if not storage.getNode("pixel_locking_px").empty():
        a_sin, a_cos = _matrix(storage, path, "pixel_locking_px", (2,))
        locking = (float(a_sin), float(a_cos))
    deltas = None
    if not storage.getNode("covariance_view_deltas").empty():
        deltas = _matrix(storage, path, "covariance_view_deltas")
        if deltas.ndim != 2 or deltas.shape[1] != len(names) or not np.all(np.isfinite(deltas)):
            raise CalibrationFileError(f"{path}: key 'covariance_view_deltas' has shape {deltas.shape}, expected "
                                       f"(views, {len(names)}) finite values")
    try:
        covariance = CalibrationCovariance(
            names, matrix, sigma_px=float("nan") if sigma_node.empty() else float(sigma_node.real()),
            dof=0 if dof_node.empty() else int(dof_node.real()), pixel_locking_px=locking, view_deltas=deltas)
    except ValueError as error:
        raise CalibrationFileError(f"{path}: key 'covariance_parameters': {error}") from None
    return covariance, ""


def read_intrinsics_covariance(path: str | Path) -> CalibrationCovariance | None:
    """The covariance of the intrinsics (``left.*``, ``right.*``) stored with them, or None (unknown)."""
    path = _resolve(path, INTRINSICS_FILE)
    storage = _open(path)
    try:
        return _covariance(storage, path)[0]
    finally:
        storage.release()


def calibration_board_scale_u(calib_dir: str | Path) -> float | None:
    """The calibration board's relative scale uncertainty a calibration recorded (``board_scale_u_rel``), or None."""
    path = _resolve(calib_dir, EXTRINSICS_FILE)
    storage = _open(path)
    try:
        node = storage.getNode("board_scale_u_rel")
        return None if node.empty() else float(node.real())
    finally:
        storage.release()


def _resolve(path: str | Path, name: str) -> Path:
    path = Path(path)
    return path / name if path.is_dir() else path


def read_intrinsics(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[int, int] | None]:
    """(M1, D1, M2, D2, image_size or None) from a calibration directory or an intrinsics file."""
    path = _resolve(path, INTRINSICS_FILE)
    storage = _open(path)
    try:
        K1, D1 = _matrix(storage, path, "M1", (3, 3)), _matrix(storage, path, "D1").reshape(1, -1)
        K2, D2 = _matrix(storage, path, "M2", (3, 3)), _matrix(storage, path, "D2").reshape(1, -1)
        size = _image_size(storage)
    finally:
        storage.release()
    # Refused here, where the file is named, rather than measured into nothing later (a zero focal length).
    problems = camera_problems(K1, D1, size, "M1, D1 (left camera)") + camera_problems(K2, D2, size,
                                                                                        "M2, D2 (right camera)")
    if problems:
        raise CalibrationFileError(f"{path}: not usable intrinsics: {problems[0]}")
    return K1, D1, K2, D2, size


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
        covariance, note = _covariance(storage, path)
        adequacy = _adequacy(storage, path)
        lens_node = storage.getNode("lens_model")
        lens_model = "" if lens_node.empty() else lens_node.string()
    finally:
        storage.release()
    size = stored_size or image_size
    if size is None:
        raise CalibrationFileError(f"{calib_dir}: files do not record the image size (image_width, image_height)")
    calib = StereoCalibration(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=size, rms_px=rms_px, mode=mode,
                              covariance=covariance, covariance_note=note, adequacy=adequacy,
                              lens_model=lens_model)
    problems = calibration_problems(calib)
    if problems:
        raise CalibrationFileError(f"{calib_dir}: not a usable stereo calibration: {problems[0]}")
    return calib


def _adequacy(storage: cv2.FileStorage, path: Path):
    """The calibration's leave-one-view-out check (uncertainty.ModelAdequacy) from its keys; None without them."""
    from stereo_bench.vision.uncertainty import ModelAdequacy

    if storage.getNode(_ADEQUACY_KEYS["u_rel"]).empty():
        return None
    values = {}
    for name, key in _ADEQUACY_KEYS.items():
        node = storage.getNode(key)
        if node.empty() or not node.isReal() and not node.isInt():
            raise CalibrationFileError(f"{path}: key {key!r} is missing or not a number (the adequacy_* keys go "
                                       "together)")
        values[name] = float(node.real())
    for name, key in _ADEQUACY_OPTIONAL_KEYS.items():
        node = storage.getNode(key)
        if not node.empty():
            if not node.isReal() and not node.isInt() or not np.isfinite(node.real()):
                raise CalibrationFileError(f"{path}: key {key!r} must be a finite number")
            values[name] = float(node.real())
    if not all(np.isfinite(v) for k, v in values.items() if k != "corner_px") or values["u_rel"] < 0:
        raise CalibrationFileError(f"{path}: key 'adequacy_u_rel' must be a finite number >= 0")
    return ModelAdequacy.from_dict(values)


def recorded_target(calib_dir: str | Path) -> tuple[str, str, float, float | None, str | None] | None:
    """(kind, "COLSxROWS", square mm, marker mm, ArUco dictionary) of the board a calibration recorded (``board``:
    "checkerboard 8x5 square 15.0 mm", or "charuco-inverted 4x5 square 54.0 mm marker 40.5 mm DICT_4X4_1000", as
    ``calibrate`` writes it: kind "charuco-inverted" for a ChArUco board printed white on black; marker and
    dictionary None for a checkerboard or a file written before they were recorded), or None when the file records
    none or in another form."""
    path = _resolve(calib_dir, EXTRINSICS_FILE)
    storage = _open(path)
    try:
        node = storage.getNode("board")
        text = "" if node.empty() or not node.isString() else node.string()
    finally:
        storage.release()
    match = re.fullmatch(r"\s*([\w-]+)\s+(\d+x\d+)\s+square\s+([0-9.eE+-]+)\s*mm"
                         r"(?:\s+marker\s+([0-9.eE+-]+)\s*mm\s+(\w+))?\s*", text)
    if not match:
        return None
    square, marker = _positive(match.group(3)), _positive(match.group(4))
    if square is None:
        return None
    return match.group(1), match.group(2), square, marker, match.group(5) if marker is not None else None


def _positive(text: str | None) -> float | None:
    try:
        value = float(text) if text is not None else None
    except ValueError:
        return None
    return value if value is not None and np.isfinite(value) and value > 0 else None


def recorded_board(calib_dir: str | Path) -> tuple[str, str, float] | None:
    """(kind, "COLSxROWS", square mm) of :func:`recorded_target`, or None."""
    target = recorded_target(calib_dir)
    return None if target is None else target[:3]


def read_gates(calib_dir: str | Path) -> dict[str, dict] | None:
    """The quality gates a calibration recorded (``gates_run``, ``gate_NAME_{value,threshold,unit,verdict,line}``:
    :meth:`stereo_bench.vision.gates.GateReport.file_items`), by gate name; None for a file written before the
    gates (or by another program): which gates it passed is unknown."""
    path = _resolve(calib_dir, EXTRINSICS_FILE)
    storage = _open(path)
    try:
        run = storage.getNode("gates_run")
        if run.empty():
            return None
        gates = {}
        for name in run.string().split():
            entry = {}
            for key in ("value", "threshold", "unit", "verdict", "line"):
                node = storage.getNode(f"gate_{name}_{key}")
                entry[key] = None if node.empty() else (node.real() if node.isReal() or node.isInt() else node.string())
            gates[name] = entry
        return gates
    finally:
        storage.release()


def recorded_epipolar_rms_px(calib_dir: str | Path) -> float | None:
    """The rectified epipolar RMS (px) the calibration recorded of its own views, else its reprojection RMS.

    The reference a measurement's epipolar error is compared with (:func:`~stereo_bench.vision.pipeline.
    check_epipolar`); None when the files record neither (OpenCV's sample, a ground truth).
    """
    path = _resolve(calib_dir, EXTRINSICS_FILE)
    storage = _open(path)
    try:
        for key in ("epipolar_rms_px", "rms_px"):
            node = storage.getNode(key)
            if not node.empty() and node.isReal() and np.isfinite(node.real()) and node.real() > 0:
                return float(node.real())
        return None
    finally:
        storage.release()


def recorded_keys(calib_dir: str | Path) -> set[str]:
    """The top-level keys of a calibration directory's two files (what an export into another format may drop)."""
    keys: set[str] = set()
    for name in (INTRINSICS_FILE, EXTRINSICS_FILE):
        path = _resolve(calib_dir, name)
        storage = _open(path)
        try:
            keys.update(storage.root().keys())
        finally:
            storage.release()
    return keys


def read_rectification(calib_dir: str | Path, image_size: tuple[int, int]) -> Rectification | None:
    """The rectification ``extrinsics.yml`` records (R1 R2 P1 P2 Q), or None when it records none."""
    path = _resolve(calib_dir, EXTRINSICS_FILE)
    storage = _open(path)
    try:
        if any(storage.getNode(key).empty() for key in ("R1", "R2", "P1", "P2", "Q")):
            return None
        return Rectification(R1=_matrix(storage, path, "R1", (3, 3)), R2=_matrix(storage, path, "R2", (3, 3)),
                             P1=_matrix(storage, path, "P1", (3, 4)), P2=_matrix(storage, path, "P2", (3, 4)),
                             Q=_matrix(storage, path, "Q", (4, 4)), image_size=tuple(image_size))
    finally:
        storage.release()
