"""The bench clock (drivers/sim/clock.py), the emulator's motion events on it, and the draws keyed by configuration."""

from __future__ import annotations

import math
import time

import pytest

from drivers.rig.motion import trapezoid
from drivers.rig.rig import GrblRig
from drivers.sim.bench import BenchSimulator
from drivers.sim.clock import BenchClock
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.firmware import DEFAULT_AXES
from drivers.sim.profile import LAB
from stereo_bench.geometry import CameraModel
from stereo_bench.targets import Checkerboard


class Wall:
    """A real clock the test sets."""

    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_the_clock_is_frozen_while_nothing_is_pending_and_advances_only_when_told():
    wall = Wall()
    clock = BenchClock(10.0, wall=wall)
    wall.t += 5.0
    assert clock.now() == 0.0 and not clock.running
    assert clock.advance(0.25) == 0.25
    wall.t += 5.0
    assert clock.now() == 0.25
    assert clock.real_seconds_until(1.0) == math.inf  # frozen: it will not get there by itself


def test_the_clock_runs_paced_by_the_wall_and_stops_at_the_exact_end_of_the_activity():
    wall = Wall()
    clock = BenchClock(10.0, wall=wall)
    end = 0.1 + 0.2  # 0.30000000000000004: the end is the float the emulator computed, not a wall reading
    clock.run_until(end)
    assert clock.running and clock.real_seconds_until(end) == pytest.approx(end / 10.0)
    wall.t += 0.01
    assert clock.now() == pytest.approx(0.1)
    wall.t += 3.0  # the emulator noticed the end late (a loaded machine)
    assert clock.now() == end and clock.real_seconds_until(end) == 0.0
    assert clock.freeze() == end
    wall.t += 3.0
    assert clock.now() == end and not clock.running
    clock.run_until(end - 1.0)  # an end already passed: frozen where it is
    assert clock.now() == end and not clock.running
    with pytest.raises(ValueError):
        clock.advance(-1.0)
    with pytest.raises(ValueError):
        BenchClock(0.0)


def test_a_move_starts_at_the_frozen_time_and_ends_exactly_when_the_motion_model_says():
    """The line arrives whenever the driver sends it in real time; the block starts at the bench time the clock
    froze at (the end of homing) and ends t_start + duration later, reported as such to the listener."""
    events = []
    clock = BenchClock(20.0)
    with GrblEmulator(clock=clock, on_motion=events.append) as emulator, \
            GrblRig(emulator.tty_path) as rig:
        rig.home()
        homed_at = clock.now()
        time.sleep(0.05)  # real time passes: the bench's does not
        assert clock.now() == homed_at and not clock.running
        rig.move_to(baseline_mm=100.0).wait()
        time.sleep(0.05)
        assert clock.now() == events[-1].end_s
    home, move = events
    assert home.kind == "home" and home.end_s == homed_at and home.approach == {"X": -1, "Y": -1, "Z": -1}
    spec = DEFAULT_AXES["X"]
    duration = trapezoid(abs(move.end["X"] - move.start["X"]), spec.max_rate_per_min / 60.0, spec.acceleration)
    assert move.kind == "move" and move.start_s == homed_at and move.approach == {"X": -1}
    assert move.end_s == pytest.approx(homed_at + duration.duration_s, abs=1e-12)
    assert move.end["X"] == -250.0  # B = 100 mm: machine X = B - 350, whole steps


HALF = {"image_size": (960, 540), "pixel_um": 6.0}


def _bench(seed: int = 3) -> BenchSimulator:
    return BenchSimulator(time_scale=50.0, profile=LAB, seed=seed, left=CameraModel.from_sensor(name="left", **HALF),
                          right=CameraModel.from_sensor(name="right", **HALF))


TARGETS = {"baseline_mm": 150.0, "toe_in_left_deg": 3.0, "toe_in_right_deg": 3.0}


def _landings(bench: BenchSimulator) -> dict[str, float]:
    return {q: entry["landing"] for q, entry in bench.history.snapshot().items()}


def test_a_landing_is_keyed_by_where_the_plan_arrived_not_by_the_moves_before_it():
    """Arriving at configuration "c3" from the plan's previous one, or after homing and a re-approach (a resume),
    draws the same landing errors for the axes that end at its targets; another arrival draws others."""
    arrivals = {"baseline_mm": "c3", "toe_in_left_deg": "c2", "toe_in_right_deg": "c2"}
    with _bench() as first, GrblRig(first.tty_path, first.rig_config) as rig:
        rig.home()
        first.begin_configuration("c2", targets={**TARGETS, "baseline_mm": 100.0},
                                  arrivals={q: "c2" for q in TARGETS})
        rig.move_to(baseline_mm=100.0, toe_in_left_deg=3.0, toe_in_right_deg=3.0).wait()
        first.begin_configuration("c3", targets=TARGETS, arrivals=arrivals)
        rig.move_to(baseline_mm=150.0).wait()  # the heads stay: their landing is c2's
        direct = _landings(first)
    with _bench() as second, GrblRig(second.tty_path, second.rig_config) as rig:
        rig.home()
        second.begin_configuration("c0", targets={**TARGETS, "baseline_mm": 200.0}, arrivals={q: "c0" for q in TARGETS})
        rig.move_to(baseline_mm=200.0, toe_in_left_deg=10.0, toe_in_right_deg=10.0).wait()  # other moves first
        rig.home()  # as a resume does
        second.begin_configuration("c3", targets=TARGETS, arrivals=arrivals)
        rig.move_to(baseline_mm=100.0).wait()  # the re-approach: not an arrival at c3's targets
        rig.move_to(baseline_mm=100.0, toe_in_left_deg=3.0, toe_in_right_deg=3.0).wait()
        rig.move_to(baseline_mm=150.0).wait()
        assert _landings(second) == direct
        second.begin_configuration("c9", targets={**TARGETS, "baseline_mm": 120.0},
                                   arrivals={**arrivals, "baseline_mm": "c9"})
        rig.move_to(baseline_mm=120.0).wait()
        rig.move_to(baseline_mm=150.0).wait()  # back at 150 mm, but not arriving at c9's target: a transit draw
        assert _landings(second)["baseline_mm"] != direct["baseline_mm"]


def test_a_named_placement_is_the_same_whatever_was_placed_before():
    board = Checkerboard(9, 6, 27.0)
    with _bench() as first, _bench() as second:
        placed = first.place_target(board, distance_mm=450.0, placement="c1")
        second.place_target(board, distance_mm=450.0, placement="c0")
        second.place_target(board, distance_mm=500.0, placement="c1b")
        again = second.place_target(board, distance_mm=450.0, placement="c1")
        assert (placed == again).all()
        assert first.truth()["target"]["placement"] == second.truth()["target"]["placement"]
        assert (second.place_target(board, distance_mm=450.0, placement="c7") != placed).any()
