"""Reading recorded frames in a replay: the decoder's fast path gives OpenCV's pixels bit for bit on rendered,
real and random frames, from any bytes-like buffer; SessionReader.frame confines every frame as
SessionReader.path does while resolving a frame's directory once per reader, not every frame.

(tests/test_frames.py checks the format and the refusal of damaged files; tests/test_confine.py and
tests/test_session.py the confinement of every path.)
"""

from __future__ import annotations

import contextlib
import os
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereo_bench import frames
from stereo_bench.campaign.session import SessionError, SessionReader
from stereo_bench.frames import FrameError, decode_frame, encode_frame
from tests.campaigns import SAMPLE_SESSION
from tests.real_data import REAL
from tests.test_session import record


def grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def sample_frames() -> list[np.ndarray]:
    """Rendered frames (the sample session's, recorded in an older PNG setting) and real camera images."""
    rendered = [grey(cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
                for path in sorted((SAMPLE_SESSION / "frames").rglob("*.png"))[::6]]
    real = [cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) for path in sorted(REAL.rglob("*.jpg"))[::20]]
    assert len(rendered) >= 4 and len(real) >= 4
    return rendered + real


def random_frames() -> list[np.ndarray]:
    """Uniformly random bytes (every running sum wraps mod 256) in odd shapes, single rows and columns included."""
    rng = np.random.default_rng(11)
    shapes = [(1, 1), (1, 9), (9, 1), (2, 3), (37, 53), (64, 1921), (1080, 1920)]
    return [rng.integers(0, 256, shape, dtype=np.uint8) for shape in shapes]


@pytest.fixture
def no_opencv_decode(monkeypatch):
    pytest.importorskip("deflate")
    monkeypatch.setattr(frames.cv2, "imdecode", lambda *args: pytest.fail("OpenCV decoded a grey frame of ours"))


def test_fast_path_pixels_are_opencvs_bit_for_bit_on_rendered_real_and_random_frames(monkeypatch):
    pytest.importorskip("deflate")
    cases = [(image, encode_frame(image)) for image in sample_frames() + random_frames()]
    expected = [cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) for _, data in cases]
    monkeypatch.setattr(frames.cv2, "imdecode", lambda *args: pytest.fail("OpenCV decoded a grey frame of ours"))
    for (image, data), opencv in zip(cases, expected, strict=True):
        decoded = decode_frame(data, "f.png")
        assert decoded.dtype == np.uint8 and decoded.flags.c_contiguous and decoded.flags.writeable
        assert np.array_equal(decoded, opencv) and np.array_equal(decoded, image)


def test_any_bytes_like_buffer_decodes_and_is_left_as_it_was(no_opencv_decode):
    """A frame read into a reused buffer: bytearray or memoryview (a slice of a larger buffer too), with the
    checks of bytes (trailing zero bytes tolerated, truncation refused)."""
    image = random_frames()[4]
    data = encode_frame(image)
    larger = bytearray(b"\xff" * 7 + data + b"\x00" * 5)
    for buffer in (bytearray(data), memoryview(data), memoryview(larger)[7:], memoryview(larger)[7: 7 + len(data)]):
        before = bytes(buffer)
        assert np.array_equal(decode_frame(buffer, "f.png"), image)
        assert bytes(buffer) == before
    with pytest.raises(FrameError, match="f.png: not a complete PNG frame"):
        decode_frame(memoryview(larger)[7: 6 + len(data)], "f.png")


def test_a_second_frame_in_another_thread_does_not_disturb_the_first(no_opencv_decode):
    """The chunks are gathered in a per-thread scratch buffer: frames of different sizes, decoded by turns on two
    threads, each come out whole."""
    from concurrent.futures import ThreadPoolExecutor

    images = random_frames()[3:]
    encoded = [encode_frame(image) for image in images] * 3
    with ThreadPoolExecutor(2) as pool:
        decoded = list(pool.map(lambda data: decode_frame(data, "f.png"), encoded))
    assert all(np.array_equal(a, b) for a, b in zip(decoded, images * 3, strict=True))


@pytest.mark.parametrize("size", [0, 1, 13, 8192, 100_003])
def test_libdeflates_crc32_is_zlibs(size):
    deflate = pytest.importorskip("deflate")
    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    assert deflate.crc32(data) == zlib.crc32(data) and deflate.crc32(memoryview(data)[1:]) == zlib.crc32(data[1:])


# -- SessionReader.frame: confined as SessionReader.path confines ----------------------------------------
def frame_paths(out: Path) -> list[str]:
    reader = SessionReader(out)
    return [relative for event in reader.events() if event.frames for relative in event.frames.values()]


def test_a_frames_directory_is_resolved_once_per_reader_not_per_frame(tmp_path, monkeypatch):
    out = record(tmp_path / "s")
    relatives = frame_paths(out)
    reader = SessionReader(out)
    expected = [reader.frame(relative) for relative in relatives]  # every directory resolved once here
    calls = []
    original = Path.resolve
    monkeypatch.setattr(Path, "resolve", lambda self, *args, **kw: calls.append(self) or original(self, *args, **kw))
    again = [reader.frame(relative) for relative in relatives]
    assert calls == [] and all(np.array_equal(a, b) for a, b in zip(again, expected, strict=True))
    reader.reload()  # forgets the directories: they are checked anew
    reader.frame(relatives[0])
    assert calls


def test_a_frame_replaced_by_a_symlink_after_its_directory_was_checked_is_treated_as_path_treats_it(tmp_path):
    out = record(tmp_path / "s")
    left, right = frame_paths(out)[:2]
    reader = SessionReader(out)
    reader.frame(left)  # the directory is now resolved and checked
    outside = tmp_path / "outside.png"
    outside.write_bytes((out / left).read_bytes())
    (out / left).unlink()
    (out / left).symlink_to(outside)
    with pytest.raises(SessionError, match="outside the session directory"):
        reader.frame(left)
    (out / left).unlink()
    (out / left).symlink_to(out / right)  # inside the session: followed, as path() allows
    assert np.array_equal(reader.frame(left), reader.frame(right))
    (out / right).unlink()
    with pytest.raises(SessionError, match=r"000001_right\.png: side file missing"):
        reader.frame(right)


def test_a_frames_directory_leading_outside_is_refused_with_paths_message(tmp_path):
    out = record(tmp_path / "s")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "x.png").write_bytes((out / frame_paths(out)[0]).read_bytes())
    (out / "frames" / "away").symlink_to(tmp_path / "elsewhere")
    reader = SessionReader(out)
    with pytest.raises(SessionError) as by_path:
        reader.path("frames/away/x.png")
    with pytest.raises(SessionError) as by_frame:
        reader.frame("frames/away/x.png")
    assert str(by_frame.value) == str(by_path.value) and "outside the session directory" in str(by_path.value)


@pytest.mark.parametrize("block", [1, 2, 16, 32, 40])
def test_the_blocked_running_sum_down_the_rows_is_the_row_by_row_one(block):
    rng = np.random.default_rng(block)
    shapes = [(1, 1), (1, 5), (5, 1), (31, 7), (32, 7), (33, 7), (63, 3), (64, 3), (65, 3), (97, 131), (1080, 1920)]
    for shape in shapes:
        differences = rng.integers(0, 256, shape, dtype=np.uint8)
        expected = differences.copy()
        for row in range(1, shape[0]):
            expected[row] += expected[row - 1]
        summed = frames._sum_down_rows(differences, np.empty(shape, np.uint8), block)
        assert np.array_equal(summed, expected) and np.array_equal(summed, np.cumsum(differences, 0, dtype=np.uint8))


def test_a_directory_named_as_a_frame_is_refused_as_path_refuses_it_and_leaks_no_descriptor(tmp_path):
    out = record(tmp_path / "s")
    reader = SessionReader(out)

    def open_in_session() -> list[str]:
        """What this process holds open inside the session (other threads' files, e.g. an earlier test's daemon
        threads under pytest-xdist, are not this reader's: counting every descriptor made the check flaky)."""
        held = []
        for fd in Path("/proc/self/fd").iterdir():
            with contextlib.suppress(OSError):  # a descriptor closed while listing
                target = os.readlink(fd)
                if target.startswith(str(out)):
                    held.append(target)
        return sorted(held)

    before = open_in_session() if Path("/proc/self/fd").is_dir() else None
    for _ in range(3):
        with pytest.raises(SessionError, match=r"frames/c0: is a directory, not a frame"):
            reader.frame("frames/c0")
    if before is not None:
        assert open_in_session() == before
