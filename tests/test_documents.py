"""Typed session documents: every document validated on write and parsed on read, one result row, a schema."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereo_bench.campaign.documents import (
    ADDED_COLUMNS,
    COMPARED_COLUMNS,
    RESULT_COLUMNS,
    SCHEMA_VERSION,
    CalibrationViewEvent,
    DocumentError,
    Draft,
    MoveEvent,
    ResultDocument,
    ResultRow,
    StartDocument,
    StopDocument,
    document_json,
    parse_document,
)
from stereo_bench.campaign.session import SessionError, SessionReader, SessionWriter
from stereo_bench.cli import main

SAMPLE_SESSION = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"


def test_the_shipped_version_1_session_parses_into_typed_documents_and_back_unchanged():
    reader = SessionReader(SAMPLE_SESSION)
    assert reader.start().schema_version == 1 < SCHEMA_VERSION
    typed = reader.documents()
    assert isinstance(typed[0], StartDocument) and isinstance(typed[-1], StopDocument)
    assert len(reader.documents(MoveEvent)) == 2 and len(reader.documents(CalibrationViewEvent)) == 14
    recorded = [json.loads(line) for line in (SAMPLE_SESSION / "documents.jsonl").read_text().splitlines() if line]
    for raw, document in zip(recorded, typed, strict=True):
        assert document_json(document) == raw  # nothing lost or added by the models
    rows = [doc.row for doc in reader.documents(ResultDocument)]
    assert {row.status for row in rows} == {"measured", "infeasible"}


def test_a_document_that_breaks_its_schema_is_refused_on_write_naming_the_field(tmp_path):
    with SessionWriter(tmp_path / "s").open() as session:
        session.start(config={}, plan=[], software={})
        with pytest.raises(SessionError, match=r"event document \(kind move\): data\.rig\.state: Field required"):
            session.record(Draft(MoveEvent, config_id="c0", data={"rig": {"baseline_mm": 100.0}}))
        with pytest.raises(SessionError, match="status: Input should be 'measured'"):
            session.result("c0", {"config_id": "c0", "status": "done"})
        with pytest.raises(SessionError, match="exit_status 'finished' is not one of"):
            session.stop(exit_status="finished")
        session.stop(exit_status="success")
    assert [doc.type for doc in SessionReader(tmp_path / "s").documents()] == ["start", "stop"]


def test_a_document_that_breaks_its_schema_is_refused_on_read_naming_file_line_and_field(tmp_path):
    with SessionWriter(tmp_path / "s").open() as session:
        session.start(config={}, plan=[], software={})
        session.event("move", config_id="c0", data={"rig": {"state": "Idle"}})
        session.stop(exit_status="success")
    stream = tmp_path / "s" / "documents.jsonl"
    lines = stream.read_text().splitlines()
    move = json.loads(lines[1])
    move["data"]["rig"]["baseline_mm"] = "far"
    stream.write_text("\n".join([lines[0], json.dumps(move), *lines[2:]]) + "\n")
    with pytest.raises(SessionError, match=r"documents.jsonl line 2: event document \(kind move\): "
                                           r"data\.rig\.baseline_mm: Input should be a valid number"):
        SessionReader(tmp_path / "s").documents()


def test_unknown_event_kinds_are_plain_events_and_unknown_types_are_refused():
    header = {"seq": 3, "time": "2026-01-01T00:00:00.000000Z", "monotonic": 1.0, "attempt": 1}
    note = parse_document({"type": "event", "kind": "note", "data": {"text": "hi"}, **header})
    assert type(note).__name__ == "EventDocument" and note.data == {"text": "hi"}
    with pytest.raises(DocumentError, match="unknown document type 'descriptor'"):
        parse_document({"type": "descriptor", **header})


def test_the_result_row_is_defined_once():
    from stereo_bench.campaign import store
    from stereo_bench.report import build

    nested_fields = ["uncertainty"]  # the budget: kept in SQLite's extra column, not a column
    assert store.RESULT_COLUMNS == [n for n in ResultRow.model_fields if n not in nested_fields] == list(RESULT_COLUMNS)
    assert set(COMPARED_COLUMNS) == {"status", "square_mean_mm", "square_std_mm", "n_squares", "error_mm",
                                     "sigma_mm", "rms_px", "epipolar_rms_px", "extrinsics_mode", "baseline_used_mm",
                                     "alpha_left_used_deg", "alpha_right_used_deg", "u_combined_mm", "U_expanded_mm"}
    # Sessions recorded before the extrinsics sources lack these: a replay of one does not compare them.
    assert ADDED_COLUMNS == {"extrinsics_mode", "baseline_used_mm", "alpha_left_used_deg", "alpha_right_used_deg",
                             "u_combined_mm", "U_expanded_mm"}
    assert set(build.RESULT_COLUMNS) - {"K"} <= set(RESULT_COLUMNS)
    row = ResultRow(config_id="c0", status="measured", square_mean_mm=27.01, per_square=[27.0, 27.02])
    assert row.stored() == {"config_id": "c0", "status": "measured", "square_mean_mm": 27.01,
                            "per_square": [27.0, 27.02]}


def test_a_new_column_is_one_line_and_a_nested_field_stays_out_of_the_columns(tmp_path):
    from stereo_bench.campaign.documents import column, columns_of, nested
    from stereo_bench.campaign.store import ResultStore

    class Extended(ResultRow):
        u_extra_mm: float | None = column("another standard uncertainty of square_mean_mm, mm")
        budget: dict[str, float] | None = nested("uncertainty budget: contribution -> mm")

    assert columns_of(Extended) == (*RESULT_COLUMNS, "u_extra_mm")
    row = Extended(config_id="c0", status="measured", u_extra_mm=0.01, budget={"pixel_noise": 0.008})
    assert row.stored() == {"config_id": "c0", "status": "measured", "u_extra_mm": 0.01,
                            "budget": {"pixel_noise": 0.008}}
    with ResultStore(tmp_path / "results.sqlite") as store:  # the nested value lands in the JSON extra column
        store.upsert(row.stored())
        assert store.rows()[0]["budget"] == {"pixel_noise": 0.008}


def test_session_schema_prints_the_json_schema_of_every_document(capsys):
    assert main(["session", "schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    text = json.dumps(schema)
    for name in ("StartDocument", "ResumeDocument", "MoveEvent", "PromptEvent", "CalibrationEvent",
                 "ResultDocument", "StopDocument", "ResultRow", "TruthEvent", "ControllerEvent", "StructureEvent",
                 "KinematicModelEvent", "IntrinsicsEvent"):
        assert name in schema["$defs"], name
    assert f"schema version {SCHEMA_VERSION}" in schema["title"] and "square_mean_mm" in text
    assert main(["session", "schema", "--row"]) == 0
    assert "square_mean_mm" in json.loads(capsys.readouterr().out)["properties"]
