"""Digests of recorded and replayed sessions: does a change leave every recorded number as it was?

    python scripts/session_digest.py record DIR          # record the reference sessions (one per extrinsics mode)
    python scripts/session_digest.py digest DIR/* calib_data/sample_session --json before.json
    ... change the code ...
    python scripts/session_digest.py record DIR2 && python scripts/session_digest.py digest DIR2/* ... --json after.json
    python scripts/session_digest.py compare before.json after.json

A session's digest is a SHA-256 over its ``documents.jsonl`` read as plain JSON lines (never through
stereo-bench's own reader, which a refactor may change), with what differs between two runs of one plan
by design left out: wall-clock times, durations, versions, the numeric environment, host and paths (the keys
in ``VOLATILE``, wherever they appear). Its replay's digest is the same over the session a
``stereo-bench replay SESSION --out`` records, run as a subprocess, so that a change to the replay path
shows too. The simulated bench is a function of its seed and plan (docs/SIMULATED_BENCH.md), so two
recordings of one plan by the same code have one digest; ``record`` twice and ``compare`` checks that first.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.campaigns import LAB, SMALL  # noqa: E402 - the tests' small campaigns, not written again here

#: Keys whose values differ between two runs of one plan by design (wherever they stand in a document).
VOLATILE = frozenset({
    "time", "monotonic", "software", "numeric_environment", "host", "replay_of", "resume_command", "waited_s",
    "fit_s", "elapsed_s", "timestamp", "timestamp_s", "port", "tty", "path", "session", "out", "transcript",
    "started", "duration_s", "uid", "seq",
})

#: The reference sessions: (name, campaign TOML). Small plans on half-resolution cameras: seconds each.
CAMPAIGNS = {
    "per-config-ideal": SMALL,
    "per-config-lab": LAB,
    "kinematic-lab": LAB + '[extrinsics]\nmode = "kinematic"\n',
    "nominal-lab": LAB + '[extrinsics]\nmode = "nominal"\n',
    "keep-measurement-lab": LAB.replace("[capture]\n", '[capture]\nkeep_frames = "measurement"\n'),
}


def normalised(value, session: Path | None = None, root: Path | None = None):
    """``value`` with every VOLATILE key left out (recursively), each frame file it names replaced by the
    SHA-256 of its bytes (a frame's name carries its arrival number; its pixels are what must not change), and
    the directory the sessions were recorded in written as ``<recording root>``."""
    if isinstance(value, dict):
        return {k: normalised(v, session, root) for k, v in sorted(value.items()) if k not in VOLATILE}
    if isinstance(value, list):
        return [normalised(v, session, root) for v in value]
    if session is not None and isinstance(value, str) and value.startswith("frames/") and value.endswith(".png"):
        return "png " + hashlib.sha256((session / value).read_bytes()).hexdigest()
    if session is not None and isinstance(value, str):
        # Files beside the session (fixed-calib/) are named by where the reference set was recorded.
        return value.replace(str(root or session.resolve().parent), "<recording root>")
    return value


def stream_digest(session: Path, root: Path | None = None) -> tuple[str, int]:
    """(SHA-256 of the normalised documents, documents). Taken as a sorted multiset: analyses run beside the
    captures, so a configuration's result may be written before or after the next one's first frames (``seq``
    numbers arrival), while what each document holds is fixed."""
    lines = []
    with (session / "documents.jsonl").open("rb") as stream:
        for line in stream:
            if line.strip():
                lines.append(json.dumps(normalised(json.loads(line), session, root), sort_keys=True))
    digest = hashlib.sha256()
    for line in sorted(lines):
        digest.update(line.encode())
        digest.update(b"\n")
    return digest.hexdigest(), len(lines)


def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stereo_bench", *argv], cwd=REPO, capture_output=True, text=True,
                          check=False)


def record(root: Path) -> None:
    root.mkdir(parents=True, exist_ok=True)
    for name, text in CAMPAIGNS.items():
        plan = root / f"{name}.toml"
        plan.write_text(text)
        done = _cli("campaign", "run", str(plan), "--out", str(root / name), "--yes")
        print(f"{name:24s} exit {done.returncode}")
        if done.returncode:
            print(done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "(nothing on stderr)")
    # Fixed extrinsics: a calibration the per-config session made, read from a calib_dir.
    made = next(path.parent for path in sorted((root / "per-config-lab" / "calib").rglob("extrinsics.yml")))
    calib = root / "fixed-calib"
    shutil.copytree(made, calib, dirs_exist_ok=True)
    plan = root / "fixed-lab.toml"
    plan.write_text(LAB + f'[extrinsics]\nmode = "fixed"\ncalib_dir = "{calib}"\n')
    done = _cli("campaign", "run", str(plan), "--out", str(root / "fixed-lab"), "--yes")
    print(f"{'fixed-lab':24s} exit {done.returncode}")
    if done.returncode:
        print(done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "(nothing on stderr)")


def digest(sessions: list[Path]) -> dict[str, dict]:
    out = {}
    for session in sessions:
        if not (session / "documents.jsonl").is_file():
            continue
        recorded, count = stream_digest(session)
        work = Path(tempfile.mkdtemp(prefix="digest-"))
        try:
            done = _cli("replay", str(session), "--out", str(work / "r"), "--json")
            replayed = None
            if (work / "r" / "documents.jsonl").is_file():
                replayed = stream_digest(work / "r", session.resolve().parent)[0]
            report = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
        finally:
            shutil.rmtree(work, ignore_errors=True)
        out[session.name] = {"documents": count, "recorded": recorded, "replay": replayed,
                             "replay_exit": done.returncode, "identical": report.get("identical"),
                             "compared": report.get("compared")}
        print(f"{session.name:24s} {count:5d} documents  recorded {recorded[:16]}  replay "
              f"{(replayed or '-')[:16]}  exit {done.returncode}  identical {report.get('identical')}/"
              f"{report.get('compared')}")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="action", required=True)
    sub.add_parser("record", help="record the reference sessions into DIR").add_argument("dir", type=Path)
    d = sub.add_parser("digest", help="digest sessions and their replays")
    d.add_argument("sessions", nargs="+", type=Path)
    d.add_argument("--json", type=Path, help="write the digests here")
    c = sub.add_parser("compare", help="compare two digest files")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.action == "record":
        record(args.dir)
        return 0
    if args.action == "digest":
        result = digest(args.sessions)
        if args.json:
            args.json.write_text(json.dumps(result, indent=1) + "\n")
        return 0
    before, after = json.loads(args.before.read_text()), json.loads(args.after.read_text())
    same = True
    for name in sorted(set(before) | set(after)):
        b, a = before.get(name, {}), after.get(name, {})
        for key in ("recorded", "replay", "replay_exit"):
            if b.get(key) != a.get(key):
                same = False
                print(f"{name}: {key} differs: {b.get(key)} -> {a.get(key)}")
    print("all digests equal" if same else "digests differ")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
