"""Recorded frames: the lossless format a session writes them in, and the reader for every format it may hold.

Format, chosen by measurement (scripts/bench_frame_format.py and the same frames of the lab bench, 1080p,
one thread, 2 cores, load ~1-3 from other jobs): PNG, every row with the "up" filter, one IDAT chunk deflated
by libdeflate at level 1 (grey 8-bit frames, what the cameras deliver; written here). Against OpenCV's fastest
setting (zlib level 1, Huffman coding only, "up"; what sessions were written with until 2026-12-03):

- a lab-bench frame (MJPG, as USB cameras deliver): 11 ms of CPU instead of 34, 0.38 MB instead of 0.53;
- an ideal-bench frame (white sensor noise, no MJPG): 19 ms instead of 34, but 1.09 MB instead of 0.97.
- real 640x480 frames (calib_data/real, 6 per set): present_cjn 3.3 ms instead of 6.4, 0.115 MB instead of
  0.110; smiler488_box 1.7 instead of 4.6 ms, 0.043 instead of 0.066 MB; opencv_sample 2.9 instead of 5.9 ms,
  0.150 instead of 0.170 MB.

The encoder had been a sixth of a simulated campaign's CPU (~70 ms a stereo pair). Colour and 16-bit
frames, and every frame when the ``deflate`` package is missing, are written by OpenCV with the earlier
setting. Either is a plain PNG that any reader opens.

Why not smaller: a camera frame is mostly sensor noise, which no lossless coder can compress (2 DN
of white noise alone carries ~3 bits per pixel, 0.79 MB per 1080p frame). The best lossless coders
OpenCV offers save 4-7 % (AVIF 0.87 MB, WebP 0.88 MB, JPEG 2000 0.89 MB) at 4-40x the encode time
(100-620 ms per frame) and, for AVIF and JPEG 2000, 7-9x the decode time; uncompressed PGM/TIFF
decode in ~2 ms but double the session. The "up" filter costs 4 % of size against "avg" (0.94 MB)
but unfilters with vector instructions where "avg" and "paeth" run byte by byte on grey frames, and
replay decodes every frame: at 60 pairs/s on 2 cores a pair may cost ~30 ms of CPU in all, of which
decoding takes ~12.5 (with "avg", ~8 more).

Every frame a session ever wrote is a PNG, whatever its settings (the reader needs none of them),
so old sessions read and replay exactly. :func:`decode_frame` recognises the format by its magic
bytes, not the file name: a format added later goes beside PNG there.

Decoding: a grey frame written with this setting (8-bit, every row "up") is inflated by libdeflate
and unfiltered here, with the same checks as libpng: every chunk's CRC, the data's Adler-32 and its
length. Per 1080p frame (thread CPU, load 5-10 from other jobs): ~6.3 ms in a replay
(scripts/bench_campaign.py --replay) against OpenCV's 8.8. The inflate is 4.3-4.7 of it (zlib's:
8.6), the floor of this format; the rest is the chunk CRCs (0.07, libdeflate's), gathering the IDAT
chunks (0.06, into a reused buffer) and the blocked un-filter (0.55), of which the page faults of the
image's fresh 2 MB are 0.3-0.9 depending on how the allocator reuses freed memory. Any other PNG
(colour, 16-bit, other filters, extra chunks: older sessions) is decoded by OpenCV, as is everything
when the ``deflate`` package (the libdeflate binding) is missing. The pixels are the same either way
(tests/test_frames.py, tests/test_frame_reading.py).
"""

from __future__ import annotations

import ctypes
import os
import platform
import struct
import threading

import cv2
import numpy as np

try:  # libdeflate inflates a frame ~1.7x faster than zlib; optional, OpenCV decodes without it
    import deflate as _libdeflate
except ImportError:  # pragma: no cover - the dependency is declared; a trimmed install still reads frames
    _libdeflate = None

FRAME_EXTENSION = ".png"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"  # the IEND chunk with its CRC: the last 12 bytes of a complete PNG


def _png_params() -> list[int]:
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.11; older ones choose filters per row (31 ms, 0.93 MB)
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]
    return params


PNG_PARAMS = _png_params()


class FrameError(ValueError):
    """A frame cannot be encoded losslessly, or recorded bytes are not a complete frame."""


def encode_frame(image: np.ndarray) -> bytes:
    """Lossless bytes (:data:`FRAME_EXTENSION`) of a grey (H, W) or colour (H, W, 3|4, BGR[A]) uint8/uint16 image.

    Raises:
        FrameError: the image cannot be stored losslessly (dtype, shape) or the encoder failed.
    """
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise FrameError(f"frames must be uint8 or uint16, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3, 4))):
        raise FrameError(f"frames must be (H, W) or (H, W, 1|3|4), got shape {image.shape}")
    if image.size == 0:
        raise FrameError("cannot write an empty frame")
    if image.dtype == np.uint8 and (image.ndim == 2 or image.shape[2] == 1) and _libdeflate is not None:
        return _encode_grey_up_png(image.reshape(image.shape[:2]))
    ok, buffer = cv2.imencode(FRAME_EXTENSION, np.ascontiguousarray(image), PNG_PARAMS)
    if not ok:
        raise FrameError(f"cv2.imencode failed for a frame of shape {image.shape} {image.dtype}")
    return buffer.tobytes()


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    crc = _libdeflate.crc32(body, _libdeflate.crc32(kind))  # zlib's CRC-32, continued from the chunk type
    return b"".join((struct.pack(">I", len(body)), kind, body, struct.pack(">I", crc)))


def _encode_grey_up_png(image: np.ndarray) -> bytes:
    """A PNG of the (H, W) uint8 ``image``: IHDR (8-bit grey), one IDAT (every row "up", libdeflate level 1), IEND.

    The rows' differences are taken into this thread's scratch buffer (reused: a fresh 2 MB costs page faults).
    """
    height, width = image.shape
    size = height * (width + 1)
    buffer = getattr(_scratch, "encode", None)
    if buffer is None or buffer.size < size:
        buffer = _scratch.encode = np.empty(size, np.uint8)
    rows = buffer[:size].reshape(height, width + 1)
    rows[:, 0] = _FILTER_UP
    rows[0, 1:] = image[0]  # "up" from the zero row above the first
    np.subtract(image[1:], image[:-1], out=rows[1:, 1:])  # mod 256, as the filter is defined
    try:
        data = _libdeflate.zlib_compress(memoryview(rows).cast("B"), 1)
    except _libdeflate.DeflateError as error:  # pragma: no cover - libdeflate fails only when out of memory
        raise FrameError(f"libdeflate could not compress a frame of shape {image.shape}: {error}") from None
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"".join((PNG_MAGIC, _png_chunk(b"IHDR", header), _png_chunk(b"IDAT", data),
                     struct.pack(">I", 0) + PNG_END))


def decode_frame(data: bytes | bytearray | memoryview, name: str) -> np.ndarray:
    """The image in ``data`` exactly as it was encoded; ``name`` (a file name) is for the error message.

    A PNG must end with its IEND chunk (trailing zero bytes, which some filesystems leave after a
    crash, are tolerated): a truncated file is refused rather than decoded into a partly black image.
    libpng checks every chunk's CRC and zlib the data's checksum, so a corrupted byte is refused too.
    ``data`` may be any bytes-like object; it is only read, and no reference to it is kept.

    Raises:
        FrameError: not a complete frame in a known format (truncated, corrupt, or something else).
    """
    view = memoryview(data).cast("B")
    image = None
    if view[: len(PNG_MAGIC)] == PNG_MAGIC and _png_end(view):
        image = _decode_grey_up_png(view, name) if _libdeflate is not None else None
        if image is None:
            image = cv2.imdecode(np.frombuffer(view, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:  # PNG is the only format sessions hold: anything else is a damaged one
        raise _damaged(name)
    return image


def _png_end(view: memoryview) -> int:
    """Where the data ends if it ends with an IEND chunk (trailing zero bytes ignored), else 0."""
    end = len(view)
    if end and view[end - 1] == 0:  # rare (crash leftovers): the copy is paid only then
        end = len(bytes(view).rstrip(b"\x00"))
    return end if end >= len(PNG_END) and view[end - len(PNG_END): end] == PNG_END else 0


def _damaged(name: str) -> FrameError:
    return FrameError(f"{name}: not a complete PNG frame (corrupt or truncated)")


_FILTER_NONE, _FILTER_UP = 0, 2
_scratch = threading.local()  # per thread: the buffers a frame is filtered (encode) or gathered (decode) in


def _joined(parts: list[memoryview]) -> memoryview:
    """The chunks' bytes one after the other, in this thread's scratch buffer (valid until its next call).

    The same bytes as ``b"".join(parts)``, without a new 1 MB object per frame: fresh memory costs a
    page fault per 4 kB page on first touch (~0.4 ms a frame here), reused memory does not.
    """
    size = sum(len(part) for part in parts)
    buffer = getattr(_scratch, "buffer", None)
    if buffer is None or len(buffer) < size:
        buffer = _scratch.buffer = bytearray(size)
    view = memoryview(buffer)
    position = 0
    for part in parts:
        view[position: position + len(part)] = part
        position += len(part)
    return view[:size]


def _decode_grey_up_png(data: memoryview, name: str) -> np.ndarray | None:
    """The (H, W) uint8 image of a PNG laid out as :func:`encode_frame` writes grey frames, else None.

    That layout: IHDR (8-bit grey, not interlaced), IDAT chunks, IEND, and every row filtered "up"
    (or "none", the same on the first row). Anything else returns None for OpenCV to decode. Checks
    what libpng checks: each chunk's CRC, and (libdeflate) the Adler-32 and length of the data.

    Raises:
        FrameError: a chunk's CRC or the data do not check out (corrupt or truncated).
    """
    crc32 = _libdeflate.crc32  # the same CRC-32 as zlib's (tests/test_frames.py), 0.07 ms a frame instead of 0.29
    position, size = len(PNG_MAGIC), len(data)
    header, parts = None, []
    while True:
        if position + 12 > size:
            raise _damaged(name)
        (length,) = struct.unpack_from(">I", data, position)
        kind = data[position + 4: position + 8]
        end = position + 8 + length
        if end + 4 > size or crc32(data[position + 4: end]) != struct.unpack_from(">I", data, end)[0]:
            raise _damaged(name)
        if kind == b"IHDR" and header is None and length == 13:
            header = struct.unpack_from(">IIBBBBB", data, position + 8)
        elif kind == b"IDAT" and header is not None:
            parts.append(data[position + 8: end])
        elif kind == b"IEND" and parts:
            break
        else:  # ancillary chunks, palettes, ...: OpenCV's reader knows what they mean
            return None
        position = end + 4
    width, height, bit_depth, colour_type, compression, filter_method, interlace = header
    if (bit_depth, colour_type, compression, filter_method, interlace) != (8, 0, 0, 0, 0) or not width * height:
        return None
    expected = height * (width + 1)
    try:
        raw = _libdeflate.zlib_decompress(_joined(parts), expected)
    except _libdeflate.DeflateError:
        raise _damaged(name) from None
    if len(raw) != expected:
        raise _damaged(name)
    rows = np.frombuffer(raw, np.uint8).reshape(height, width + 1)
    filters = rows[:, 0]
    if not np.all((filters == _FILTER_UP) | (filters == _FILTER_NONE)):
        return None  # sub, average or Paeth rows: OpenCV's reader
    # "up": each row is the difference to the row above, mod 256 (on the first row, to a zero row); "none":
    # the row itself. Summed straight from the inflated data into the image (no copy of the differences first).
    differences = rows[:, 1:]
    image = np.empty((height, width), np.uint8)
    if np.all(filters[1:] == _FILTER_UP):  # every frame encode_frame writes
        return _sum_down_rows(differences, image)
    lines = list(image)
    lines[0][...] = differences[0]
    for above, line, difference, kind in zip(lines[:-1], lines[1:], differences[1:], filters[1:].tolist(),
                                             strict=True):
        if kind == _FILTER_UP:
            np.add(above, difference, out=line)
        else:
            line[...] = difference
    return image


def _sum_down_rows(differences: np.ndarray, image: np.ndarray, block: int = 32) -> np.ndarray:
    """``image[r] = differences[0] + ... + differences[r]`` (mod 256) for (H, W) uint8 arrays; returns ``image``.

    The running sum down the rows in ~H/16 numpy calls instead of H: within blocks of ``block`` rows first
    (row j of every block in one call), then the blocks' last rows summed down, then each block's offset
    (the true last row of the block above) added to its other rows in one call. Sums mod 256 are exact and
    may be taken in any order, so the bytes are those of the row-by-row sum; 0.55 ms a 1080p frame instead
    of 0.85 (tests/test_frame_reading.py checks them against np.cumsum on random and odd shapes).
    """
    height = len(image)
    image[::block] = differences[::block]
    for row in range(1, min(block, height)):
        below = image[row::block]
        np.add(image[row - 1::block][: len(below)], differences[row::block], out=below)
    ends = image[block - 1::block]  # the last row of each full block, summed from its block's first row
    for k in range(1, len(ends)):
        np.add(ends[k - 1], ends[k], out=ends[k])
    full = len(ends) * block
    if len(ends) > 1:
        blocks = image[:full].reshape(len(ends), block, -1)
        np.add(blocks[1:, :-1], ends[:-1, None], out=blocks[1:, :-1])
    if len(ends) and full < height:
        np.add(image[full:], ends[-1], out=image[full:])
    return image


# glibc's mallopt parameters (malloc.h) and the environment variables through which a user tunes them instead.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MALLOC_ENVIRONMENT = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "GLIBC_TUNABLES")
FRAME_MEMORY_MMAP_THRESHOLD_BYTES = 32 << 20
FRAME_MEMORY_TRIM_THRESHOLD_BYTES = 256 << 20
_frame_memory_lock = threading.Lock()
_frame_memory_kept: bool | None = None


def keep_freed_frame_memory() -> bool:
    """Let this process keep the memory of freed frames for the next ones (glibc); True if it now does.

    A replay decodes ~4 MB of frames a stereo pair on several threads and frees them a configuration at a
    time. With glibc's defaults that memory goes back to the kernel (a heap is trimmed once 4 MB lie free at
    its top) and is taken again page by page: ~600-800 page faults and ~4 ms of kernel CPU a pair. Large
    blocks taken from the heap (below ``FRAME_MEMORY_MMAP_THRESHOLD_BYTES``) and heaps trimmed only beyond
    ``FRAME_MEMORY_TRIM_THRESHOLD_BYTES`` free: the freed frames are reused, ~1-2 ms less CPU a pair and
    2-6 pairs/s more on 2 cores (scripts/results/bench_replay.json). Not ``MALLOC_ARENA_MAX=1``: one heap
    for every thread removes the faults but costs more in lock contention than it saves.

    Process-wide and not undone: the process may keep up to 256 MiB of freed memory. A no-op (False) off
    glibc and where the user tunes malloc through the environment. The numbers computed are the same: only
    where memory comes from changes.
    """
    global _frame_memory_kept
    with _frame_memory_lock:
        if _frame_memory_kept is None:
            _frame_memory_kept = False
            if platform.libc_ver()[0] == "glibc" and not any(name in os.environ for name in _MALLOC_ENVIRONMENT):
                try:
                    mallopt = ctypes.CDLL(None).mallopt
                except (OSError, AttributeError):
                    return False
                mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
                # mmap threshold first: setting either fixes both (glibc stops adapting them to the process).
                _frame_memory_kept = bool(mallopt(_M_MMAP_THRESHOLD, FRAME_MEMORY_MMAP_THRESHOLD_BYTES)
                                          and mallopt(_M_TRIM_THRESHOLD, FRAME_MEMORY_TRIM_THRESHOLD_BYTES))
        return _frame_memory_kept
