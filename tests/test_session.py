"""Session recording: document round trip, lossless frames, refusal to overwrite, resume, repair, safe paths."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import sqlite3

import numpy as np
import pytest

from stereo_bench.campaign.documents import document_json
from stereo_bench.campaign.session import (
    DOCUMENTS_FILE,
    SCHEMA_VERSION,
    SessionError,
    SessionReader,
    SessionWriter,
)
from stereo_bench.campaign.store import RESULT_COLUMNS, ResultStore
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.rectify import rectify

CONFIG = {"campaign": "unit", "board": {"square_mm": 27.0, "cols": 9}, "grid": {"baseline_mm": [100, 200]}}
PLAN = [{"config_id": f"c{i}", "baseline_mm": 100.0 * (i + 1), "distance_mm": 400.0, "alpha_deg": 90.0}
        for i in range(3)]
SOFTWARE = {"stereo_bench": "test", "opencv": "5", "numpy": np.__version__}


def calibration() -> StereoCalibration:
    K = np.array([[1333.3, 0, 959.5], [0, 1333.3, 539.5], [0, 0, 1]])
    return StereoCalibration(K1=K, D1=np.zeros((1, 5)), K2=K, D2=np.zeros((1, 5)), R=np.eye(3),
                             T=np.array([-100.0, 0.2, 0.1]), image_size=(1920, 1080), rms_px=0.04, mode="joint")


def frames(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"left": rng.integers(0, 256, (48, 64), dtype=np.uint8),
            "right": rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)}


def result_row(config_id: str, **values) -> dict:
    return {"config_id": config_id, "baseline_mm": 100.0, "distance_mm": 400.0, "alpha_deg": 90.0, "status": "measured",
            "square_mean_mm": 27.01, "square_std_mm": 0.02, "n_squares": 84, "error_mm": 0.01,
            "sigma_mm": 0.004, "rms_px": 0.05, "epipolar_rms_px": 0.08, **values}


def record(directory, config_ids=("c0", "c1"), *, stop: str | None = "success", partial: str | None = None):
    """A small session: per configuration a capture event with frames, a calibration and a result."""
    with SessionWriter(directory).open() as session:
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE, extra={"operator": "test"})
        for i, config_id in enumerate(config_ids):
            session.event("capture", config_id=config_id, data={"rig": {"x": np.float64(1.5)}}, frames=frames(i))
            session.write_calibration(config_id, calibration(), None, board="chessboard 9x6 27 mm")
            session.result(config_id, result_row(config_id))
        if partial:
            session.event("capture", config_id=partial, frames=frames(99))
        if stop:
            session.stop(exit_status=stop)
    return directory


def all_files(directory):
    return sorted(p.relative_to(directory).as_posix() for p in directory.rglob("*") if p.is_file())


def temp_files(directory):
    return [p for p in directory.rglob("*") if p.name.startswith(".") and p.name.endswith(".tmp")]


# -- writing a session -------------------------------------------------------------------------------
def test_construction_does_no_io(tmp_path):
    SessionWriter(tmp_path / "s")
    SessionWriter(tmp_path / "s", resume=True)
    SessionReader(tmp_path / "s")
    assert not list(tmp_path.iterdir())


def test_round_trip_of_every_document_type(tmp_path):
    out = tmp_path / "s"
    with SessionWriter(out).open() as session:
        assert session.attempt == 1
        transcript = session.transcript_path()
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE, extra={"operator": "anna"})
        doc = session.event("capture", config_id="c0", data={"dt_ms": np.float32(1.25), "bad": float("nan"),
                                                              "pose": np.eye(2)},
                            frames=frames(0), files={"telemetry.json": b'{"x": 1}'})
        files = session.write_calibration("c0", calibration(), rectify(calibration()), board="chessboard")
        session.event("note", data={"text": "line\nbreak"})
        session.result("c0", result_row("c0", per_square=np.array([27.0, 27.02])))
        session.stop(exit_status="success", reason=None)
    assert transcript == out / "transcripts" / "serial-a1.jsonl"

    reader = SessionReader(out)
    types = [d.type for d in reader.documents()]
    assert types == ["start", "event", "event", "event", "event", "result", "stop"]
    start = reader.start()
    assert start.schema_version == SCHEMA_VERSION and start.attempt == 1 and len(start.uid) == 32
    assert start.config == CONFIG and start.plan == PLAN and start.software == SOFTWARE
    assert start.extra == {"operator": "anna"} and start.time.endswith("Z")
    seqs = [d.seq for d in reader.documents()]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert [d.kind for d in reader.events()] == ["transcript", "capture", "calibration", "note"]
    assert reader.events(kind="transcript")[0].files == {"serial": "transcripts/serial-a1.jsonl"}
    capture = reader.events("c0", kind="capture")[0]
    assert document_json(capture) == json.loads(json.dumps(doc))
    assert capture.data == {"dt_ms": 1.25, "bad": None, "pose": [[1.0, 0.0], [0.0, 1.0]]}
    assert capture.frames["left"] == "frames/c0/a1/000002_left.png"
    assert reader.read_bytes(capture.files["telemetry.json"]) == b'{"x": 1}'
    for name, image in frames(0).items():  # lossless, bit-exact, grey and BGR
        back = reader.frame(capture.frames[name])
        assert back.dtype == image.dtype and back.shape == image.shape
        np.testing.assert_array_equal(back, image)
    assert reader.events(kind="note")[0].config_id is None
    assert reader.events(kind="note")[0].data["text"] == "line\nbreak"
    assert files == {"intrinsics": "calib/c0/a1/intrinsics.yml", "extrinsics": "calib/c0/a1/extrinsics.yml"}
    loaded = reader.calibration("c0")
    np.testing.assert_allclose(loaded.T, calibration().T)
    assert "Q:" in (out / files["extrinsics"]).read_text()
    assert reader.results()[0].model_extra["per_square"] == [27.0, 27.02]
    assert reader.stops()[0].exit_status == "success" and reader.status() == "success"
    assert reader.completed_config_ids() == {"c0"}
    assert reader.torn is None and reader.warnings == []
    for line in (out / DOCUMENTS_FILE).read_text().splitlines():  # strict JSON, one object a line
        json.loads(line, parse_constant=lambda name: pytest.fail(f"non-strict JSON constant {name}"))
    assert not temp_files(out)


def test_results_csv_and_sqlite_agree_with_the_stream(tmp_path):
    out = record(tmp_path / "s")
    reader = SessionReader(out)
    with ResultStore(out / "results.sqlite") as store:
        assert store.rows() == [row.stored() for row in reader.results()]
    with open(out / "results.csv", newline="") as handle:
        lines = list(csv.reader(handle))
    assert lines[0][: len(RESULT_COLUMNS)] == RESULT_COLUMNS
    assert lines[0][:12] == ["config_id", "baseline_mm", "distance_mm", "alpha_deg", "status", "square_mean_mm",
                             "square_std_mm", "n_squares", "error_mm", "sigma_mm", "rms_px", "epipolar_rms_px"]
    assert [line[0] for line in lines[1:]] == ["c0", "c1"]
    assert all(row.attempt == 1 and row.time for row in reader.results())


def test_layout_and_no_temporary_files(tmp_path):
    out = record(tmp_path / "s")
    files = all_files(out)
    assert {"documents.jsonl", "results.sqlite", "results.csv"} <= set(files)
    assert "frames/c0/a1/000001_left.png" in files and "frames/c1/a1/000004_right.png" in files
    assert "calib/c1/a1/intrinsics.yml" in files and "calib/c1/a1/extrinsics.yml" in files
    assert not temp_files(out)


def test_an_existing_directory_is_never_overwritten(tmp_path):
    out = record(tmp_path / "s")
    before = {name: (out / name).read_bytes() for name in all_files(out)}
    with pytest.raises(SessionError, match="exists: pass --resume or choose another --out"):
        SessionWriter(out).open()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(SessionError, match="exists"):
        SessionWriter(tmp_path / "other").open()
    (tmp_path / "afile").write_text("x")
    with pytest.raises(SessionError, match="not a directory"):
        SessionWriter(tmp_path / "afile").open()
    assert {name: (out / name).read_bytes() for name in all_files(out)} == before
    assert (tmp_path / "other" / "notes.txt").read_text() == "mine"
    (tmp_path / "empty").mkdir()
    SessionWriter(tmp_path / "empty").open().close()  # an empty directory is fine
    # nor is a new session written into a recorded one (its frames/, below it, anywhere)
    for inside in (out / "sub", out / "frames" / "c0" / "a2", out / "frames" / "c0" / "a1"):
        with pytest.raises(SessionError, match=f"lies inside the session {out}: a recording is never written to"):
            SessionWriter(inside).open()
    assert {name: (out / name).read_bytes() for name in all_files(out)} == before


def test_resume_refuses_what_is_not_a_session(tmp_path):
    with pytest.raises(SessionError, match="nothing to resume"):
        SessionWriter(tmp_path / "missing", resume=True).open()
    (tmp_path / "other").mkdir()
    with pytest.raises(SessionError, match="not a session"):
        SessionWriter(tmp_path / "other", resume=True).open()


def test_one_writer_at_a_time(tmp_path):
    out = record(tmp_path / "s", stop=None)
    with SessionWriter(out, resume=True).open(), pytest.raises(SessionError, match="in use"):
        SessionWriter(out, resume=True).open()


def test_bad_input_records_nothing(tmp_path):
    out = tmp_path / "s"
    with SessionWriter(out).open() as session:
        with pytest.raises(SessionError, match="start"):
            session.event("capture", config_id="c0")
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE)
        with pytest.raises(SessionError, match="config_id"):
            session.event("capture", config_id="../escape", frames=frames(0))
        with pytest.raises(SessionError, match="uint8 or uint16"):
            session.event("capture", config_id="c0", frames={"left": np.zeros((4, 4), np.float32)})
        with pytest.raises(SessionError, match=r"data\.obj"):
            session.event("capture", config_id="c0", data={"obj": object()}, frames=frames(0))
        with pytest.raises(SessionError, match="exit_status"):
            session.stop(exit_status="fine")
    assert [d.type for d in SessionReader(out).documents()] == ["start"]
    assert not (out / "frames").exists() or not [p for p in (out / "frames").rglob("*") if p.is_file()]


def test_leaving_the_block_on_ctrl_c_records_an_interrupted_stop(tmp_path):
    out = tmp_path / "s"
    with pytest.raises(KeyboardInterrupt), SessionWriter(out).open() as session:
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE)
        raise KeyboardInterrupt
    stop = SessionReader(out).stops()[-1]
    assert stop.exit_status == "interrupted" and "KeyboardInterrupt" in stop.reason


# -- resume ------------------------------------------------------------------------------------------
def test_resume_continues_as_attempt_2_without_duplicates(tmp_path):
    out = record(tmp_path / "s", ("c0",), stop="interrupted", partial="c1")
    with SessionWriter(out, resume=True).open() as session:
        assert session.attempt == 2
        assert session.completed_config_ids() == {"c0"}
        session.start(config=CONFIG, plan=PLAN, software={**SOFTWARE, "stereo_bench": "newer"})
        for config_id in [entry["config_id"] for entry in PLAN]:
            if config_id in session.completed_config_ids():
                continue
            session.event("capture", config_id=config_id, frames=frames(int(config_id[1:])))
            session.write_calibration(config_id, calibration(), None, board="chessboard")
            session.result(config_id, result_row(config_id))
        session.result("c1", result_row("c1", square_mean_mm=26.98))  # re-measured: the last one wins
        session.stop(exit_status="success")
    reader = SessionReader(out)
    assert reader.attempts() == [1, 2]
    resume = reader.resumes()[0]
    assert resume.previous_attempt == 1 and resume.completed == ["c0"]
    assert resume.start_uid == reader.start().uid and resume.software["stereo_bench"] == "newer"
    results = reader.results()
    assert [r.config_id for r in results] == ["c0", "c1", "c2"]
    assert [r.attempt for r in results] == [1, 2, 2] and results[1].square_mean_mm == 26.98
    with ResultStore(out / "results.sqlite") as store:
        assert store.rows() == [row.stored() for row in results]
    with sqlite3.connect(out / "results.sqlite") as db:
        assert db.execute("SELECT count(*), count(DISTINCT config_id) FROM results").fetchone() == (3, 3)
    assert len((out / "results.csv").read_text().splitlines()) == 4
    # the interrupted attempt's frames of c1 are kept; replay sees the attempt that produced the result
    assert (out / "frames/c1/a1/000004_left.png").is_file()
    assert {e.attempt for e in reader.events("c1", attempt="last")} == {2}
    assert {e.attempt for e in reader.events("c1", attempt=None)} == {1, 2}
    assert {e.attempt for e in reader.events("c0")} == {1}
    assert [s.exit_status for s in reader.stops()] == ["interrupted", "success"]
    assert reader.status() == "success"


def test_resume_with_a_different_config_names_the_first_differing_key(tmp_path):
    out = record(tmp_path / "s", ("c0",), stop=None)
    with SessionWriter(out, resume=True).open() as session:
        changed = {**CONFIG, "board": {"square_mm": 25.0, "cols": 9}}
        with pytest.raises(SessionError, match=r"config\.board\.square_mm: recorded 27\.0, now 25\.0"):
            session.start(config=changed, plan=PLAN, software=SOFTWARE)
        with pytest.raises(SessionError, match=r"plan: recorded 3 entries, now 2"):
            session.start(config=CONFIG, plan=PLAN[:2], software=SOFTWARE)
    assert SessionReader(out).resumes() == []


def test_resume_of_a_stream_cut_before_its_start(tmp_path):
    out = tmp_path / "s"
    SessionWriter(out).open().close()  # killed between open() and start()
    with SessionWriter(out, resume=True).open() as session:
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE)
    assert SessionReader(out).start().config == CONFIG


# -- repair and corruption ---------------------------------------------------------------------------
def test_torn_last_line_is_tolerated_then_repaired_and_kept_aside(tmp_path):
    out = record(tmp_path / "s", ("c0",), stop=None)
    stream = out / DOCUMENTS_FILE
    good = stream.read_bytes()
    torn = b'{"type": "event", "kind": "capture", "seq": 9, "data": {"x": 1.2'
    stream.write_bytes(good + torn)
    reader = SessionReader(out)
    assert len(reader.documents()) == good.count(b"\n")
    assert reader.torn.data == torn and reader.torn.line == good.count(b"\n") + 1
    assert "torn last line" in reader.warnings[0] and DOCUMENTS_FILE in reader.warnings[0]
    with SessionWriter(out, resume=True).open() as session:
        assert session.recovery["torn_line"]["bytes"] == len(torn)
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE)
    kept = out / "recovered" / "documents.jsonl.torn-a2.bin"
    assert kept.read_bytes() == torn
    data = stream.read_bytes()
    assert data.startswith(good) and torn not in data
    reader = SessionReader(out)
    assert reader.torn is None and reader.resumes()[0].recovery["torn_line"]["kept_in"] == \
        "recovered/documents.jsonl.torn-a2.bin"


def test_power_loss_zeros_at_the_end_are_a_torn_line(tmp_path):
    out = record(tmp_path / "s", ("c0",), stop=None)
    with open(out / DOCUMENTS_FILE, "ab") as handle:
        handle.write(b"\x00" * 300)
    assert SessionReader(out).torn.data == b"\x00" * 300
    SessionWriter(out, resume=True).open().close()
    assert (out / "recovered" / "documents.jsonl.torn-a2.bin").read_bytes() == b"\x00" * 300


def test_a_complete_last_line_without_its_newline_is_kept(tmp_path):
    out = record(tmp_path / "s", ("c0",), stop="success")
    stream = out / DOCUMENTS_FILE
    stream.write_bytes(stream.read_bytes()[:-1])
    assert SessionReader(out).status() == "success"
    with SessionWriter(out, resume=True).open() as session:
        assert session.recovery == {"newline_added": True}
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE)
    assert [d.type for d in SessionReader(out).documents()][-2:] == ["stop", "resume"]


def test_a_corrupt_middle_line_names_the_file_and_the_line(tmp_path):
    out = record(tmp_path / "s")
    stream = out / DOCUMENTS_FILE
    lines = stream.read_bytes().split(b"\n")
    lines[2] = b"#garbage#" + lines[2]
    stream.write_bytes(b"\n".join(lines))
    with pytest.raises(SessionError, match=rf"{DOCUMENTS_FILE} line 3: not JSON") as info:
        SessionReader(out).documents()
    assert "\n" not in str(info.value) and str(stream) in str(info.value)
    with pytest.raises(SessionError, match="line 3"):
        SessionWriter(out, resume=True).open()


def test_a_document_that_is_not_a_document_is_refused(tmp_path):
    out = record(tmp_path / "s")
    stream = out / DOCUMENTS_FILE
    with open(stream, "ab") as handle:
        handle.write(b"[1, 2]\n")
    with pytest.raises(SessionError, match="line 9: not a session document"):
        SessionReader(out).documents()


def test_a_newer_schema_is_refused_with_advice(tmp_path):
    out = record(tmp_path / "s")
    stream = out / DOCUMENTS_FILE
    first, rest = stream.read_bytes().split(b"\n", 1)
    start = json.loads(first)
    start["schema_version"] = SCHEMA_VERSION + 1
    stream.write_bytes(json.dumps(start).encode() + b"\n" + rest)
    with pytest.raises(SessionError, match=f"line 1: written with schema version {SCHEMA_VERSION + 1}.*upgrade"):
        SessionReader(out).start()


def test_temporary_files_left_by_a_crash_are_removed_on_resume(tmp_path):
    out = record(tmp_path / "s", ("c0",), stop=None)
    (out / "frames/c0/a1/.000009_left.png.x1y2.tmp").write_bytes(b"\x89PNG half")
    (out / "calib/c0/.a1.abc.tmp").mkdir()
    (out / "calib/c0/.a1.abc.tmp/intrinsics.yml").write_text("%YAML 1.2\n")
    orphan = out / "frames/c0/a1/000010_left.png"  # complete but never referenced: kept
    orphan.write_bytes((out / "frames/c0/a1/000001_left.png").read_bytes())
    with SessionWriter(out, resume=True).open() as session:
        assert session.recovery["removed_temp_files"] == ["calib/c0/.a1.abc.tmp",
                                                          "frames/c0/a1/.000009_left.png.x1y2.tmp"]
    assert not temp_files(out) and orphan.is_file()


# -- the results store after a crash -----------------------------------------------------------------
def test_missing_store_is_rebuilt_from_the_stream(tmp_path):
    out = record(tmp_path / "s", stop=None)
    expected = [row.stored() for row in SessionReader(out).results()]
    os.unlink(out / "results.sqlite")
    os.unlink(out / "results.csv")
    with SessionWriter(out, resume=True).open() as session:
        assert session.recovery["store_rebuilt"]["added"] == ["c0", "c1"]
        assert session.results() == expected
    assert len((out / "results.csv").read_text().splitlines()) == 3


def test_a_store_row_whose_document_never_landed_is_dropped_but_recorded(tmp_path):
    out = record(tmp_path / "s", ("c0",), stop=None)
    with ResultStore(out / "results.sqlite") as store:  # as if killed between the upsert and the document
        store.upsert(result_row("c1"))
    with SessionWriter(out, resume=True).open() as session:
        assert session.completed_config_ids() == {"c0"}
        assert [r["config_id"] for r in session.results()] == ["c0"]
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE)
    rebuilt = SessionReader(out).resumes()[0].recovery["store_rebuilt"]
    assert [r["config_id"] for r in rebuilt["dropped_rows"]] == ["c1"]
    assert json.loads((out / rebuilt["dropped_rows_kept_in"]).read_text()) == rebuilt["dropped_rows"]


def test_a_corrupt_store_is_kept_aside_and_rebuilt(tmp_path):
    out = record(tmp_path / "s", stop=None)
    (out / "results.sqlite").write_bytes(b"garbage" * 500)
    with SessionWriter(out, resume=True).open() as session:
        assert session.recovery["corrupt_store_kept_in"] == ["recovered/results.sqlite.corrupt-a2"]
        assert [r["config_id"] for r in session.results()] == ["c0", "c1"]
    assert (out / "recovered/results.sqlite.corrupt-a2").read_bytes() == b"garbage" * 500


# -- reading safely ----------------------------------------------------------------------------------
@pytest.mark.parametrize("relative", ["../x.png", "/etc/passwd", "frames/../../x.png", "frames/..", "",
                                      "C:/Windows/x.png", "frames\\..\\..\\x.png"])
def test_manifest_paths_outside_the_session_are_refused(tmp_path, relative):
    out = record(tmp_path / "s")
    with pytest.raises(SessionError, match="refused"):
        SessionReader(out).path(relative)


def test_a_symlink_leading_outside_is_refused(tmp_path):
    out = record(tmp_path / "s")
    secret = tmp_path / "secret.png"
    secret.write_bytes((out / "frames/c0/a1/000001_left.png").read_bytes())
    (out / "frames" / "evil.png").symlink_to(secret)
    (out / "frames" / "evildir").symlink_to(tmp_path)
    (out / "frames" / "fine.png").symlink_to(out / "frames/c0/a1/000001_left.png")
    reader = SessionReader(out)
    with pytest.raises(SessionError, match="outside the session directory"):
        reader.frame("frames/evil.png")
    with pytest.raises(SessionError, match="outside the session directory"):
        reader.path("frames/evildir/secret.png")
    assert reader.frame("frames/fine.png").shape == (48, 64)


def test_a_missing_or_truncated_frame_is_named(tmp_path):
    out = record(tmp_path / "s")
    reader = SessionReader(out)
    relative = reader.events("c0", kind="capture")[0].frames["right"]
    data = (out / relative).read_bytes()
    (out / relative).write_bytes(data[: len(data) // 2])
    with pytest.raises(SessionError, match="000001_right.png: not a complete PNG"):
        reader.frame(relative)
    with pytest.raises(SessionError, match="nope.png: side file missing"):
        reader.frame("frames/nope.png")
    with pytest.raises(SessionError, match="no calibration recorded"):
        reader.calibration("c9")


def test_reader_on_a_missing_directory_says_so(tmp_path):
    with pytest.raises(SessionError, match="session directory not found"):
        SessionReader(tmp_path / "nope").documents()


def test_a_second_calibration_in_one_attempt_is_kept_beside_the_first(tmp_path):
    out = tmp_path / "s"
    second = dataclasses.replace(calibration(), T=np.array([-101.0, 0.0, 0.0]))
    with SessionWriter(out).open() as session:
        session.start(config=CONFIG, plan=PLAN, software=SOFTWARE)
        first = session.write_calibration("c0", calibration(), None, board="chessboard")
        again = session.write_calibration("c0", second, None, board="chessboard", extra={"views_removed": 2})
        transcript = session.transcript_path("serial")
        assert session.reader().transcripts() == {"serial": ["transcripts/serial-a1.jsonl"]}
    assert first["intrinsics"] == "calib/c0/a1/intrinsics.yml" and again["intrinsics"] == "calib/c0/a1-2/intrinsics.yml"
    assert (out / first["extrinsics"]).is_file()
    assert SessionReader(out).calibration("c0").T[0] == -101.0
    assert transcript.parent == out / "transcripts"
