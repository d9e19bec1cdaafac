"""mrcal, out of process: where it is, and the cross-check fit of the same corners (docs/FORMATS.md).

mrcal has no wheel for the Python the project runs on (BRIEF section 8); Debian's ``python3-mrcal`` installs it for
the system Python. So it runs in a child process: :func:`mrcal_python` finds an interpreter that imports it
(``STEREO_BENCH_MRCAL_PYTHON``, else ``/usr/bin/python3``, else ``python3`` on PATH), and the solve's inputs and
results cross as JSON.
"""

from __future__ import annotations

import functools
import math
import os
import shutil
import subprocess

#: The interpreter to run mrcal with, when it is not the system Python (a venv of Python >= 3.12 with mrcal 2.5).
MRCAL_PYTHON_ENV = "STEREO_BENCH_MRCAL_PYTHON"
PROBE_TIMEOUT_S = 60


class MrcalUnavailable(RuntimeError):
    """No Python with mrcal was found (the message says where it looked and how to install it)."""


def _candidates() -> list[str]:
    given = os.environ.get(MRCAL_PYTHON_ENV)
    if given:
        return [given]
    found = ["/usr/bin/python3"]
    on_path = shutil.which("python3")
    if on_path and on_path not in found:
        found.append(on_path)
    return found


@functools.cache
def _probe(python: str) -> str | None:
    """mrcal's version as ``python`` imports it, or None."""
    try:
        done = subprocess.run([python, "-c", "import mrcal, numpy; print(getattr(mrcal, '__version__', '2'))"],
                              capture_output=True, text=True, timeout=PROBE_TIMEOUT_S)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() or "unknown" if done.returncode == 0 else None


def mrcal_python() -> str | None:
    """The first interpreter that imports mrcal: ``$STEREO_BENCH_MRCAL_PYTHON`` (only it, when set), else
    ``/usr/bin/python3`` (Debian's python3-mrcal), else ``python3`` on PATH; None when none does."""
    for python in _candidates():
        if _probe(python) is not None:
            return python
    return None


def unavailable_reason() -> str:
    where = ", ".join(_candidates())
    return (f"mrcal is not importable by {where} (install Debian's packages: apt-get install mrcal python3-mrcal; "
            f"or set {MRCAL_PYTHON_ENV} to a Python that imports mrcal)")


#: Our lens model -> the mrcal model that holds it (mrcal frees all its distortion terms: for fixed-aspect fx and fy
#: are both free, for thin-prism k3..k6 too; the cross-check says so).
MRCAL_LENSMODELS = {"fixed-aspect": "LENSMODEL_OPENCV4", "opencv4": "LENSMODEL_OPENCV4", "opencv5": "LENSMODEL_OPENCV5",
                    "rational": "LENSMODEL_OPENCV8", "thin-prism": "LENSMODEL_OPENCV12"}
MRCAL_LENGTHS = {"LENSMODEL_OPENCV4": 4, "LENSMODEL_OPENCV5": 5, "LENSMODEL_OPENCV8": 8, "LENSMODEL_OPENCV12": 12}
#: Seconds the child solve may take (20-30 views: 1-3 s; the uncertainty's dense algebra included).
SOLVE_TIMEOUT_S = 600
#: Grid over the image for the projection difference and uncertainty (mrcal-show-projection-diff's default: 60).
GRID_WIDTH = 60
#: Agreement: a difference within this many standard uncertainties (|T|) or median projection uncertainties.
AGREE_Z = 2.0

# The child: mrcal.optimize of the same corners seeded by our solution, then its RMS in OpenCV's convention, the
# covariance of |T| (mrcal's formulation: sigma^2 (J'J)^-1 J_obs' J_obs (J'J)^-1, sigma from the residuals), and
# projection_diff / projection_uncertainty over the image. JSON in on stdin, JSON out on stdout.
_CHILD = r"""
import json, sys
import numpy as np
import mrcal

inp = json.load(sys.stdin)
H, W, spacing = inp["H"], inp["W"], inp["spacing"]
lensmodel = inp["lensmodel"]
observations = np.array(inp["observations"], float)  # (Nobs, H, W, 3): x, y, weight (-1: corner not seen)
indices = np.array(inp["indices"], np.int32)
version = getattr(mrcal, "__version__", None)
if version is None and mrcal.__file__.startswith("/usr/lib/python3/dist-packages/"):
    import subprocess
    try:  # Debian's python3-mrcal has no __version__ and no package metadata
        version = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "python3-mrcal"], capture_output=True,
                                 text=True, timeout=30).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        version = None
out = {"mrcal_version": version or "(version unknown)"}

def solve(warp):
    inputs = dict(
        intrinsics=np.array(inp["intrinsics"], float), extrinsics_rt_fromref=np.array([inp["rt_right_left"]], float),
        frames_rt_toref=np.array(inp["frames_rt_toref"], float), points=None, observations_board=observations.copy(),
        indices_frame_camintrinsics_camextrinsics=indices, observations_point=None,
        indices_point_camintrinsics_camextrinsics=None, lensmodel=lensmodel,
        imagersizes=np.array([inp["imagersize"]] * 2, np.int32), calobject_warp=np.zeros(2) if warp else None,
        do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=True, do_optimize_extrinsics=True,
        do_optimize_frames=True, do_optimize_calobject_warp=warp, calibration_object_spacing=spacing,
        do_apply_outlier_rejection=True, do_apply_regularization=True, verbose=False)
    stats = mrcal.optimize(**inputs)
    return inputs, stats

def rms_opencv(inputs):
    x = mrcal.optimizer_callback(**inputs, no_jacobian=True)[1]
    i0 = mrcal.measurement_index_boards(0, **inputs)
    xb = x[i0:i0 + mrcal.num_measurements_boards(**inputs)].reshape(-1, 2)
    inlier = inputs["observations_board"][..., 2].ravel() > 0
    return float(np.sqrt(np.mean(np.sum(xb[inlier] ** 2, axis=1)))), int(np.sum(~inlier)), xb, inlier

def rms_all(inputs):
    # over every corner seen, the ones mrcal rejected as outliers included (as OpenCV's RMS is): their residuals are
    # those of mrcal's solution, recomputed with their weight restored
    restored = dict(inputs, observations_board=observations.copy())
    x = mrcal.optimizer_callback(**restored, no_jacobian=True)[1]
    i0 = mrcal.measurement_index_boards(0, **restored)
    xb = x[i0:i0 + mrcal.num_measurements_boards(**restored)].reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(xb[observations[..., 2].ravel() > 0] ** 2, axis=1))))

inputs, stats = solve(False)
rms, noutliers, xb, inlier = rms_opencv(inputs)
seen = np.array(inp["observations"], float)[..., 2].ravel() > 0
rt = inputs["extrinsics_rt_fromref"][0]
out.update(intrinsics=inputs["intrinsics"].tolist(), rt_right_left=rt.tolist(), rms_px=rms, rms_all_px=rms_all(inputs),
           outliers=int(np.sum(seen & ~inlier)), corners=int(np.sum(seen)))

# sigma of |T|: the state's covariance from the board measurements' Jacobian.
b, x, J = mrcal.optimizer_callback(**inputs)[:3]
J = J.toarray()
i0 = mrcal.measurement_index_boards(0, **inputs)
nb = mrcal.num_measurements_boards(**inputs)
Jobs = J[i0:i0 + nb]
nstate = J.shape[1]
nmeas = int(np.sum(inlier)) * 2
sigma = float(np.sqrt(np.sum(xb[inlier] ** 2) / max(nmeas - nstate, 1)))
JtJ_inv = np.linalg.inv(J.T @ J)
C_packed = sigma ** 2 * JtJ_inv @ (Jobs.T @ Jobs) @ JtJ_inv
scale = np.ones(nstate)
mrcal.unpack_state(scale, **inputs)
C = C_packed * np.outer(scale, scale)
ie = mrcal.state_index_extrinsics(0, **inputs)
t = rt[3:]
u = t / np.linalg.norm(t)
out["baseline_sigma_mm"] = float(np.sqrt(u @ C[ie + 3:ie + 6, ie + 3:ie + 6] @ u))
out["sigma_px"] = sigma

# Board warp (mrcal-calibrate-cameras' default): reported beside, not compared.
try:
    winputs, _ = solve(True)
    wrms = rms_opencv(winputs)[0]
    out["warp"] = {"baseline_mm": float(np.linalg.norm(winputs["extrinsics_rt_fromref"][0][3:])), "rms_px": wrms,
                   "calobject_warp_mm": winputs["calobject_warp"].tolist()}
except Exception as error:  # the flat solve is the cross-check; the warp is information
    out["warp"] = {"error": " ".join(str(error).split())}

# Projection: ours against mrcal's, per camera, over the image (mrcal-show-projection-diff's grid) and at the corners
# the camera saw (where the data are: away from them both models extrapolate and mrcal's uncertainty grows).
def stats(values):
    values = np.asarray(values, float)
    finite = values[np.isfinite(values)]
    if not finite.size:
        return None, None, 0.0
    return float(np.median(finite)), float(np.percentile(finite, 95)), float(finite.size / values.size)

obs = np.array(inp["observations"], float)
out["cameras"] = []
for icam, ours in enumerate(inp["ours"]):
    theirs = mrcal.cameramodel(optimization_inputs=inputs, icam_intrinsics=icam)
    mine = mrcal.cameramodel(intrinsics=(lensmodel, np.array(ours, float)), imagersize=inp["imagersize"])
    difflen, _, q0, Rt10 = mrcal.projection_diff((mine, theirs), gridn_width=inp["grid"], use_uncertainties=False)
    unc = mrcal.projection_uncertainty(mrcal.unproject(q0, *theirs.intrinsics()), theirs, atinfinity=True,
                                       what="rms-stdev")
    q = obs[indices[:, 1] == icam].reshape(-1, 3)
    q = q[q[:, 2] > 0, :2]
    v1 = mrcal.transform_point_Rt(Rt10, mrcal.unproject(q, *mine.intrinsics()))
    corner_diff = np.linalg.norm(mrcal.project(v1, *theirs.intrinsics()) - q, axis=-1)
    corner_unc = mrcal.projection_uncertainty(mrcal.unproject(q, *theirs.intrinsics()), theirs, atinfinity=True,
                                              what="rms-stdev")
    d_med, d_p95, d_share = stats(difflen)
    u_med, u_p95, _ = stats(unc)
    c_med, c_p95, _ = stats(corner_diff)
    cu_med, _, _ = stats(corner_unc)
    out["cameras"].append({"diff_median_px": d_med, "diff_p95_px": d_p95, "grid_share_valid": d_share,
                           "uncertainty_median_px": u_med, "uncertainty_p95_px": u_p95,
                           "corners_diff_median_px": c_med, "corners_diff_p95_px": c_p95,
                           "corners_uncertainty_median_px": cu_med})
print(json.dumps(out))
"""


def _board_grid(object_points, spacing: float) -> tuple[int, int]:
    """(H, W): the rows and columns of a flat board's corners (N, 3) mm, a grid of ``spacing`` from (0, 0)."""
    import numpy as np

    xy = np.asarray(object_points, float)[:, :2]
    grid = np.rint(xy / spacing).astype(int)
    if np.any(np.abs(grid * spacing - xy) > 1e-6 * spacing) or np.any(np.asarray(object_points)[:, 2] != 0):
        raise ValueError("the board's corners are not a flat grid of its square: mrcal needs one")
    if grid.min() < 0:
        raise ValueError("the board's corners do not start at (0, 0)")
    return int(grid[:, 1].max()) + 1, int(grid[:, 0].max()) + 1


def cross_check(calib, corners, board_points, square_mm: float, *, python: str | None = None) -> dict:
    """Fit the corners ``corners`` (per view: board points (N, 3) mm, left (N, 2) px, right (N, 2) px) again with
    mrcal, seeded by ``calib`` (a StereoCalibration), and compare: |T| with both standard uncertainties, both RMS
    (OpenCV's convention: sqrt of the mean squared 2-D residual over both cameras' corners), and per camera
    mrcal.projection_diff of our intrinsics against mrcal's over the image beside mrcal's projection uncertainty.

    ``board_points``: the whole board's corners (n_corners, 3) mm, a flat grid of ``square_mm``. Returns the
    JSON-ready comparison (``rows``: what to print). Raises MrcalUnavailable, or RuntimeError when mrcal fails.
    """
    import json

    import cv2
    import numpy as np

    from stereo_bench.vision.covariance import EXTRINSIC_NAMES
    from stereo_bench.vision.formats import lens_name

    python = python or mrcal_python()
    if python is None:
        raise MrcalUnavailable(unavailable_reason())
    ours_model = calib.lens_model or lens_name(calib.D1, calib.K1)
    lensmodel = MRCAL_LENSMODELS.get(ours_model)
    if lensmodel is None or len(np.ravel(calib.D1)) > 12:
        raise ValueError(f"lens model {ours_model or 'of D ' + str(np.ravel(calib.D1).size)} has no mrcal counterpart")
    n = MRCAL_LENGTHS[lensmodel]

    def intrinsics(K, D):
        d = np.zeros(n)
        values = np.ravel(D)[:n]
        d[:len(values)] = values
        return [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), *map(float, d)]

    H, W = _board_grid(board_points, square_mm)
    observations, indices, frames = [], [], []
    for view, (objects, left, right) in enumerate(corners):
        objects = np.asarray(objects, float)
        col = np.rint(objects[:, 0] / square_mm).astype(int)
        row = np.rint(objects[:, 1] / square_mm).astype(int)
        for camera, pixels in ((0, left), (1, right)):
            grid = np.full((H, W, 3), -1.0)
            grid[row, col, :2] = np.asarray(pixels, float)
            grid[row, col, 2] = 1.0
            observations.append(grid.tolist())
            indices.append([view, camera, camera - 1])
        ok, rvec, tvec = cv2.solvePnP(objects, np.asarray(left, float), calib.K1, calib.D1)
        if not ok:
            raise RuntimeError(f"view {view}: solvePnP found no board pose to seed mrcal with")
        frames.append([*map(float, np.ravel(rvec)), *map(float, np.ravel(tvec))])
    mine = [intrinsics(calib.K1, calib.D1), intrinsics(calib.K2, calib.D2)]
    request = {"H": H, "W": W, "spacing": float(square_mm), "lensmodel": lensmodel, "observations": observations,
               "indices": indices, "intrinsics": mine, "ours": mine, "frames_rt_toref": frames,
               "rt_right_left": [*map(float, cv2.Rodrigues(np.asarray(calib.R, float))[0].ravel()),
                                 *map(float, np.ravel(calib.T))],
               "imagersize": [int(calib.image_size[0]), int(calib.image_size[1])], "grid": GRID_WIDTH}
    try:
        done = subprocess.run([python, "-c", _CHILD], input=json.dumps(request), capture_output=True, text=True,
                              timeout=SOLVE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"mrcal ({python}) did not finish within {SOLVE_TIMEOUT_S} s") from None
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise RuntimeError(f"mrcal ({python}) failed: {last}")
    theirs = json.loads(done.stdout)
    sigma_ours = sigma_residuals = source = None
    if calib.covariance is not None:  # as calibrate states it: the views' jackknife where it is significantly larger
        u = np.ravel(calib.T) / np.linalg.norm(calib.T)
        variance, _, source = calib.covariance.variance_of(u, EXTRINSIC_NAMES[3:])
        sigma_ours = math.sqrt(variance)
        i = calib.covariance.index(EXTRINSIC_NAMES[3:])
        sigma_residuals = math.sqrt(max(float(u @ calib.covariance.matrix[np.ix_(i, i)] @ u), 0.0))
    baseline_mrcal = float(np.linalg.norm(theirs["rt_right_left"][3:]))
    delta = baseline_mrcal - calib.baseline_mm
    sigma_both = math.hypot(sigma_ours or 0.0, theirs["baseline_sigma_mm"])
    z = delta / sigma_both if sigma_both > 0 else math.inf
    cameras = []
    for side, cam in zip(("left", "right"), theirs["cameras"], strict=True):
        diff, unc = cam["corners_diff_median_px"], cam["corners_uncertainty_median_px"]
        ratio = diff / unc if diff is not None and unc else math.inf
        cameras.append({"camera": side, **cam, "agree": bool(ratio <= AGREE_Z), "ratio": ratio})
    notes = []
    if ours_model == "fixed-aspect":
        notes.append("our model holds fx = fy, mrcal's OPENCV4 frees both")
    if ours_model == "thin-prism":
        notes.append("mrcal's OPENCV12 frees k3..k6 too")
    if theirs["outliers"]:
        notes.append(f"mrcal rejected {theirs['outliers']} of {theirs['corners']} corners as outliers")
    notes.append("mrcal regularises the distortion and the principal point")
    return {
        "mrcal": python, "mrcal_version": theirs["mrcal_version"], "lensmodel": lensmodel, "our_lens_model": ours_model,
        "views": len(corners),
        "baseline_mm": {"ours": calib.baseline_mm, "ours_sigma": sigma_ours, "ours_sigma_source": source,
                        "ours_sigma_residuals": sigma_residuals, "mrcal": baseline_mrcal,
                        "mrcal_sigma": theirs["baseline_sigma_mm"], "difference": delta, "z": z,
                        "agree": bool(abs(z) <= AGREE_Z)},
        "rms_px": {"ours": float(calib.rms_px), "mrcal": theirs["rms_px"], "mrcal_all_corners": theirs["rms_all_px"],
                   "mrcal_outliers": theirs["outliers"],
                   "corners": theirs["corners"]},
        "sigma_px": {"mrcal": theirs["sigma_px"]},
        "projection": cameras,
        "mrcal_with_board_warp": theirs["warp"],
        "mrcal_intrinsics": theirs["intrinsics"], "mrcal_rt_right_left": theirs["rt_right_left"],
        "notes": notes,
        "agree": bool(abs(z) <= AGREE_Z and all(c["agree"] for c in cameras)),
    }


def cross_check_lines(check: dict) -> list[str]:
    """The comparison as the lines ``calibrate --cross-check mrcal`` prints."""
    b, r = check["baseline_mm"], check["rms_px"]
    ours_sigma = "unknown" if b["ours_sigma"] is None else (
        f"{b['ours_sigma']:.3f}" + (f" (views' jackknife; residuals {b['ours_sigma_residuals']:.3f})"
                                    if b["ours_sigma_source"] == "views" else ""))
    lines = [f"cross-check with mrcal {check['mrcal_version']} ({check['lensmodel']}, the same {check['views']} views' "
             "corners, flat board):",
             f"  |T| ours {b['ours']:.3f} +- {ours_sigma} mm, mrcal {b['mrcal']:.3f} +- {b['mrcal_sigma']:.3f} mm: "
             f"difference {b['difference']:+.3f} mm = {b['z']:+.2f} sigma ({'agree' if b['agree'] else 'DIFFER'})",
             f"  RMS ours {r['ours']:.4f} px, mrcal {r['mrcal']:.4f} px ({r['mrcal_outliers']} of {r['corners']} "
             f"corners rejected by mrcal; {r['mrcal_all_corners']:.4f} px over all corners)"]

    def px(value):
        return "n/a" if value is None else f"{value:.3f}"

    for cam in check["projection"]:
        lines.append(f"  {cam['camera']:5s} projection difference at the corners seen: median "
                     f"{px(cam['corners_diff_median_px'])} px against mrcal's projection uncertainty there "
                     f"{px(cam['corners_uncertainty_median_px'])} px ({'agree' if cam['agree'] else 'DIFFER'}); over "
                     f"the image: median {px(cam['diff_median_px'])} px (95 % {px(cam['diff_p95_px'])}), "
                     f"uncertainty {px(cam['uncertainty_median_px'])} px")
    warp = check["mrcal_with_board_warp"]
    if "baseline_mm" in warp:
        lines.append(f"  mrcal with board warp (its default): |T| {warp['baseline_mm']:.3f} mm, RMS "
                     f"{warp['rms_px']:.4f} px, warp {warp['calobject_warp_mm'][0]:+.3f} / "
                     f"{warp['calobject_warp_mm'][1]:+.3f} mm")
    lines.append("  " + "; ".join(check["notes"]))
    return lines
