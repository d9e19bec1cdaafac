"""The real image sets in calib_data/real (see its README for sources and licences) and their leave-one-out.

:func:`leave_one_out` is the check the issue asks of every set (tests/test_real_data.py, scripts/coverage_real.py):
calibrate without pair k, measure pair k's square, compare the deviation from the nominal square with the budget's
u_c and U, beside plain OpenCV (findChessboardCorners + cornerSubPix, calibrateCamera per camera, stereoCalibrate
with the intrinsics fixed, the pipeline of shared/data/README.md) on the same images in the same run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path

import cv2
import numpy as np

from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision.calibrate import StereoCalibration, calibrate_stereo
from stereo_bench.vision.covariance import EXTRINSIC_NAMES
from stereo_bench.vision.detect import common_corners, detect
from stereo_bench.vision.pipeline import drop_scale_outliers, measure_pair, refit_from
from stereo_bench.vision.triangulate import triangulate
from stereo_bench.vision.uncertainty import BoardScale, configuration_budget, with_adequacy

REAL = Path(__file__).resolve().parents[1] / "calib_data" / "real"
OPENCV_SAMPLE = REAL / "opencv_sample"
PRESENT_CJN = REAL / "present_cjn"
SMILER488_BOX = REAL / "smiler488_box"
OPENCV_FORMAT = REAL / "opencv_stereo_calib_format"


@dataclass(frozen=True)
class RealSet:
    folder: Path
    left_glob: str
    right_glob: str
    board: Checkerboard
    reference_baseline_mm: float  # the set's published abs(T) (SOURCE.md)


SETS = {
    "opencv_sample": RealSet(OPENCV_SAMPLE, "left*.jpg", "right*.jpg", Checkerboard(9, 6, 30.0), 99.81),
    "present_cjn": RealSet(PRESENT_CJN, "leftPic*.jpg", "rightPic*.jpg", Checkerboard(8, 11, 12.0), 49.30),
    "smiler488_box": RealSet(SMILER488_BOX, "L_*.png", "R_*.png", Checkerboard(8, 5, 15.0), 59.99),
}
#: Intrinsics reported beside abs(T) in the jackknife check.
JACKKNIFE_INTRINSICS = tuple(f"{side}.{n}" for side in ("left", "right") for n in ("fx", "fy", "cx", "cy"))


@cache
def images(name: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    s = SETS[name]
    left = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(s.folder.glob(s.left_glob))]
    right = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(s.folder.glob(s.right_glob))]
    return left, right


@cache
def detections(name: str) -> tuple:
    """Per pair (left, right) stereo-bench detections (thorough, as for stored images)."""
    board = SETS[name].board
    return tuple((detect(left, board, thorough=True), detect(right, board, thorough=True))
                 for left, right in zip(*images(name), strict=True))


def _opencv_corners(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    found, corners = cv2.findChessboardCorners(image, (board.cols, board.rows),
                                               cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    corners = np.asarray(corners, np.float32).reshape(-1, 1, 2)
    # OpenCV's sample's 11 x 11 half-window, narrowed to a third of the corner spacing where the squares are
    # smaller (present_cjn's ~20 px): a window reaching the next corner pulls the estimate there (1 mm errors).
    spacing = float(np.median(np.linalg.norm(np.diff(corners.reshape(board.rows, board.cols, 2), axis=1), axis=2)))
    half = int(max(2, min(11, spacing // 3)))
    corners = cv2.cornerSubPix(image, corners, (half, half), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3))
    return corners.reshape(-1, 2).astype(np.float64)


@cache
def opencv_detections(name: str) -> tuple:
    board = SETS[name].board
    out = []
    for left, right in zip(*images(name), strict=True):
        a, b = _opencv_corners(left, board), _opencv_corners(right, board)
        # findChessboardCorners may start a grid at either end: a 180-degree turn of the grid in one image of a
        # pair (first-to-last corner directions opposed) is reversed, as any stereo use of its corners must.
        if a is not None and b is not None and np.dot(a[-1] - a[0], b[-1] - b[0]) < 0:
            b = b[::-1].copy()
        out.append((a, b))
    return tuple(out)


def _adjacent_mean_mm(points: np.ndarray, board: Checkerboard) -> float:
    pairs = np.array(list(board.adjacent_pairs()))
    return float(np.mean(np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)))


def plain_opencv_stereo(object_points, left_points, right_points, image_size, flags: int = 0) -> StereoCalibration:
    """calibrateCamera per camera, then stereoCalibrate with the intrinsics fixed (OpenCV's defaults otherwise)."""
    obj = [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points]
    lp = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in left_points]
    rp = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in right_points]
    _, K1, D1, _, _ = cv2.calibrateCamera(obj, lp, image_size, None, None, flags=flags)
    _, K2, D2, _, _ = cv2.calibrateCamera(obj, rp, image_size, None, None, flags=flags)
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(obj, lp, rp, K1, D1, K2, D2, image_size,
                                                          flags=cv2.CALIB_FIX_INTRINSIC)
    return StereoCalibration(K1=K1, D1=D1.reshape(1, -1), K2=K2, D2=D2.reshape(1, -1), R=R,
                             T=np.asarray(T, float).reshape(3), image_size=tuple(image_size), rms_px=float(rms))


def opencv_leave_one_out(name: str) -> np.ndarray:
    """Plain OpenCV's held-out square errors (mm), one per pair it finds in both images."""
    board = SETS[name].board
    found = [i for i, (a, b) in enumerate(opencv_detections(name)) if a is not None and b is not None]
    det = opencv_detections(name)
    size = images(name)[0][0].shape[::-1]
    errors = []
    for held_out in found:
        keep = [i for i in found if i != held_out]
        calib = plain_opencv_stereo([board.object_points] * len(keep), [det[i][0] for i in keep],
                                    [det[i][1] for i in keep], size)
        points = triangulate(calib, det[held_out][0], det[held_out][1])
        errors.append(_adjacent_mean_mm(points, board) - board.square_mm)
    return np.array(errors)


def _calibrate(object_points, left_points, right_points, image_size) -> StereoCalibration:
    """The stereo calibration calibrate_from_images makes of these views, with its held-out check and without a
    view the check finds alone in its error (``views_used`` indexes the views given)."""
    calib = with_adequacy(calibrate_stereo(object_points, left_points, right_points, image_size), object_points,
                          left_points, right_points)
    calib, kept, _ = drop_scale_outliers(calib, refit_from(calib, image_size), object_points, left_points,
                                         right_points, most=len(object_points) // 4)
    return replace(calib, views_used=[kept[i] for i in calib.views_used])


@cache
def full_calibration(name: str) -> tuple[StereoCalibration, list[int]]:
    s = SETS[name]
    views = {i: common_corners(*d) for i, d in enumerate(detections(name)) if d[0] is not None and d[1] is not None}
    keys = sorted(views)
    return _calibrate([s.board.object_points[views[i][0]] for i in keys], [views[i][1] for i in keys],
                      [views[i][2] for i in keys], images(name)[0][0].shape[::-1]), keys


def parameter(calib: StereoCalibration, name: str) -> float:
    if name == "baseline":
        return calib.baseline_mm
    side, _, what = name.partition(".")
    K = calib.K1 if side == "left" else calib.K2
    return float(K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[what]])


@cache
def leave_one_out_calibrations(name: str) -> dict[int, StereoCalibration]:
    """Per pair the full calibration keeps (its image index), the calibration of all the others: what
    :func:`leave_one_out` and :func:`leave_one_out_without_covariance` measure that pair with (made once)."""
    s = SETS[name]
    det = detections(name)
    full, usable = full_calibration(name)
    usable = [usable[i] for i in full.views_used]
    views = {i: common_corners(*det[i]) for i in usable}
    size = images(name)[0][0].shape[::-1]
    calibrations = {}
    for held_out in usable:
        keep = [i for i in usable if i != held_out]
        calibrations[held_out] = _calibrate([s.board.object_points[views[i][0]] for i in keep],
                                            [views[i][1] for i in keep], [views[i][2] for i in keep], size)
    return calibrations


@cache
def leave_one_out(name: str) -> dict:
    """Each pair the full calibration keeps, held out in turn (stereo-bench), with plain OpenCV beside it.

    Returns ``rows`` (per held-out pair: error_mm, u_c_mm, U_mm, the components), ``opencv_errors_mm`` and
    ``jackknife``: per parameter (abs(T) as ``baseline``, ``left.fx`` ...) the full calibration's sigma and the
    jackknife scatter of the leave-one-out calibrations, sqrt((n-1)/n sum (theta_i - mean)^2).
    """
    s = SETS[name]
    left_images, right_images = images(name)
    det = detections(name)
    full, _ = full_calibration(name)
    rows, loo_params, sensitivities, jackknifed = [], [], [], False
    for held_out, calib in leave_one_out_calibrations(name).items():
        loo_params.append([parameter(calib, p) for p in ("baseline", *JACKKNIFE_INTRINSICS)])
        pair = measure_pair(left_images[held_out], right_images[held_out], calib, s.board, detections=det[held_out])
        budget = configuration_budget([pair], calib, s.board, board_scale=BoardScale(same_board=True),
                                      structure_covariance=np.zeros((6, 6)), structure_source="unmoved within the set")
        rows.append({"pair": held_out, "error_mm": budget.error_mm, "u_c_mm": budget.combined,
                     "U_mm": budget.expanded, **{f"u_{k}_mm": v for k, v in budget.components.items()},
                     "u_adequacy_mm": budget.adequacy, "k": budget.k,
                     "noise_random_mm": budget.noise_random_mm, "noise_systematic_mm": budget.noise_systematic_mm,
                     "detector_bias_mm": budget.detector_bias_mm, "corner_systematic_px": budget.corner_systematic_px,
                     "systematic_model": budget.systematic_model, "dominant": budget.dominant,
                     "details": {k: v for k, v in budget.details().items() if k != "sensitivities"}})
        sensitivities.append(budget.sensitivities)
        jackknifed |= np.isfinite(budget.calibration_dof)
    loo_params = np.array(loo_params)
    n = len(loo_params)
    jack = np.sqrt((n - 1) / n * np.sum((loo_params - loo_params.mean(axis=0)) ** 2, axis=0))
    cov = full.covariance
    u = full.T / np.linalg.norm(full.T)
    gradients = {"baseline": (u, list(EXTRINSIC_NAMES[3:]))}
    gradients.update({p: (np.ones(1), [p]) for p in JACKKNIFE_INTRINSICS})
    jackknife = {}
    for (p, (g, names)), scatter in zip(gradients.items(), jack, strict=True):
        i = cov.index(names)
        linear = cov.view_deltas[:, i] @ g if cov.view_deltas is not None else np.full(n, np.nan)
        jackknife[p] = {"value": parameter(full, p), "scatter": float(scatter),
                        "sigma": float(np.sqrt(cov.variance_of(g, names)[0])),
                        "sigma_residuals": float(np.sqrt(g @ cov.matrix[np.ix_(i, i)] @ g)),
                        "linearised_scatter": float(np.sqrt((n - 1) / n * np.sum((linear - linear.mean()) ** 2)))}
    adequacy = full.adequacy.as_dict() if full.adequacy is not None else None
    return {"rows": rows, "opencv_errors_mm": opencv_leave_one_out(name), "jackknife": jackknife, "calibration": full,
            "adequacy": adequacy,
            "calibration_correlation": calibration_correlation(full.covariance, sensitivities, jackknife=jackknifed)}


def calibration_correlation(covariance, sensitivities: list[dict], *, jackknife: bool) -> np.ndarray:
    """(n, n) correlation of the held-out pairs' calibration errors: the leave-one-out calibrations share all
    views but two, so their errors are nearly one draw of the full calibration's, seen by each pair through its
    own sensitivities g_i: g_i S g_j normalised, S the matrix or (``jackknife``: where the budget took the
    views' scatter) the views' jackknife covariance (n - 1)/n sum (d_v - mean)(d_v - mean)^T."""
    names = list(covariance.names)
    g = np.array([[float(s.get(p, 0.0)) for p in names] for s in sensitivities])
    if jackknife and covariance.view_deltas is not None:
        d = covariance.view_deltas - covariance.view_deltas.mean(axis=0)
        S = (len(d) - 1) / len(d) * d.T @ d
    else:
        S = covariance.matrix
    c = g @ S @ g.T
    scale = np.sqrt(np.clip(np.diag(c), 1e-300, None))
    return c / np.outer(scale, scale)


def summary(result: dict) -> dict:
    """The issue's figures of one set's :func:`leave_one_out`."""
    baseline = result["jackknife"]["baseline"]
    return {**summary_rows(result), "baseline_sigma_ratio": baseline["scatter"] / baseline["sigma"],
            "baseline_sigma_ratio_residuals": baseline["scatter"] / baseline["sigma_residuals"]}


def summary_rows(result: dict) -> dict:
    """The held-out figures of a leave-one-out's ``rows`` and ``opencv_errors_mm`` (no jackknife)."""
    errors = np.array([r["error_mm"] for r in result["rows"]])
    u_c = np.array([r["u_c_mm"] for r in result["rows"]])
    U = np.array([r["U_mm"] for r in result["rows"]])
    opencv = result["opencv_errors_mm"]
    return {
        "pairs": len(errors), "rms_error_mm": float(np.sqrt(np.mean(errors**2))),
        "opencv_pairs": len(opencv), "opencv_rms_error_mm": float(np.sqrt(np.mean(opencv**2))),
        "rms_normalised": float(np.sqrt(np.mean((errors / u_c) ** 2))),
        # The same without the pair of the largest |error| / u_c: what the bulk of the pairs shows beside one odd one.
        "rms_normalised_without_worst": float(np.sqrt(np.mean(np.sort((errors / u_c) ** 2)[:-1]))),
        "within_U": float(np.mean(np.abs(errors) <= U)),
        "inflation": float(np.median(U) / np.median(np.abs(errors))),
        "median_U_mm": float(np.median(U)), "median_abs_error_mm": float(np.median(np.abs(errors))),
        **exact_budget_inflation(U / u_c),
        **({} if "calibration_correlation" not in result else {
            f"inflation_exact_shared_{k.removeprefix('inflation_exact_')}": v for k, v in exact_budget_inflation(
                U / u_c, shared=np.array([r["u_calibration_mm"] or 0.0 for r in result["rows"]]) / u_c,
                correlation=result["calibration_correlation"]).items()}),
    }


def exact_budget_inflation(k: np.ndarray, *, shared: np.ndarray | None = None, correlation: np.ndarray | None = None,
                           draws: int = 20000, seed: int = 0) -> dict:
    """What median U / median |error| an exact budget gives on these pairs: errors drawn normal with their u_c,
    U = k u_c (``k`` (n,) the pairs' coverage factors). Its median and 95 % band (seeded Monte Carlo): a ratio
    inside the band is what ``len(k)`` pairs of an exact budget show, whatever the bar (for k = 2 the median
    is 2 / 0.674 = 2.97, so a bar of 3 is missed by about half of all sets whose budget is exact).

    ``shared`` (n,): the part of each u_c (as a fraction of it) that is one draw for all pairs with
    ``correlation`` (n, n) between them (a leave-one-out's calibration component, :func:`calibration_correlation`);
    the rest independent. A shared error that happens to be small leaves the set's errors small and the ratio
    large: the band widens."""
    k = np.asarray(k, dtype=np.float64)
    rng = np.random.default_rng(seed)
    if shared is None:
        errors = rng.standard_normal((draws, len(k)))
    else:
        shared = np.clip(np.asarray(shared, dtype=np.float64), 0.0, 1.0)
        w, v = np.linalg.eigh(np.asarray(correlation, dtype=np.float64))
        root = v * np.sqrt(np.clip(w, 0.0, None))  # correlation = root root^T (positive semi-definite)
        errors = (shared * (rng.standard_normal((draws, len(k))) @ root.T)
                  + np.sqrt(1.0 - shared**2) * rng.standard_normal((draws, len(k))))
    # The errors in units of each pair's u_c; U / u_c = k: the ratio of medians in those units as well.
    ratio = np.median(k) / np.median(np.abs(errors), axis=1)
    low, median, high = np.percentile(ratio, [2.5, 50.0, 97.5])
    return {"inflation_exact_median": float(median), "inflation_exact_95": [float(low), float(high)],
            "inflation_exact_share_at_most_3": float(np.mean(ratio <= 3.0))}


@cache
def _inconsistent_calibrations(name: str, views: tuple[int, ...], shift_px: float) -> tuple:
    """:func:`inconsistent_leave_one_out`'s corners (right ones of ``views`` shifted), per usable pair the
    calibration without it, and the calibration of them all: made once per (set, views, shift)."""
    s = SETS[name]
    det = detections(name)
    usable = [i for i, d in enumerate(det) if d[0] is not None and d[1] is not None]
    corners = {}
    for position, i in enumerate(usable):
        ids, left, right = common_corners(*det[i])
        corners[i] = (ids, left, right + np.array([shift_px, 0.0]) if position in views else right)
    size = images(name)[0][0].shape[::-1]

    def calibrate(keys):
        return _calibrate([s.board.object_points[corners[i][0]] for i in keys], [corners[i][1] for i in keys],
                          [corners[i][2] for i in keys], size)

    return corners, {held_out: calibrate([i for i in usable if i != held_out]) for held_out in usable}, \
        calibrate(usable)


def inconsistent_leave_one_out(name: str, views: tuple[int, ...], shift_px: float, *, adequacy: bool = True) -> dict:
    """Leave-one-out on ``name`` with the right corners of ``views`` (positions among the usable pairs) moved
    ``shift_px`` along x: pairs whose left and right images disagree (a board that moved between the two
    exposures), kept by the calibration, the class of the issue's anamorphic webcam. ``adequacy`` False: the
    budget without the model-adequacy component (as before it existed). Returns errors_mm, u_c_mm, U_mm per pair
    and the full calibration's adequacy."""
    from dataclasses import replace as _replace

    from stereo_bench.vision.uncertainty import FrameCorners

    s = SETS[name]
    det = detections(name)
    corners, calibrations, full = _inconsistent_calibrations(name, tuple(views), float(shift_px))
    errors, u_c, U = [], [], []
    for held_out, calib in calibrations.items():
        pair = measure_pair(images(name)[0][held_out], images(name)[1][held_out], calib, s.board,
                            detections=det[held_out])
        frame = _replace(FrameCorners.from_pair(pair), right_px=corners[held_out][2], triangulated=None)
        budget = configuration_budget([frame], calib, s.board, board_scale=BoardScale(same_board=True),
                                      structure_covariance=np.zeros((6, 6)), adequacy="calib" if adequacy else None)
        errors.append(budget.error_mm)
        u_c.append(budget.combined)
        U.append(budget.expanded)
    return {"errors_mm": np.array(errors), "u_c_mm": np.array(u_c), "U_mm": np.array(U), "adequacy": full.adequacy}


# caliscope_charuco_2cam: an inverted ChArUco board in two synchronised videos, the cameras 83 deg convergent
# (calib_data/real/caliscope_charuco_2cam/SOURCE.md). Held out per synchronised frame; the calibration is the
# project's default (joint, each camera's intrinsics from the frames in the calibration), the square is
# triangulated without rectification (measure_square on undistorted rays).
CALISCOPE = REAL / "caliscope_charuco_2cam"
CALISCOPE_BOARD = CharucoTarget(4, 5, 54.0, 40.5, "DICT_4X4_1000", inverted=True)
CALISCOPE_MIN_COMMON = 6


@cache
def caliscope_frames() -> tuple[list[np.ndarray], list[np.ndarray]]:
    def read(path):
        capture, out = cv2.VideoCapture(str(path)), []
        while True:
            ok, frame = capture.read()
            if not ok:
                return out
            out.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
    return read(CALISCOPE / "cam_0.mp4"), read(CALISCOPE / "cam_1.mp4")


@cache
def caliscope_views() -> tuple[list[int], tuple]:
    """(synchronised frames with >= 6 common corners, per frame the (left, right) detections with noise)."""
    left, right = caliscope_frames()
    det = tuple((detect(a, CALISCOPE_BOARD), detect(b, CALISCOPE_BOARD)) for a, b in zip(left, right, strict=True))
    frames = [i for i, (a, b) in enumerate(det) if a is not None and b is not None
              and len(common_corners(a, b)[0]) >= CALISCOPE_MIN_COMMON]
    return frames, det


def _opencv_charuco(image: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """OpenCV's own CharucoDetector (whole dictionary) on the inverted grey image: (ids, corners) or None."""
    b = CALISCOPE_BOARD
    board = cv2.aruco.CharucoBoard((b.squares_x, b.squares_y), b.square_mm, b.marker_mm,
                                   cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_1000))
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(255 - image)
    if ids is None:
        return None
    return np.asarray(ids).reshape(-1), np.asarray(corners, np.float64).reshape(-1, 2)


def caliscope_opencv_leave_one_out() -> np.ndarray:
    """Plain OpenCV's held-out square errors (mm), per synchronised frame with >= 6 common corners."""
    left, right = caliscope_frames()
    views = {}
    for i, (a, b) in enumerate(zip(left, right, strict=True)):
        da, db = _opencv_charuco(a), _opencv_charuco(b)
        if da is None or db is None:
            continue
        ids, ia, ib = np.intersect1d(da[0], db[0], return_indices=True)
        if len(ids) >= CALISCOPE_MIN_COMMON:
            views[i] = (ids, da[1][ia], db[1][ib])
    errors = []
    for held_out in views:
        keep = [i for i in views if i != held_out]
        calib = plain_opencv_stereo([CALISCOPE_BOARD.object_points[views[i][0]] for i in keep],
                                    [views[i][1] for i in keep], [views[i][2] for i in keep], (1280, 720))
        ids, lp, rp = views[held_out]
        points = triangulate(calib, lp, rp)
        pos = {k: j for j, k in enumerate(ids.tolist())}
        pairs = [p for p in CALISCOPE_BOARD.adjacent_pairs() if p[0] in pos and p[1] in pos]
        errors.append(float(np.mean([np.linalg.norm(points[pos[a]] - points[pos[b]]) for a, b in pairs]))
                      - CALISCOPE_BOARD.square_mm)
    return np.array(errors)


@cache
def caliscope_leave_one_out() -> dict:
    """:func:`leave_one_out`'s ``rows`` and ``opencv_errors_mm`` for caliscope_charuco_2cam (no jackknife)."""
    frames, det = caliscope_views()
    left, right = caliscope_frames()
    views = {i: common_corners(*det[i]) for i in frames}
    rows = []
    for held_out in frames:
        keep = [i for i in frames if i != held_out]
        calib = _calibrate([CALISCOPE_BOARD.object_points[views[i][0]] for i in keep], [views[i][1] for i in keep],
                           [views[i][2] for i in keep], (1280, 720))
        pair = measure_pair(left[held_out], right[held_out], calib, CALISCOPE_BOARD, detections=det[held_out])
        budget = configuration_budget([pair], calib, CALISCOPE_BOARD, board_scale=BoardScale(same_board=True),
                                      structure_covariance=np.zeros((6, 6)), structure_source="unmoved within the set")
        rows.append({"pair": held_out, "error_mm": budget.error_mm, "u_c_mm": budget.combined,
                     "U_mm": budget.expanded, **{f"u_{k}_mm": v for k, v in budget.components.items()},
                     "u_adequacy_mm": budget.adequacy, "noise_random_mm": budget.noise_random_mm,
                     "noise_systematic_mm": budget.noise_systematic_mm, "dominant": budget.dominant,
                     "baseline_mm": calib.baseline_mm, "rms_px": calib.rms_px})
    return {"rows": rows, "opencv_errors_mm": caliscope_opencv_leave_one_out()}


def corner_sigmas(name: str) -> list[dict]:
    """Per pair the full calibration keeps, measured with it: the budget's corner error per coordinate beside the
    image noise and the pair's own planar-fit residual, with the calibration's covariance and without it."""
    from dataclasses import replace as _replace

    from stereo_bench.vision.uncertainty import FrameCorners, frames_residual_px

    s = SETS[name]
    det = detections(name)
    full, usable = full_calibration(name)
    bare = _replace(full, covariance=None, adequacy=None)
    rows = []
    for i in [usable[k] for k in full.views_used]:
        pair = measure_pair(images(name)[0][i], images(name)[1][i], full, s.board, detections=det[i])
        with_it = configuration_budget([pair], full, s.board, board_scale=BoardScale(same_board=True))
        without = configuration_budget([pair], bare, s.board, board_scale=BoardScale(same_board=True))
        rows.append({"image_noise_px": with_it.corner_random_px, "corner_sigma_px": with_it.corner_sigma_px,
                     "corner_sigma_without_covariance_px": without.corner_sigma_px,
                     "planar_fit_px": frames_residual_px([FrameCorners.from_pair(pair)])[0],
                     "fit_sigma_px": full.covariance.sigma_px})
    return rows


@cache
def leave_one_out_without_covariance(name: str) -> dict:
    """:func:`leave_one_out`'s held-out errors and budgets (``errors_mm``, ``u_c_mm``, ``U_mm``) with each
    leave-one-out calibration's covariance and adequacy check removed: a calibration file that has none."""
    from dataclasses import replace as _replace

    s = SETS[name]
    det = detections(name)
    errors, u_c, U = [], [], []
    for held_out, calib in leave_one_out_calibrations(name).items():
        calib = _replace(calib, covariance=None, adequacy=None)
        pair = measure_pair(images(name)[0][held_out], images(name)[1][held_out], calib, s.board,
                            detections=det[held_out])
        budget = configuration_budget([pair], calib, s.board, board_scale=BoardScale(same_board=True),
                                      structure_covariance=np.zeros((6, 6)))
        errors.append(budget.error_mm)
        u_c.append(budget.combined)
        U.append(budget.expanded)
    return {"errors_mm": np.array(errors), "u_c_mm": np.array(u_c), "U_mm": np.array(U)}
