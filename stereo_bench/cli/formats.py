"""``stereo-bench export | import``: a calibration directory to and from ROS, Kalibr and mrcal files.

The codecs are :mod:`stereo_bench.vision.formats`; this module reads and writes the files and says, one line per
item, what a format could not hold (docs/FORMATS.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from stereo_bench import atomic
from stereo_bench.cli import CliError, print_json
from stereo_bench.cli.args import SQUARE_MM, board_pattern, image_size, output_dir

UNITS = {"m": 1000.0, "mm": 1.0}
#: The largest file an import reads: an mrcal model with its optimization_inputs is a few MB.
MAX_IMPORT_FILE_BYTES = 64 << 20
#: Exit status of an export refused because the format cannot represent the lens model (without --lossy).
EXIT_UNREPRESENTABLE = 2


def cmd_export(args: argparse.Namespace) -> int:
    from stereo_bench.vision.calibio import read_calibration, read_rectification, recorded_keys
    from stereo_bench.vision.formats import UnrepresentableLens, dropped_on_export, export_texts

    calib = read_calibration(args.calib_dir, image_size=args.image_size)
    rect = read_rectification(args.calib_dir, calib.image_size) if args.to == "ros" else None
    try:
        exported = export_texts(calib, args.to, rect=rect, unit_mm=UNITS[args.units], lossy=args.lossy,
                                source=str(args.calib_dir))
    except UnrepresentableLens as error:
        raise CliError(f"{args.calib_dir}: {error}", EXIT_UNREPRESENTABLE) from None
    out = Path(args.out)
    existing = [out / name for name in exported.files if (out / name).exists()]
    if existing and not args.force:
        raise CliError(f"{existing[0]} exists: choose another --out or pass --force to replace it")
    from stereo_bench.cli.vision import make_out_dir

    make_out_dir(out)
    for name, text in exported.files.items():
        atomic.write_text(out / name, text)
    dropped = exported.dropped + dropped_on_export(recorded_keys(args.calib_dir), args.to)
    written = [str(out / name) for name in exported.files]
    if args.json:
        print_json({"format": args.to, "units": args.units, "files": written, "dropped": dropped})
    else:
        for line in dropped:
            print(line)
        print(f"wrote {', '.join(written)} (lengths in {args.units})")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from drivers.files import read_regular_file
    from stereo_bench.vision.calibio import read_calibration, write_calibration
    from stereo_bench.vision.formats import import_texts
    from stereo_bench.vision.rectify import rectify

    if (args.board is None) != (args.square is None):
        raise CliError("--board and --square go together: the calibration board is recorded with both")
    texts = []
    for path in args.files:
        data = read_regular_file(path, what="calibration file", max_bytes=MAX_IMPORT_FILE_BYTES)
        try:
            texts.append((str(path), data.decode("utf-8")))
        except UnicodeDecodeError as error:
            raise CliError(f"{path}: not UTF-8 text (at byte {error.start})") from None
    imported = import_texts(args.source, texts, unit_mm=UNITS[args.units])
    out = Path(args.out)
    existing = [p for p in (out / "intrinsics.yml", out / "extrinsics.yml") if p.exists()]
    if existing and not args.force:
        raise CliError(f"{existing[0]} exists: choose another --out or pass --force to replace it")
    from stereo_bench.cli.vision import make_out_dir

    make_out_dir(out)
    calib = imported.calib
    board = "" if args.board is None else f"checkerboard {args.board} square {args.square} mm"
    write_calibration(out, calib, imported.rect or rectify(calib), board=board,
                      extra={"imported_from": f"{args.source}: {' '.join(str(p) for p in args.files)}",
                             "imported_units": args.units})
    read_calibration(out)  # what every consumer of a calib_dir reads: refuses here, not at the first measurement
    dropped = [line for line in imported.dropped if not board or "calibration board" not in line]
    report = {"format": args.source, "units": args.units, "out": str(out), "lens_model": calib.lens_model or None,
              "baseline_mm": calib.baseline_mm, "image_size": list(calib.image_size), "dropped": dropped}
    if args.json:
        print_json(report)
    else:
        for line in dropped:
            print(line)
        print(f"imported {args.source} ({calib.image_size[0]}x{calib.image_size[1]}, lens model "
              f"{calib.lens_model or 'unnamed'}, |T| = {calib.baseline_mm:.3f} mm): wrote {out / 'intrinsics.yml'} "
              f"and {out / 'extrinsics.yml'}")
    return 0


#: stereo_bench.vision.formats.FORMATS, spelled here so that --help imports no codec (OpenCV, pydantic).
FORMATS = ("ros", "kalibr", "mrcal")


def register(subparsers) -> None:
    export = subparsers.add_parser(
        "export", help="write a calibration directory as ROS camera_info, Kalibr camchain or mrcal .cameramodel",
        description="Write CALIB_DIR (intrinsics.yml, extrinsics.yml) in another tool's format: ros (left.yaml, "
                    "right.yaml: camera_info with the rectification R1/P1, R2/P2), kalibr (camchain.yaml: cam0 = "
                    "left, cam1 = right, T_cn_cnm1 = [R T]), mrcal (left.cameramodel, right.cameramodel: the left "
                    "camera is the reference, extrinsics rt_cam_ref). Prints one 'dropped:' line per thing the "
                    "format cannot hold (covariance, gates, lens-model comparison, ...). A lens model the format "
                    "cannot represent (thin-prism or k3 in Kalibr's radtan, thin-prism in ROS) is refused with exit "
                    "status 2 unless --lossy. docs/FORMATS.md.",
        epilog="Exit status: 0 written; 2 a file or argument error, or a lens model the format cannot represent "
               "(without --lossy).")
    export.add_argument("calib_dir", metavar="CALIB_DIR", help="directory with intrinsics.yml and extrinsics.yml")
    export.add_argument("--to", required=True, choices=FORMATS, help="the format to write")
    export.add_argument("--out", required=True, type=output_dir, metavar="DIR", help="directory for the files")
    export.add_argument("--units", choices=tuple(UNITS), default="m",
                        help="length unit of the written files (default m: ROS and Kalibr state metres)")
    export.add_argument("--lossy", action="store_true",
                        help="drop lens terms the format cannot hold instead of refusing; prints how far the "
                             "projection moves (px)")
    export.add_argument("--image-size", type=image_size, metavar="WxH",
                        help="image size, for files that do not record it (OpenCV's sample)")
    export.add_argument("--force", action="store_true", help="replace files already in --out")
    export.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    export.set_defaults(func=cmd_export)

    imp = subparsers.add_parser(
        "import", help="make a calibration directory from ROS camera_info, Kalibr camchain or mrcal files",
        description="Read another tool's stereo calibration and write --out as a calibration directory "
                    "(intrinsics.yml, extrinsics.yml) that measure, calibrate --intrinsics and campaigns read: "
                    "ros: two camera_info YAML files, left then right; kalibr: one camchain YAML (cam0 = left, "
                    "cam1 = right); mrcal: two .cameramodel files, left then right. docs/FORMATS.md.",
        epilog="Exit status: 0 written; 2 a file that cannot be read (the line names the file and the field) or a "
               "calibration that is not usable.")
    imp.add_argument("files", nargs="+", metavar="FILE", help="the files, left camera first")
    imp.add_argument("--from", dest="source", required=True, choices=FORMATS, help="the files' format")
    imp.add_argument("--out", required=True, type=output_dir, metavar="CALIB_DIR", help="directory to write")
    imp.add_argument("--units", choices=tuple(UNITS), default="m",
                     help="length unit of the files (default m: ROS and Kalibr state metres)")
    imp.add_argument("--board", type=board_pattern, metavar="COLSxROWS",
                     help="record the calibration board (checkerboard inner corners), which measure then defaults to")
    imp.add_argument("--square", type=SQUARE_MM, metavar="MM", help="its square size, with --board")
    imp.add_argument("--force", action="store_true", help="replace calibration files already in --out")
    imp.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    imp.set_defaults(func=cmd_import)
