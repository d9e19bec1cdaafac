"""Reading a session directory: :class:`SessionReader`, typed documents, results, frames and calibrations."""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath
from typing import TypeVar

import numpy as np

from drivers.files import InputFileError
from stereo_bench import paths
from stereo_bench.campaign.documents import (
    CalibrationEvent,
    Document,
    EventDocument,
    ResultDocument,
    ResultRow,
    ResumeDocument,
    StartDocument,
    StopDocument,
    TranscriptEvent,
)
from stereo_bench.campaign.session.errors import SessionError
from stereo_bench.campaign.session.files import _read_no_follow, _read_side_file
from stereo_bench.campaign.session.jsonl import DOCUMENTS_FILE, TornLine, parse_stream
from stereo_bench.frames import FrameError, decode_frame
from stereo_bench.vision import calibio
from stereo_bench.vision.calibrate import StereoCalibration

D = TypeVar("D", bound=Document)
E = TypeVar("E", bound=EventDocument)


class SessionReader:
    """Read a session directory: its documents, results, frames and calibrations.

    Construction does no I/O; the stream is read at the first query (:meth:`reload` re-reads it).
    A torn last line (a crash mid-write) is tolerated and reported in :attr:`torn`.
    """

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        self.documents_path = self.directory / DOCUMENTS_FILE
        self._documents: list[Document] | None = None
        self._lines: dict[int, int] = {}  # id(document) -> its line, for messages
        self._torn: TornLine | None = None
        self._frame_directories: dict[PurePosixPath, Path] = {}  # see frame()

    def reload(self) -> SessionReader:
        self._frame_directories = {}
        if not self.directory.is_dir():
            raise SessionError(f"{self.directory}: session directory not found")
        if not self.documents_path.is_file():
            raise SessionError(f"{self.directory}: not a session (no {DOCUMENTS_FILE})")
        try:
            paths.confined(self.directory, DOCUMENTS_FILE)
        except paths.OutsideRoot as error:
            raise SessionError(f"{self.documents_path}: refused: {error}") from None
        parsed = parse_stream(self.documents_path)
        self._documents = parsed.typed
        self._lines = {id(document): raw["_line"] for document, raw in zip(parsed.typed, parsed.documents,
                                                                            strict=True)}
        self._torn = parsed.torn
        return self

    @property
    def torn(self) -> TornLine | None:
        """The torn last line of the stream (a crash mid-write), if any; it is not among the documents."""
        self._docs()
        return self._torn

    def _docs(self) -> list[Document]:
        if self._documents is None:
            self.reload()
        assert self._documents is not None
        return self._documents

    def line(self, document: Document) -> int | None:
        """The line of ``documents.jsonl`` that holds ``document`` (one this reader read), for messages."""
        return self._lines.get(id(document))

    @property
    def warnings(self) -> list[str]:
        """What a reader of this session should be told (a torn last line)."""
        torn = self.torn
        if torn is None:
            return []
        return [f"{self.documents_path} line {torn.line}: torn last line ({len(torn.data)} bytes) "
                "ignored: the writer was interrupted mid-write"]

    # -- documents: typed (stereo_bench.campaign.documents), in stream order ----------------------------
    def documents(self, model: type[D] = Document) -> list[D]:
        """The documents parsed into their models, optionally of one model (and its subclasses), e.g.
        ``reader.documents(MoveEvent)``, ``reader.documents(ResumeDocument)``."""
        return [doc for doc in self._docs() if isinstance(doc, model)]

    def start(self) -> StartDocument:
        docs = self._docs()
        if not docs:
            raise SessionError(f"{self.documents_path}: no start document (the session stopped before it began)")
        start = docs[0]
        assert isinstance(start, StartDocument)  # parse_stream refuses a stream that does not begin with one
        return start

    def resumes(self) -> list[ResumeDocument]:
        return self.documents(ResumeDocument)

    def stops(self) -> list[StopDocument]:
        return self.documents(StopDocument)

    def attempts(self) -> list[int]:
        return [doc.attempt for doc in self.documents() if isinstance(doc, StartDocument | ResumeDocument)]

    def status(self) -> str:
        """The exit status of the last attempt, or ``"incomplete"`` if it has no 'stop' (a crash)."""
        status = "incomplete"
        for doc in self._docs():
            if isinstance(doc, StartDocument | ResumeDocument):
                status = "incomplete"
            elif isinstance(doc, StopDocument):
                status = str(doc.exit_status)
        return status

    def events(
        self, config_id: str | None = None, kind: str | type[E] | None = None, attempt: int | str | None = "last",
    ) -> list[E]:
        """Event documents, optionally of one configuration and/or kind (its name or its model, e.g.
        ``kind=MoveEvent``).

        ``attempt="last"``: per configuration, only the events of the attempt that produced its last
        result (or, without a result, of its last attempt) — what a replay should play back.
        ``attempt=None``: every attempt; an int: that attempt.
        """
        docs = self._docs()
        events = [doc for doc in docs if isinstance(doc, EventDocument)
                  and (config_id is None or doc.config_id == config_id)]
        if attempt == "last":
            chosen: dict[str | None, int] = {}
            for doc in events:
                chosen[doc.config_id] = max(chosen.get(doc.config_id, 0), doc.attempt)
            for doc in docs:
                if isinstance(doc, ResultDocument) and (config_id is None or doc.config_id == config_id):
                    chosen[doc.config_id] = doc.attempt
            events = [doc for doc in events if doc.attempt == chosen[doc.config_id]]
        elif attempt is not None:
            events = [doc for doc in events if doc.attempt == attempt]
        if kind is None or isinstance(kind, str):
            return [doc for doc in events if kind is None or doc.kind == kind]
        return [doc for doc in events if isinstance(doc, kind)]  # a model, or a union of models

    def transcripts(self) -> dict[str, list[str]]:
        """Relative paths of the recorded transcripts, by name, one per attempt in order."""
        out: dict[str, list[str]] = {}
        for doc in self.documents(TranscriptEvent):
            for name, relative in doc.files.items():
                out.setdefault(name, []).append(relative)
        return out

    def results(self) -> list[ResultRow]:
        """The last result row of each configuration, in order of first appearance."""
        rows: dict[str, ResultRow] = {}
        for doc in self.documents(ResultDocument):
            rows[doc.config_id] = doc.row
        return list(rows.values())

    def completed_config_ids(self) -> set[str]:
        return {doc.config_id for doc in self.documents(ResultDocument)}

    # -- side files --------------------------------------------------------------------------------
    def path(self, relative: str) -> Path:
        """The file a document refers to, refused unless it lies inside the session directory."""
        pure = self._relative(relative)
        root = self.directory.resolve()
        try:
            target = (root / pure).resolve()
        except (RuntimeError, OSError) as error:  # a symlink loop (RuntimeError before Python 3.13), a name too long
            raise self._refuse(relative, f"cannot be resolved ({error})") from None
        if not paths.is_inside(root, target):
            raise self._refuse(relative, f"resolves to {target}, outside the session directory (a symlink?)")
        return target

    def _refuse(self, relative: object, why: str) -> SessionError:
        return SessionError(f"{self.directory}: path {relative!r} refused: {why}")

    def _relative(self, relative: str) -> PurePosixPath:
        """``relative`` as a path, refused unless it names a place under the session directory (symlinks aside)."""
        if not isinstance(relative, str) or not relative:
            raise self._refuse(relative, "not a non-empty string")
        if "\x00" in relative or "\\" in relative:
            raise self._refuse(relative, "contains a NUL or a backslash")
        pure = PurePosixPath(relative)
        if pure.is_absolute() or re.match(r"[A-Za-z]:", relative):
            raise self._refuse(relative, "absolute path; session paths are relative to the session directory")
        if ".." in pure.parts:
            raise self._refuse(relative, "'..' leads outside the session directory")
        return pure

    def read_bytes(self, relative: str) -> bytes:
        return _read_side_file(self.path(relative))

    def frame(self, relative: str) -> np.ndarray:
        """A recorded frame, exactly as written (grey (H, W) or BGR (H, W, 3)).

        Confined as :meth:`path` confines, at a fraction of the cost (a replay reads every frame: resolving
        both paths component by component took 0.06-0.3 ms a frame): the directory a frame lies in is
        resolved and checked once per reader (:meth:`reload` forgets it), and the file is opened there
        with O_NOFOLLOW, so a file that is a symlink is never followed on this fast path. Anything else
        than a plain file opened there -- a symlink (inside the session: read, as :meth:`path` allows;
        outside: refused), a missing or unreadable file, a directory that leads outside -- takes
        :meth:`path` and its own read, so the outcome and message are those of :meth:`path` exactly.
        """
        path = self._frame_file(relative)
        try:
            data = _read_no_follow(path) if path is not None else None
        except InputFileError:
            data = None
        if data is None:
            path = self.path(relative)
            data = _read_side_file(path, "frame")
        try:
            return decode_frame(data, str(path))
        except FrameError as error:
            raise SessionError(str(error)) from None

    def _frame_file(self, relative: str) -> Path | None:
        """The resolved path of ``relative`` if its directory is inside the session, else None (not an error)."""
        pure = self._relative(relative)
        directory = self._frame_directories.get(pure.parent)
        if directory is None:
            root = self.directory.resolve()
            try:
                directory = (root / pure.parent).resolve()
            except (RuntimeError, OSError):  # a symlink loop: path() says so
                return None
            if not paths.is_inside(root, directory):
                return None
            self._frame_directories[pure.parent] = directory
        return directory / pure.name

    def calibration(self, config_id: str) -> StereoCalibration:
        """The calibration of ``config_id`` recorded last (its 'calibration' event)."""
        events = self.events(config_id, CalibrationEvent, attempt=None)
        events = [doc for doc in events if doc.config_id == config_id]
        if not events:
            raise SessionError(f"{self.documents_path}: no calibration recorded for configuration {config_id!r}")
        relative = events[-1].files.get("intrinsics")
        if not isinstance(relative, str):
            raise SessionError(f"{self.documents_path} line {self.line(events[-1])}: calibration event lists no "
                               "'intrinsics' file")
        directory = PurePosixPath(relative).parent
        # read_calibration opens both files of the directory: each is checked, not only the one the event names
        for name in (calibio.INTRINSICS_FILE, calibio.EXTRINSICS_FILE):
            self.path(str(directory / name))
        try:
            return calibio.read_calibration(self.path(str(directory)))
        except calibio.CalibrationFileError as error:
            raise SessionError(str(error)) from None

