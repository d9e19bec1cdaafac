#!/usr/bin/env python3
"""Rig-controller latency through the GRBL emulator on a pty: connect, ``?`` status queries, small move + wait.

    python scripts/bench_rig.py [--queries 2000] [--moves 50] [--move-mm 0.1] [--connects 20] [--time-scale 1]
                                [--out bench_rig.json]

Four figures (median, p95, p99, max; milliseconds):

- connect: ``GrblController.open()`` + ``close()``: listen for a boot (one ``?``), soft reset and
  banner, ``?``, then ``$I``, ``$$``, ``$N`` read and checked;
- raw pty round trip: pyserial writes ``?`` and reads the report line, no driver (the floor);
- driver status query: ``GrblController.status()`` through its reader thread;
- small move + wait: ``move_to({"X": -10 - move_mm}).wait()`` (line, ``ok``, ``G4 P0``, ``ok``, ``?``),
  with the simulated motion time alongside so the driver's overhead can be read off.

Target: status query <= 2 ms median. Prints a table and writes JSON (with the load average: other
programs share the machine).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import serial

from drivers.rig.grbl import GrblController
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.firmware import DEFAULT_AXES

STATUS_TARGET_MS = 2.0

RESULTS = Path(__file__).resolve().parent / "results"  # where the latest run of each benchmark is kept


def summarise(samples_s: list[float]) -> dict[str, float]:
    ms = sorted(s * 1000.0 for s in samples_s)

    def pct(p: float) -> float:
        return ms[min(len(ms) - 1, max(0, math.ceil(p / 100.0 * len(ms)) - 1))]

    return {"n": len(ms), "median": statistics.median(ms), "p95": pct(95), "p99": pct(99), "max": ms[-1],
            "mean": statistics.fmean(ms)}


def bench_raw_pty(emulator: GrblEmulator, n: int) -> list[float]:
    port = serial.Serial(emulator.tty_path, 115200, timeout=1.0)
    try:
        samples = []
        for _ in range(n):
            t0 = time.perf_counter()
            port.write(b"?")
            line = port.readline()
            samples.append(time.perf_counter() - t0)
            if not line.startswith(b"<"):
                raise RuntimeError(f"unexpected reply {line!r}")
        return samples
    finally:
        port.close()


def bench_connect(emulator: GrblEmulator, n: int) -> list[float]:
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        grbl = GrblController(emulator.tty_path).open()
        grbl.close()
        samples.append(time.perf_counter() - t0)
        if not grbl.info.settings_read:
            raise RuntimeError("connect did not read the settings")
    return samples


def bench_status(grbl: GrblController, n: int) -> list[float]:
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        grbl.status(timeout=1.0)
        samples.append(time.perf_counter() - t0)
    return samples


def motion_time_s(distance: float, rate_per_min: float, accel: float) -> float:
    """Rest-to-rest trapezoidal move time (s) the emulator simulates for one axis."""
    speed = rate_per_min / 60.0
    if speed * speed / accel >= distance:
        return 2.0 * math.sqrt(distance / accel)
    return distance / speed + speed / accel


def bench_moves(grbl: GrblController, n: int, move_mm: float, base_mm: float) -> list[float]:
    samples = []
    for i in range(n):
        target = base_mm - (move_mm if i % 2 == 0 else 0.0)  # Grbl's machine space is negative
        t0 = time.perf_counter()
        reading = grbl.move_to({"X": target}, timeout_s=30.0).wait(30.0)
        samples.append(time.perf_counter() - t0)
        if abs(reading.machine_position["X"] - target) > 1e-6:
            raise RuntimeError(f"move ended at {reading.machine_position} instead of X={target}")
    return samples


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("--queries", type=int, default=2000, help="status queries to time")
    parser.add_argument("--moves", type=int, default=50, help="small moves to time")
    parser.add_argument("--move-mm", type=float, default=0.1, help="size of each small move, mm")
    parser.add_argument("--connects", type=int, default=20, help="connects (open + close) to time")
    parser.add_argument("--time-scale", type=float, default=1.0, help="emulator time scale (1 = real time)")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_rig.json",
                        help="JSON results file (default: scripts/results/, where the latest run is kept)")
    args = parser.parse_args(argv)

    load_before = os.getloadavg()
    with GrblEmulator(time_scale=args.time_scale) as emulator:
        connects = bench_connect(emulator, args.connects)
        raw = bench_raw_pty(emulator, min(args.queries, 1000))
        with GrblController(emulator.tty_path) as grbl:
            grbl.home(timeout=60.0)
            bench_status(grbl, 50)  # warm-up
            status = bench_status(grbl, args.queries)
            base = -10.0
            grbl.move_to({"X": base}).wait(60.0)
            moves = bench_moves(grbl, args.moves, args.move_mm, base)
            lost, garbled = grbl.lost_replies, grbl.garbled_lines

    x = DEFAULT_AXES["X"]
    motion_ms = motion_time_s(args.move_mm, x.max_rate_per_min, x.acceleration) / args.time_scale * 1000.0
    results = {
        "benchmark": "rig controller latency through the GRBL emulator on a pty",
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "pyserial": serial.__version__,
        "time_scale": args.time_scale,
        "move_mm": args.move_mm,
        "load_average_1_5_15_min": {"before": list(load_before), "after": list(os.getloadavg())},
        "connect_ms": summarise(connects),
        "raw_pty_status_round_trip_ms": summarise(raw),
        "driver_status_query_ms": summarise(status),
        "small_move_and_wait_ms": summarise(moves),
        "small_move_simulated_motion_ms": motion_ms,
        "status_target_median_ms": STATUS_TARGET_MS,
        "status_target_met": statistics.median(status) * 1000.0 <= STATUS_TARGET_MS,
        "lost_replies": lost,
        "garbled_lines": garbled,
    }

    rows = [("connect ($I $$ $N read)", results["connect_ms"]),
            ("raw pty '?' round trip", results["raw_pty_status_round_trip_ms"]),
            ("driver status()", results["driver_status_query_ms"]),
            (f"move {args.move_mm:g} mm + wait", results["small_move_and_wait_ms"])]
    print(f"{'measurement':<28} {'n':>6} {'median':>9} {'p95':>9} {'p99':>9} {'max':>9}   (ms)")
    for name, s in rows:
        print(f"{name:<28} {s['n']:>6} {s['median']:>9.3f} {s['p95']:>9.3f} {s['p99']:>9.3f} {s['max']:>9.3f}")
    overhead = results["small_move_and_wait_ms"]["median"] - motion_ms
    print(f"simulated motion of one {args.move_mm:g} mm move: {motion_ms:.3f} ms "
          f"(time scale {args.time_scale:g}); driver + protocol overhead ~ {overhead:.3f} ms median")
    print(f"load average (1, 5, 15 min): before {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}, "
          f"after {os.getloadavg()[0]:.2f}")
    verdict = "met" if results["status_target_met"] else "MISSED"
    print(f"status query target <= {STATUS_TARGET_MS:g} ms median: {verdict}")
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
