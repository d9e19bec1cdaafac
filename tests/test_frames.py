"""The frame codec: lossless round trips, the measured PNG setting, refusal of damaged files, old sessions."""

from __future__ import annotations

import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereo_bench.campaign.session import SessionReader
from stereo_bench.frames import FRAME_EXTENSION, PNG_MAGIC, FrameError, decode_frame, encode_frame

SAMPLE_SESSION = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"


def noisy_frame(shape, dtype=np.uint8, seed=0) -> np.ndarray:
    """A camera-like frame: a smooth gradient, a dark square, and sensor noise (seeded)."""
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    rows, cols = shape[:2]
    base = np.linspace(0.2, 0.8, cols)[None, :] * np.ones((rows, 1))
    base[rows // 4: rows // 2, cols // 4: cols // 2] = 0.1
    if len(shape) == 3:
        base = base[..., None] * np.linspace(0.8, 1.0, shape[2])
    return np.clip(base * top + rng.normal(0, 0.01 * top, shape), 0, top).astype(dtype)


def png_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    chunks, position = [], len(PNG_MAGIC)
    while position < len(data):
        length = int.from_bytes(data[position: position + 4], "big")
        chunks.append((data[position + 4: position + 8], data[position + 8: position + 8 + length]))
        position += 12 + length
    return chunks


@pytest.mark.parametrize("shape", [(1080, 1920), (1080, 1920, 3), (37, 53, 4), (37, 53, 1)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_round_trip_is_bit_identical(shape, dtype):
    image = noisy_frame(shape, dtype)
    back = decode_frame(encode_frame(image), "f.png")
    expected = image[..., 0] if shape[-1:] == (1,) else image  # OpenCV stores one channel as grey
    assert back.dtype == image.dtype and back.shape == expected.shape
    np.testing.assert_array_equal(back, expected)


def test_frames_are_png_written_with_the_measured_setting():
    """Grey frames: one IDAT deflated by libdeflate, the 'up' filter on every row (scripts/bench_frame_format.py
    chose them); colour and 16-bit frames: OpenCV's Huffman-only deflate, 'up' filter. Each is a plain PNG that
    zlib inflates and OpenCV's libpng decodes to the same pixels."""
    from stereo_bench import frames

    grey = noisy_frame((120, 160))
    data = encode_frame(grey)
    assert FRAME_EXTENSION == ".png" and data.startswith(PNG_MAGIC)
    chunks = png_chunks(data)
    if frames._libdeflate is not None:  # written here: the three chunks and nothing else
        assert [kind for kind, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"]
    position = len(PNG_MAGIC)
    for kind, body in chunks:  # every chunk's CRC as zlib computes it, and nothing after IEND
        end = position + 8 + len(body)
        assert int.from_bytes(data[end: end + 4], "big") == zlib.crc32(kind + body)
        position = end + 4
    assert position == len(data)
    raw = zlib.decompress(b"".join(body for kind, body in chunks if kind == b"IDAT"))
    rows = np.frombuffer(raw, np.uint8).reshape(grey.shape[0], grey.shape[1] + 1)
    if frames._libdeflate is not None or hasattr(cv2, "IMWRITE_PNG_FILTER"):
        assert set(rows[:, 0]) == {2}  # PNG filter type 2 = up
    np.testing.assert_array_equal(np.cumsum(rows[:, 1:], axis=0, dtype=np.uint8), grey)
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), grey)
    # Huffman only for OpenCV's: no run lengths or back-references, so even a blank frame costs >= 1 bit per byte
    # (run-length or default deflate would store it in ~1 kB).
    blank = np.zeros((400, 500, 3), np.uint8)
    assert len(encode_frame(blank)) >= blank.size / 8


def test_grey_frames_without_libdeflate_are_written_by_opencv_and_read_alike(monkeypatch):
    from stereo_bench import frames

    grey = noisy_frame((90, 130), seed=3)
    ours = encode_frame(grey)
    monkeypatch.setattr(frames, "_libdeflate", None)
    theirs = encode_frame(grey)
    assert theirs != ours
    for data in (ours, theirs):
        np.testing.assert_array_equal(decode_frame(data, "f.png"), grey)


def test_refuses_what_it_cannot_store_losslessly():
    with pytest.raises(FrameError, match="uint8 or uint16"):
        encode_frame(np.zeros((4, 4), np.float32))
    with pytest.raises(FrameError, match="shape"):
        encode_frame(np.zeros((4, 4, 2), np.uint8))
    with pytest.raises(FrameError, match="empty"):
        encode_frame(np.zeros((0, 4), np.uint8))


def test_truncated_corrupt_or_foreign_bytes_are_refused_by_name():
    data = encode_frame(noisy_frame((200, 300)))
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x10  # inside the image data: caught by the chunk CRC
    for damaged in (data[: len(data) // 2], data[:-1], bytes(flipped), b"", b"\x00" * 64, b"GIF89a..."):
        with pytest.raises(FrameError, match=r"000007_left\.png: not a complete PNG frame"):
            decode_frame(damaged, "frames/c0/a1/000007_left.png")
    # Zero bytes after a complete file (a filesystem's leftovers after a crash) are tolerated.
    np.testing.assert_array_equal(decode_frame(data + b"\x00" * 16, "f.png"), decode_frame(data, "f.png"))


def test_old_sessions_frames_read_exactly_as_written():
    """The sample session was recorded with the previous PNG setting: every frame reads back as
    OpenCV's own PNG reader sees it."""
    reader = SessionReader(SAMPLE_SESSION)
    events = [event for event in reader.events() if event.frames]
    assert len(events) >= 10
    for event in events:
        for relative in event.frames.values():
            expected = cv2.imread(str(SAMPLE_SESSION / relative), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(reader.frame(relative), expected)


def _with_crc(kind: bytes, body: bytes) -> bytes:
    return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")


@pytest.mark.parametrize("seed", [0, 1])
def test_rows_filtered_none_or_up_in_any_mix_are_unfiltered_exactly_as_libpng_does(seed, monkeypatch):
    """Uniformly random bytes (every sum wraps mod 256 somewhere), and rows 'none' and 'up' in a random mix,
    each a 'none' row restarting the running sum: the fast path's pixels are libpng's."""
    pytest.importorskip("deflate")
    from stereo_bench import frames

    rng = np.random.default_rng(seed)
    height, width = 97, 131
    image = rng.integers(0, 256, (height, width), dtype=np.uint8)
    kinds = rng.choice([0, 2], height)  # PNG filter types: 0 none, 2 up
    above = np.vstack([np.zeros((1, width), np.uint8), image[:-1]])
    filtered = np.where(kinds[:, None] == 2, image - above, image).astype(np.uint8)
    raw = np.hstack([kinds[:, None].astype(np.uint8), filtered]).tobytes()
    header = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    data = PNG_MAGIC + _with_crc(b"IHDR", header) + _with_crc(b"IDAT", zlib.compress(raw)) + _with_crc(b"IEND", b"")
    expected = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(expected, image)  # the hand-made PNG is what it claims to be
    monkeypatch.setattr(frames.cv2, "imdecode", lambda *args: pytest.fail("OpenCV decoded a grey none/up PNG"))
    decoded = decode_frame(data, "f.png")
    assert decoded.flags.c_contiguous and decoded.flags.writeable
    np.testing.assert_array_equal(decoded, image)


def test_damaged_image_data_behind_a_valid_crc_is_refused():
    """A chunk whose CRC was recomputed over damaged data: the inflate's Adler-32 or length catches it."""
    data = encode_frame(noisy_frame((200, 300)))
    chunks = png_chunks(data)
    idat = b"".join(body for kind, body in chunks if kind == b"IDAT")
    flipped = bytearray(idat)
    flipped[len(idat) // 2] ^= 0x10
    for damaged_idat in (bytes(flipped), idat[: len(idat) - 40] + idat[-4:]):
        rebuilt = (PNG_MAGIC + _with_crc(b"IHDR", chunks[0][1]) + _with_crc(b"IDAT", damaged_idat)
                   + _with_crc(b"IEND", b""))
        with pytest.raises(FrameError, match="not a complete PNG frame"):
            decode_frame(rebuilt, "f.png")


def test_other_pngs_are_decoded_by_opencv_and_without_libdeflate_every_frame_is(monkeypatch):
    from stereo_bench import frames

    grey = noisy_frame((64, 96), seed=5)
    ok, sub_filtered = cv2.imencode(".png", grey, [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
                                    if hasattr(cv2, "IMWRITE_PNG_FILTER") else [])
    assert ok
    np.testing.assert_array_equal(decode_frame(sub_filtered.tobytes(), "f.png"), grey)
    ours = encode_frame(grey)
    monkeypatch.setattr(frames, "_libdeflate", None)
    np.testing.assert_array_equal(decode_frame(ours, "f.png"), grey)
