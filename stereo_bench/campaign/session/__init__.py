"""Session recording: a directory holding everything a campaign measured, replayable and resumable.

Layout of a session directory ``SESSION``::

    documents.jsonl                       the document stream: one JSON object per line, append-only
    frames/<config_id>/a<attempt>/<seq>_<name>.png     lossless frames referenced by 'event' documents
    files/<config_id>/a<attempt>/<seq>_<name>          other side files of events (telemetry, ...)
    calib/<config_id>/a<attempt>/{intrinsics,extrinsics}.yml   OpenCV stereo_calib layout
    transcripts/<name>-a<attempt>.jsonl   byte-level serial transcripts (the rig's spy log)
    results.sqlite, results.csv           the results store and its export (rebuilt from the stream)
    recovered/                            what a resume repaired: torn bytes, a corrupt store, kept aside

The stream follows bluesky's document model: ``start`` (schema version, uid, config, plan, software,
attempt) → ``event`` documents (``kind``, ``seq``, ``config_id``, ``data``, relative paths of side
files) and ``result`` documents (one configuration's result row) → ``stop`` (exit status, reason).
A resumed session appends a ``resume`` document instead of a second ``start``, and its attempt
number goes up by one; side files are written under the attempt's own directories, so a re-run
never overwrites what an interrupted one recorded.

Durability: side files are written atomically (temporary file, fsync, rename, directory fsync)
*before* the line that references them; each line is written with one ``write`` and fsynced.
Frames may be encoded ahead, in parallel (:meth:`SessionWriter.prepare`, a small pool of encoder
threads): only the CPU work moves; every file and line is still written by :meth:`SessionWriter.record`,
one document at a time, in the order the documents are recorded. A
crash therefore leaves at most one torn last line (repaired on resume, its bytes kept under
``recovered/``), temporary files (removed on resume: they were never referenced) and complete but
unreferenced side files (kept). A configuration is complete only when its ``result`` document is in
the stream: the SQLite store is written first and reconciled with the stream on resume.

Nothing is ever read or written outside the session directory because a document says so:
:meth:`SessionReader.path` refuses absolute paths, ``..`` and symlinks that lead outside.
"""

from __future__ import annotations

from stereo_bench.campaign.documents import DOCUMENT_TYPES, EXIT_STATUSES, SCHEMA_VERSION
from stereo_bench.campaign.session.errors import SessionError
from stereo_bench.campaign.session.files import RECOVERED_DIR, SESSION_LEVEL
from stereo_bench.campaign.session.jsonl import (
    DOCUMENTS_FILE,
    ParsedStream,
    TornLine,
    encode_document,
    first_difference,
    parse_stream,
    utc_now,
)
from stereo_bench.campaign.session.reader import SessionReader
from stereo_bench.campaign.session.writer import DEFAULT_ENCODERS, SessionWriter
from stereo_bench.campaign.store import normalise_row
from stereo_bench.frames import decode_frame, encode_frame

__all__ = [
    "DOCUMENTS_FILE", "DOCUMENT_TYPES", "EXIT_STATUSES", "SCHEMA_VERSION", "SessionError", "SessionReader",
    "SessionWriter", "TornLine", "encode_document", "first_difference", "normalise_row", "parse_stream",
    "DEFAULT_ENCODERS", "ParsedStream", "RECOVERED_DIR", "SESSION_LEVEL", "decode_frame", "encode_frame", "utc_now",
]
