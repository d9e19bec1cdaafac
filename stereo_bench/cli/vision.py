"""``stereo-bench calibrate | measure | render``: the measurement core on image files."""

from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from stereo_bench.cli import CliError
from stereo_bench.targets import ARUCO_DICTIONARIES, CharucoTarget, Checkerboard, Target, parse_pattern

IMAGE_HELP = "image file (PNG, JPEG, ...); colour images are converted to grey"


def add_target_options(parser: argparse.ArgumentParser, *, default_square_mm: float | None) -> None:
    parser.add_argument("--board", required=True, metavar="COLSxROWS",
                        help="checkerboard inner corners per row x per column, e.g. 9x6 "
                             "(with --charuco: squares per row x per column)")
    parser.add_argument("--square", type=float, required=default_square_mm is None, default=default_square_mm,
                        metavar="MM", help="square size in mm" + (f" (default {default_square_mm})"
                                                                     if default_square_mm else ""))
    parser.add_argument("--charuco", action="store_true", help="the board is a ChArUco board (partial views count)")
    parser.add_argument("--marker", type=float, metavar="MM", help="ChArUco marker size in mm (default 0.75 x square)")
    parser.add_argument("--dictionary", default="DICT_5X5_1000", choices=sorted(ARUCO_DICTIONARIES),
                        metavar="DICT", help="ChArUco ArUco dictionary (default DICT_5X5_1000)")


def target_from_args(args: argparse.Namespace) -> Target:
    try:
        cols, rows = parse_pattern(args.board)
        if args.charuco:
            marker = args.marker if args.marker else 0.75 * args.square
            return CharucoTarget(cols, rows, args.square, marker, args.dictionary)
        return Checkerboard(cols, rows, args.square)
    except ValueError as error:
        raise CliError(f"--board/--square: {error}") from None


def read_gray(path: str | Path) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise CliError(f"{path}: image not found")
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise CliError(f"{path}: cannot read image (not an image file, or corrupt)")
    return image


def expand_glob(pattern: str, option: str) -> list[str]:
    paths = sorted(glob.glob(pattern))
    if not paths:
        raise CliError(f"{option} {pattern!r} matches no file")
    return paths


def camera_summary(K: np.ndarray, D: np.ndarray) -> dict:
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "dist": [float(x) for x in np.ravel(D)]}


def cmd_calibrate(args: argparse.Namespace) -> int:
    from stereo_bench.vision.calibio import CalibrationFileError, read_intrinsics, write_calibration
    from stereo_bench.vision.pipeline import calibrate_from_images

    target = target_from_args(args)
    left_paths, right_paths = expand_glob(args.left, "--left"), expand_glob(args.right, "--right")
    if len(left_paths) != len(right_paths):
        raise CliError(f"--left matches {len(left_paths)} files but --right matches {len(right_paths)}: "
                       "pairs are formed in sorted order, so the counts must be equal")
    out = Path(args.out)
    existing = [p for p in (out / "intrinsics.yml", out / "extrinsics.yml") if p.exists()]
    if existing and not args.force:
        raise CliError(f"{existing[0]} exists: choose another --out or pass --force to replace it")
    intrinsics = None
    if args.intrinsics:
        try:
            intrinsics = read_intrinsics(args.intrinsics)[:4]
        except CalibrationFileError as error:
            raise CliError(str(error)) from None
    mode = args.mode or ("fixed" if intrinsics is not None else "joint")
    left_images = [read_gray(p) for p in left_paths]
    right_images = [read_gray(p) for p in right_paths]
    sizes = {im.shape for im in left_images + right_images}
    if len(sizes) != 1:
        raise CliError(f"all images must have the same size, found {sorted(sizes)}")
    try:
        result = calibrate_from_images(left_images, right_images, target, intrinsics=intrinsics, mode=mode)
    except (ValueError, cv2.error) as error:
        raise CliError(f"calibration failed: {error}") from None
    calib = result.calib
    write_calibration(out, calib, result.rect, board=f"{target.kind} {args.board} square {target.square_mm} mm",
                      extra={"epipolar_rms_px": result.epipolar_rms_px, "views_used": len(result.views_used)})
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
    }
    if args.json:
        json.dump(report, sys.stdout)
        print()
    else:
        print(f"calibrated {len(result.views_used)} of {len(left_paths)} pairs ({mode} intrinsics), "
              f"RMS {calib.rms_px:.3f} px, epipolar RMS {result.epipolar_rms_px:.3f} px")
        print(f"baseline |T| = {calib.baseline_mm:.3f} mm, T = {np.round(calib.T, 3).tolist()} mm")
        for side in ("left", "right"):
            s = report[side]
            print(f"{side:5s} fx {s['fx']:.2f} fy {s['fy']:.2f} cx {s['cx']:.2f} cy {s['cy']:.2f}")
        for r in report["views_rejected"]:
            print(f"rejected pair {r['index']} ({Path(r['left']).name}, {Path(r['right']).name}): {r['reason']}")
        print(f"wrote {out / 'intrinsics.yml'} and {out / 'extrinsics.yml'}")
    return 0


def cmd_measure(args: argparse.Namespace) -> int:
    from stereo_bench.vision.calibio import CalibrationFileError, read_calibration
    from stereo_bench.vision.pipeline import BoardNotFoundError, measure_pair

    target = target_from_args(args)
    left, right = read_gray(args.left), read_gray(args.right)
    if left.shape != right.shape:
        raise CliError(f"{args.left} is {left.shape[1]}x{left.shape[0]} but {args.right} is "
                       f"{right.shape[1]}x{right.shape[0]}")
    image_size = (left.shape[1], left.shape[0])
    try:
        calib = read_calibration(args.calib, image_size=image_size)
    except CalibrationFileError as error:
        raise CliError(str(error)) from None
    if tuple(calib.image_size) != image_size:
        raise CliError(f"{args.calib} is for {calib.image_size[0]}x{calib.image_size[1]} images, "
                       f"{args.left} is {image_size[0]}x{image_size[1]}")
    try:
        result = measure_pair(left, right, calib, target, pixel_sigma_px=args.pixel_sigma, thorough=True)
    except BoardNotFoundError as error:
        raise CliError(f"{args.left}, {args.right}: {error}") from None
    report = {**result.as_dict(), "left": str(args.left), "right": str(args.right), "calib": str(args.calib)}
    if args.per_square:
        report["squares"] = [{"ids": [int(a), int(b)], "length_mm": float(length)}
                             for (a, b), length in zip(result.square.pairs, result.square.lengths_mm, strict=True)]
    if args.json:
        json.dump(report, sys.stdout)
        print()
    else:
        sq = result.square
        print(f"square: {sq.mean_mm:.4f} mm  (nominal {sq.nominal_mm:g}, error {sq.error_mm:+.4f} mm)")
        print(f"        std {sq.std_mm:.4f} mm over n = {sq.n} adjacent pairs, sigma of mean {sq.sigma_mean_mm:.4f} mm")
        print(f"depth:  {sq.depth_mm:.1f} mm (left camera frame); corners in both views: {len(sq.ids)} "
              f"of {target.n_corners}")
        print(f"epipolar RMS {result.epipolar_rms_px:.3f} px; corner noise {sq.pixel_sigma_px[0]:.3f} / "
              f"{sq.pixel_sigma_px[1]:.3f} px (left / right)")
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
    calibrate.add_argument("--out", required=True, metavar="CALIB_DIR", help="directory for the two YAML files")
    calibrate.add_argument("--intrinsics", metavar="CALIB_DIR_OR_FILE",
                           help="start from these intrinsics (intrinsics.yml); implies --mode fixed unless given")
    calibrate.add_argument("--mode", choices=("joint", "fixed"),
                           help="joint: refine intrinsics with R, T (default, measured more accurate); "
                                "fixed: keep the intrinsics")
    calibrate.add_argument("--force", action="store_true", help="replace calibration files already in --out")
    calibrate.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    calibrate.set_defaults(func=cmd_calibrate)

    measure = subparsers.add_parser(
        "measure", help="measure the checkerboard square in one stereo pair",
        description="Triangulate every board corner seen in both images and report the 3-D lengths of all "
                    "horizontally and vertically adjacent corner pairs against the nominal square size.",
    )
    measure.add_argument("--calib", required=True, metavar="CALIB_DIR", help="directory with intrinsics.yml and "
                                                                             "extrinsics.yml")
    add_target_options(measure, default_square_mm=27.0)
    measure.add_argument("left", metavar="LEFT", help=IMAGE_HELP)
    measure.add_argument("right", metavar="RIGHT", help=IMAGE_HELP)
    measure.add_argument("--pixel-sigma", type=float, metavar="PX",
                         help="corner noise per coordinate for the propagated sigma (default: estimated from "
                              "the images)")
    measure.add_argument("--per-square", action="store_true", help="include every measured length in the JSON")
    measure.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    measure.set_defaults(func=cmd_measure)
