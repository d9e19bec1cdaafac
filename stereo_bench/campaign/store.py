"""The results store of a session: one SQLite row per configuration, and its CSV export.

The session's document stream is the source of truth; this store is an index of its 'result'
documents that SQL and spreadsheets can read. It is written before the stream's 'result' document,
so after a crash it can be *ahead* of the stream (a row whose document never made it) but never
behind; :meth:`ResultStore.rebuild_from_stream` makes it equal to the stream again and reports what
it changed. SQLite runs with a rollback journal and ``synchronous=FULL``: a ``kill -9`` or a power
loss rolls an unfinished transaction back on the next open and never corrupts the file.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import sqlite3
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from stereo_bench import atomic
from stereo_bench.campaign import documents
from stereo_bench.campaign.documents import json_safe

STORE_FILE = "results.sqlite"
CSV_FILE = "results.csv"
STORE_SCHEMA_VERSION = 1

__all__ = ["CSV_FILE", "RESULT_COLUMNS", "STORE_FILE", "ResultStore", "StoreError", "json_safe", "normalise_row",
           "order_rows", "rows_to_csv"]

#: The columns of ``results.csv`` and of the ``results`` table, in this order: the fields of
#: :class:`stereo_bench.campaign.documents.ResultRow`. Other keys of a row are kept as JSON in an
#: ``extra`` column and exported after these, sorted.
RESULT_COLUMNS: list[str] = list(documents.RESULT_COLUMNS)


class StoreError(ValueError):
    """The results store is unreadable or a row is invalid; the message names the file or the key."""


def normalise_row(row: Mapping[str, Any]) -> dict[str, Any]:
    """A result row as stored: validated as a ResultRow, strict JSON values, null known columns left out."""
    try:
        return documents.result_row(row).stored()
    except documents.DocumentError as error:
        raise StoreError(str(error)) from None


def _csv_cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, dict | list):
        return json.dumps(value, allow_nan=False, ensure_ascii=False)
    return str(value)


def rows_to_csv(rows: Sequence[Mapping[str, Any]]) -> str:
    """CSV text of ``rows``: :data:`RESULT_COLUMNS` first, then any other keys sorted."""
    others = sorted({key for row in rows for key in row} - set(RESULT_COLUMNS))
    columns = RESULT_COLUMNS + others
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_csv_cell(row.get(column)) for column in columns])
    return buffer.getvalue()


def order_rows(rows: Iterable[dict[str, Any]], order: Sequence[str] | None) -> list[dict[str, Any]]:
    """``rows`` with the ids listed in ``order`` first, in that order, then the rest as given."""
    rows = list(rows)
    if not order:
        return rows
    rank = {config_id: i for i, config_id in enumerate(order)}
    return sorted(rows, key=lambda row: rank.get(row["config_id"], len(rank)))  # stable: the rest keep their order


class ResultStore:
    """SQLite ``results`` table keyed by ``config_id``: an upsert replaces, never duplicates.

    Construction does no I/O; :meth:`open` creates or opens the file.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._db: sqlite3.Connection | None = None

    # -- lifecycle ---------------------------------------------------------------------------------
    def open(self) -> ResultStore:
        if self._db is not None:
            return self
        try:
            # SQLite creates a new database 0644 whatever the umask: made first here with the user's mode (0666 less
            # the umask, like every other file of a session); SQLite takes an empty file as a new database.
            with contextlib.suppress(FileExistsError):
                os.close(os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666))
        except OSError as error:
            raise StoreError(f"{self.path}: cannot create the results store ({error.strerror})") from None
        try:
            # The session writer may be driven from a recorder thread; it serialises all access itself.
            db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)  # autocommit; explicit BEGIN
        except sqlite3.Error as error:
            raise StoreError(f"{self.path}: cannot open the results store ({error})") from None
        try:
            db.execute("PRAGMA journal_mode=DELETE")
            db.execute("PRAGMA synchronous=FULL")
            db.execute("BEGIN IMMEDIATE")
            columns = ", ".join(
                "config_id TEXT PRIMARY KEY NOT NULL" if column == "config_id" else f'"{column}"'
                for column in RESULT_COLUMNS
            )
            db.execute(f"CREATE TABLE IF NOT EXISTS results ({columns}, extra TEXT)")
            db.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
            db.execute("INSERT OR IGNORE INTO meta VALUES ('schema_version', ?)", (str(STORE_SCHEMA_VERSION),))
            present = {row[1] for row in db.execute("PRAGMA table_info(results)")}
            for column in RESULT_COLUMNS:  # a store written by an older version lacks newer columns
                if column not in present:
                    db.execute(f'ALTER TABLE results ADD COLUMN "{column}"')
            db.execute("COMMIT")
        except sqlite3.Error as error:
            db.close()
            raise StoreError(f"{self.path}: not a readable results store ({error})") from None
        self._db = db
        return self

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None

    def __enter__(self) -> ResultStore:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def db(self) -> sqlite3.Connection:
        if self._db is None:
            raise StoreError(f"{self.path}: results store is not open")
        return self._db

    # -- rows --------------------------------------------------------------------------------------
    def _insert(self, row: dict[str, Any]) -> None:
        extra = {key: value for key, value in row.items() if key not in RESULT_COLUMNS}
        names = ", ".join(f'"{column}"' for column in RESULT_COLUMNS) + ", extra"
        marks = ", ".join("?" for _ in range(len(RESULT_COLUMNS) + 1))
        updates = ", ".join(f'"{column}" = excluded."{column}"' for column in RESULT_COLUMNS[1:]) + \
            ", extra = excluded.extra"
        values = [row.get(column) for column in RESULT_COLUMNS]
        values.append(json.dumps(extra, allow_nan=False, ensure_ascii=False) if extra else None)
        self.db.execute(
            f"INSERT INTO results ({names}) VALUES ({marks}) ON CONFLICT(config_id) DO UPDATE SET {updates}",
            values,
        )

    def upsert(self, row: Mapping[str, Any]) -> dict[str, Any]:
        """Insert or replace the row of ``row['config_id']`` (durable when this returns)."""
        clean = normalise_row(row)
        db = self.db
        db.execute("BEGIN IMMEDIATE")
        try:
            self._insert(clean)
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")
        return clean

    def rows(self, order: Sequence[str] | None = None) -> list[dict[str, Any]]:
        """Every row as a dict (known columns that are NULL are left out), first-inserted first."""
        cursor = self.db.execute(
            "SELECT " + ", ".join(f'"{c}"' for c in RESULT_COLUMNS) + ", extra FROM results ORDER BY rowid"
        )
        out = []
        for values in cursor:
            row = {column: value for column, value in zip(RESULT_COLUMNS, values, strict=False) if value is not None}
            if values[-1]:
                row.update(json.loads(values[-1]))
            out.append(row)
        return order_rows(out, order)

    def export_csv(self, path: str | Path, order: Sequence[str] | None = None) -> Path:
        """Write every row to ``path`` as CSV, atomically; :data:`RESULT_COLUMNS` first, in that order."""
        return atomic.write_text(path, rows_to_csv(self.rows(order)))

    def rebuild_from_stream(self, source: Any) -> dict[str, list]:
        """Make the table equal to the results of the document stream.

        ``source`` is a ``SessionReader`` (its ``results()`` are used) or a list of result rows (the
        last one per ``config_id`` wins). Returns what changed: ``{"added": [ids], "changed": [ids],
        "dropped": [rows]}`` — a dropped row (in the store, not in the stream) is returned whole so the
        caller can record it; nothing disappears silently.
        """
        rows = [row.stored() for row in source.results()] if hasattr(source, "results") else list(source)
        wanted: dict[str, dict[str, Any]] = {}
        for row in rows:
            clean = normalise_row(row)
            wanted[clean["config_id"]] = clean  # keeps the first position, takes the last value
        current = {row["config_id"]: row for row in self.rows()}
        report: dict[str, list] = {
            "added": [cid for cid in wanted if cid not in current],
            "changed": [cid for cid in wanted if cid in current and current[cid] != wanted[cid]],
            "dropped": [row for cid, row in current.items() if cid not in wanted],
        }
        if list(current) == list(wanted) and not report["changed"]:
            return report
        db = self.db
        db.execute("BEGIN IMMEDIATE")
        try:
            db.execute("DELETE FROM results")
            for row in wanted.values():
                self._insert(row)
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")
        return report
