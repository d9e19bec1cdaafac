"""kill -9 of a session writer at the worst moments: the reader and a resumed writer lose and duplicate nothing.

A subprocess records a small campaign through :class:`SessionWriter` (the real code, unpatched except
that ``os.write`` can be made to stop halfway, to place the kill exactly: mid-line in the stream,
mid-frame in a temporary file, or between the SQLite upsert and the result document). The parent
SIGKILLs it there, checks what a reader sees, resumes, and at the end checks the whole session.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from stereo_bench.campaign.documents import ResultDocument
from stereo_bench.campaign.session import DOCUMENTS_FILE, SessionReader
from stereo_bench.campaign.store import ResultStore

REPO = Path(__file__).resolve().parents[1]
N_CONFIGS = 8

WRITER = textwrap.dedent(
    """
    import os, sys, time
    import numpy as np
    from stereo_bench.campaign.session import DOCUMENTS_FILE, SessionWriter

    out, mode, hang, size = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
    N = %(n)d
    PLAN = [{"config_id": f"c{i}", "baseline_mm": 50.0 * (i + 1)} for i in range(N)]

    def frames_for(config_id):
        rng = np.random.default_rng(int(config_id[1:]))
        return {"left": rng.integers(0, 256, (size, size), dtype=np.uint8),
                "right": rng.integers(0, 256, (size, size, 3), dtype=np.uint8)}

    what, _, nth = hang.partition(":")
    nth = int(nth or 0)
    counts = {"line": 0, "frame": 0, "result": 0}
    real_write = os.write

    def stop_here(label):
        print("HANG", label, flush=True)
        time.sleep(60)
        os._exit(3)

    def write(fd, data):  # the kill point, placed by the parent
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            target = ""
        data = bytes(data)
        if target.endswith(DOCUMENTS_FILE) and len(data) > 1:
            counts["line"] += 1
            if data.startswith(b'{"type": "result"'):
                counts["result"] += 1
                if what == "before-result" and counts["result"] == nth:
                    stop_here("before result document")
            if what == "line-half" and counts["line"] == nth:
                real_write(fd, data[: len(data) // 2])
                os.fsync(fd)
                stop_here("mid-line")
        elif "/frames/" in target and target.endswith(".tmp"):
            counts["frame"] += 1
            if what == "frame-half" and counts["frame"] == nth:
                real_write(fd, data[: len(data) // 2])
                os.fsync(fd)
                stop_here("mid-frame")
        return real_write(fd, data)

    os.write = write
    with SessionWriter(out, resume=(mode == "resume")).open() as session:
        session.start(config={"n": N, "size": size}, plan=PLAN, software={"test": 1})
        print("STARTED", session.attempt, flush=True)
        for entry in PLAN:
            config_id = entry["config_id"]
            if config_id in session.completed_config_ids():
                continue
            session.event("capture", config_id=config_id, data={"b": entry["baseline_mm"]},
                          frames=frames_for(config_id))
            session.event("telemetry", config_id=config_id, data={"mpos": [entry["baseline_mm"], 0.0, 0.0]})
            session.result(config_id, {"config_id": config_id, "baseline_mm": entry["baseline_mm"],
                                       "status": "measured", "square_mean_mm": 27.0 + int(config_id[1:]) / 1000})
            print("DONE", config_id, flush=True)
        session.stop(exit_status="success")
    print("FINISHED", flush=True)
    """
) % {"n": N_CONFIGS}


def frames_for(config_id: str, size: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(int(config_id[1:]))
    return {"left": rng.integers(0, 256, (size, size), dtype=np.uint8),
            "right": rng.integers(0, 256, (size, size, 3), dtype=np.uint8)}


@pytest.fixture
def writer_script(tmp_path) -> Path:
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    return script


def launch(script: Path, out: Path, mode: str, hang: str = "none", size: int = 64) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, str(script), str(out), mode, hang, str(size)], cwd=script.parent,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(process: subprocess.Popen, word: str, timeout: float = 20.0) -> list[str]:
    lines = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line:
            break
        lines.append(line.strip())
        if line.startswith(word):
            return lines
    process.kill()
    raise AssertionError(f"writer never said {word!r}: {lines} {process.stderr.read()}")


def kill9(process: subprocess.Popen, *, may_have_finished: bool = False) -> None:
    """SIGKILL the writer. ``may_have_finished``: it may exit on its own between a poll() and the kill."""
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=10)
    if may_have_finished and process.returncode == 0:
        return
    assert process.returncode == -signal.SIGKILL


def run_to_end(script: Path, out: Path, size: int) -> None:
    process = launch(script, out, "resume", size=size)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 0, stderr
    assert "FINISHED" in stdout


def temp_files(directory: Path) -> list[Path]:
    return [p for p in directory.rglob("*") if p.name.startswith(".") and p.name.endswith(".tmp")]


def check_complete(out: Path, size: int) -> SessionReader:
    """Every configuration measured exactly once, every referenced frame intact, store = stream."""
    reader = SessionReader(out)
    assert reader.torn is None and reader.status() == "success"
    config_ids = [f"c{i}" for i in range(N_CONFIGS)]
    result_docs = reader.documents(ResultDocument)
    assert sorted(doc.config_id for doc in result_docs) == config_ids, "a result lost or duplicated"
    results = reader.results()
    assert [row.config_id for row in results] == config_ids
    with ResultStore(out / "results.sqlite") as store:
        assert store.rows() == [row.stored() for row in results]
    assert len((out / "results.csv").read_text().splitlines()) == N_CONFIGS + 1
    for event in reader.events(kind="capture", attempt=None):  # every frame any document references
        expected = frames_for(event.config_id, size)
        for name, relative in event.frames.items():
            np.testing.assert_array_equal(reader.frame(relative), expected[name])
    for config_id in config_ids:  # replay's view: one capture per configuration, from the attempt of its result
        captures = reader.events(config_id, kind="capture")
        assert len(captures) == 1
        assert captures[0].attempt == next(d.attempt for d in result_docs if d.config_id == config_id)
    assert not temp_files(out)
    return reader


def test_kill_mid_line_mid_frame_and_between_store_and_stream(writer_script, tmp_path):
    out = tmp_path / "session"
    stream = out / DOCUMENTS_FILE

    # 1. killed half-way through the 5th line (c1's capture event): a torn last line
    process = launch(writer_script, out, "new", "line-half:5")
    wait_for(process, "HANG")
    kill9(process)
    reader = SessionReader(out)
    assert reader.completed_config_ids() == {"c0"}
    assert reader.torn is not None and reader.torn.line == 5
    torn_bytes = reader.torn.data
    before = stream.read_bytes()

    # 2. resumed (attempt 2), killed half-way through writing the 3rd frame (c2's left) to its temporary file
    process = launch(writer_script, out, "resume", "frame-half:3")
    assert wait_for(process, "HANG")[0] == "STARTED 2"
    kill9(process)
    assert [p.parent.relative_to(out).as_posix() for p in temp_files(out)] == ["frames/c2/a2"]
    assert not list((out / "frames/c2/a2").glob("*.png"))
    reader = SessionReader(out)
    assert reader.completed_config_ids() == {"c0", "c1"} and reader.torn is None
    assert stream.read_bytes().startswith(before[: len(before) - len(torn_bytes)])
    assert (out / "recovered/documents.jsonl.torn-a2.bin").read_bytes() == torn_bytes

    # 3. resumed (attempt 3), killed after c2's SQLite upsert, before its result document
    process = launch(writer_script, out, "resume", "before-result:1")
    assert wait_for(process, "HANG")[0] == "STARTED 3"
    kill9(process)
    assert SessionReader(out).completed_config_ids() == {"c0", "c1"}
    with ResultStore(out / "results.sqlite") as store:
        assert [row["config_id"] for row in store.rows()] == ["c0", "c1", "c2"]  # the store is ahead

    # 4. resumed (attempt 4) to the end
    run_to_end(writer_script, out, size=64)
    reader = check_complete(out, size=64)
    assert reader.attempts() == [1, 2, 3, 4]
    recoveries = [doc.recovery for doc in reader.resumes()]
    assert recoveries[0]["torn_line"]["line"] == 5
    assert any(path.startswith("frames/c2/a2/.") for path in recoveries[1]["removed_temp_files"])
    assert [row["config_id"] for row in recoveries[2]["store_rebuilt"]["dropped_rows"]] == ["c2"]
    # c1's frames from attempt 1 (written, then the line referencing them was torn) are kept, unreferenced
    assert sorted(p.name for p in (out / "frames/c1/a1").iterdir()) == ["000004_left.png", "000004_right.png"]


def test_kill_at_random_moments_then_resume(writer_script, tmp_path):
    out = tmp_path / "session"
    size = 400  # large enough that frame encoding and writing take a good share of the time
    rng = random.Random(20240611)
    snapshots = []
    for round_ in range(5):
        process = launch(writer_script, out, "new" if round_ == 0 else "resume", size=size)
        wait_for(process, "STARTED")
        time.sleep(rng.uniform(0.0, 0.15))
        if process.poll() is None:
            kill9(process, may_have_finished=True)
        else:
            process.communicate()
        reader = SessionReader(out)  # always readable, whatever the moment of the kill
        torn = reader.torn.data if reader.torn else b""
        data = (out / DOCUMENTS_FILE).read_bytes()
        snapshots.append(data[: len(data) - len(torn)])
        for event in reader.events(kind="capture", attempt=None):
            for relative in event.frames.values():
                assert reader.frame(relative).shape[:2] == (size, size)
    run_to_end(writer_script, out, size=size)
    reader = check_complete(out, size=size)
    final = (out / DOCUMENTS_FILE).read_bytes()
    for snapshot in snapshots:  # nothing complete was ever removed from the stream
        assert final.startswith(snapshot)
