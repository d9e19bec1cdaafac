"""The field's calibration formats, in and out: ROS ``camera_info`` YAML, Kalibr camchain YAML, mrcal ``.cameramodel``.

Pure codecs: a :class:`~stereo_bench.vision.calibrate.StereoCalibration` (and, for ROS, its rectification) in, file
texts out (:func:`export_texts`), and file texts in, a calibration out (:func:`import_texts`). The files are read
and written by the command (``stereo-bench export`` / ``import``, :mod:`stereo_bench.cli.formats`); each file schema
is a pydantic model checked against the reading code of its own project:

- ROS (``camera_calibration_parsers/src/parse_yml.cpp``, ros-perception/image_common): ``image_width``,
  ``image_height``, ``camera_name`` (optional, "unknown"), ``camera_matrix`` / ``rectification_matrix`` /
  ``projection_matrix`` / ``distortion_coefficients`` as ``{rows, cols, data}`` (3x3, 3x3, 3x4, 1xN),
  ``distortion_model`` (optional: ``plumb_bob`` assumed), extra keys ignored. One file per camera; the pair is
  tied by the rectification: R1 / P1 in the left file, R2 / P2 in the right, P2[0, 3] = -fx' B (ROS ``CameraInfo``).
- Kalibr (``kalibr_common/ConfigReader.py``, ethz-asl/kalibr): ``cam0``, ``cam1``, each ``camera_model`` (pinhole),
  ``intrinsics`` [fu, fv, pu, pv] (floats), ``distortion_model`` (``radtan``: 4 coefficients k1 k2 r1 r2, OpenCV's
  k1 k2 p1 p2), ``distortion_coeffs``, ``resolution`` [w, h] (ints), ``cam1.T_cn_cnm1`` (4x4: cam0 -> cam1),
  ``rostopic``, ``cam_overlaps`` optional.
- mrcal (``mrcal/cameramodel.py``, its ``_read_into_self``): a Python literal (``ast.literal_eval``) dict with
  ``lensmodel``, ``intrinsics`` [fx, fy, cx, cy, distortion...], ``extrinsics`` rt_cam_ref (rotation vector, then
  translation: ref -> cam), ``imagersize`` [w, h]; ``valid_intrinsics_region``, ``optimization_inputs`` and
  ``icam_intrinsics`` optional. The left camera is the reference (its extrinsics are zero); LENSMODEL_OPENCV4 / 5 /
  8 / 12 are OpenCV's vector (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4) cut to that length.

Conventions: our X_right = R X_left + T (mm) is Kalibr's ``cam1.T_cn_cnm1`` = [R T; 0 1] and mrcal's right
``rt_cam_ref`` = (rodrigues(R), T) with the left camera as ref. Lengths are written in ``unit_mm`` millimetres per
file unit: 1000 (metres, the default: ROS and Kalibr state metres, mrcal's examples use them) or 1.

What a format cannot hold is said, one line per item (:attr:`Exported.dropped`, :attr:`Imported.dropped`); a lens
model a format cannot represent at all raises :class:`UnrepresentableLens` unless ``lossy``, which refits the
format's model to the lens over the image (:func:`refit_lens`) and states how far its projection is off (px).
"""

from __future__ import annotations

import ast
import math
from dataclasses import dataclass, field
from typing import Annotated

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError, field_validator, model_validator

from stereo_bench.vision.calibio import CalibrationFileError
from stereo_bench.vision.calibrate import StereoCalibration, calibration_problems, camera_problems
from stereo_bench.vision.rectify import Rectification, rectify

FORMATS = ("ros", "kalibr", "mrcal")
MM_PER_M = 1000.0

#: OpenCV's distortion vector, in its order.
COEFFICIENTS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")
#: The lengths of OpenCV's vector each format holds (4 = k3 absent), and the format's name for each.
FORMAT_LENGTHS: dict[str, dict[int, str]] = {
    "ros": {5: "plumb_bob", 8: "rational_polynomial"},
    "kalibr": {4: "radtan"},
    "mrcal": {4: "LENSMODEL_OPENCV4", 5: "LENSMODEL_OPENCV5", 8: "LENSMODEL_OPENCV8", 12: "LENSMODEL_OPENCV12"},
}
#: The length of our lens models' vectors (stereo_bench.vision.lensmodels), as written to intrinsics.yml.
MODEL_LENGTHS = {"fixed-aspect": 5, "opencv4": 5, "opencv5": 5, "rational": 8, "thin-prism": 12}
#: Where the lens model's terms end (the format must hold at least this many coefficients to be exact).
MODEL_NEEDS = {"fixed-aspect": 4, "opencv4": 4, "opencv5": 5, "rational": 8, "thin-prism": 12}
FORMAT_TITLES = {"ros": "ROS camera_info", "kalibr": "Kalibr camchain", "mrcal": "mrcal .cameramodel"}
#: Pixel grid over which a dropped lens term's effect on the projection is measured (per image axis).
LOSS_GRID = 33


class FormatError(CalibrationFileError):
    """A file of another tool that cannot be read: the message names the file and the field."""


class UnrepresentableLens(ValueError):
    """The calibration's lens model has terms the format cannot hold (``lossy`` drops them, saying what it costs)."""


@dataclass(frozen=True)
class Exported:
    """The files of one export (name -> text) and one line per thing the format could not hold."""

    files: dict[str, str]
    dropped: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Imported:
    """A calibration read from another tool's files, its rectification when the files hold one (ROS), and one line
    per thing in the files the calibration directory does not keep."""

    calib: StereoCalibration
    rect: Rectification | None
    dropped: list[str] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------- file schemas

FloatList = list[float]


class _Schema(BaseModel):
    # Every reader named above ignores keys it does not know: so do we (a ROS file may carry a header comment key).
    model_config = ConfigDict(extra="ignore")


class RosMatrix(_Schema):
    rows: StrictInt
    cols: StrictInt
    data: FloatList

    @model_validator(mode="after")
    def _size(self):
        if self.rows < 1 or self.cols < 1 or len(self.data) != self.rows * self.cols:
            raise ValueError(f"data has {len(self.data)} values for rows {self.rows} x cols {self.cols}")
        if not all(math.isfinite(v) for v in self.data):
            raise ValueError("data has non-finite values")
        return self

    def array(self) -> np.ndarray:
        return np.array(self.data, float).reshape(self.rows, self.cols)


class RosCameraInfo(_Schema):
    """One camera's ``camera_info`` YAML, as camera_calibration_parsers reads it."""

    image_width: StrictInt = Field(gt=0)
    image_height: StrictInt = Field(gt=0)
    camera_name: str = "unknown"
    camera_matrix: RosMatrix
    distortion_model: str = "plumb_bob"
    distortion_coefficients: RosMatrix
    rectification_matrix: RosMatrix
    projection_matrix: RosMatrix

    @model_validator(mode="after")
    def _shapes(self):
        for name, shape in (("camera_matrix", (3, 3)), ("rectification_matrix", (3, 3)),
                            ("projection_matrix", (3, 4))):
            matrix = getattr(self, name)
            if (matrix.rows, matrix.cols) != shape:
                raise ValueError(f"{name}: rows x cols is {matrix.rows} x {matrix.cols}, expected {shape[0]} x "
                                 f"{shape[1]}")
        if self.distortion_coefficients.rows != 1:
            raise ValueError(f"distortion_coefficients: rows is {self.distortion_coefficients.rows}, expected 1")
        return self


class KalibrCamera(_Schema):
    """One camera of a Kalibr camchain, as ``CameraParameters`` / ``CameraChainParameters`` read it."""

    camera_model: str
    intrinsics: FloatList
    distortion_model: str
    distortion_coeffs: FloatList
    resolution: Annotated[list[StrictInt], Field(min_length=2, max_length=2)]
    T_cn_cnm1: list[Annotated[FloatList, Field(min_length=4, max_length=4)]] | None = None
    rostopic: str | None = None
    cam_overlaps: list[int] | None = None

    @field_validator("resolution")
    @classmethod
    def _positive(cls, value):
        if min(value) <= 0:
            raise ValueError("must be two positive integers [width, height]")
        return value

    @field_validator("T_cn_cnm1")
    @classmethod
    def _four_by_four(cls, value):
        if value is not None and len(value) != 4:
            raise ValueError(f"has {len(value)} rows, expected 4 (a 4x4 transformation)")
        return value


class KalibrCamchain(_Schema):
    cam0: KalibrCamera
    cam1: KalibrCamera


class MrcalCameraModel(_Schema):
    """A ``.cameramodel``, as ``mrcal.cameramodel`` reads it (the legacy key ``distortion_model`` included)."""

    lensmodel: str
    intrinsics: FloatList
    extrinsics: Annotated[FloatList, Field(min_length=6, max_length=6)]
    imagersize: Annotated[list[StrictInt], Field(min_length=2, max_length=2)]
    valid_intrinsics_region: list[FloatList] | None = None
    optimization_inputs: bytes | None = None
    icam_intrinsics: int | None = None

    @model_validator(mode="before")
    @classmethod
    def _legacy(cls, data):
        if isinstance(data, dict):
            data = dict(data)
            for old in ("distortion_model", "lens_model"):
                if old in data and "lensmodel" not in data:
                    data["lensmodel"] = data.pop(old)
            if isinstance(data.get("lensmodel"), str):
                data["lensmodel"] = data["lensmodel"].replace("DISTORTION", "LENSMODEL")
        return data


def _validated(schema: type[BaseModel], data, name: str) -> BaseModel:
    """``schema`` of ``data`` (from file ``name``), or FormatError naming the file and the first bad field."""
    if not isinstance(data, dict):
        raise FormatError(f"{name}: not a {schema.__name__} file (expected a mapping of keys, found "
                          f"{type(data).__name__})")
    try:
        return schema.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first.get("loc", ())) or "(top level)"
        message = first.get("msg", "invalid").removeprefix("Value error, ")
        if first.get("type") == "missing":
            message = "missing"
        raise FormatError(f"{name}: field {where!r}: {message}") from None


def _yaml(text: str, name: str):
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise FormatError(f"{name}: not readable YAML{where} ({getattr(error, 'problem', None) or 'parse error'})") \
            from None


# ---------------------------------------------------------------------------------------------- lens models


def lens_name(D: np.ndarray, K: np.ndarray, recorded: str = "") -> str:
    """The lens model a distortion vector is (:data:`MODEL_LENGTHS` names), inferred when none is recorded: k1 k2
    p1 p2 with fx = fy is fixed-aspect; "" when the vector is none of ours (tilted sensor, rational with prism)."""
    if recorded in MODEL_LENGTHS:
        return recorded
    d = np.zeros(14)
    values = np.ravel(D)
    d[:len(values)] = values
    need = _needed_length(d)
    if need <= 4:
        return "fixed-aspect" if float(K[0, 0]) == float(K[1, 1]) else "opencv4"
    if need == 5:
        return "opencv5"
    if need == 8:
        return "rational"
    if need == 12 and not np.any(d[4:8]):
        return "thin-prism"
    return ""


def _needed_length(d: np.ndarray) -> int:
    """The shortest of OpenCV's vector lengths (4, 5, 8, 12, 14) that holds every non-zero coefficient of ``d``."""
    for length in (4, 5, 8, 12):
        if not np.any(d[length:]):
            return length
    return 14


def _coefficients_for(calib: StereoCalibration, D: np.ndarray, K: np.ndarray, fmt: str, side: str,
                      lossy: bool) -> tuple[np.ndarray, np.ndarray, str, list[str]]:
    """(camera matrix, coefficients, the format's model name, dropped lines) of one camera in format ``fmt``."""
    d = np.zeros(14)
    values = np.ravel(D).astype(float)
    d[:len(values)] = values
    lengths = FORMAT_LENGTHS[fmt]
    model = lens_name(D, K, calib.lens_model)
    need = _needed_length(d)
    preferred = MODEL_NEEDS.get(model, need)
    fits = sorted(n for n in lengths if n >= need)
    if fits:
        length = preferred if preferred in fits else fits[0]
        return np.asarray(K, float), d[:length], lengths[length], []
    length = max(lengths)
    lost = [COEFFICIENTS[i] for i in range(length, 14) if d[i] != 0]
    K_fit, d_fit, worst_px, rms_px = refit_lens(K, d, length, calib.image_size)
    holds = "; ".join(f"{name}: {' '.join(COEFFICIENTS[:n])}" for n, name in lengths.items())
    line = (f"{side} camera: lens model {model or 'with ' + ' '.join(lost)} has {' '.join(lost)}, which "
            f"{FORMAT_TITLES[fmt]} cannot hold ({holds})")
    if not lossy:
        raise UnrepresentableLens(f"{line}; --lossy refits {lengths[length]} over the image instead (projection off "
                                  f"by up to {worst_px:.3g} px)")
    return K_fit, d_fit, lengths[length], [
        f"dropped: {line}: refitted {lengths[length]} (fx fy cx cy {' '.join(COEFFICIENTS[:length])}) over the image, "
        f"projection off by up to {worst_px:.3g} px (RMS {rms_px:.3g} px)"]


def _grid_rays(K: np.ndarray, d: np.ndarray, image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (N, 2), their rays (N, 3) at z = 1) of a ``LOSS_GRID`` x ``LOSS_GRID`` grid over the image."""
    from stereo_bench.vision.rectify import undistort_points

    width, height = image_size
    u, v = np.meshgrid(np.linspace(0, width - 1, LOSS_GRID), np.linspace(0, height - 1, LOSS_GRID))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = undistort_points(pixels, K, np.asarray(d, float).reshape(1, -1))
    return pixels, np.column_stack([rays, np.ones(len(rays))])


def projection_change_px(K_from: np.ndarray, d_from: np.ndarray, d_to: np.ndarray, image_size: tuple[int, int], *,
                         K_to: np.ndarray | None = None) -> np.ndarray:
    """(N,) distances (px) between the pixels of a ``LOSS_GRID`` x ``LOSS_GRID`` grid over the image and where their
    rays (undistorted with ``K_from``, ``d_from``) project with ``K_to`` (default ``K_from``), ``d_to``."""
    pixels, rays = _grid_rays(K_from, d_from, image_size)
    K_to = K_from if K_to is None else K_to
    projected, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K_to, np.asarray(d_to, float).reshape(1, -1))
    return np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1)


#: Gauss-Newton iterations of a lens refit (it converges in 3-6 on the real sets' lenses).
REFIT_ITERATIONS = 30


def refit_lens(K: np.ndarray, d: np.ndarray, length: int, image_size: tuple[int, int]
               ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The shorter model (fx fy cx cy and the first ``length`` of OpenCV's coefficients) that projects the rays of
    a grid over the image closest to where lens (``K``, ``d``) puts them, least squares in pixels (what
    mrcal-convert-lensmodel does between its models). Returns (K (3, 3), coefficients (length,), max px, RMS px)."""
    pixels, rays = _grid_rays(K, d, image_size)
    K_fit = np.array(K, float)
    d_fit = np.array(np.ravel(d)[:length], float)
    for _ in range(REFIT_ITERATIONS):
        projected, jacobian = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K_fit, d_fit.reshape(1, -1))
        residual = (projected.reshape(-1, 2) - pixels).ravel()
        J = jacobian[:, 6:10 + length]  # d/d(fx fy cx cy k1 ...): after the rvec, tvec columns
        step = np.linalg.lstsq(J, -residual, rcond=None)[0]
        K_fit[0, 0] += step[0]
        K_fit[1, 1] += step[1]
        K_fit[0, 2] += step[2]
        K_fit[1, 2] += step[3]
        d_fit += step[4:]
        if np.max(np.abs(step[:4])) < 1e-10 and np.max(np.abs(step[4:]), initial=0) < 1e-14:
            break
    miss = projection_change_px(K, d, d_fit, image_size, K_to=K_fit)
    return K_fit, d_fit, float(np.max(miss)), float(np.sqrt(np.mean(miss**2)))


def _skew_check(K: np.ndarray, fmt: str, side: str) -> None:
    if fmt != "ros" and K[0, 1] != 0:
        raise UnrepresentableLens(f"{side} camera: camera matrix has skew {K[0, 1]:g} px, which {FORMAT_TITLES[fmt]} "
                                  "cannot hold (fx fy cx cy only)")


# ---------------------------------------------------------------------------------------------- writing


def _num(value: float) -> str:
    """A float written so that it reads back to the same double (repr), always with a decimal point or exponent
    (Kalibr checks ``isinstance(x, float)``)."""
    text = repr(float(value))
    return text if any(c in text for c in ".en") else text + ".0"


def _flow(values) -> str:
    return "[" + ", ".join(_num(v) for v in np.ravel(values)) + "]"


def _ros_matrix(name: str, matrix: np.ndarray) -> str:
    matrix = np.atleast_2d(matrix)
    return f"{name}:\n  rows: {matrix.shape[0]}\n  cols: {matrix.shape[1]}\n  data: {_flow(matrix)}\n"


def _provenance(source: str) -> str:
    from stereo_bench import __version__

    return f"# written by stereo-bench {__version__} from {source}\n" if source else ""


def export_texts(calib: StereoCalibration, fmt: str, *, rect: Rectification | None = None, unit_mm: float = MM_PER_M,
                 lossy: bool = False, source: str = "") -> Exported:
    """The files of ``calib`` in format ``fmt`` ("ros": left.yaml + right.yaml; "kalibr": camchain.yaml; "mrcal":
    left.cameramodel + right.cameramodel). ``rect``: the rectification ROS files carry (default: :func:`rectify`).
    ``unit_mm``: millimetres per length unit of the files. ``source`` goes into a comment.

    Raises UnrepresentableLens when a camera's lens model has terms the format lacks, unless ``lossy``.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}: one of {', '.join(FORMATS)}")
    cameras = []
    dropped: list[str] = []
    for side, K, D in (("left", calib.K1, calib.D1), ("right", calib.K2, calib.D2)):
        _skew_check(K, fmt, side)
        K_out, coefficients, model, lines = _coefficients_for(calib, D, K, fmt, side, lossy)
        cameras.append((side, K_out, coefficients, model))
        dropped += lines
    T = np.asarray(calib.T, float).reshape(3) / unit_mm
    R = np.asarray(calib.R, float)
    width, height = (int(n) for n in calib.image_size)
    header = _provenance(source)
    files: dict[str, str] = {}
    if fmt == "ros":
        rect = rect or rectify(calib)
        for (side, K, coefficients, model), R_rect, P in zip(cameras, (rect.R1, rect.R2), (rect.P1, rect.P2),
                                                             strict=True):
            P = np.asarray(P, float).copy()
            P[:, 3] /= unit_mm  # ROS: P[0, 3] = -fx' B with B in the file's length unit
            files[f"{side}.yaml"] = (header + f"image_width: {width}\nimage_height: {height}\ncamera_name: {side}\n"
                                     + _ros_matrix("camera_matrix", K) + f"distortion_model: {model}\n"
                                     + _ros_matrix("distortion_coefficients", coefficients.reshape(1, -1))
                                     + _ros_matrix("rectification_matrix", R_rect)
                                     + _ros_matrix("projection_matrix", P))
    elif fmt == "kalibr":
        T_cn_cnm1 = np.eye(4)
        T_cn_cnm1[:3, :3], T_cn_cnm1[:3, 3] = R, T
        text = header
        for index, (side, K, coefficients, model) in enumerate(cameras):
            text += f"cam{index}:\n"
            if index == 1:
                text += "  T_cn_cnm1:\n" + "".join(f"  - {_flow(row)}\n" for row in T_cn_cnm1)
            text += (f"  camera_model: pinhole\n  intrinsics: {_flow([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])}\n"
                     f"  distortion_model: {model}\n  distortion_coeffs: {_flow(coefficients)}\n"
                     f"  resolution: [{width}, {height}]\n  cam_overlaps: [{1 - index}]\n"
                     f"  rostopic: /{side}/image_raw\n")
        files["camchain.yaml"] = text
    else:
        rvec = cv2.Rodrigues(R)[0].ravel()
        for (side, K, coefficients, model), extrinsics in zip(cameras, (np.zeros(6), np.concatenate([rvec, T])),
                                                              strict=True):
            intrinsics = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], coefficients])
            files[f"{side}.cameramodel"] = (
                header + "{\n" + f"    'lensmodel': '{model}',\n\n"
                "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....\n"
                f"    'intrinsics': {_flow(intrinsics)},\n\n"
                "    # extrinsics are rt_fromref (rotation vector, translation: ref -> this camera; ref = the left "
                f"camera, lengths in units of {unit_mm:g} mm)\n"
                f"    'extrinsics': {_flow(extrinsics)},\n\n"
                f"    'imagersize': [{width}, {height}],\n" + "}\n")
    return Exported(files, dropped)


# ---------------------------------------------------------------------------------------------- reading


def _camera(name: str, K: np.ndarray, d: list[float], model: str, size: tuple[int, int]) -> tuple[np.ndarray, str]:
    """Our (1, n) D and lens-model name for coefficients ``d`` in OpenCV's order; FormatError if unusable."""
    values = np.zeros(14)
    values[:len(d)] = d
    name_ = lens_name(values, K)
    if model == "LENSMODEL_OPENCV5" and name_ in ("opencv4", "fixed-aspect"):
        name_ = "opencv5"  # the file says k3 is a parameter, even if it came out 0
    length = MODEL_LENGTHS.get(name_, max(len(d), 5))
    D = values[:length].reshape(1, -1)
    problems = camera_problems(K, D, size, "the camera")
    if problems:
        raise FormatError(f"{name}: not usable intrinsics: {problems[0]}")
    return D, name_


#: An imported baseline above this (mm) is refused: no bench holds a 10 m stereo pair (campaign.config's
#: MAX_BASELINE_MM), and a file written in millimetres read as metres gives 1000x its |T| (99.86 mm -> 99 860 mm).
MAX_IMPORTED_BASELINE_MM = 10_000.0


def _stereo(names: list[str], calib: StereoCalibration, unit_mm: float) -> StereoCalibration:
    """``calib`` when it is a usable stereo pair read in the right units and order, else FormatError saying why."""
    from stereo_bench.vision.gates import gate_left_right

    problems = calibration_problems(calib)
    if problems:
        raise FormatError(f"{', '.join(names)}: not a usable stereo calibration: {problems[0]}")
    baseline = float(np.linalg.norm(calib.T))
    if baseline > MAX_IMPORTED_BASELINE_MM:
        hint = (" were the file's lengths in millimetres? --units mm reads them so" if unit_mm == MM_PER_M
                else " not a stereo bench")
        raise FormatError(f"{', '.join(names)}: baseline |T| = {baseline:.0f} mm read in "
                          f"{'metres' if unit_mm == MM_PER_M else 'millimetres'} is over "
                          f"{MAX_IMPORTED_BASELINE_MM / MM_PER_M:g} m:{hint}")
    side = gate_left_right(calib)
    if side.verdict == "fail":
        raise FormatError(f"{', '.join(names)}: the right camera sits {-side.value * baseline:.1f} mm to the LEFT of "
                          "the left one: the files name the cameras the other way round (give the left camera's "
                          "first, or cam0 = left)")
    return calib


def _note(fmt: str) -> str:
    return f"imported from {FORMAT_TITLES[fmt]}, which carries no covariance: its uncertainty is unknown"


def import_ros(texts: list[tuple[str, str]], *, unit_mm: float = MM_PER_M) -> Imported:
    """Two ROS ``camera_info`` files (name, text), left then right -> the calibration and its rectification."""
    if len(texts) != 2:
        raise FormatError(f"--from ros needs two camera_info files, left then right, not {len(texts)}")
    infos = [_validated(RosCameraInfo, _yaml(text, name), name) for name, text in texts]
    names = [name for name, _ in texts]
    size = (infos[0].image_width, infos[0].image_height)
    if (infos[1].image_width, infos[1].image_height) != size:
        raise FormatError(f"{names[1]}: field 'image_width'/'image_height' is {infos[1].image_width}x"
                          f"{infos[1].image_height}, {names[0]} is {size[0]}x{size[1]}")
    cams = []
    for name, info in zip(names, infos, strict=True):
        expected = {"plumb_bob": 5, "rational_polynomial": 8}
        n = len(info.distortion_coefficients.data)
        if info.distortion_model not in expected:
            raise FormatError(f"{name}: field 'distortion_model': {info.distortion_model!r} is not supported (plumb_bob"
                              " or rational_polynomial; equidistant is a fisheye model: docs/CALIBRATION.md)")
        if n not in (expected[info.distortion_model], 4 if info.distortion_model == "plumb_bob" else 8):
            raise FormatError(f"{name}: field 'distortion_coefficients': {n} coefficients for "
                              f"{info.distortion_model} (expected {expected[info.distortion_model]})")
        K = info.camera_matrix.array()
        D, model = _camera(name, K, info.distortion_coefficients.data, "", size)
        cams.append((K, D, model, info.rectification_matrix.array(), info.projection_matrix.array()))
    (K1, D1, m1, R1, P1), (K2, D2, m2, R2, P2) = cams
    for name, R_rect in zip(names, (R1, R2), strict=True):
        if not np.allclose(R_rect @ R_rect.T, np.eye(3), atol=1e-6) or np.linalg.det(R_rect) < 0:
            raise FormatError(f"{name}: field 'rectification_matrix' is not a rotation")
    P1m, P2m = P1.copy(), P2.copy()
    P1m[:, 3] *= unit_mm
    P2m[:, 3] *= unit_mm
    t_rect = np.linalg.solve(P2m[:, :3], P2m[:, 3]) - np.linalg.solve(P1m[:, :3], P1m[:, 3])
    if np.linalg.norm(t_rect) == 0:
        raise FormatError(f"{names[1]}: field 'projection_matrix': P[0, 3] = P[1, 3] = 0, no stereo baseline (were the "
                          "cameras calibrated one by one? a stereo pair's right camera_info has P[0, 3] = -fx' B)")
    R = R2.T @ R1
    T = R2.T @ t_rect
    calib = _stereo(names, StereoCalibration(
        K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=size, mode="imported",
        covariance_note=_note("ros"), lens_model=m1 if m1 == m2 else ""), unit_mm)
    Q = _disparity_to_depth(P1m, P2m)
    rect = Rectification(R1=R1, R2=R2, P1=P1m, P2=P2m, Q=Q, image_size=size)
    return Imported(calib, rect, [f"not in {FORMAT_TITLES['ros']}: {item}" for item in _NOT_IN_FILES])


_NOT_IN_FILES = ("covariance (the imported calibration's uncertainty is unknown)",
                 "fit RMS and views (rms_px is .nan)", "calibration board (give measure --board/--square)")


def _disparity_to_depth(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """OpenCV's Q of a horizontal rectification (stereoRectify's, CALIB_ZERO_DISPARITY): disparity -> depth."""
    f, cx, cy = P1[0, 0], P1[0, 2], P1[1, 2]
    tx = P2[0, 3] / P2[0, 0]
    Q = np.zeros((4, 4))
    Q[0, 0] = Q[1, 1] = 1.0
    Q[0, 3], Q[1, 3], Q[2, 3] = -cx, -cy, f
    Q[3, 2] = -1.0 / tx if tx else 0.0
    Q[3, 3] = (cx - P2[0, 2]) / tx if tx else 0.0
    return Q


def import_kalibr(texts: list[tuple[str, str]], *, unit_mm: float = MM_PER_M) -> Imported:
    """One Kalibr camchain (cam0 = left, cam1 = right) -> the calibration (rectification: none in the file)."""
    if len(texts) != 1:
        raise FormatError(f"--from kalibr needs one camchain file, not {len(texts)}")
    name, text = texts[0]
    data = _yaml(text, name)
    chain = _validated(KalibrCamchain, data, name)
    dropped = []
    extra = sorted(k for k in data if k.startswith("cam") and k not in ("cam0", "cam1"))
    if extra:
        dropped.append(f"ignored: {', '.join(extra)} (a stereo calibration is cam0 and cam1)")
    cams = []
    for key in ("cam0", "cam1"):
        cam: KalibrCamera = getattr(chain, key)
        if cam.camera_model != "pinhole":
            raise FormatError(f"{name}: field '{key}.camera_model': {cam.camera_model!r} is not supported (pinhole)")
        if len(cam.intrinsics) != 4:
            raise FormatError(f"{name}: field '{key}.intrinsics': {len(cam.intrinsics)} values, expected [fu, fv, pu, "
                              "pv]")
        counts = {"radtan": 4, "none": 0}
        if cam.distortion_model not in counts:
            raise FormatError(f"{name}: field '{key}.distortion_model': {cam.distortion_model!r} is not supported "
                              "(radtan or none; equidistant and fov are fisheye models: docs/CALIBRATION.md)")
        if len(cam.distortion_coeffs) != counts[cam.distortion_model]:
            raise FormatError(f"{name}: field '{key}.distortion_coeffs': {len(cam.distortion_coeffs)} values for "
                              f"{cam.distortion_model} (expected {counts[cam.distortion_model]})")
        fu, fv, pu, pv = cam.intrinsics
        K = np.array([[fu, 0, pu], [0, fv, pv], [0, 0, 1]], float)
        size = (cam.resolution[0], cam.resolution[1])
        D, model = _camera(f"{name} ({key})", K, cam.distortion_coeffs, "", size)
        cams.append((K, D, model, size))
    if cams[0][3] != cams[1][3]:
        raise FormatError(f"{name}: field 'cam1.resolution' is {cams[1][3]}, cam0's is {cams[0][3]}")
    if chain.cam1.T_cn_cnm1 is None:
        raise FormatError(f"{name}: field 'cam1.T_cn_cnm1': missing (cam0 -> cam1, the stereo extrinsics)")
    T_cn_cnm1 = np.array(chain.cam1.T_cn_cnm1, float)
    R, T = T_cn_cnm1[:3, :3], T_cn_cnm1[:3, 3] * unit_mm
    if not np.allclose(T_cn_cnm1[3], [0, 0, 0, 1]) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) \
            or np.linalg.det(R) < 0:
        raise FormatError(f"{name}: field 'cam1.T_cn_cnm1' is not a rigid transformation")
    (K1, D1, m1, size), (K2, D2, m2, _) = cams
    calib = _stereo([name], StereoCalibration(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=size, mode="imported",
                                              covariance_note=_note("kalibr"), lens_model=m1 if m1 == m2 else ""),
                    unit_mm)
    return Imported(calib, None, dropped + [f"not in {FORMAT_TITLES['kalibr']}: {item}" for item in _NOT_IN_FILES])


_MRCAL_LENGTHS = {v: k for k, v in FORMAT_LENGTHS["mrcal"].items()} | {"LENSMODEL_PINHOLE": 0}


def import_mrcal(texts: list[tuple[str, str]], *, unit_mm: float = MM_PER_M) -> Imported:
    """Two ``.cameramodel`` files, left then right (extrinsics rt_cam_ref to any common ref) -> the calibration."""
    if len(texts) != 2:
        raise FormatError(f"--from mrcal needs two .cameramodel files, left then right, not {len(texts)}")
    models, dropped = [], []
    for name, text in texts:
        try:
            data = ast.literal_eval(text)
        except (ValueError, SyntaxError, MemoryError, RecursionError) as error:
            raise FormatError(f"{name}: not a readable .cameramodel (a Python literal: "
                              f"{' '.join(str(error).split()) or type(error).__name__})") from None
        model = _validated(MrcalCameraModel, data, name)
        if model.lensmodel not in _MRCAL_LENGTHS:
            raise FormatError(f"{name}: field 'lensmodel': {model.lensmodel!r} is not supported (LENSMODEL_PINHOLE, "
                              "LENSMODEL_OPENCV4/5/8/12: OpenCV's vector; mrcal-convert-lensmodel can fit one of "
                              "them)")
        expected = 4 + _MRCAL_LENGTHS[model.lensmodel]
        if len(model.intrinsics) != expected:
            raise FormatError(f"{name}: field 'intrinsics': {len(model.intrinsics)} values for {model.lensmodel} "
                              f"(expected {expected}: fx fy cx cy and the distortion)")
        if not all(math.isfinite(v) for v in model.intrinsics + model.extrinsics):
            raise FormatError(f"{name}: field 'intrinsics'/'extrinsics' has non-finite values")
        if model.optimization_inputs is not None:
            dropped.append(f"dropped: {name}: optimization_inputs (mrcal's own uncertainty inputs)")
        if model.valid_intrinsics_region is not None:
            dropped.append(f"dropped: {name}: valid_intrinsics_region")
        models.append(model)
    names = [name for name, _ in texts]
    sizes = [tuple(m.imagersize) for m in models]
    if sizes[0] != sizes[1]:
        raise FormatError(f"{names[1]}: field 'imagersize' is {list(sizes[1])}, {names[0]} is {list(sizes[0])}")
    cams = []
    for name, model in zip(names, models, strict=True):
        fx, fy, cx, cy = model.intrinsics[:4]
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], float)
        D, lens = _camera(name, K, model.intrinsics[4:], model.lensmodel, sizes[0])
        rt = np.array(model.extrinsics, float)
        cams.append((K, D, lens, cv2.Rodrigues(rt[:3])[0], rt[3:] * unit_mm))
    (K1, D1, m1, R_l, t_l), (K2, D2, m2, R_r, t_r) = cams
    if not np.any(models[0].extrinsics):  # the left camera is the reference: exactly the right camera's rt
        R, T = R_r, t_r
    else:  # T_right_left = T_right_ref T_left_ref^-1
        R, T = R_r @ R_l.T, t_r - R_r @ R_l.T @ t_l
    calib = _stereo(names, StereoCalibration(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=sizes[0],
                                             mode="imported", covariance_note=_note("mrcal"),
                                             lens_model=m1 if m1 == m2 else ""), unit_mm)
    return Imported(calib, None, dropped + [f"not in {FORMAT_TITLES['mrcal']}: {item}" for item in _NOT_IN_FILES])


def import_texts(fmt: str, texts: list[tuple[str, str]], *, unit_mm: float = MM_PER_M) -> Imported:
    """The calibration in files ``texts`` ((name, text) pairs, in the order given) of format ``fmt``."""
    readers = {"ros": import_ros, "kalibr": import_kalibr, "mrcal": import_mrcal}
    if fmt not in readers:
        raise ValueError(f"unknown format {fmt!r}: one of {', '.join(FORMATS)}")
    return readers[fmt](texts, unit_mm=unit_mm)


#: What a calibration directory records beyond the geometry, by key prefix: the line an export says when dropping it.
RECORDED_ITEMS = (
    (("covariance",), "covariance of the calibration parameters (its uncertainty: covariance, covariance_*)"),
    (("adequacy_",), "model-adequacy check on held-out views (adequacy_*)"),
    (("lens_model_comparison", "lens_model_candidates", "lens_model_reason"),
     "lens-model comparison on held-out views (lens_model_*)"),
    (("gates_run", "gate_"), "quality gates' results (gates_run, gate_*)"),
    (("board",), "calibration board (board, board_scale_u_rel)"),
    (("rms_px", "epipolar_rms_px", "views_used"), "fit RMS, epipolar RMS and views used"),
)


def dropped_on_export(keys: set[str], fmt: str) -> list[str]:
    """One line per recorded item (``keys`` of extrinsics.yml / intrinsics.yml) the format has no place for."""
    lines = []
    for prefixes, what in RECORDED_ITEMS:
        if any(key.startswith(prefixes) for key in keys):
            lines.append(f"dropped: {what}: {FORMAT_TITLES[fmt]} has no field for it")
    if fmt != "ros" and "R1" in keys:
        lines.append(f"dropped: rectification R1 R2 P1 P2 Q: {FORMAT_TITLES[fmt]} has no field for it (import "
                     "recomputes it with stereoRectify)")
    return lines
