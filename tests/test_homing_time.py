"""The homing cycle as the firmware runs it, in the emulator and in the plan's estimate.

limits.c ``limits_go_home`` (Grbl 1.1h; grblHAL's machine_limits.c ``homing_cycle`` is the same sequence): per
cycle of config.h (HOMING_CYCLE_0 = Z, then X and Y) a seek to the switches at ``$25`` over 1.5 x the cycle's
longest ``$13x``, a pull-off of ``$27`` at ``$25``, a locate at ``$24`` over 5 x ``$27``, a last pull-off; each
move followed by the ``$26`` debounce. The old emulator moved every axis at once at the seek rate and added a
fixed 0.5 s (3.5 s where the firmware takes 10-15 s), and the plan counted the longest travel plus that 0.5 s.
"""

from __future__ import annotations

import pytest

from drivers.rig.config import RigConfig
from drivers.rig.grbl import GrblController
from drivers.rig.motion import REFERENCE_AXIS_MOTION, HomingSettings, homing_time_s
from drivers.sim.grbl.emulator import GrblEmulator
from stereo_bench.campaign.plan import homing_estimate_s

# Simulated seconds are measured around the driver's $H, so its round trips (a few ms real, more on a loaded host)
# count x SCALE: 10 keeps them to a few per cent of a 2-14 s cycle.
SCALE = 10.0


def _homing_sim_s(emu: GrblEmulator) -> float:
    """Simulated seconds from ``$H`` to its ``ok``, through the real driver."""
    with GrblController(emu.tty_path, connect_timeout_s=3.0, poll_interval_s=0.02) as grbl:
        t0 = emu.sim_time()
        grbl.home(timeout=60.0)
        return emu.sim_time() - t0


@pytest.mark.parametrize("simulated", [True, False], ids=["simulated-rig-at-power-up", "real-rig-at-the-far-end"])
def test_the_plan_predicts_the_emulators_homing_within_20_percent(simulated):
    travel = RigConfig().machine_travel()
    predicted = homing_estimate_s(travel, simulated=simulated)
    # Where the plan assumes the axes stand: machine 0 on the simulated rig, else the far end of each range.
    start = {} if simulated else {axis: low for axis, (low, _high) in travel.items()}
    with GrblEmulator(time_scale=SCALE, start_position=start) as emu:
        measured = _homing_sim_s(emu)
    assert measured == pytest.approx(predicted, rel=0.20)
    if not simulated:
        assert measured > 3.5 * 2  # a seek of 348 mm: not the old 3.5 s


def test_the_emulators_homing_follows_the_firmwares_settings():
    # defaults.h: $24=25, $25=500 mm/min, $26=250 ms, $27=1; X 200 mm, Y 30 deg and Z 10 deg from their switches.
    defaults = HomingSettings(seek_rate_per_min=500.0, feed_rate_per_min=25.0, debounce_ms=250.0, pulloff=1.0)
    with GrblEmulator(time_scale=SCALE, homing_seek_rate_per_min=500.0, homing_feed_rate_per_min=25.0,
                      homing_debounce_ms=250.0, start_position={"X": -200.0, "Y": -30.0, "Z": -10.0}) as emu:
        measured = _homing_sim_s(emu)
        assert emu.physical_position() == {"X": -1.0, "Y": -1.0, "Z": -1.0}
    expected = homing_time_s({"X": 200.0, "Y": 30.0, "Z": 10.0}, max_travel={"X": 350.0, "Y": 90.0, "Z": 90.0},
                             homing=defaults,
                             max_rate_per_min={a: REFERENCE_AXIS_MOTION[a].max_rate_per_min for a in "XYZ"},
                             acceleration={a: REFERENCE_AXIS_MOTION[a].acceleration for a in "XYZ"})
    # By hand: seeks of 10 mm (Z) and 200 mm (X, with Y) at 8.33 mm/s, 1.22 + 24.02 s; per cycle a locate of 1 mm at
    # 0.417 mm/s (2.4 s), two pull-offs of 1 mm (0.166 s each) and four debounces (1 s): 32.7 s in all.
    assert expected == pytest.approx(1.22 + 24.02 + 2 * (2.4 + 2 * 0.166 + 1.0), abs=0.05)
    assert measured == pytest.approx(expected, rel=0.10)
