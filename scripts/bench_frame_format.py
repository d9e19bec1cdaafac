"""Lossless formats for recorded frames: size, encode time and decode time on rendered 1080p frames.

Frames are what a paper-exp1 session records: calibration views of the 11x8 checkerboard (25 mm)
and measurement frames of the 9x6 target (27 mm), rendered by the simulated bench's renderer at
configurations B x Z drawn from the preset's grid (--baselines, --distances), both cameras, grey
(what the simulated cameras deliver). BGR frames (colour USB cameras) are the same renders with a
white-balance tint and independent sensor noise per channel (a colour sensor's channels are not
copies of each other). ChArUco calibration views (exp2's 12x9 board, 15 mm) are included too.

Every codec is something OpenCV reads and writes and other tools open (PNG at several levels,
strategies and filters; lossless WebP; TIFF with LZW/deflate/PackBits, with and without the
horizontal predictor; lossless JPEG 2000 and AVIF; raw PGM/PPM), plus lossless WebP through Pillow
(installed with matplotlib), whose effort setting OpenCV does not expose. Each frame is encoded and
decoded (``cv2.imdecode``, what the session reader uses) --repeats times per codec, codecs
interleaved so load changes on this shared machine hit all of them alike; every round trip is
checked bit for bit. "Pair on 2 cores": both frames of a stereo pair encoded (decoded) at once in
two threads (OpenCV releases the GIL), wall time.

Session-size estimate: a paper-exp1 session holds 25 configurations x (12 calibration + 3
measurement) stereo pairs = 750 frames; it is estimated as 750 x (12/15 x the mean calibration frame
+ 3/15 x the mean measurement frame) over the rendered configurations. The non-frame files
(documents, SQLite, calibration YAML, transcripts) add ~50 kB per configuration (calib_data/
sample_session: 104 kB for 2 configurations), ~1.3 MB for paper-exp1: left out.

    python scripts/bench_frame_format.py [--repeats 3] [--out scripts/results/bench_frame_format.json]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from drivers.sim.render import StereoRenderer, calibration_board_poses
from stereo_bench import frames as frame_codec
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
from stereo_bench.targets import CharucoTarget, Checkerboard

CALIBRATION_BOARD = Checkerboard(11, 8, 25.0)  # paper-exp1's calibration board (the default)
TARGET = Checkerboard(9, 6, 27.0)
CHARUCO = CharucoTarget(12, 9, 15.0, 11.25)  # exp2's calibration board
EXP1_CONFIGURATIONS = 25
EXP1_CALIBRATION_PAIRS, EXP1_MEASUREMENT_PAIRS = 12, 3
CURRENT = "png level 1, RLE, adaptive filters"  # what stereo_bench.atomic.encode_png wrote until now


@dataclass
class Codec:
    name: str
    ext: str  # for cv2.imencode; ".pgm" becomes ".ppm" for BGR
    params: list[int] = field(default_factory=list)
    pillow: dict | None = None  # encode with Pillow instead (format and save options)
    own: bool = False  # encode with stereo_bench.frames.encode_frame (what sessions are written with)

    def encode(self, image: np.ndarray) -> bytes:
        if self.own:
            return frame_codec.encode_frame(image)
        if self.pillow is not None:
            from PIL import Image

            buffer = io.BytesIO()
            Image.fromarray(image if image.ndim == 2 else image[..., ::-1]).save(buffer, **self.pillow)
            return buffer.getvalue()
        ext = ".ppm" if self.ext == ".pgm" and image.ndim == 3 else self.ext
        ok, data = cv2.imencode(ext, image, self.params)
        if not ok:
            raise RuntimeError(f"{self.name}: imencode failed")
        return data.tobytes()


def decode(data: bytes) -> np.ndarray | None:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


def codecs() -> tuple[list[Codec], dict[str, str]]:
    """The codecs this OpenCV build offers, and {name: why not} for those it does not."""
    c = cv2
    png, skipped = [], {}
    png.append(Codec("png level 0 (stored)", ".png", [c.IMWRITE_PNG_COMPRESSION, 0]))
    if frame_codec._libdeflate is not None:
        png.append(Codec("png up filter, libdeflate level 1 (stereo_bench.frames; colour and 16-bit: "
                         "OpenCV, Huffman only, up)", ".png", own=True))
    else:
        skipped["png libdeflate"] = "the deflate package (libdeflate) is not installed"
    png.append(Codec(CURRENT, ".png",
                     [c.IMWRITE_PNG_COMPRESSION, 1, c.IMWRITE_PNG_STRATEGY, c.IMWRITE_PNG_STRATEGY_RLE]))
    for level in (1, 3, 6, 9):
        png.append(Codec(f"png level {level}, default strategy, adaptive filters", ".png",
                         [c.IMWRITE_PNG_COMPRESSION, level]))
    png.append(Codec("png level 1, Huffman only, adaptive filters", ".png",
                     [c.IMWRITE_PNG_COMPRESSION, 1, c.IMWRITE_PNG_STRATEGY, c.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]))
    if hasattr(c, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.11
        filters = {"none": c.IMWRITE_PNG_FILTER_NONE, "sub": c.IMWRITE_PNG_FILTER_SUB, "up": c.IMWRITE_PNG_FILTER_UP,
                   "avg": c.IMWRITE_PNG_FILTER_AVG, "paeth": c.IMWRITE_PNG_FILTER_PAETH,
                   "fast (none/sub/up)": c.IMWRITE_PNG_FAST_FILTERS}
        strategies = (("RLE", c.IMWRITE_PNG_STRATEGY_RLE), ("Huffman only", c.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY),
                      ("default strategy", c.IMWRITE_PNG_STRATEGY_DEFAULT))
        for strategy, value in strategies:
            for filter_name, filter_value in filters.items():
                if strategy == "default strategy" and filter_name not in ("up", "avg"):
                    continue
                png.append(Codec(f"png level 1, {strategy}, {filter_name} filter", ".png",
                                 [c.IMWRITE_PNG_COMPRESSION, 1, c.IMWRITE_PNG_STRATEGY, value,
                                  c.IMWRITE_PNG_FILTER, filter_value]))
    else:
        skipped["png filters"] = f"IMWRITE_PNG_FILTER needs OpenCV >= 4.11 (this is {cv2.__version__})"
    others = [Codec("webp lossless (OpenCV, quality 101)", ".webp", [c.IMWRITE_WEBP_QUALITY, 101])]
    try:
        from PIL import features

        if features.check("webp"):
            for method in (0, 1):
                others.append(Codec(f"webp lossless (Pillow, method {method})", ".webp",
                                    pillow={"format": "WEBP", "lossless": True, "quality": 0, "method": method}))
    except ImportError:
        skipped["webp via Pillow"] = "Pillow is not installed"
    tiff = {"none": c.IMWRITE_TIFF_COMPRESSION_NONE, "PackBits": c.IMWRITE_TIFF_COMPRESSION_PACKBITS,
            "LZW": c.IMWRITE_TIFF_COMPRESSION_LZW, "deflate": c.IMWRITE_TIFF_COMPRESSION_ADOBE_DEFLATE}
    for name, value in tiff.items():
        # OpenCV already writes LZW and deflate with the horizontal predictor (TIFF tag 317 = 2): asking
        # for it with IMWRITE_TIFF_PREDICTOR gives the same bytes.
        others.append(Codec(f"tiff {name}", ".tiff", [c.IMWRITE_TIFF_COMPRESSION, value]))
    for name in ("ZSTD", "LZMA", "WEBP"):  # compiled out of OpenCV's bundled libtiff here: say so
        value = getattr(c, f"IMWRITE_TIFF_COMPRESSION_{name}", None)
        probe = np.zeros((8, 8), np.uint8)
        if value is None or not cv2.imencode(".tiff", probe, [c.IMWRITE_TIFF_COMPRESSION, value])[0]:
            skipped[f"tiff {name}"] = "not supported by this OpenCV build's libtiff"
    others.append(Codec("jpeg 2000 lossless", ".jp2", [c.IMWRITE_JPEG2000_COMPRESSION_X1000, 1000]))
    if hasattr(c, "IMWRITE_AVIF_QUALITY") and cv2.haveImageWriter(".avif"):
        others.append(Codec("avif lossless (quality 100, speed 10)", ".avif",
                            [c.IMWRITE_AVIF_QUALITY, 100, c.IMWRITE_AVIF_SPEED, 10]))
    else:
        skipped["avif"] = "no AVIF writer in this OpenCV build"
    if not cv2.haveImageWriter(".jxl"):
        skipped["jpeg xl"] = "no JPEG XL codec in this OpenCV build"
    others.append(Codec("pgm/ppm (raw)", ".pgm"))
    return png + others, skipped


def render_frames(baselines: list[float], distances: list[float], seed: int) -> list[tuple[str, np.ndarray]]:
    """(kind, image) with kind 'calibration', 'measurement' or 'charuco'; one stereo pair of each per B x Z."""
    camera = CameraModel.from_sensor()
    calibration = StereoRenderer(CALIBRATION_BOARD, camera, camera)
    target = StereoRenderer(TARGET, camera, camera)
    charuco = StereoRenderer(CHARUCO, camera, camera)
    rng = np.random.default_rng(seed)
    frames = []
    for baseline in baselines:
        for distance in distances:
            rig = RigPose.symmetric(baseline, 90.0)
            # The simulated presenter's calibration range for this Z.
            near, far = max(250.0, 0.6 * distance), 1.3 * distance
            pose = calibration_board_poses(rig, CALIBRATION_BOARD, n_views=1, rng=rng, distance_mm=(near, far))[0]
            pair = calibration.render_pair(rig, pose, rng)
            frames += [("calibration", pair.left.image), ("calibration", pair.right.image)]
            pose = board_pose_facing_rig(distance_mm=distance, board_size_mm=TARGET.grid_size_mm)
            pair = target.render_pair(rig, pose, rng)
            frames += [("measurement", pair.left.image), ("measurement", pair.right.image)]
    rig = RigPose.symmetric(100.0, 75.0)
    for pose in calibration_board_poses(rig, CHARUCO, n_views=2, rng=rng, min_fraction_visible=0.5,
                                        distance_mm=(300.0, 650.0)):
        pair = charuco.render_pair(rig, pose, rng)
        frames += [("charuco", pair.left.image), ("charuco", pair.right.image)]
    return frames


def to_bgr(grey: np.ndarray, rng: np.random.Generator, noise_dn: float = 2.0) -> np.ndarray:
    """A colour sensor's view of the same scene: white-balance tint, independent noise per channel."""
    tint = np.array([0.85, 1.0, 0.92])
    noisy = grey.astype(np.float32)[..., None] * tint + rng.normal(0.0, noise_dn, grey.shape + (3,))
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def lossless(image: np.ndarray, decoded: np.ndarray | None) -> str:
    """'yes' (bit-identical), 'as 3 channels' (a grey frame comes back as equal B, G, R planes) or 'no'."""
    if decoded is None or decoded.dtype != image.dtype:
        return "no"
    if decoded.shape == image.shape:
        return "yes" if np.array_equal(decoded, image) else "no"
    if image.ndim == 2 and decoded.shape == image.shape + (3,) and all(
            np.array_equal(decoded[..., i], image) for i in range(3)):
        return "as 3 channels"
    return "no"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baselines", type=float, nargs="+", default=[50.0, 250.0], metavar="MM")
    parser.add_argument("--distances", type=float, nargs="+", default=[300.0, 500.0, 700.0], metavar="MM")
    parser.add_argument("--bgr-frames", type=int, default=4, help="BGR frames (from the first grey frames)")
    parser.add_argument("--repeats", type=int, default=3, help="timed encodes and decodes per frame and codec")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="scripts/results/bench_frame_format.json")
    args = parser.parse_args()

    load_before = [round(v, 2) for v in os.getloadavg()]
    all_codecs, skipped = codecs()
    frames = render_frames(args.baselines, args.distances, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    grey = [(kind, image) for kind, image in frames]
    bgr = [("bgr", to_bgr(image, rng)) for _, image in frames[: args.bgr_frames]]
    print(f"{len(grey)} grey and {len(bgr)} BGR 1080p frames, {len(all_codecs)} codecs, {args.repeats} repeats; "
          f"load average {load_before}")

    stats = {codec.name: {"bytes": {}, "encode_s": {}, "decode_s": {}, "lossless": set(), "errors": []}
             for codec in all_codecs}
    for index, (kind, image) in enumerate(grey + bgr):
        for codec in all_codecs:  # interleaved: every codec sees the same load
            row = stats[codec.name]
            try:
                encode_s, decode_s = [], []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    data = codec.encode(image)
                    encode_s.append(time.perf_counter() - start)
                    start = time.perf_counter()
                    decoded = decode(data)
                    decode_s.append(time.perf_counter() - start)
            except Exception as error:  # a codec this build cannot write: recorded, not fatal
                row["errors"].append(f"{kind} frame {index}: {error}")
                continue
            row["lossless"].add(lossless(image, decoded))
            row["bytes"].setdefault(kind, []).append(len(data))
            row["encode_s"].setdefault(kind, []).append(float(np.median(encode_s)))
            row["decode_s"].setdefault(kind, []).append(float(np.median(decode_s)))

    # A stereo pair on 2 cores: both frames at once in two threads (OpenCV releases the GIL).
    pairs = [(grey[i][1], grey[i + 1][1]) for i in range(0, len(grey), 2)]
    with ThreadPoolExecutor(2) as pool:
        for codec in all_codecs:
            row = stats[codec.name]
            if row["errors"]:
                continue
            encode_pair, decode_pair = [], []
            for left, right in pairs:
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    encoded = list(pool.map(codec.encode, (left, right)))
                    encode_pair.append(time.perf_counter() - start)
                    start = time.perf_counter()
                    list(pool.map(decode, encoded))
                    decode_pair.append(time.perf_counter() - start)
            row["pair_2cores_ms"] = {"encode": float(np.median(encode_pair) * 1000),
                                     "decode": float(np.median(decode_pair) * 1000)}
    load_after = [round(v, 2) for v in os.getloadavg()]

    results, table = {}, []
    for codec in all_codecs:
        row = stats[codec.name]
        if row["errors"] and not row["bytes"]:
            results[codec.name] = {"error": row["errors"][0]}
            continue
        grey_kinds = [kind for kind in ("calibration", "measurement", "charuco") if kind in row["bytes"]]
        grey_bytes = [b for kind in grey_kinds for b in row["bytes"][kind]]
        grey_encode = [t for kind in grey_kinds for t in row["encode_s"][kind]]
        grey_decode = [t for kind in grey_kinds for t in row["decode_s"][kind]]
        mean_mb = {kind: float(np.mean(values) / 1e6) for kind, values in row["bytes"].items()}
        exp1_frame_mb = (EXP1_CALIBRATION_PAIRS * mean_mb["calibration"]
                         + EXP1_MEASUREMENT_PAIRS * mean_mb["measurement"]) / (EXP1_CALIBRATION_PAIRS
                                                                             + EXP1_MEASUREMENT_PAIRS)
        exp1_frames = 2 * EXP1_CONFIGURATIONS * (EXP1_CALIBRATION_PAIRS + EXP1_MEASUREMENT_PAIRS)
        result = {
            "extension": codec.ext, "opencv_params": codec.params, "pillow": codec.pillow,
            "chosen": codec.own or (frame_codec._libdeflate is None and codec.ext == frame_codec.FRAME_EXTENSION
                                    and codec.params == frame_codec.PNG_PARAMS),
            "lossless": ("no" if "no" in row["lossless"] or row["errors"] else
                         "yes" if row["lossless"] == {"yes"} else "yes, grey frames decode as 3 channels"),
            "errors": row["errors"],
            "mean_mb": mean_mb,
            "grey_frame": {"mean_mb": float(np.mean(grey_bytes) / 1e6),
                           "encode_ms_median": float(np.median(grey_encode) * 1000),
                           "decode_ms_median": float(np.median(grey_decode) * 1000)},
            "bgr_frame": ({"mean_mb": mean_mb["bgr"],
                           "encode_ms_median": float(np.median(row["encode_s"]["bgr"]) * 1000),
                           "decode_ms_median": float(np.median(row["decode_s"]["bgr"]) * 1000)}
                          if "bgr" in row["bytes"] else None),
            "pair_2cores_ms": row.get("pair_2cores_ms"),
            "paper_exp1_session_mb": exp1_frame_mb * exp1_frames,
        }
        results[codec.name] = result
        table.append((codec.name, result))

    current = results[CURRENT]
    chosen = next((r for r in results.values() if r.get("chosen")), None)
    print(f"\n{'codec':48s} {'grey MB':>7s} {'vs now':>6s} {'enc ms':>7s} {'dec ms':>7s} {'pair enc':>8s} "
          f"{'pair dec':>8s} {'BGR MB':>7s} {'BGR enc':>7s} {'BGR dec':>7s} {'exp1 MB':>7s} lossless")
    for name, r in sorted(table, key=lambda item: item[1]["grey_frame"]["mean_mb"]):
        g, b, p = r["grey_frame"], r["bgr_frame"] or {}, r["pair_2cores_ms"] or {}
        ratio = g["mean_mb"] / current["grey_frame"]["mean_mb"]
        name = ("* " if r["chosen"] else "") + name
        print(f"{name[:48]:48s} {g['mean_mb']:7.3f} {ratio:6.2f} {g['encode_ms_median']:7.1f} "
              f"{g['decode_ms_median']:7.1f} {p.get('encode', float('nan')):8.1f} {p.get('decode', float('nan')):8.1f} "
              f"{b.get('mean_mb', float('nan')):7.3f} {b.get('encode_ms_median', float('nan')):7.1f} "
              f"{b.get('decode_ms_median', float('nan')):7.1f} {r['paper_exp1_session_mb']:7.0f} {r['lossless']}")
    for name, why in skipped.items():
        print(f"{name[:48]:48s} not measured: {why}")
    print("(grey MB: mean per 1080p grey frame; enc/dec: median ms per frame, one thread; pair: both frames of a "
          "stereo pair at once on 2 cores, wall ms; exp1 MB: estimated paper-exp1 session frames)")
    print("(* = what stereo_bench.frames writes)")
    if chosen is not None:
        before, after = current["grey_frame"], chosen["grey_frame"]
        print(f"stereo_bench.frames against {CURRENT!r}: grey frame {before['mean_mb']:.3f} -> "
              f"{after['mean_mb']:.3f} MB, "
              f"encode {before['encode_ms_median']:.1f} -> {after['encode_ms_median']:.1f} ms, decode "
              f"{before['decode_ms_median']:.1f} -> {after['decode_ms_median']:.1f} ms; paper-exp1 frames "
              f"{current['paper_exp1_session_mb']:.0f} -> {chosen['paper_exp1_session_mb']:.0f} MB (estimated)")
    print(f"load average before {load_before}, after {load_after}")

    output = {
        "machine": {"cpus": os.cpu_count(), "opencv": cv2.__version__, "python": platform.python_version()},
        "load_average_before_after": [load_before, load_after],
        "frames": {"grey": len(grey), "bgr": len(bgr), "baselines_mm": args.baselines,
                   "distances_mm": args.distances, "repeats": args.repeats},
        "paper_exp1": {"configurations": EXP1_CONFIGURATIONS, "calibration_pairs": EXP1_CALIBRATION_PAIRS,
                       "measurement_pairs": EXP1_MEASUREMENT_PAIRS},
        "current": CURRENT, "codecs": results, "not_measured": skipped,
    }
    with open(args.out, "w") as handle:
        json.dump(output, handle, indent=1)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
