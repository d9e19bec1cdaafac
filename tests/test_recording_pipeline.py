"""The recorder's encoder pool: frames are encoded in parallel, but the stream keeps its order and no line
ever references a frame that is not complete on disk (the crash-safety rule of docs/SESSION_FORMAT.md)."""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from stereo_bench.campaign.documents import event_draft
from stereo_bench.campaign.session import SessionError, SessionReader, SessionWriter
from stereo_bench.campaign.session import writer as session_module  # where frames are encoded
from stereo_bench.campaign.stream import DocumentBus
from stereo_bench.frames import decode_frame

PLAN = [{"config_id": "c0", "baseline_mm": 100.0}]


def test_encoded_in_parallel_recorded_in_order_each_frame_on_disk_before_its_line(tmp_path, monkeypatch):
    rng = np.random.default_rng(11)
    images = [{"left": rng.integers(0, 256, (40, 56), dtype=np.uint8),
               "right": rng.integers(0, 256, (40, 56, 3), dtype=np.uint8)} for _ in range(24)]
    # Early frames encode slowly, later ones at once: the pool finishes them out of order.
    delay_s = {id(pair[side]): (0.03 if i % 4 == 0 else 0.0) for i, pair in enumerate(images) for side in pair}
    encoded_on: set[str] = set()
    real_encode = session_module.encode_frame

    def slow_encode(image):
        encoded_on.add(threading.current_thread().name)
        time.sleep(delay_s[id(image)])
        return real_encode(image)

    monkeypatch.setattr(session_module, "encode_frame", slow_encode)
    lines_checked = []
    real_append = SessionWriter._append

    def append(self, doc):  # the moment a line goes to disk: everything it references must be there, complete
        for relative in (doc.get("frames") or {}).values():
            path = self.directory / relative
            assert path.is_file(), f"line {doc['seq']} references {relative}, not yet on disk"
            decode_frame(path.read_bytes(), relative)  # complete, not a torn file
            lines_checked.append(doc["seq"])
        return real_append(self, doc)

    monkeypatch.setattr(SessionWriter, "_append", append)
    out = tmp_path / "session"
    with SessionWriter(out, encoders=3) as writer, ThreadPoolExecutor(1) as recorder:
        writer.start(config={"n": 1}, plan=PLAN, software={"test": 1})
        bus = DocumentBus(writer)
        # As the campaign runner does: prepare on the capturing thread, publish on one ordered recorder thread.
        futures = [recorder.submit(bus.publish, bus.prepare(event_draft("capture", config_id="c0",
                                                                        data={"index": i}, frames=pair)))
                   for i, pair in enumerate(images)]
        for future in futures:
            future.result()
        writer.stop(exit_status="success")

    assert {name for name in encoded_on if name.startswith("frame-encoder")} and len(encoded_on) > 1
    events = SessionReader(out).events(kind="capture")
    assert [event.data["index"] for event in events] == list(range(len(images)))
    assert [event.seq for event in events] == sorted(event.seq for event in events)
    assert len(lines_checked) == 2 * len(images)
    reader = SessionReader(out)
    for event, pair in zip(events, images, strict=True):
        for side, image in pair.items():
            assert np.array_equal(reader.frame(event.frames[side]), image)


def test_a_frame_that_cannot_be_encoded_fails_its_document_when_recorded(tmp_path):
    with SessionWriter(tmp_path / "session") as writer:
        writer.start(config={"n": 1}, plan=PLAN, software={"test": 1})
        draft = writer.prepare(event_draft("capture", config_id="c0", frames={"left": np.zeros((4, 4), np.float32)}))
        with pytest.raises(SessionError, match="frame 'left' of event 'capture'.*uint8 or uint16"):
            writer.record(draft)
        writer.stop(exit_status="success")
    assert SessionReader(tmp_path / "session").events(kind="capture") == []


def test_without_encoders_frames_are_encoded_when_recorded(tmp_path):
    image = np.arange(48 * 64, dtype=np.uint16).reshape(48, 64)
    with SessionWriter(tmp_path / "session", encoders=0) as writer:
        writer.start(config={"n": 1}, plan=PLAN, software={"test": 1})
        draft = event_draft("capture", config_id="c0", frames={"left": image})
        assert writer.prepare(draft) is draft
        writer.record(draft)
        writer.stop(exit_status="success")
    reader = SessionReader(tmp_path / "session")
    assert np.array_equal(reader.frame(reader.events(kind="capture")[0].frames["left"]), image)


@pytest.mark.skipif(not hasattr(os, "getpriority") or not os.path.isdir("/proc/self/task"), reason="Linux only")
def test_frames_are_encoded_on_threads_nicer_than_the_one_that_records(tmp_path, monkeypatch):
    """A recording can wait, the capture it would slow down cannot (executors.background_threads)."""
    from stereo_bench.executors import BACKGROUND_NICE

    priorities = []
    real_encode = session_module.encode_frame

    def encode(image):
        priorities.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
        return real_encode(image)

    monkeypatch.setattr(session_module, "encode_frame", encode)
    mine = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    with SessionWriter(tmp_path / "session") as writer:
        writer.start(config={"n": 1}, plan=PLAN, software={"test": 1})
        draft = event_draft("capture", config_id="c0", frames={"left": np.zeros((8, 8), np.uint8)})
        writer.record(writer.prepare(draft))
        writer.stop(exit_status="success")
    assert priorities == [min(mine + BACKGROUND_NICE, 19)]
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == mine


def test_a_prepared_draft_keeps_its_images_for_frame_subscribers(tmp_path):
    """The live page's previews subscribe to the recorded frames' pixels: encoding ahead must not replace them."""
    image = np.arange(48 * 64, dtype=np.uint8).reshape(48, 64)
    seen = []
    with SessionWriter(tmp_path / "session") as writer:
        writer.start(config={"n": 1}, plan=PLAN, software={"test": 1})
        bus = DocumentBus(writer)
        bus.subscribe_frames(lambda document, frames: seen.append(frames["left"]))
        bus.publish(bus.prepare(event_draft("capture", config_id="c0", frames={"left": image})))
        writer.stop(exit_status="success")
    assert len(seen) == 1 and seen[0] is image
    reader = SessionReader(tmp_path / "session")
    assert np.array_equal(reader.frame(reader.events(kind="capture")[0].frames["left"]), image)
