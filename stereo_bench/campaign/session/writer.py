"""Writing (or resuming) a session directory: :class:`SessionWriter`, durable and crash-consistent."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import socket
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from stereo_bench import atomic, paths
from stereo_bench.campaign.documents import (
    EXIT_STATUSES,
    SCHEMA_VERSION,
    CalibrationEvent,
    CalibrationFiles,
    Document,
    DocumentError,
    Draft,
    EventDocument,
    ResultDocument,
    ResumeDocument,
    StartDocument,
    StopDocument,
    TranscriptEvent,
    document_json,
    event_draft,
    json_safe,
    result_row,
)
from stereo_bench.campaign.router import DocumentRouter
from stereo_bench.campaign.session.errors import SessionError, _check_name
from stereo_bench.campaign.session.files import RECOVERED_DIR, SESSION_LEVEL, _attempts_on_disk
from stereo_bench.campaign.session.jsonl import (
    DOCUMENTS_FILE,
    TornLine,
    _completed,
    _last_results,
    encode_document,
    first_difference,
    parse_stream,
    utc_now,
)
from stereo_bench.campaign.session.reader import SessionReader
from stereo_bench.campaign.store import CSV_FILE, STORE_FILE, ResultStore, StoreError, order_rows
from stereo_bench.executors import background_threads
from stereo_bench.frames import FRAME_EXTENSION, FrameError, encode_frame
from stereo_bench.vision import calibio
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.rectify import Rectification

# Frames encoded at once by a session writer (:meth:`SessionWriter.prepare`): a grey 1080p frame takes
# ~16 ms of one core to encode and a stereo pair comes every ~20 ms at the bench, so one encoder
# falls behind while two keep up with the capture on a 2-core machine (scripts/bench_campaign.py).
DEFAULT_ENCODERS = 2


class SessionWriter:
    """Write (or resume) a session directory. Construction does no I/O; see :meth:`open`.

    ``with SessionWriter(out).open() as session:`` then :meth:`start`, :meth:`event` /
    :meth:`write_calibration` / :meth:`result` per configuration, and :meth:`stop`. Leaving the
    ``with`` block on an exception before :meth:`stop` records a 'stop' with exit status
    ``"interrupted"`` (Ctrl-C) or ``"failed"``. One process at a time: the stream is locked.

    ``encoders``: threads that encode frames ahead for :meth:`prepare` (0: each frame is encoded
    when its document is recorded).
    """

    def __init__(self, directory: str | Path, *, resume: bool = False, encoders: int = DEFAULT_ENCODERS):
        if encoders < 0:
            raise ValueError(f"encoders must be >= 0, got {encoders}")
        self.directory = Path(directory)
        self.resume = resume
        self.encoders = encoders
        self._encoder_pool: ThreadPoolExecutor | None = None
        self._encoding: dict[int, tuple[Draft, dict[str, Future]]] = {}  # prepared drafts' frames being encoded
        self._encoding_lock = threading.Lock()
        self.documents_path = self.directory / DOCUMENTS_FILE
        self.attempt = 0
        self.recovery: dict[str, Any] = {}  # what open() repaired when resuming
        self._fd: int | None = None
        self._size = 0
        self._next_seq = 0
        self._recorded_start: StartDocument | None = None
        self._previous_attempt = 0
        self._completed: set[str] = set()
        self._started = False
        self._stopped = False
        self._store: ResultStore | None = None
        self._plan_order: list[str] = []
        self._made_dirs: set[Path] = set()
        self._created_dirs: list[Path] = []  # the directories _mkdir created (not found), in creation order
        self._began_stream = False  # this writer created documents.jsonl (a new session): discard() may remove it
        self._transcripts: dict[str, str] = {}
        self._pending_transcripts: list[str] = []
        self._recorders = self._recorders_by_model()

    # -- lifecycle ---------------------------------------------------------------------------------
    def open(self) -> SessionWriter:
        if self._fd is not None:
            return self
        try:
            if self.resume:
                self._open_resume()
            else:
                self._open_new()
        except BaseException:
            self.close()
            raise
        if self.encoders:
            # At a lower priority: a recording can wait, the capture it would slow down cannot; the
            # encoders catch up while the rig moves on.
            self._encoder_pool = background_threads(self.encoders, "frame-encoder")
        return self

    def _lock(self, fd: int) -> None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise SessionError(f"{self.directory}: in use by another stereo-bench process") from None

    def _open_new(self) -> None:
        root = self.directory
        # A new session inside a recorded one would write into that recording (its frames/, its calib/): refused,
        # as a replay's --out is. The nearest enclosing session is named (root itself being one is "exists" below).
        enclosing = paths.recording_holding(root.parent)
        if enclosing is not None:
            raise SessionError(f"{root}: lies inside the session {enclosing}: a recording is never written to; "
                               "choose a directory outside it")
        if root.exists() or root.is_symlink():
            if not root.is_dir():
                raise SessionError(f"{root} exists and is not a directory: choose another --out")
            if any(root.iterdir()):
                raise SessionError(f"{root} exists: pass --resume or choose another --out")
        self._mkdir(root)
        try:
            self._fd = os.open(self.documents_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC,
                               0o666)  # the user's umask decides who may read the session
        except FileExistsError:
            raise SessionError(f"{root} exists: pass --resume or choose another --out") from None
        self._began_stream = True
        self._lock(self._fd)
        atomic.fsync_dir(root)
        self.attempt = 1
        self._open_store(rebuild=False)

    def _open_resume(self) -> None:
        root = self.directory
        if not root.is_dir():
            raise SessionError(f"{root}: no such session directory: nothing to resume")
        if not self.documents_path.is_file():
            raise SessionError(f"{root}: not a session (no {DOCUMENTS_FILE}): refusing to resume into it")
        # A resume appends to the stream and writes under frames/, files/, calib/, ...: a symlink anywhere in the
        # session that leads outside would take those writes (or the repairs) out of it. Refused before anything.
        leaving = paths.symlinks_leaving(root)
        if leaving:
            raise SessionError(f"{leaving[0]}: is a symlink to {leaving[0].resolve()}, outside the session "
                               f"{root}: refusing to resume (nothing was written)")
        self._fd = os.open(self.documents_path, os.O_RDWR | os.O_APPEND | os.O_CLOEXEC | os.O_NOFOLLOW)
        self._lock(self._fd)
        parsed = parse_stream(self.documents_path)
        docs = parsed.documents
        self._previous_attempt = max((doc.get("attempt", 0) for doc in docs if isinstance(doc.get("attempt"), int)),
                                     default=0)
        self.attempt = max(self._previous_attempt, _attempts_on_disk(root)) + 1
        recovery: dict[str, Any] = {}
        if parsed.torn is not None:
            recovery["torn_line"] = self._set_aside_torn(parsed.torn)
        elif parsed.needs_newline:
            self._write_all(b"\n")
            recovery["newline_added"] = True
        self._size = os.fstat(self._fd).st_size
        self._next_seq = 1 + max((doc["seq"] for doc in docs if isinstance(doc.get("seq"), int)), default=-1)
        self._recorded_start = parsed.typed[0] if parsed.typed else None  # a StartDocument (parse_stream)
        self._completed = _completed(docs)
        removed = self._remove_temp_files()
        if removed:
            recovery["removed_temp_files"] = removed
        recovery.update(self._open_store(rebuild=True, stream_rows=_last_results(docs)))
        self.recovery = recovery

    def _set_aside_torn(self, torn: TornLine) -> dict[str, Any]:
        """Keep the torn bytes in a side file, then cut them off the stream (in that order)."""
        relative = f"{RECOVERED_DIR}/{DOCUMENTS_FILE}.torn-a{self.attempt}.bin"
        self._mkdir(self.directory / RECOVERED_DIR)
        atomic.write_bytes(self.directory / relative, torn.data, overwrite=False)
        assert self._fd is not None
        os.ftruncate(self._fd, torn.offset)
        os.fsync(self._fd)
        return {"line": torn.line, "offset": torn.offset, "bytes": len(torn.data), "kept_in": relative}

    def _remove_temp_files(self) -> list[str]:
        """Temporary files (and calibration temp dirs) a crash left: never referenced, so not recorded."""
        removed = []
        for area in ("frames", "files", "calib", RECOVERED_DIR, "."):
            base = self.directory / area
            candidates = base.glob("*") if area == "." else base.rglob("*")
            for path in sorted(candidates, reverse=True):
                if not atomic.is_temp_file(path):
                    continue
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path)
                else:
                    path.unlink()
                removed.append(path.relative_to(self.directory).as_posix())
        return sorted(removed)

    def _open_store(self, *, rebuild: bool, stream_rows: list[dict] | None = None) -> dict[str, Any]:
        report: dict[str, Any] = {}
        path = self.directory / STORE_FILE
        store = ResultStore(path)
        try:
            store.open()
        except StoreError as error:
            if not rebuild:
                raise SessionError(str(error)) from None
            kept = []
            self._mkdir(self.directory / RECOVERED_DIR)
            for suffix in ("", "-journal", "-wal", "-shm"):
                source = path.with_name(path.name + suffix)
                if source.exists():
                    target = self.directory / RECOVERED_DIR / f"{source.name}.corrupt-a{self.attempt}"
                    os.rename(source, target)
                    kept.append(target.relative_to(self.directory).as_posix())
            atomic.fsync_dir(self.directory)
            report["corrupt_store_kept_in"] = kept
            store = ResultStore(path).open()
        self._store = store
        if rebuild:
            changes = store.rebuild_from_stream(stream_rows or [])
            if changes["added"] or changes["changed"] or changes["dropped"]:
                report["store_rebuilt"] = {"added": changes["added"], "changed": changes["changed"]}
            if changes["dropped"]:
                # rows the store had but the stream did not (a crash between the two writes): kept, in the
                # resume document and in a side file (in case this attempt never gets as far as its start())
                relative = f"{RECOVERED_DIR}/dropped-store-rows-a{self.attempt}.json"
                self._mkdir(self.directory / RECOVERED_DIR)
                atomic.write_text(self.directory / relative, json.dumps(changes["dropped"], indent=1) + "\n",
                                  overwrite=False)
                report["store_rebuilt"].update(dropped_rows=changes["dropped"], dropped_rows_kept_in=relative)
            self._export_csv()
        return report

    def close(self) -> None:
        if self._encoder_pool is not None:  # frames encoded for documents that were never recorded are dropped
            self._encoder_pool.shutdown(wait=True, cancel_futures=True)
            self._encoder_pool = None
            self._encoding.clear()
        if self._store is not None:
            self._store.close()
            self._store = None
        if self._fd is not None:
            os.close(self._fd)  # releases the lock
            self._fd = None

    def discard(self) -> None:
        """Remove the new session this writer began, when nothing was recorded in it beyond its start (a run refused
        before it did anything: a serial port that is not there, a controller that never answers), so that
        ``--out`` is as it was and the corrected command is accepted. Only what this writer made goes: its stream,
        results store and CSV, the transcripts it registered (a driver wrote them, here), and the directories it
        created, if they are then empty: an ``--out`` the user made stays, and so does anything else in it. Closes
        the writer first. SessionError, and nothing removed, for a resumed session or one that recorded more."""
        self.close()
        if not self._began_stream:
            raise SessionError(f"{self.directory}: not removed: this writer did not begin it (a resumed session, or "
                               "one that was there)")
        if self.documents_path.is_file():
            kinds = {(doc.get("type"), doc.get("kind")) for doc in parse_stream(self.documents_path).documents}
            recorded = kinds - {("start", None), ("stop", None), ("event", "transcript")}
            if recorded:
                raise SessionError(f"{self.directory}: not removed: it records more than its start")
        store = self.directory / STORE_FILE
        made = [self.documents_path, self.directory / CSV_FILE, store,
                *(store.with_name(store.name + suffix) for suffix in ("-journal", "-wal", "-shm")),
                *(self.directory / relative for relative in self._transcripts.values())]
        for path in made:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        for directory in reversed(self._created_dirs):
            with contextlib.suppress(OSError):  # not empty: something this writer did not make is in it
                directory.rmdir()
                atomic.fsync_dir(directory.parent)
        self._created_dirs.clear()

    def __enter__(self) -> SessionWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        try:
            if exc_type is not None and self._started and not self._stopped and self._fd is not None:
                status = "interrupted" if issubclass(exc_type, KeyboardInterrupt) else "failed"
                with contextlib.suppress(Exception):
                    self.stop(exit_status=status, reason=f"{exc_type.__name__}: {exc}".rstrip(": "))
        finally:
            self.close()

    # -- low level ---------------------------------------------------------------------------------
    def _mkdir(self, path: Path) -> None:
        """Create ``path`` and any missing parents, fsyncing each new entry's parent directory."""
        if path in self._made_dirs:
            return
        missing = []
        probe = path
        while not probe.is_dir():
            missing.append(probe)
            probe = probe.parent
        for directory in reversed(missing):
            directory.mkdir(exist_ok=True)
            self._created_dirs.append(directory)
            atomic.fsync_dir(directory.parent)
        self._made_dirs.add(path)

    def _write_all(self, data: bytes) -> None:
        assert self._fd is not None
        view = memoryview(data)
        while view:
            view = view[os.write(self._fd, view):]
        os.fsync(self._fd)

    def _append(self, doc: dict) -> None:
        """Append one document as one line and fsync; on failure cut the partial line off again."""
        if self._fd is None:
            raise SessionError(f"{self.directory}: session is not open")
        line = encode_document(doc)
        offset = self._size
        try:
            self._write_all(line)
        except BaseException:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, offset)
                os.fsync(self._fd)
            raise
        self._size = offset + len(line)

    def _require_started(self) -> None:
        if self._fd is None:
            raise SessionError(f"{self.directory}: session is not open")
        if not self._started:
            raise SessionError(f"{self.directory}: start() must come first")

    def _reserve_seq(self) -> int:
        seq = self._next_seq
        self._next_seq += 1
        return seq

    def _header(self, doc_type: str, seq: int) -> dict[str, Any]:
        return {"type": doc_type, "seq": seq, "time": utc_now(), "monotonic": time.monotonic(),
                "attempt": self.attempt}

    def _export_csv(self) -> None:
        assert self._store is not None
        self._store.export_csv(self.directory / CSV_FILE, order=self._plan_order)

    # -- the document stream -----------------------------------------------------------------------
    def record(self, draft: Draft) -> list[Document]:
        """Stamp ``draft`` (seq, time, attempt), validate it against its model, write it; the documents written.

        The one way into the stream, routed by the draft's model: a start (or, when resuming, the
        resume document, plus the transcript events registered before it), a result (SQLite first,
        then its line), a stop, a calibration (YAML files first) or any other event (side files first).
        A draft that does not follow its schema raises :class:`SessionError` before anything is written.
        """
        try:
            return self._recorders.handler(draft.model)(draft)
        except DocumentError as error:
            raise SessionError(f"cannot record: {error}") from None

    def _recorders_by_model(self) -> DocumentRouter:
        """How each draft is recorded, by its model (:meth:`record` routes ``draft.model`` through it)."""
        def started(record: Callable[[Draft], Document]) -> Callable[[Draft], list[Document]]:
            def after_start(draft: Draft) -> list[Document]:
                self._require_started()
                return [record(draft)]
            return after_start

        def refuse(draft: Draft) -> list[Document]:
            self._require_started()
            raise SessionError(f"cannot record a {draft.model.__name__}: start, event, result or stop only")

        router = DocumentRouter().on(StartDocument, self._record_start).on(ResultDocument, started(self._record_result))
        router.on(StopDocument, started(self._record_stop)).on(CalibrationEvent, started(self._record_calibration))
        router.on(EventDocument, started(self._record_event)).default = refuse
        return router

    def _write(self, document: Document) -> Document:
        self._append(document_json(document))
        return document

    def prepare(self, draft: Draft) -> Draft:
        """Start encoding ``draft``'s frames on the encoder pool now; returns the draft to :meth:`record` later.

        Only the encoding moves ahead (it is pure CPU): :meth:`record` still writes each frame file,
        then the line that references it, in the order documents are recorded, so what is on disk
        after a crash is exactly what it would be without the pool. Documents may be prepared on
        one thread and recorded on another (the campaign runner records on an ordered thread).
        """
        if not draft.frames or self._encoder_pool is None:
            return draft
        encoding = {name: self._encoder_pool.submit(encode_frame, image) for name, image in draft.frames.items()}
        with self._encoding_lock:  # the draft itself keeps its images (frame subscribers show them)
            self._encoding[id(draft)] = (draft, encoding)  # holding the draft keeps its id unique meanwhile
        return draft

    def start(self, *, config: dict, plan: list[dict], software: dict, extra: dict | None = None,
              **more: Any) -> Document:
        """Write the 'start' document — or, when resuming, check the config and plan and write 'resume'.

        ``more``: further start fields (``bench``; on resume ``plan_drift``). Returns the document written.
        """
        return self.record(Draft(StartDocument, config=config, plan=plan, software=software, extra=extra or {},
                                 **more))[0]

    def _record_start(self, draft: Draft) -> list[Document]:
        if self._fd is None:
            raise SessionError(f"{self.directory}: session is not open")
        if self._started:
            raise SessionError(f"{self.directory}: start() called twice")
        fields = dict(draft.fields)
        try:
            config, plan = json_safe(fields.pop("config"), "config"), json_safe(fields.pop("plan"), "plan")
        except TypeError as error:
            raise SessionError(f"cannot record {error}") from None
        host = {"hostname": socket.gethostname(), "pid": os.getpid()}
        software, extra = fields.pop("software"), fields.pop("extra", None) or {}
        plan_drift = fields.pop("plan_drift", None)
        environment = fields.get("numeric_environment")  # the start's, or this attempt's in its resume
        for entry in plan if isinstance(plan, list) else []:
            if isinstance(entry, dict) and "config_id" in entry:
                _check_name(entry["config_id"], "plan config_id")
        recorded = self._recorded_start
        if recorded is None:
            document = Draft(StartDocument, config=config, plan=plan, software=software, extra=extra,
                             **fields).build(self._header("start", self._next_seq), schema_version=SCHEMA_VERSION,
                                             uid=uuid.uuid4().hex, host=host,
                                             **({"recovery": self.recovery} if self.recovery else {}))
        else:
            for name, value in (("config", config), ("plan", plan)):
                difference = first_difference(getattr(recorded, name), value, name)
                if difference:
                    raise SessionError(f"{self.documents_path}: cannot resume with a different {name}: {difference}")
            document = Draft(ResumeDocument, software=software, extra=extra).build(
                self._header("resume", self._next_seq), schema_version=SCHEMA_VERSION, uid=uuid.uuid4().hex,
                start_uid=recorded.uid, previous_attempt=self._previous_attempt, host=host,
                completed=sorted(self._completed), recovery=self.recovery,
                bench=recorded.bench, config=recorded.config, plan=recorded.plan, results=self.reader().results(),
                **({"plan_drift": plan_drift} if plan_drift else {}),
                **({"numeric_environment": environment} if environment is not None else {}))
        self._reserve_seq()
        written = [self._write(document)]
        self._started = True
        self._plan_order = [entry["config_id"] for entry in plan
                            if isinstance(entry, dict) and isinstance(entry.get("config_id"), str)]
        for name in self._pending_transcripts:
            written.append(self._record_transcript(name))
        self._pending_transcripts.clear()
        return written

    def _side_dir(self, area: str, config_id: str | None) -> tuple[Path, str]:
        part = SESSION_LEVEL if config_id is None else _check_name(config_id, "config_id")
        relative = f"{area}/{part}/a{self.attempt}"
        return self.directory / relative, relative

    def event(
        self, kind: str, *, config_id: str | None = None, data: dict | None = None,
        frames: dict[str, np.ndarray] | None = None, files: dict[str, bytes] | None = None,
    ) -> dict:
        """Record one event of ``kind`` (its typed model when the kind is known); returns it as recorded."""
        if not isinstance(kind, str) or not kind:
            raise SessionError(f"event kind {kind!r} must be a non-empty string")
        return document_json(self.record(event_draft(kind, config_id=config_id, data=data, frames=frames,
                                                      files=files))[0])

    def _record_event(self, draft: Draft) -> Document:
        """Side files first (atomically, never overwriting), then the event's line (fsynced)."""
        frames, files = dict(draft.frames or {}), dict(draft.files or {})
        for name in list(frames) + list(files):
            _check_name(name, "side file name")
        config_id = draft.fields.get("config_id")
        if config_id is not None:  # the reader refuses a session carrying a bad id: never record one
            _check_name(config_id, "config_id")
        seq = self._next_seq
        frame_paths, file_paths = {}, {}
        if frames:
            _, relative = self._side_dir("frames", config_id)
            frame_paths = {name: f"{relative}/{seq:06d}_{name}{FRAME_EXTENSION}" for name in frames}
        if files:
            _, relative = self._side_dir("files", config_id)
            file_paths = {name: f"{relative}/{seq:06d}_{name}" for name in files}
        # Validated before any side file is written: an unrecordable event leaves nothing behind.
        document = draft.build(self._header("event", seq), frames=frame_paths, files=file_paths)
        self._reserve_seq()
        kind = draft.fields.get("kind")
        if frames:
            directory, _ = self._side_dir("frames", config_id)
            self._mkdir(directory)
            with self._encoding_lock:
                _, encoding = self._encoding.pop(id(draft), (None, {}))
            for name, image in frames.items():
                try:  # encoded ahead by prepare(), or now
                    data = encoding[name].result() if name in encoding else encode_frame(image)
                except FrameError as error:
                    raise SessionError(f"frame {name!r} of event {kind!r}: {error}") from None
                atomic.write_bytes(self.directory / frame_paths[name], data, overwrite=False)
        if files:
            directory, _ = self._side_dir("files", config_id)
            self._mkdir(directory)
            for name, payload in files.items():
                atomic.write_bytes(self.directory / file_paths[name], bytes(payload), overwrite=False)
        return self._write(document)

    def write_calibration(
        self, config_id: str, calib: StereoCalibration, rect: Rectification | None, *,
        board: str, extra: dict | None = None,
    ) -> dict[str, str]:
        """Write the configuration's calibration (OpenCV stereo_calib YAML) and a 'calibration' event.

        Returns ``{"intrinsics": path, "extrinsics": path}``.
        """
        document = self.record(Draft(CalibrationEvent, config_id=config_id,
                                     calibration=CalibrationFiles(calib, rect, board, extra or {})))[0]
        return dict(document.files)

    def _record_calibration(self, draft: Draft) -> Document:
        """Both YAML files are written into a temporary directory that is renamed into place, so the pair
        appears together or not at all; then the 'calibration' event that references them."""
        files_in = draft.calibration
        if files_in is None:
            raise SessionError("a calibration event needs the calibration to write")
        config_id = draft.fields.get("config_id")
        part = SESSION_LEVEL if config_id is None else _check_name(config_id, "config_id")
        calib, rect = files_in.calib, files_in.rect
        seq = self._next_seq
        data = files_in.data()
        parent = self.directory / "calib" / part
        name = f"a{self.attempt}"
        if (parent / name).exists():  # a second calibration of the configuration in this attempt
            name = f"a{self.attempt}-{seq}"
        relative = f"calib/{part}/{name}"
        files = {"intrinsics": f"{relative}/{calibio.INTRINSICS_FILE}",
                 "extrinsics": f"{relative}/{calibio.EXTRINSICS_FILE}"}
        document = draft.build(self._header("event", seq), kind="calibration", data=data, files=files)
        self._reserve_seq()
        self._mkdir(parent)
        tmp = atomic.make_temp_dir(parent, prefix=f".{name}.")
        try:
            calibio.write_calibration(tmp, calib, rect, board=files_in.board, extra=files_in.extra)
            atomic.fsync_dir(tmp)
            os.rename(tmp, parent / name)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        atomic.fsync_dir(parent)
        return self._write(document)

    def transcript_path(self, name: str = "serial") -> Path:
        """Where the rig's byte-level transcript of this attempt goes (recorded in the stream)."""
        if self._fd is None:
            raise SessionError(f"{self.directory}: session is not open")
        _check_name(name, "transcript name")
        relative = f"transcripts/{name}-a{self.attempt}.jsonl"
        self._mkdir(self.directory / "transcripts")
        if name not in self._transcripts:
            self._transcripts[name] = relative
            if self._started:
                self._record_transcript(name)
            else:
                self._pending_transcripts.append(name)
        return self.directory / relative

    def _record_transcript(self, name: str) -> Document:
        draft = Draft(TranscriptEvent, config_id=None, data={"name": name})
        document = draft.build(self._header("event", self._next_seq), files={name: self._transcripts[name]})
        self._reserve_seq()
        return self._write(document)

    def result(self, config_id: str, row: dict) -> None:
        """Record the configuration's result: SQLite upsert, then its 'result' document, then results.csv."""
        self.record(Draft(ResultDocument, config_id=config_id, row=row))

    def _record_result(self, draft: Draft) -> Document:
        config_id = _check_name(draft.fields.get("config_id"), "config_id")
        raw = draft.fields.get("row")
        try:
            row = result_row(raw if raw is not None else {"config_id": config_id}).stored()
        except DocumentError as error:
            raise SessionError(f"cannot record the result of {config_id}: {error}") from None
        if row.get("config_id", config_id) != config_id:
            raise SessionError(f"result row says config_id {row.get('config_id')!r}, recorded as {config_id!r}")
        row = {**row, "config_id": config_id, "attempt": row.get("attempt", self.attempt),
               "time": row.get("time") or utc_now()}
        document = draft.build(self._header("result", self._next_seq), row=row)
        self._reserve_seq()
        assert self._store is not None
        try:
            self._store.upsert(document.row.stored())
        except StoreError as error:
            raise SessionError(f"cannot record the result of {config_id}: {error}") from None
        self._write(document)
        self._completed.add(config_id)
        self._export_csv()
        return document

    def stop(self, *, exit_status: str, reason: str | None = None, resume_command: str | None = None) -> Document:
        """Write the 'stop' document, then export results.csv (atomically)."""
        more = {"resume_command": resume_command} if resume_command else {}
        return self.record(Draft(StopDocument, exit_status=exit_status, reason=reason, **more))[0]

    def _record_stop(self, draft: Draft) -> Document:
        if self._stopped:
            raise SessionError(f"{self.directory}: stop() called twice")
        exit_status = draft.fields.get("exit_status")
        if exit_status not in EXIT_STATUSES:
            raise SessionError(f"exit_status {exit_status!r} is not one of {', '.join(EXIT_STATUSES)}")
        assert self._store is not None
        document = draft.build(self._header("stop", self._next_seq), completed=len(self._completed))
        self._reserve_seq()
        self._write(document)
        self._stopped = True
        self._export_csv()
        return document

    def completed_config_ids(self) -> set[str]:
        return set(self._completed)

    @property
    def recorded_start(self) -> StartDocument | None:
        """The start document of the session being resumed (None for a new session)."""
        return self._recorded_start

    def reader(self) -> SessionReader:
        """A reader of this session as recorded so far."""
        return SessionReader(self.directory)

    def results(self) -> list[dict]:
        """The rows of the results store, in plan order."""
        assert self._store is not None
        return order_rows(self._store.rows(), self._plan_order)

