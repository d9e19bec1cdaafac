"""The document bus: the runner publishes drafts, a recorder stamps and writes them, subscribers watch.

    bus = DocumentBus(SessionWriter(out).open())        # or DocumentBus(MemoryRecorder()) for a dry replay
    bus.subscribe(progress)                             # progress display, --json lines, a test collector,
    bus.subscribe(JsonLines(sys.stdout))                # a live page: all of them see every document
    bus.publish(Draft(MoveEvent, config_id=..., data=...))

The recorder (:class:`~stereo_bench.campaign.session.SessionWriter` or :class:`MemoryRecorder`) gives
each document its header (seq, time, attempt) and its side files; subscribers then get the typed
document as recorded, in stream order, on the thread that published it. A frame subscriber
(``bus.subscribe_frames(watch)``, e.g. the live page's previews) also gets the pixels of the frames
a document recorded, ``watch(document, {"left": image, "right": image})``, without reading them back.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from typing import IO, Protocol

import numpy as np

from stereo_bench.campaign.documents import (
    CalibrationEvent,
    Document,
    Draft,
    EventDocument,
    ResultDocument,
    StartDocument,
    StopDocument,
    result_row,
)
from stereo_bench.campaign.router import DocumentRouter, handles
from stereo_bench.campaign.session import encode_document, utc_now

Subscriber = Callable[[Document], None]
FrameSubscriber = Callable[[Document, Mapping[str, np.ndarray]], None]


class Recorder(Protocol):
    """Turns drafts into documents: :class:`SessionWriter` (a session directory) or :class:`MemoryRecorder`.

    ``prepare`` may start work on a draft ahead of its turn (a session writer encodes its frames on
    a pool); ``record`` records drafts one at a time, in the order they are to appear in the stream.
    """

    attempt: int

    def prepare(self, draft: Draft) -> Draft: ...

    def record(self, draft: Draft) -> list[Document]: ...


class MemoryRecorder:
    """Records nothing to disk: stamps documents and keeps the result rows (a replay without ``--out``)."""

    def __init__(self, attempt: int = 1):
        self.attempt = attempt
        self.rows: dict[str, dict] = {}
        self._seq = 0
        self._lock = threading.Lock()

    def prepare(self, draft: Draft) -> Draft:
        return draft  # frames are not kept: nothing to encode

    def record(self, draft: Draft) -> list[Document]:
        build = _MEMORY_RECORDERS.handler(draft.model)  # before a seq is taken: a model it cannot record takes none
        with self._lock:
            header = {"type": draft.type, "seq": self._seq, "time": utc_now(), "monotonic": time.monotonic(),
                      "attempt": self.attempt}
            self._seq += 1
        return [build(self, draft, header)]

    def _start(self, draft: Draft, header: dict) -> Document:
        return draft.build(header, schema_version=0, uid="memory", host={"hostname": "memory", "pid": 0})

    def _result(self, draft: Draft, header: dict) -> Document:
        row = {"attempt": self.attempt, **result_row(draft.fields["row"]).stored()}
        row.setdefault("time", header["time"])
        document = draft.build(header, row=row)
        self.rows[document.config_id] = document.row.stored()
        return document

    def _stop(self, draft: Draft, header: dict) -> Document:
        return draft.build(header, completed=len(self.rows))

    def _calibration(self, draft: Draft, header: dict) -> Document:
        return draft.build(header, data=draft.calibration.data())  # no files: nothing is written

    def _event(self, draft: Draft, header: dict) -> Document:
        return draft.build(header)  # frames and files are not kept


def _cannot_record(recorder: MemoryRecorder, draft: Draft, header: dict) -> Document:
    raise TypeError(f"cannot record a {draft.model.__name__}")


#: How a MemoryRecorder records each draft, by its model (handlers take the recorder, the draft and its header).
_MEMORY_RECORDERS = DocumentRouter()
_MEMORY_RECORDERS.on(StartDocument, MemoryRecorder._start).on(ResultDocument, MemoryRecorder._result)
_MEMORY_RECORDERS.on(StopDocument, MemoryRecorder._stop).on(CalibrationEvent, MemoryRecorder._calibration)
_MEMORY_RECORDERS.on(EventDocument, MemoryRecorder._event).default = _cannot_record


class DocumentBus:
    """Publishes drafts through one recorder to every subscriber (see the module docstring)."""

    def __init__(self, recorder: Recorder):
        self.recorder = recorder
        self._subscribers: list[Subscriber] = []
        self._frame_subscribers: list[FrameSubscriber] = []
        self._lock = threading.Lock()

    @property
    def attempt(self) -> int:
        return self.recorder.attempt

    def subscribe(self, subscriber: Subscriber) -> Callable[[], None]:
        """Call ``subscriber(document)`` for every document from now on; returns the unsubscribe function."""
        with self._lock:
            self._subscribers.append(subscriber)
        return lambda: self._unsubscribe(subscriber)

    def subscribe_frames(self, subscriber: FrameSubscriber) -> Callable[[], None]:
        """Call ``subscriber(document, frames)`` for every document that recorded frames (name -> the image
        written), after the plain subscribers; it must return quickly (keep a reference, work elsewhere)."""
        with self._lock:
            self._frame_subscribers.append(subscriber)
        return lambda: self._unsubscribe(subscriber)

    def _unsubscribe(self, subscriber) -> None:
        with self._lock:
            for subscribers in (self._subscribers, self._frame_subscribers):
                if subscriber in subscribers:
                    subscribers.remove(subscriber)

    def prepare(self, draft: Draft) -> Draft:
        """Let the recorder start on ``draft`` now (e.g. encode its frames), before :meth:`publish` records it.

        For a publisher that records on another thread: prepare on the capturing thread, publish on
        the recording one, in stream order.
        """
        return self.recorder.prepare(draft)

    def publish(self, draft: Draft) -> list[Document]:
        """Record ``draft`` and hand every document written to the subscribers, in order."""
        documents = self.recorder.record(draft)
        with self._lock:
            subscribers, frame_subscribers = list(self._subscribers), list(self._frame_subscribers)
        for document in documents:
            for subscriber in subscribers:
                subscriber(document)
        if draft.frames and documents and frame_subscribers:
            for frame_subscriber in frame_subscribers:  # the draft's own document is the last one written
                frame_subscriber(documents[-1], draft.frames)
        return documents


class JsonLines(DocumentRouter):
    """A subscriber that writes each document as one JSON line (``campaign run --json``): every model alike."""

    def __init__(self, stream: IO[str]):
        super().__init__()
        self.stream = stream

    @handles(Document)
    def line(self, document: Document) -> None:
        self.stream.write(encode_document(document).decode("utf-8"))
        self.stream.flush()


class Collector:
    """A subscriber that keeps every document (tests, summaries)."""

    def __init__(self):
        self.documents: list[Document] = []

    def __call__(self, document: Document) -> None:
        self.documents.append(document)

    def of(self, model: type[Document]) -> list:
        return [doc for doc in self.documents if isinstance(doc, model)]

    @property
    def rows(self) -> list[dict]:
        return [doc.row.stored() for doc in self.of(ResultDocument)]
