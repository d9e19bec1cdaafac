"""Issue 9, "What must exist" 2 and 4: every path a session, report or replay reads or writes stays inside its
root (symlinks resolved), one name rule for identifiers used in file names, reports atomic per run, files made
with the user's umask, paths recorded in a session independent of the working directory, and replay's honest
endings. The CLI's one-line cases are rows of tests/test_cli_errors.py; these are the rest.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import threading
from pathlib import Path

import pytest

from stereo_bench import atomic, paths
from stereo_bench.campaign.session import SessionError, SessionReader, SessionWriter
from stereo_bench.cli import main
from tests.campaigns import SMALL
from tests.test_session import record


# -- the one name rule ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["B100_Z450_A90", "B100_Z450_A90_T5", "extrinsics-source", "c0", "x.y+z-1",
                                  "a" * paths.NAME_MAX])
def test_a_safe_name_passes(name):
    assert paths.is_safe_name(name) and paths.check_name(name, "config_id") == name


@pytest.mark.parametrize("name", ["../x", "..", ".", "a/b", "/abs", "a\\b", ".hidden", "", "-x", "a b", "a\x00",
                                  "a" * (paths.NAME_MAX + 1), None, 5, "ü"])
def test_an_unsafe_name_is_refused_naming_it(name):
    assert not paths.is_safe_name(name)
    with pytest.raises(paths.UnsafeName, match="config_id .* is not a valid name"):
        paths.check_name(name, "config_id")


def test_the_writer_refuses_what_the_reader_refuses(tmp_path):
    with SessionWriter(tmp_path / "t").open() as session:
        with pytest.raises(SessionError, match="plan config_id '../x' is not a valid name"):
            session.start(config={}, plan=[{"config_id": "../x"}], software={})
    with SessionWriter(tmp_path / "s").open() as session:
        session.start(config={}, plan=[], software={})
        for bad in ("../x", "a/b", ".hidden"):
            with pytest.raises(SessionError, match="not a valid name"):
                session.result(bad, {"status": "measured"})
            with pytest.raises(SessionError, match="not a valid name"):
                session.event("capture", config_id=bad, data={})
    assert not (tmp_path / "x").exists()


def test_a_session_whose_plan_carries_a_bad_id_is_corrupt(tmp_path):
    out = record(tmp_path / "s")
    lines = (out / "documents.jsonl").read_text().splitlines()
    start = json.loads(lines[0])
    start["plan"] = [{"config_id": "/etc/passwd"}]
    (out / "documents.jsonl").write_text("\n".join([json.dumps(start), *lines[1:]]) + "\n")
    with pytest.raises(SessionError, match=r"corrupt session .*documents.jsonl line 1: config_id '/etc/passwd'"):
        SessionReader(out).documents()


def test_confined_follows_symlinks(tmp_path):
    root = tmp_path / "root"
    (root / "d").mkdir(parents=True)
    (root / "in.txt").write_text("x")
    (root / "d" / "link_in").symlink_to(root / "in.txt")
    (root / "d" / "link_out").symlink_to(tmp_path)
    assert paths.confined(root, "d/link_in") == (root / "in.txt").resolve()
    assert paths.confined(root, "d/new_file") == (root / "d" / "new_file").resolve()  # need not exist yet
    with pytest.raises(paths.OutsideRoot, match="link_out/x resolves to .*, outside"):
        paths.confined(root, "d/link_out/x")
    with pytest.raises(paths.OutsideRoot):
        paths.confined(root, "../root2/x")
    assert paths.symlinks_leaving(root) == [root / "d" / "link_out"]


# -- reading: every file a reader opens is checked -----------------------------------------------------------
def test_a_calibration_file_symlinked_outside_is_refused_naming_it(tmp_path):
    out = record(tmp_path / "s")
    outside = tmp_path / "elsewhere.yml"
    extrinsics = out / "calib" / "c0" / "a1" / "extrinsics.yml"
    shutil.copy(extrinsics, outside)
    extrinsics.unlink()
    extrinsics.symlink_to(outside)
    reader = SessionReader(out)
    with pytest.raises(SessionError, match=r"calib/c0/a1/extrinsics.yml' refused: resolves to .*elsewhere.yml"):
        reader.calibration("c0")  # was read: only the intrinsics path was checked
    assert reader.calibration("c1").T.shape == (3,)


def test_documents_symlinked_outside_are_refused(tmp_path):
    out = record(tmp_path / "s")
    (out / "documents.jsonl").rename(tmp_path / "elsewhere.jsonl")
    (out / "documents.jsonl").symlink_to(tmp_path / "elsewhere.jsonl")
    with pytest.raises(SessionError, match="documents.jsonl: refused: .*outside"):
        SessionReader(out).documents()


@pytest.mark.slow  # a report of the small session (~2 s)
def test_report_refuses_a_calibration_symlinked_outside(small_copy, tmp_path, capfd):
    extrinsics = next((small_copy / "calib").glob("*/a1")) / "extrinsics.yml"
    shutil.copy(extrinsics, tmp_path / "elsewhere.yml")
    extrinsics.unlink()
    extrinsics.symlink_to(tmp_path / "elsewhere.yml")
    assert main(["report", str(small_copy), "--out", str(tmp_path / "r")]) == 0
    warnings = [line for line in capfd.readouterr().err.splitlines() if "warning" in line]
    assert warnings and all("extrinsics.yml' refused" in line and "outside the session" in line
                            for line in warnings), warnings


def test_report_of_an_escaping_config_id_writes_nothing(small_reference, tmp_path, capfd):
    from tests.test_cli_errors import ESCAPED, _damage_session, _escape_config_id

    session = _damage_session(small_reference, tmp_path / "deep" / "esc", _escape_config_id)
    assert ESCAPED in (session / "documents.jsonl").read_text()
    assert main(["report", str(session), "--out", str(tmp_path / "deep" / "r" / "out")]) == 2
    assert "ESCAPED" in capfd.readouterr().err
    assert not [p for p in tmp_path.rglob("*ESCAPED*")]  # was ESCAPED_corners.jpg, ESCAPED_rectified.jpg
    assert not (tmp_path / "deep" / "r").exists()


# -- writing: a resume never writes through a symlink that leads outside -------------------------------------
@pytest.mark.parametrize("link", ["documents.jsonl", "frames/B100_Z450_A90", "results.csv", "transcripts"])
def test_resume_through_a_symlink_outside_is_refused_before_anything_moves(small_copy, tmp_path, link):
    lines = (small_copy / "documents.jsonl").read_text().splitlines(keepends=True)
    (small_copy / "documents.jsonl").write_text("".join(lines[:-1]))  # no stop: an interrupted session
    target = tmp_path / "outside" / Path(link).name
    target.parent.mkdir()
    (small_copy / link).rename(target)
    (small_copy / link).symlink_to(target)

    def snapshot():
        return {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in [small_copy, *small_copy.rglob("*"), target,
                                                                      *target.rglob("*")] if p.exists()}

    before = snapshot()
    with pytest.raises(SessionError, match=f"{link}: is a symlink to .*outside the session .*refusing to resume"):
        SessionWriter(small_copy, resume=True).open()
    assert snapshot() == before


# -- replay: never into the source, never a partial --out ----------------------------------------------------
@pytest.mark.slow  # a replay up to the damaged move (~2 s)
def test_a_replay_that_fails_leaves_no_out(small_reference, tmp_path, capfd):
    from tests.test_cli_errors import _damage_session, _second_move

    def mismatch(doc):
        if _second_move(doc):
            doc["data"]["rig"]["baseline_mm"] = 151.0
        return doc

    session = _damage_session(small_reference, tmp_path / "mismatch", mismatch)
    out = tmp_path / "replays" / "r"
    assert main(["replay", str(session), "--out", str(out)]) == 2
    assert "cannot be replayed" in capfd.readouterr().err
    assert not out.exists()  # was: a session directory with the configurations before the mismatch
    assert list((tmp_path / "replays").iterdir()) == []  # nor its temporary directory


@pytest.mark.slow  # a replay of the small session (~2 s)
def test_a_replay_into_out_is_a_whole_session(small_reference, tmp_path):
    out = tmp_path / "r"
    assert main(["replay", str(small_reference), "--out", str(out)]) == 0
    reader = SessionReader(out)
    assert reader.status() == "success" and len(reader.results()) == len(SessionReader(small_reference).results())
    assert [p.name for p in tmp_path.iterdir()] == ["r"]


# -- reports: atomic per run ---------------------------------------------------------------------------------
def test_a_report_run_never_removes_another_runs_work(small_reference, tmp_path, monkeypatch):
    """Two runs to one --out: the second runs start to end while the first is half written; both complete, and
    the first (the last to finish) wins whole. Before, the second removed the first's temporary directory as
    stale, and the first renamed what it wrote afterwards into place: a report missing most of its files."""
    from stereo_bench.report import build

    real = build._structural_section
    paused, release = threading.Event(), threading.Event()

    def slow(writer, sessions):
        if threading.current_thread().name == "first":
            paused.set()
            release.wait(60)
        return real(writer, sessions)

    monkeypatch.setattr(build, "_structural_section", slow)
    out, errors = tmp_path / "r", []

    def first():
        try:
            build.build_report([small_reference], out, images=False)
        except BaseException as error:  # noqa: BLE001 - reported by the assertion below
            errors.append(error)

    thread = threading.Thread(target=first, name="first")
    thread.start()
    assert paused.wait(60)
    build.build_report([small_reference], out, images=False)  # the second run, start to end
    release.set()
    thread.join(60)
    assert not errors and not thread.is_alive()
    manifest = json.loads((out / "report.json").read_text())
    assert len(manifest["files"]) > 20 and all((out / f).is_file() for f in manifest["files"])
    assert {p.name for p in tmp_path.iterdir()} == {"r"}  # nothing left beside it


def test_two_swaps_into_one_out_take_turns(tmp_path, monkeypatch):
    """The second run's swap comes while the first has moved the old report aside but not yet renamed its own
    into place: it waits for the parent's lock (before, its rename took the free name and the first's failed)."""
    from stereo_bench.report import build

    out = tmp_path / "r"
    for name in ("old", "first", "second"):
        (tmp_path / name).mkdir()
        (tmp_path / name / build.MANIFEST).write_text(json.dumps({"kind": build.REPORT_KIND, "run": name}))
    (tmp_path / "old").rename(out)
    moved_aside, second_done = threading.Event(), threading.Event()
    real_rename = os.rename

    def rename(source, target):
        real_rename(source, target)
        if threading.current_thread().name == "first" and Path(source) == out:
            moved_aside.set()
            second_done.wait(1.0)  # with the lock the second run cannot finish meanwhile: this times out

    monkeypatch.setattr(build, "os", type("Os", (), {"rename": staticmethod(rename),
                                                     "__getattr__": lambda self, n: getattr(os, n)})())
    errors = []

    def swap(name):
        try:
            if name == "second":
                moved_aside.wait(10)
            build._replace_dir(tmp_path / name, out)
        except BaseException as error:  # noqa: BLE001 - reported by the assertion below
            errors.append(error)
        if name == "second":
            second_done.set()

    threads = [threading.Thread(target=swap, args=(name,), name=name) for name in ("first", "second")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(20)
    assert not errors
    assert json.loads((out / build.MANIFEST).read_text())["run"] == "second"  # the last one, whole
    assert {p.name for p in tmp_path.iterdir()} == {"r"}


def test_a_crashed_reports_temporary_directory_is_cleaned_but_not_a_running_one(tmp_path):
    from stereo_bench.report.build import _locked, _remove_stale_temps

    crashed = atomic.make_temp_dir(tmp_path, prefix=".r.")
    running = atomic.make_temp_dir(tmp_path, prefix=".r.")
    with _locked(running):
        _remove_stale_temps(tmp_path, "r")
        assert not crashed.exists() and running.exists()


# -- modes: the user's umask ---------------------------------------------------------------------------------
@pytest.fixture(params=[0o022, 0o077, 0o002])
def umask(request):
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


def _modes(root: Path) -> set[tuple[str, int]]:
    return {("dir" if p.is_dir() else "file", stat.S_IMODE(p.stat().st_mode)) for p in [root, *root.rglob("*")]}


def test_a_session_is_created_with_the_umask(tmp_path, umask):
    out = record(tmp_path / "s")  # frames, side files, a calibration directory, the store, the CSV
    atomic.write_text(out / "extra.txt", "x")
    assert _modes(out) == {("dir", 0o777 & ~umask), ("file", 0o666 & ~umask)}  # was 0600 files, 0700 calib dirs


@pytest.mark.slow  # a report of the small session (~1.5 s)
@pytest.mark.parametrize("mask", [0o022, 0o077])
def test_a_report_is_created_with_the_umask(small_reference, tmp_path, mask):
    from stereo_bench.report.build import build_report

    old = os.umask(mask)
    try:
        build_report([small_reference], tmp_path / "r", images=False)
    finally:
        os.umask(old)
    assert _modes(tmp_path / "r") == {("dir", 0o777 & ~mask), ("file", 0o666 & ~mask)}  # was 0755 whatever the mask


# -- paths recorded in a session: relative to the plan file, never to the working directory ------------------
@pytest.mark.slow  # a campaign, a resume and a replay (~8 s)
def test_a_plan_with_relative_paths_resumes_from_anywhere_and_replays_after_the_calibration_moved(
        small_reference, tmp_path, monkeypatch):
    plans = tmp_path / "plans"
    plans.mkdir()
    shutil.copytree(next((small_reference / "calib").glob("*/a1")), plans / "cal")
    (plans / "fixed.toml").write_text(SMALL + '\n[extrinsics]\nintrinsics = "fixed"\ncalib_dir = "cal"\n')
    monkeypatch.chdir(tmp_path)
    assert main(["campaign", "run", "plans/fixed.toml", "--out", "s", "--yes", "--quiet"]) == 0
    start = SessionReader(tmp_path / "s").start()
    assert start.config["extrinsics"]["calib_dir"] == str((plans / "cal").resolve())  # was "plans/cal"
    lines = (tmp_path / "s" / "documents.jsonl").read_text().splitlines(keepends=True)
    (tmp_path / "s" / "documents.jsonl").write_text("".join(lines[:-1]))  # interrupted before its stop
    monkeypatch.chdir(plans)
    assert main(["campaign", "run", str(plans / "fixed.toml"), "--out", "../s", "--yes", "--quiet",
                 "--resume"]) == 0  # was: "cannot resume with a different config: ... calib_dir"
    (plans / "cal").rename(tmp_path / "moved")
    assert main(["replay", "../s"]) == 0  # was: "extrinsics.calib_dir: ... calibration file not found"


@pytest.mark.replay
@pytest.mark.slow  # a replay of the small session (~1 s)
def test_a_torn_recording_replays_what_is_complete_and_says_what_is_left_out(small_copy, capfd):
    data = (small_copy / "documents.jsonl").read_bytes()
    (small_copy / "documents.jsonl").write_bytes(data[: len(data) - 200])  # cut inside the last result
    assert main(["replay", str(small_copy)]) == 0
    out = capfd.readouterr().out
    assert "1 identical" in out  # the configuration whose result is complete
    assert "torn last line" in out and "no 'stop' document (interrupted)" in out  # was silent


@pytest.mark.slow  # a campaign and a replay (~5 s)
@pytest.mark.parametrize("mode", ["fixed", "nominal"])
def test_a_session_replays_after_its_calib_dir_moved(small_reference, tmp_path, mode):
    shutil.copytree(next((small_reference / "calib").glob("*/a1")), tmp_path / "cal")
    (tmp_path / "plan.toml").write_text(SMALL + f'\n[extrinsics]\nmode = "{mode}"\ncalib_dir = "cal"\n')
    assert main(["campaign", "run", str(tmp_path / "plan.toml"), "--out", str(tmp_path / "s"), "--yes",
                 "--quiet"]) == 0
    (tmp_path / "cal").rename(tmp_path / "moved")
    assert main(["replay", str(tmp_path / "s")]) == 0  # nominal was: "extrinsics.calib_dir: ... not found"


@pytest.mark.slow  # a campaign and a replay (~5 s)
def test_a_session_replays_after_its_rig_config_file_moved(tmp_path):
    (tmp_path / "rig.toml").write_text("# the default mapping and limits\n")
    (tmp_path / "plan.toml").write_text(SMALL.replace("[rig]\n", '[rig]\nconfig_file = "rig.toml"\n'))
    assert main(["campaign", "run", str(tmp_path / "plan.toml"), "--out", str(tmp_path / "s"), "--yes",
                 "--quiet"]) == 0
    (tmp_path / "rig.toml").rename(tmp_path / "moved.toml")
    assert main(["replay", str(tmp_path / "s"), "--out", str(tmp_path / "r")]) == 0  # was: no such rig config file
    assert main(["replay", str(tmp_path / "r")]) == 0  # the replay's session carries the copy too
