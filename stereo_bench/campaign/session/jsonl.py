"""The document stream ``documents.jsonl``: one document as one line, the stream parsed back with its torn
last line set aside, and where two recorded JSON values first differ."""

from __future__ import annotations

import datetime as _dt
import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.files import InputFileError, read_regular_file
from stereo_bench import paths
from stereo_bench.campaign.documents import (
    READABLE_SCHEMA_VERSIONS,
    SCHEMA_VERSION,
    Document,
    DocumentError,
    document_json,
    json_safe,
    parse_document,
)
from stereo_bench.campaign.session.errors import SessionError

DOCUMENTS_FILE = "documents.jsonl"


def utc_now() -> str:
    """Current UTC time, ISO-8601 with microseconds and a ``Z``."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def encode_document(doc: Mapping[str, Any] | Document) -> bytes:
    """One document as one strict-JSON line (NaN → null, numpy → Python), newline-terminated."""
    if isinstance(doc, Document):
        doc = document_json(doc)
    try:
        clean = json_safe(doc, str(doc.get("type", "document")))
        return (json.dumps(clean, allow_nan=False, ensure_ascii=False) + "\n").encode("utf-8")
    except TypeError as error:
        raise SessionError(f"cannot record {error}") from None
    except UnicodeEncodeError as error:
        raise SessionError(f"cannot record a {doc.get('type', 'document')} document: {error.reason}") from None


# -- reading the stream ------------------------------------------------------------------------------
@dataclass(frozen=True)
class TornLine:
    """The incomplete last line of a stream that a crash cut short: where it starts, and its bytes."""

    line: int
    offset: int
    data: bytes


@dataclass
class ParsedStream:
    documents: list[dict]  # as recorded, each with its line number under '_line'
    typed: list[Document]  # the same documents parsed into their models (stereo_bench.campaign.documents)
    torn: TornLine | None
    needs_newline: bool  # the last document is complete but its newline never made it to disk


def _reject_constant(name: str) -> None:
    raise ValueError(f"non-standard JSON constant {name}")


def parse_stream(path: Path) -> ParsedStream:
    """Parse ``documents.jsonl``: every line must be a JSON object that follows its document's schema.

    A last line that does not parse (cut by a crash, or zeros after a power loss) is returned as
    ``torn``; a bad line anywhere else raises :class:`SessionError` naming the file and the line.
    Lines are first read as JSON, then checked in order (start first, schema version, each document
    against its model), so a corrupt file is reported where its JSON breaks.
    """
    try:
        data = read_regular_file(path, what="document stream", max_bytes=None)
    except InputFileError as error:
        raise SessionError(str(error)) from None
    documents: list[dict] = []
    torn = None
    needs_newline = False
    offset, line_no, size = 0, 0, len(data)
    while offset < size:
        end = data.find(b"\n", offset)
        complete = end >= 0
        raw = data[offset:end] if complete else data[offset:]
        next_offset = end + 1 if complete else size
        line_no += 1
        is_last = next_offset >= size
        if complete and not raw.strip():
            offset = next_offset
            continue
        try:
            doc = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
        except (UnicodeDecodeError, ValueError) as error:
            if is_last:
                torn = TornLine(line=line_no, offset=offset, data=bytes(data[offset:]))
                break
            reason = error.msg if isinstance(error, json.JSONDecodeError) else str(error)
            raise SessionError(f"{path} line {line_no}: not JSON ({reason})") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("type"), str):
            raise SessionError(f"{path} line {line_no}: not a session document (a JSON object with a 'type')")
        doc["_line"] = line_no
        documents.append(doc)
        needs_newline = not complete
        offset = next_offset
    typed = _check_documents(path, documents)
    return ParsedStream(documents, typed, torn, needs_newline)


def _check_documents(path: Path, documents: list[dict]) -> list[Document]:
    typed = []
    for index, doc in enumerate(documents):
        kind = doc["type"]
        line = doc["_line"]
        if index == 0 and kind != "start":
            raise SessionError(f"{path} line {line}: the first document is {kind!r}, not 'start'")
        if index > 0 and kind == "start":
            raise SessionError(f"{path} line {line}: a second 'start' document (a resume writes 'resume')")
        if kind in ("start", "resume"):
            version = doc.get("schema_version")
            if not isinstance(version, int):
                raise SessionError(f"{path} line {line}: {kind} document has no integer 'schema_version'")
            if version > SCHEMA_VERSION:
                raise SessionError(
                    f"{path} line {line}: written with schema version {version}; "
                    f"this stereo-bench reads up to {SCHEMA_VERSION}: upgrade it"
                )
            if version not in READABLE_SCHEMA_VERSIONS:
                raise SessionError(f"{path} line {line}: schema version {version} is not one this stereo-bench "
                                   f"reads ({', '.join(map(str, READABLE_SCHEMA_VERSIONS))})")
        if kind in ("event", "result") and not isinstance(doc.get("attempt"), int):
            raise SessionError(f"{path} line {line}: {kind} document has no integer 'attempt'")
        if kind == "result" and (not isinstance(doc.get("row"), dict) or not isinstance(doc.get("config_id"), str)):
            raise SessionError(f"{path} line {line}: result document needs 'config_id' and a 'row' object")
        _check_ids(path, doc)
        try:
            typed.append(parse_document(_strip(doc)))
        except DocumentError as error:
            raise SessionError(f"{path} line {line}: {error}") from None
    return typed


def _check_ids(path: Path, doc: dict) -> None:
    """The configuration ids a document carries (its own, its plan's) follow the one name rule: a reader builds
    file names from them (a report's images), so an id such as ``../x`` makes the session corrupt."""
    ids = [doc.get("config_id")] if doc.get("config_id") is not None else []
    if doc["type"] == "start" and isinstance(doc.get("plan"), list):
        ids += [entry.get("config_id") for entry in doc["plan"] if isinstance(entry, dict) and "config_id" in entry]
    for value in ids:
        if not paths.is_safe_name(value):
            raise SessionError(f"corrupt session {path} line {doc['_line']}: config_id {value!r} is not a valid name "
                               f"({paths.NAME_RULE})")


def _completed(documents: Iterable[dict]) -> set[str]:
    return {doc["config_id"] for doc in documents if doc["type"] == "result"}


def _last_results(documents: Iterable[dict]) -> list[dict]:
    """The row of the last 'result' document of each configuration, in order of first appearance."""
    rows: dict[str, dict] = {}
    for doc in documents:
        if doc["type"] == "result":
            rows[doc["config_id"]] = doc["row"]
    return list(rows.values())


def _strip(doc: dict) -> dict:
    return {key: value for key, value in doc.items() if key != "_line"}


def first_difference(recorded: Any, now: Any, where: str) -> str | None:
    """Where two JSON values first differ, as ``key.path: recorded X, now Y``; None if equal."""
    def show(value: Any) -> str:
        text = json.dumps(value, ensure_ascii=False)
        return text if len(text) <= 60 else text[:57] + "..."

    if isinstance(recorded, dict) and isinstance(now, dict):
        for key in list(recorded) + [key for key in now if key not in recorded]:
            if key not in now:
                return f"{where}.{key}: recorded {show(recorded[key])}, now missing"
            if key not in recorded:
                return f"{where}.{key}: not recorded, now {show(now[key])}"
            found = first_difference(recorded[key], now[key], f"{where}.{key}")
            if found:
                return found
        return None
    if isinstance(recorded, list) and isinstance(now, list):
        for index, (a, b) in enumerate(zip(recorded, now, strict=False)):
            found = first_difference(a, b, f"{where}[{index}]")
            if found:
                return found
        if len(recorded) != len(now):
            return f"{where}: recorded {len(recorded)} entries, now {len(now)}"
        return None
    if type(recorded) is not type(now) and not (isinstance(recorded, int | float) and isinstance(now, int | float)):
        return f"{where}: recorded {show(recorded)}, now {show(now)}"
    return None if recorded == now else f"{where}: recorded {show(recorded)}, now {show(now)}"

