"""Atomic writes and the SQLite results store: upsert never duplicates, CSV columns in order, rebuild."""

from __future__ import annotations

import csv
import math
import sqlite3

import numpy as np
import pytest

from stereo_bench import atomic
from stereo_bench.campaign.store import (
    RESULT_COLUMNS,
    ResultStore,
    StoreError,
    json_safe,
    normalise_row,
    rows_to_csv,
)

REQUIRED = ["config_id", "baseline_mm", "distance_mm", "alpha_deg", "status", "square_mean_mm", "square_std_mm",
            "n_squares", "error_mm", "sigma_mm", "rms_px", "epipolar_rms_px"]


def row(config_id: str, **values) -> dict:
    return {"config_id": config_id, "baseline_mm": 100.0, "distance_mm": 400.0, "alpha_deg": 90.0, "status": "measured",
            "square_mean_mm": 27.01, "square_std_mm": 0.02, "n_squares": 84, "error_mm": 0.01, "sigma_mm": 0.004,
            "rms_px": 0.05, "epipolar_rms_px": 0.08, **values}


# -- atomic writes -----------------------------------------------------------------------------------
def test_atomic_write_replaces_and_leaves_no_temporary_file(tmp_path):
    target = tmp_path / "sub" / "a.txt"
    atomic.write_text(target, "one")
    atomic.write_text(target, "two")
    assert target.read_text() == "two"
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.txt"]


def test_atomic_write_without_overwrite_never_replaces(tmp_path):
    target = tmp_path / "a.bin"
    atomic.write_bytes(target, b"first", overwrite=False)
    with pytest.raises(FileExistsError):
        atomic.write_bytes(target, b"second", overwrite=False)
    assert target.read_bytes() == b"first"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_a_failing_writer_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "a.txt"
    atomic.write_text(target, "kept")
    with pytest.raises(RuntimeError), atomic.atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash while writing")
    assert target.read_text() == "kept"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_atomic_path_serves_writers_that_want_a_file_name(tmp_path):
    with atomic.atomic_path(tmp_path / "x.sqlite") as tmp:
        assert atomic.is_temp_file(tmp) and tmp.parent == tmp_path
        sqlite3.connect(tmp).close()
    assert [p.name for p in tmp_path.iterdir()] == ["x.sqlite"]


@pytest.mark.parametrize("shape", [(37, 53), (37, 53, 3), (5, 7, 4)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_is_lossless(tmp_path, shape, dtype):
    import cv2

    rng = np.random.default_rng(1)
    image = rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True).astype(dtype)
    atomic.write_png(tmp_path / "f.png", image)
    back = cv2.imread(str(tmp_path / "f.png"), cv2.IMREAD_UNCHANGED)
    assert back.dtype == dtype and back.shape == shape
    np.testing.assert_array_equal(back, image)


def test_png_refuses_what_it_cannot_store_losslessly(tmp_path):
    with pytest.raises(ValueError, match="uint8 or uint16"):
        atomic.write_png(tmp_path / "f.png", np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="shape"):
        atomic.write_png(tmp_path / "f.png", np.zeros((4, 4, 2), np.uint8))
    assert not list(tmp_path.iterdir())


# -- JSON values -------------------------------------------------------------------------------------
def test_json_safe_is_strict_json():
    value = json_safe({"a": np.float32(1.5), "b": float("nan"), "c": np.arange(3), "d": (1, np.int64(2)),
                       "e": [float("inf")], np.int64(7): True})
    assert value == {"a": 1.5, "b": None, "c": [0, 1, 2], "d": [1, 2], "e": [None], "7": True}
    with pytest.raises(TypeError, match=r"data\.x"):
        json_safe({"x": object()}, "data")


def test_normalise_row_drops_nulls_and_needs_a_config_id():
    clean = normalise_row(row("c1", error_mm=float("nan"), reason=None, flag=True, note=None))
    assert "error_mm" not in clean and "reason" not in clean
    assert clean["note"] is None  # an extra key keeps its null
    with pytest.raises(StoreError, match="config_id"):
        normalise_row({"baseline_mm": 1.0})
    with pytest.raises(StoreError, match="status: Input should be 'measured', 'failed', 'infeasible' or 'limit'"):
        normalise_row(row("c1", status="ok"))
    with pytest.raises(StoreError, match="n_squares: Input should be a valid integer"):
        normalise_row(row("c1", n_squares=[84]))


# -- the store ---------------------------------------------------------------------------------------
def test_store_construction_does_no_io(tmp_path):
    ResultStore(tmp_path / "results.sqlite")
    assert not list(tmp_path.iterdir())


def test_upsert_replaces_never_duplicates_and_keeps_first_position(tmp_path):
    with ResultStore(tmp_path / "results.sqlite") as store:
        store.upsert(row("c1"))
        store.upsert(row("c2", per_square=[27.0, 27.1], attempt=1))
        store.upsert(row("c1", square_mean_mm=26.99, attempt=2))
        rows = store.rows()
    assert [r["config_id"] for r in rows] == ["c1", "c2"]
    assert rows[0]["square_mean_mm"] == 26.99 and rows[0]["attempt"] == 2
    assert rows[1]["per_square"] == [27.0, 27.1]
    assert isinstance(rows[0]["n_squares"], int)
    with sqlite3.connect(tmp_path / "results.sqlite") as db:
        assert db.execute("SELECT count(*) FROM results").fetchone() == (2,)
        assert db.execute("PRAGMA synchronous").fetchone() is not None


def test_store_is_durable_across_reopen(tmp_path):
    with ResultStore(tmp_path / "results.sqlite") as store:
        store.upsert(row("c1"))
    with ResultStore(tmp_path / "results.sqlite") as store:
        assert store.rows() == [normalise_row(row("c1"))]


def test_csv_has_the_required_columns_first_in_order(tmp_path):
    with ResultStore(tmp_path / "results.sqlite") as store:
        store.upsert(row("c2", zz_extra="x"))
        store.upsert(row("c1", error_mm=float("nan")))
        store.export_csv(tmp_path / "results.csv", order=["c1", "c2"])
    with open(tmp_path / "results.csv", newline="") as handle:
        lines = list(csv.reader(handle))
    header = lines[0]
    assert header[: len(REQUIRED)] == REQUIRED
    assert header[: len(RESULT_COLUMNS)] == RESULT_COLUMNS and header[-1] == "zz_extra"
    assert [line[0] for line in lines[1:]] == ["c1", "c2"]
    c1 = dict(zip(header, lines[1], strict=True))
    assert c1["error_mm"] == "" and c1["n_squares"] == "84" and float(c1["square_mean_mm"]) == 27.01
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.csv", "results.sqlite"]


def test_csv_floats_round_trip_exactly():
    value = 27.000000000000004
    text = rows_to_csv([row("c1", square_mean_mm=value)])
    assert str(value) in text and math.isclose(float(text.splitlines()[1].split(",")[5]), value, rel_tol=0)


def test_rebuild_from_stream_rows_reports_what_it_changed(tmp_path):
    with ResultStore(tmp_path / "results.sqlite") as store:
        store.upsert(row("c1"))
        store.upsert(row("ahead"))  # a row whose result document never reached the stream
        report = store.rebuild_from_stream([row("c1", attempt=1), row("c2"), row("c1", square_mean_mm=26.9)])
        assert report["added"] == ["c2"] and report["changed"] == ["c1"]
        assert [r["config_id"] for r in report["dropped"]] == ["ahead"]
        assert [(r["config_id"], r["square_mean_mm"]) for r in store.rows()] == [("c1", 26.9), ("c2", 27.01)]
        again = store.rebuild_from_stream([row("c1", square_mean_mm=26.9), row("c2")])
        assert again == {"added": [], "changed": [], "dropped": []}


def test_a_corrupt_store_file_is_named(tmp_path):
    path = tmp_path / "results.sqlite"
    path.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StoreError, match="results.sqlite"):
        ResultStore(path).open()
