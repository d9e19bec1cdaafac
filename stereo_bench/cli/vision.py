"""``stereo-bench calibrate | measure | render``: the measurement core on image files."""

from __future__ import annotations

import argparse
import contextlib
import functools
import glob
import json
import math
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from stereo_bench import atomic
from stereo_bench.cli import CliError, print_json
from stereo_bench.cli.args import (
    ALPHA_DEG,
    BASELINE_MM,
    DISTANCE_MM,
    FOCAL_MM,
    PIXEL_SIGMA_PX,
    PIXEL_UM,
    SEED,
    SQUARE_MM,
    TILT_DEG,
    TOE_IN_DEG,
    board_pattern,
    finite_float,
    output_dir,
)
from stereo_bench.targets import ARUCO_DICTIONARIES, CharucoTarget, Checkerboard, Target, parse_pattern
from stereo_bench.vision.lensmodels import CHOICES as LENS_CHOICES
from stereo_bench.vision.lensmodels import MODELS as LENS_MODELS

IMAGE_HELP = "image file (PNG, JPEG, ...); colour images are converted to grey"

# Ranges of the numeric options only these commands take (the shared ones: stereo_bench/cli/args.py).
BOARD_SCALE_U = finite_float(min=0, max=0.1, inclusive=(True, False))  # a relative standard uncertainty
NOISE_DN = finite_float(min=0, max=255, unit="DN")  # 8-bit frames
# The renderer's cost grows with the blur (kernel ~ 6 sigma): 50 px took 3.6 s, 200 px 48 s at load 16
# (scripts/bench_input_bounds.py), 1000 px ran for minutes; at 50 px a 9x6 board at 500 mm is no longer detected.
BLUR_PX = finite_float(min=0, max=50, unit="px")


def add_target_options(parser: argparse.ArgumentParser, *, default_square_mm: float | None,
                       from_calibration: bool = False) -> None:
    """``from_calibration``: --board and --square default to the board the calibration records (``measure``),
    ``default_square_mm`` then only when it records none."""
    recorded = " (default: the board the calibration records)" if from_calibration else ""
    parser.add_argument("--board", required=not from_calibration, metavar="COLSxROWS", type=board_pattern,
                        help="checkerboard inner corners per row x per column, e.g. 9x6 "
                             "(with --charuco: squares per row x per column)" + recorded)
    square_default = ""
    if from_calibration:
        square_default = (" (default: the calibration's recorded square, for its board: another --board needs "
                          "--square" + (f"; {default_square_mm:g} when it records none)" if default_square_mm else ")"))
    elif default_square_mm:
        square_default = f" (default {default_square_mm})"
    parser.add_argument("--square", type=SQUARE_MM, required=default_square_mm is None and not from_calibration,
                        default=None if from_calibration else default_square_mm,
                        metavar="MM", help="square size in mm" + square_default)
    parser.add_argument("--charuco", action="store_true", help="the board is a ChArUco board (partial views count)")
    parser.add_argument("--marker", type=SQUARE_MM, metavar="MM",
                        help="ChArUco marker size in mm (default 0.75 x square)")
    parser.add_argument("--dictionary", default=None, choices=sorted(ARUCO_DICTIONARIES), metavar="DICT",
                        help=f"ChArUco ArUco dictionary (default {DEFAULT_DICTIONARY}"
                             + (", or the calibration's recorded one)" if from_calibration else ")"))
    parser.add_argument("--inverted", action="store_true",
                        help="the ChArUco board is printed white on black (white markers on black squares, as "
                             "caliscope's); calibrate records it for measure")


#: The ChArUco dictionary when neither --dictionary nor the calibration says.
DEFAULT_DICTIONARY = "DICT_5X5_1000"

#: ``measure``'s square when neither --square nor the calibration says (files from OpenCV or ``render``).
MEASURE_DEFAULT_SQUARE_MM = 27.0


def fixed_or_significant(value: float, decimals: int) -> str:
    """``value`` with ``decimals`` decimals, or two significant digits where those would print only zeros
    ("0.0000" for 3.9e-05): a quantity is never shown as 0 when it is not."""
    if value != 0 and math.isfinite(value) and abs(value) < 0.5 * 10.0**-decimals:
        return format(value, ".2g")
    return format(value, f".{decimals}f")


def target_from_args(args: argparse.Namespace) -> Target:
    try:
        cols, rows = parse_pattern(args.board)
        if args.charuco:
            marker = args.marker if args.marker else 0.75 * args.square
            return CharucoTarget(cols, rows, args.square, marker, args.dictionary or DEFAULT_DICTIONARY,
                                 inverted=getattr(args, "inverted", False))
        if getattr(args, "inverted", False):
            raise ValueError("--inverted is for a ChArUco board (--charuco): a checkerboard's colours are found "
                             "either way")
        return Checkerboard(cols, rows, args.square)
    except ValueError as error:
        raise CliError(f"--board/--square: {error}") from None


# What libjpeg and libpng print about a damaged file (their other messages are harmless, e.g. libpng's
# "iCCP: known incorrect sRGB profile").
_CORRUPT_DECODE = re.compile(r"corrupt|premature|truncat|invalid|error|bad |crc|extraneous", re.IGNORECASE)


@contextlib.contextmanager
def _decoder_messages() -> Iterator[list[str]]:
    """Collect what C libraries write to file descriptor 2 meanwhile (the list is filled on exit).

    libjpeg reports a truncated or damaged JPEG only as warnings on stderr and still returns an image; they
    are caught here to name the file, and kept off the terminal.
    """
    messages: list[str] = []
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all: nothing to keep clean
        yield messages
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield messages
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            messages.extend(line.strip() for line in sink.read().decode(errors="replace").splitlines()
                            if line.strip())


def read_gray(path: str | Path) -> np.ndarray:
    """A grey image from a file; CliError naming the file when it is missing, not an image, or corrupt."""
    path = Path(path)
    if not path.is_file():
        raise CliError(f"{path}: image not found" if not path.exists() else f"{path}: not a file")
    if not os.access(path, os.R_OK):
        raise CliError(f"{path}: cannot read the image (permission denied)")
    with _decoder_messages() as messages:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    damage = [m for m in messages if _CORRUPT_DECODE.search(m)]
    if damage:
        raise CliError(f"{path}: corrupt image ({damage[0]})")
    if image is None:
        raise CliError(f"{path}: cannot read image (not an image file, or corrupt)")
    return image


#: Threads decoding a calibration's image files (libjpeg and libpng run without the GIL).
READ_THREADS = 4


def read_grays(paths: list[str]) -> list[np.ndarray]:
    """:func:`read_gray` of each path, decoded on :data:`READ_THREADS` threads: the same images, and the same
    error for the first bad file, because any decoder complaint or failed decode is read again file by file in
    order (the decoders' stderr is process-wide, so a complaint is only attributable to its file that way)."""
    if not all(Path(path).is_file() and os.access(path, os.R_OK) for path in paths):
        return [read_gray(path) for path in paths]  # the first missing or unreadable file named, in order
    workers = max(1, min(READ_THREADS, os.cpu_count() or 1, len(paths)))
    with _decoder_messages() as messages, ThreadPoolExecutor(max_workers=workers) as pool:
        images = list(pool.map(lambda path: cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), paths))
    if any(image is None for image in images) or any(_CORRUPT_DECODE.search(m) for m in messages):
        return [read_gray(path) for path in paths]
    return images


def same_pixels(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.array_equal(a, b))


def make_out_dir(out: Path, option: str = "--out") -> None:
    """Create an output directory, or say in one line why it cannot be (a file in the way, no permission, ...)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise CliError(f"{option} {out}: a file is in the way (not a directory)") from None
    except OSError as error:
        raise CliError(f"{option} {out}: cannot create the directory: {error.strerror or error}") from None


def expand_glob(pattern: str, option: str) -> list[str]:
    paths = sorted(glob.glob(pattern))
    if not paths:
        raise CliError(f"{option} {pattern!r} matches no file")
    return paths


def camera_summary(K: np.ndarray, D: np.ndarray) -> dict:
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "dist": [float(x) for x in np.ravel(D)]}


def calibration_uncertainty(calib) -> dict | None:
    """Standard uncertainties of a calibration's parameters in the units they are shown in; None if unknown."""
    from stereo_bench.vision.covariance import extrinsic_sigmas

    cov = calib.covariance
    if cov is None:
        return None
    sides = {side: {name.split(".", 1)[1]: sigma for name, sigma in cov.sigmas().items() if name.startswith(side + ".")}
             for side in ("left", "right")}
    return {"sigma_px": cov.sigma_px, "dof": cov.dof, **sides, **extrinsic_sigmas(calib.R, calib.T, cov),
            "pixel_locking_px": None if cov.pixel_locking_px is None else list(cov.pixel_locking_px)}


def _pm(value: float, sigma: float | None, spec: str) -> str:
    return format(value, spec) + ("" if sigma is None else " +- " + format(sigma, spec))


def _lens_report(calib) -> dict:
    """The calibration's lens model and, when it was chosen, the held-out comparison (``calibrate --json``)."""
    if calib.lens_choice is None:
        return {"chosen": calib.lens_model or None, "requested": None, "reason": None, "comparison": []}
    return calib.lens_choice.as_dict()


def cmd_calibrate(args: argparse.Namespace) -> int:
    from stereo_bench.vision.calibio import (
        CalibrationFileError,
        read_intrinsics,
        read_intrinsics_covariance,
        write_calibration,
    )
    from stereo_bench.vision.gates import CalibrationRefused
    from stereo_bench.vision.pipeline import calibrate_from_images

    target = target_from_args(args)
    mrcal = _mrcal_for_cross_check(args)
    left_paths, right_paths = expand_glob(args.left, "--left"), expand_glob(args.right, "--right")
    if len(left_paths) != len(right_paths):
        raise CliError(f"--left matches {len(left_paths)} files but --right matches {len(right_paths)}: "
                       "pairs are formed in sorted order, so the counts must be equal")
    out = Path(args.out)
    existing = [p for p in (out / "intrinsics.yml", out / "extrinsics.yml") if p.exists()]
    if existing and not args.force:
        raise CliError(f"{existing[0]} exists: choose another --out or pass --force to replace it")
    intrinsics = intrinsics_covariance = intrinsics_size = None
    if args.intrinsics:
        try:
            *intrinsics, intrinsics_size = read_intrinsics(args.intrinsics)
            intrinsics_covariance = read_intrinsics_covariance(args.intrinsics)
        except CalibrationFileError as error:
            raise CliError(str(error)) from None
    mode = args.mode or ("fixed" if intrinsics is not None else "joint")
    images = read_grays(left_paths + right_paths)
    left_images, right_images = images[:len(left_paths)], images[len(left_paths):]
    sizes = {im.shape for im in left_images + right_images}
    if len(sizes) != 1:
        # The first image's size, and the first image of each other size (W x H, as measure names them).
        paths = left_paths + right_paths
        first = {}
        for path, image in zip(paths, images, strict=True):
            first.setdefault(image.shape, path)
        other = [f"{first[shape]} is {shape[1]}x{shape[0]}" for shape in first if shape != images[0].shape]
        raise CliError(f"all images must have the same size: {paths[0]} is {images[0].shape[1]}x{images[0].shape[0]}"
                       f", but {'; '.join(other)}")
    height, width = left_images[0].shape
    if intrinsics_size is not None and tuple(intrinsics_size) != (width, height):
        raise CliError(f"--intrinsics {args.intrinsics} is for {intrinsics_size[0]}x{intrinsics_size[1]} images, "
                       f"the --left/--right images are {width}x{height}")
    same = [i for i, (a, b) in enumerate(zip(left_images, right_images, strict=True)) if same_pixels(a, b)]
    if same:
        raise CliError(f"{left_paths[same[0]]} and {right_paths[same[0]]} are the same image"
                       + (f" ({len(same)} of {len(left_paths)} pairs are)" if len(same) > 1 else "")
                       + ": a stereo calibration needs the left and the right camera's views")
    from threadpoolctl import threadpool_limits

    try:
        # One BLAS thread (numpy's OpenBLAS and OpenCV's own): every product and solve of a calibration is small
        # (~200 x 200 at most), the work is spread over the cores by the pipeline's own threads, and a threaded
        # OpenBLAS spins: on the loaded 2-core machine it doubled the CPU of an auto calibration (present_cjn 3.7 ->
        # 1.8 s) and multiplied the held-out estimates' by 5 (docs/CALIBRATION.md, Speed). The numbers move in
        # their last digits only (R, T ~1e-9 relative; a campaign's calibrations keep the default threads).
        with threadpool_limits(1):
            result = calibrate_from_images(left_images, right_images, target, intrinsics=intrinsics, mode=mode,
                                           intrinsics_covariance=intrinsics_covariance, lens_model=args.lens_model,
                                           accept_poor=args.accept_poor,
                                           view_names=[f"{Path(a).name}, {Path(b).name}"
                                                       for a, b in zip(left_paths, right_paths, strict=True)])
    except CalibrationRefused as error:
        raise CliError(f"{error} (--accept-poor keeps it anyway)") from None
    except (ValueError, cv2.error) as error:
        raise CliError(f"calibration failed: {' '.join(str(error).split())}") from None
    calib = result.calib
    make_out_dir(out)
    # What measure reads back: a ChArUco board's colours, marker and dictionary too.
    kind = target.kind + ("-inverted" if getattr(target, "inverted", False) else "")
    charuco = f" marker {target.marker_mm} mm {target.dictionary}" if target.kind == "charuco" else ""
    write_calibration(out, calib, result.rect, board=f"{kind} {args.board} square {target.square_mm} mm{charuco}",
                      extra={"epipolar_rms_px": result.epipolar_rms_px, "views_used": len(result.views_used),
                             "board_scale_u_rel": args.board_scale_u,
                             **(result.gates.file_items() if result.gates else {})})
    uncertainty = calibration_uncertainty(calib)
    report = {
        "rms_px": calib.rms_px, "views_used": len(result.views_used),
        "views_used_files": [[left_paths[i], right_paths[i]] for i in result.views_used],
        "views_rejected": [{"index": r.index, "left": left_paths[r.index], "right": right_paths[r.index],
                            "reason": r.reason} for r in result.views_rejected],
        "per_view_rms_px": calib.per_view_rms_px.tolist(),
        "baseline_mm": calib.baseline_mm, "T_mm": calib.T.tolist(), "R": calib.R.tolist(),
        "epipolar_rms_px": result.epipolar_rms_px, "mode": mode,
        "left": camera_summary(calib.K1, calib.D1), "right": camera_summary(calib.K2, calib.D2),
        "image_size": list(calib.image_size), "out": str(out),
        "uncertainty": uncertainty, "uncertainty_note": calib.covariance_note or None,
        "board_scale_u_rel": args.board_scale_u,
        "adequacy": None if calib.adequacy is None else calib.adequacy.as_dict(),
        "lens_model": _lens_report(calib),
        "gates": None if result.gates is None else result.gates.as_dict(),
    }
    if mrcal is not None:
        report["cross_check"] = _cross_check(mrcal, result, target, out)
    if args.json:
        print_json(report)
    else:
        print(f"calibrated {len(result.views_used)} of {len(left_paths)} pairs ({mode} intrinsics), "
              f"RMS {calib.rms_px:.3f} px, epipolar RMS {result.epipolar_rms_px:.3f} px")
        u = uncertainty or {}
        print(f"baseline |T| = {_pm(calib.baseline_mm, u.get('baseline_mm'), '.3f')} mm, "
              f"T = {np.round(calib.T, 3).tolist()} mm"
              + (f" (+- {np.round(u['T_mm'], 3).tolist()}), rotation +- {u['rotation_deg']:.4f} deg" if u else ""))
        for side in ("left", "right"):
            s, su = report[side], u.get(side, {})
            print(f"{side:5s} " + " ".join(f"{k} {_pm(s[k], su.get(k), '.2f')}" for k in ("fx", "fy", "cx", "cy")))
        if uncertainty:
            print(f"uncertainties are standard (1 sigma), from the fit's residual corner noise "
                  f"{uncertainty['sigma_px']:.3f} px, or the views' jackknife where that is significantly larger")
        else:
            print(f"uncertainty unknown: {calib.covariance_note}")
        if calib.adequacy is not None:
            a = calib.adequacy
            print(f"model adequacy: the board's squares in {a.n_views} held-out views err {a.rms_rel:.2%} RMS "
                  f"(mean {a.bias_rel:+.2%}, {a.lengthening_rel:+.2%} of it the corner noise's lengthening), "
                  f"{a.predicted_rel:.2%} predicted: "
                  + (f"component {a.u_rel:.2%} of a length ({a.dof:.0f} degrees of freedom)" if a.u_rel > 0 else
                     "no excess, component 0"))
        lens = report["lens_model"]
        if lens["comparison"]:
            print(f"lens model {lens['chosen']} ({lens['reason']}); held-out (linearised leave-one-pair-out):")
            print(calib.lens_choice.table())
        elif lens["chosen"]:
            print(f"lens model {lens['chosen']}")
        for r in report["views_rejected"]:
            print(f"rejected pair {r['index']} ({Path(r['left']).name}, {Path(r['right']).name}): {r['reason']}")
        for gate in (result.gates.results if result.gates else ()):
            if gate.verdict == "fail":
                print(f"quality gate {gate.name} FAILED (kept: --accept-poor): {gate.line}", file=sys.stderr)
        print(f"wrote {out / 'intrinsics.yml'} and {out / 'extrinsics.yml'}")
        if mrcal is not None:
            from stereo_bench.vision.mrcal_bridge import cross_check_lines

            print("\n".join(cross_check_lines(report["cross_check"])))
    return 0


def _mrcal_for_cross_check(args: argparse.Namespace) -> str | None:
    """The Python that runs mrcal for ``--cross-check mrcal`` (None without it), found before anything is fitted."""
    if args.cross_check != "mrcal":
        return None
    from stereo_bench.vision.mrcal_bridge import mrcal_python, unavailable_reason

    python = mrcal_python()
    if python is None:
        raise CliError(f"--cross-check mrcal: {unavailable_reason()}")
    return python


def _cross_check(python: str, result, target, out: Path) -> dict:
    """mrcal's fit of the calibration's corners beside ours (docs/FORMATS.md); the files are written already."""
    from stereo_bench.cli import EXIT_FAILED
    from stereo_bench.vision.mrcal_bridge import cross_check

    try:
        return cross_check(result.calib, result.corners, target.object_points, target.square_mm, python=python)
    except ValueError as error:
        raise CliError(f"--cross-check mrcal: {error} (the calibration is written to {out})") from None
    except RuntimeError as error:
        raise CliError(f"--cross-check mrcal: {error} (the calibration is written to {out})", EXIT_FAILED) from None


def cmd_measure(args: argparse.Namespace) -> int:
    from stereo_bench.vision.calibio import (
        CalibrationFileError,
        calibration_board_scale_u,
        read_calibration,
        recorded_epipolar_rms_px,
        recorded_target,
    )
    from stereo_bench.vision.detect import AmbiguousViewError
    from stereo_bench.vision.pipeline import BoardNotFoundError, ImplausibleMeasurement, check_epipolar, measure_pair
    from stereo_bench.vision.uncertainty import DEFAULT_BOARD_SCALE_U_REL, BoardScale, configuration_budget

    if not Path(args.calib).is_dir():
        raise CliError(f"--calib: {args.calib}: calibration directory not found")
    try:
        recorded = recorded_target(args.calib)
    except CalibrationFileError as error:
        raise CliError(str(error)) from None
    board_source = {"board": "--board", "square": "--square"}
    if recorded is not None:
        kind, pattern, square, marker, dictionary = recorded
        if args.board is None:
            args.board, board_source["board"] = pattern, f"{args.calib} (recorded)"
            args.charuco = args.charuco or kind.startswith("charuco")
            args.inverted = args.inverted or kind == "charuco-inverted"
            args.marker = args.marker or marker
            args.dictionary = args.dictionary or dictionary
        # The recorded board given with its sides the other way round is the same board, and its squares the same.
        same = args.board in (pattern, "x".join(reversed(pattern.split("x"))))
        if args.square is None and same:
            args.square, board_source["square"] = square, f"{args.calib} (recorded)"
        elif args.square is None:
            raise CliError(f"--square: {args.calib} records the squares of a {pattern} board ({square:g} mm), not of "
                           f"the --board {args.board} measured here: give --square")
        if args.same_board and not (same and math.isclose(args.square, square, rel_tol=1e-9)):
            raise CliError(f"--same-board: {args.calib} was calibrated with a {pattern} board of {square:g} mm "
                           f"squares, not the {args.board} of {args.square:g} mm measured here: drop --same-board, or "
                           "give the calibration's board")
    if args.board is None:
        raise CliError(f"--board: {args.calib} does not record the calibration board (COLSxROWS): give --board")
    if args.square is None:
        args.square, board_source["square"] = MEASURE_DEFAULT_SQUARE_MM, "default"
    target = target_from_args(args)
    left, right = read_gray(args.left), read_gray(args.right)
    if left.shape != right.shape:
        raise CliError(f"{args.left} is {left.shape[1]}x{left.shape[0]} but {args.right} is "
                       f"{right.shape[1]}x{right.shape[0]}")
    if same_pixels(left, right):
        raise CliError(f"{args.left} and {args.right} are the same image: a stereo measurement needs the left "
                       "and the right camera's views")
    image_size = (left.shape[1], left.shape[0])
    try:
        calib = read_calibration(args.calib, image_size=image_size)
        calib_board_u = args.calib_board_scale_u
        if calib_board_u is None:
            calib_board_u = calibration_board_scale_u(args.calib)
        calibration_epipolar = recorded_epipolar_rms_px(args.calib)
    except CalibrationFileError as error:
        raise CliError(str(error)) from None
    board_scale = BoardScale(target_u_rel=args.board_scale_u, same_board=args.same_board,
                             calibration_board_u_rel=DEFAULT_BOARD_SCALE_U_REL if calib_board_u is None
                             else calib_board_u)
    if tuple(calib.image_size) != image_size:
        raise CliError(f"{args.calib} is for {calib.image_size[0]}x{calib.image_size[1]} images, "
                       f"{args.left} is {image_size[0]}x{image_size[1]}")
    try:
        result = measure_pair(left, right, calib, target, pixel_sigma_px=args.pixel_sigma, thorough=True,
                              partial=args.partial)
        check_epipolar(result.epipolar_rms_px, calibration_epipolar)
    except (BoardNotFoundError, AmbiguousViewError) as error:
        raise CliError(f"{args.left}, {args.right}: {error}") from None
    except ImplausibleMeasurement as error:
        raise CliError(f"{args.left}, {args.right} with {args.calib}: measurement refused: {error}") from None
    budget = configuration_budget([result], calib, target, board_scale=board_scale)
    report = {**result.as_dict(), "left": str(args.left), "right": str(args.right), "calib": str(args.calib),
              "board": {"pattern": args.board, "square_mm": target.square_mm, "board_from": board_source["board"],
                        "square_from": board_source["square"]},
              "uncertainty_mm": budget.as_dict(), "uncertainty": {
                  **budget.details(), "board_scale": {"target_u_rel": board_scale.target_u_rel,
                                                      "calibration_board_u_rel": board_scale.calibration_board_u_rel,
                                                      "same_board": board_scale.same_board}}}
    if args.per_square:
        report["squares"] = [{"ids": [int(a), int(b)], "length_mm": float(length)}
                             for (a, b), length in zip(result.square.pairs, result.square.lengths_mm, strict=True)]
    if args.json:
        print_json(report)
    else:
        sq = result.square
        mm = functools.partial(fixed_or_significant, decimals=4)
        print(f"square: {sq.mean_mm:.4f} mm  (nominal {sq.nominal_mm:g} from {board_source['square']}, error "
              f"{'+' if sq.error_mm >= 0 else ''}{mm(sq.error_mm)} +- {mm(budget.expanded)} mm (k={budget.k:.3g}))")
        components = {**budget.components, **({} if budget.adequacy is None else {"adequacy": budget.adequacy})}

        def part(name: str, value: float | None) -> str:
            if value is None:
                return f"{name} unknown"
            if name == "adequacy" and value == 0 and calib.adequacy is not None:
                # Truncated at zero (docs/UNCERTAINTY.md): the held-out squares show no excess, not a tiny one.
                return f"adequacy 0 (no excess in {calib.adequacy.n_views} held-out views)"
            return f"{name} {mm(value)}"

        parts = ", ".join(part(name, value) for name, value in components.items())
        print(f"        uncertainty: {parts} -> u_c {mm(budget.combined)} mm, dominant: {budget.dominant}"
              + (f"; not included: {', '.join(budget.unknown)}" if budget.unknown else ""))
        print(f"        std {mm(sq.std_mm)} mm over n = {sq.n} adjacent pairs, sigma of mean {mm(sq.sigma_mean_mm)} mm "
              f"from the sensor noise alone")
        print(f"depth:  {sq.depth_mm:.1f} mm (left camera frame); corners in both views: {len(sq.ids)} "
              f"of {target.n_corners}")
        fit = result.planar_fit_rms_px
        px = functools.partial(fixed_or_significant, decimals=3)
        reference = f"{px(budget.corner_reference_px)} px in {budget.corner_reference or 'no residuals'}"
        print(f"epipolar RMS {px(result.epipolar_rms_px)} px; planar-fit RMS {px(fit[0])} / {px(fit[1])} px (left / "
              f"right); corner error counted {px(budget.corner_sigma_px)} px per coordinate: sensor noise "
              f"{px(sq.pixel_sigma_px[0])} / {px(sq.pixel_sigma_px[1])} px, beyond it "
              f"{px(budget.corner_systematic_px)} px (of {reference})")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from drivers.sim.render import Optics, StereoRenderer
    from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
    from stereo_bench.vision.calibio import write_calibration
    from stereo_bench.vision.calibrate import StereoCalibration
    from stereo_bench.vision.rectify import rectify

    target = target_from_args(args)
    out = Path(args.out)
    outputs = [out / name for name in ("left.png", "right.png", "truth.json", "intrinsics.yml", "extrinsics.yml")]
    existing = [p for p in outputs if p.exists()]
    if existing and not args.force:
        raise CliError(f"{existing[0]} exists: choose another --out or pass --force to replace the rendered pair")
    if args.alpha is not None and (args.toe_in is not None):
        raise CliError("give --alpha or --toe-in, not both")
    alpha = args.alpha if args.alpha is not None else 90.0 - (args.toe_in or 0.0)
    camera = CameraModel.from_sensor(focal_mm=args.focal, pixel_um=args.pixel)
    rig = RigPose.symmetric(args.baseline, alpha, args.tilt)
    try:
        optics = Optics(noise_sigma_dn=args.noise, blur_sigma_px=args.blur)
    except ValueError as error:
        raise CliError(str(error)) from None
    make_out_dir(out)  # before the seconds of rendering: a --out that cannot be written fails at once
    renderer = StereoRenderer(target, camera, camera, optics=optics)
    T_rig_board = board_pose_facing_rig(distance_mm=args.distance, board_size_mm=target.grid_size_mm)
    pair = renderer.render_pair(rig, T_rig_board, np.random.default_rng(args.seed))
    for name, view in (("left.png", pair.left), ("right.png", pair.right)):
        # Encoded here, written by Python: cv2.imwrite reports a full disk only as 'libpng error' on stderr.
        encoded, data = cv2.imencode(".png", view.image)
        if not encoded:
            raise CliError(f"{out / name}: cannot encode the image as PNG")
        atomic.write_bytes(out / name, data.tobytes())
    truth_calib = StereoCalibration(
        K1=camera.K, D1=camera.dist.reshape(1, -1), K2=camera.K, D2=camera.dist.reshape(1, -1),
        R=pair.R, T=pair.T, image_size=camera.image_size, rms_px=0.0, mode="truth",
    )
    write_calibration(out, truth_calib, rectify(truth_calib), board=f"{target.kind} {args.board}",
                      extra={"note": "ground truth of the simulated rig, not estimated"})
    truth = {
        "baseline_mm": args.baseline, "distance_mm": args.distance, "alpha_deg": alpha, "tilt_deg": args.tilt,
        "seed": args.seed, "target": {"kind": target.kind, "board": args.board, "square_mm": target.square_mm},
        "camera": {"K": camera.K.tolist(), "dist": camera.dist.tolist(), "image_size": list(camera.image_size)},
        "R": pair.R.tolist(), "T_mm": pair.T.tolist(), "T_rig_left": pair.T_rig_left.tolist(),
        "T_rig_right": pair.T_rig_right.tolist(), "T_rig_board": pair.T_rig_board.tolist(),
        "left": {"corners_px": pair.left.corners_px.tolist(), "visible": pair.left.visible.tolist()},
        "right": {"corners_px": pair.right.corners_px.tolist(), "visible": pair.right.visible.tolist()},
        "fraction_in_both": float((pair.left.visible & pair.right.visible).mean()),
    }
    atomic.write_text(out / "truth.json", json.dumps(truth, indent=1))
    print(f"rendered B = {args.baseline:g} mm, Z = {args.distance:g} mm, alpha = {alpha:g} deg: "
          f"{truth['fraction_in_both']:.0%} of the board's corners in both views")
    print(f"wrote {out / 'left.png'}, {out / 'right.png'}, ground-truth calibration and {out / 'truth.json'}")
    charuco = "" if target.kind == "checkerboard" else (
        f" --charuco --marker {target.marker_mm:g}" + ("" if args.dictionary == "DICT_5X5_1000"
                                                      else f" --dictionary {args.dictionary}"))
    print(f"next: stereo-bench measure --calib {out} --board {args.board} --square {target.square_mm:g}{charuco} "
          f"{out / 'left.png'} {out / 'right.png'}")
    return 0


def register(subparsers) -> None:
    calibrate = subparsers.add_parser(
        "calibrate", help="stereo-calibrate from image pairs of a calibration board",
        description="Pair --left and --right images in sorted order, detect the board, calibrate both cameras "
                    "and the stereo extrinsics, and write intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml "
                    "(R T R1 R2 P1 P2 Q) in OpenCV's stereo_calib layout.",
    )
    add_target_options(calibrate, default_square_mm=None)
    calibrate.add_argument("--left", required=True, metavar="GLOB", help="left images, e.g. 'DIR/left*.jpg' (quote it)")
    calibrate.add_argument("--right", required=True, metavar="GLOB", help="right images, e.g. 'DIR/right*.jpg'")
    calibrate.add_argument("--out", required=True, type=output_dir, metavar="CALIB_DIR",
                           help="directory for the two YAML files")
    calibrate.add_argument("--intrinsics", metavar="CALIB_DIR_OR_FILE",
                           help="start from these intrinsics (intrinsics.yml); implies --mode fixed unless given")
    calibrate.add_argument("--mode", choices=("joint", "fixed"),
                           help="joint: refine intrinsics with R, T (default, measured more accurate); "
                                "fixed: keep the intrinsics")
    calibrate.add_argument(
        "--lens-model", choices=LENS_CHOICES, default="auto", metavar="MODEL",
        help="lens model: auto (default: every model below fitted and compared on held-out pairs, the simplest "
             "one kept unless a richer one is better by more than the comparison's noise) or one of: "
             + "; ".join(f"{m.name} ({m.description})" for m in LENS_MODELS.values())
             + ". With --intrinsics, auto keeps the given model")
    calibrate.add_argument("--force", action="store_true", help="replace calibration files already in --out")
    calibrate.add_argument("--board-scale-u", type=BOARD_SCALE_U, default=1e-4, metavar="REL",
                           help="relative standard uncertainty of the calibration board's square, recorded for "
                                "'measure' (default 1e-4)")
    calibrate.add_argument("--accept-poor", action="store_true",
                           help="write the calibration even when a quality gate refuses it (pairs not taken together, "
                                "inconsistent views, blur, a bent board, left/right swapped: docs/CALIBRATION.md); "
                                "the files record which gates failed. Without it a refusal exits with status 2")
    calibrate.add_argument("--cross-check", choices=("mrcal",), metavar="mrcal",
                           help="fit the same corners again with mrcal (Debian's python3-mrcal, or the Python in "
                                "$STEREO_BENCH_MRCAL_PYTHON) and compare |T| with both uncertainties, both RMS and "
                                "mrcal's projection difference over the image (docs/FORMATS.md)")
    calibrate.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    calibrate.set_defaults(func=cmd_calibrate)

    measure = subparsers.add_parser(
        "measure", help="measure the checkerboard square in one stereo pair",
        description="Triangulate every board corner seen in both images and report the 3-D lengths of all "
                    "horizontally and vertically adjacent corner pairs against the nominal square size.",
    )
    measure.add_argument("--calib", required=True, metavar="CALIB_DIR", help="directory with intrinsics.yml and "
                                                                             "extrinsics.yml")
    add_target_options(measure, default_square_mm=MEASURE_DEFAULT_SQUARE_MM, from_calibration=True)
    measure.add_argument("left", metavar="LEFT", help=IMAGE_HELP)
    measure.add_argument("right", metavar="RIGHT", help=IMAGE_HELP)
    measure.add_argument("--pixel-sigma", type=PIXEL_SIGMA_PX, metavar="PX",
                         help="corner noise per coordinate for the propagated sigma, 0-10 px (default: estimated "
                              "from the images)")
    measure.add_argument("--per-square", action="store_true", help="include every measured length in the JSON")
    measure.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    measure.add_argument("--partial", action="store_true",
                         help="accept a checkerboard cut by the image border (ids proven from the board's edges)")
    measure.add_argument("--board-scale-u", type=BOARD_SCALE_U, default=1e-4, metavar="REL",
                         help="relative standard uncertainty of the measured board's square (certificate or "
                              "stated tolerance; default 1e-4, a rigid printed target; an office print is 1e-3 "
                              "or worse)")
    measure.add_argument("--calib-board-scale-u", type=BOARD_SCALE_U, metavar="REL",
                         help="the same for the board the calibration used (default: as recorded by "
                              "'stereo-bench calibrate', else 1e-4)")
    measure.add_argument("--same-board", action="store_true",
                         help="the calibration used this very board: its scale error cancels")
    measure.set_defaults(func=cmd_measure)

    render = subparsers.add_parser(
        "render", help="render a stereo pair of the board on the simulated rig, with ground truth",
        description="Render both 1920x1080 views of a checkerboard facing the rig at distance Z, with lens "
                    "distortion, blur and sensor noise, and write left.png, right.png, the true calibration "
                    "(intrinsics.yml, extrinsics.yml) and truth.json (corner pixels, poses, R, T).",
    )
    render.add_argument("--baseline", type=BASELINE_MM, required=True, metavar="MM",
                        help="B: optical-centre distance (0-10000)")
    render.add_argument("--distance", type=DISTANCE_MM, required=True, metavar="MM",
                        help="Z: rig origin to board plane (0-100000)")
    render.add_argument("--alpha", type=ALPHA_DEG, metavar="DEG", help="angle between baseline and optical axes, "
                                                                       "0-180 (90 = parallel, default)")
    render.add_argument("--toe-in", type=TOE_IN_DEG, metavar="DEG", help="pan from parallel instead of --alpha, "
                                                                         "-90-90 (toe-in = 90 - alpha)")
    render.add_argument("--tilt", type=TILT_DEG, default=0.0, metavar="DEG", help="heads' tilt, positive down "
                                                                                  "(-90-90)")
    render.add_argument("--out", required=True, type=output_dir, metavar="DIR")
    render.add_argument("--board", default="9x6", type=board_pattern, metavar="COLSxROWS",
                        help="inner corners (default 9x6)")
    render.add_argument("--square", type=SQUARE_MM, default=27.0, metavar="MM", help="square size (default 27)")
    render.add_argument("--charuco", action="store_true", help="render a ChArUco board (--board gives squares)")
    render.add_argument("--marker", type=SQUARE_MM, metavar="MM", help="ChArUco marker size (default 0.75 x square)")
    render.add_argument("--dictionary", default="DICT_5X5_1000", choices=sorted(ARUCO_DICTIONARIES), metavar="DICT")
    render.add_argument("--focal", type=FOCAL_MM, default=4.0, metavar="MM", help="lens focal length (default 4)")
    render.add_argument("--pixel", type=PIXEL_UM, default=3.0, metavar="UM", help="pixel pitch (default 3)")
    render.add_argument("--noise", type=NOISE_DN, default=2.0, metavar="DN", help="sensor noise std, 0-255 "
                                                                                  "(default 2)")
    render.add_argument("--blur", type=BLUR_PX, default=0.7, metavar="PX", help="optical blur sigma, 0-50 "
                                                                                "(default 0.7)")
    render.add_argument("--seed", type=SEED, default=0, help="noise seed, >= 0 (default 0)")
    render.add_argument("--force", action="store_true", help="replace a pair already rendered in --out")
    render.set_defaults(func=cmd_render)
