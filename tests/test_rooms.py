"""The rooms of issue 21 item 4: each split file's names live in one room, and the faces still hand them on."""

from __future__ import annotations

import importlib

import pytest

import drivers.rig.grbl as grbl
import stereo_bench.kinematics as kinematics
from tests.test_layering import imports, modules


def test_the_grbl_driver_still_exports_every_name_it_did_from_the_rooms_that_hold_them():
    from drivers.rig import grbl_errors, grbl_reports

    for name in grbl.__all__:
        assert hasattr(grbl, name), name
    assert grbl.GrblReading is grbl_reports.GrblReading and grbl.ControllerInfo is grbl_reports.ControllerInfo
    for name in ("GrblError", "GrblAlarm", "GrblPositionUnknown", "GrblTimeout", "GrblConnectionLost"):
        assert getattr(grbl, name) is getattr(grbl_errors, name)
    assert grbl.MoveStatus.__module__ == grbl.GrblController.__module__ == "drivers.rig.grbl"


@pytest.mark.parametrize("name", kinematics.__all__)
def test_the_kinematics_face_hands_on_each_name_from_its_room(name):
    value = getattr(kinematics, name)
    homes = [m for m in ("model", "nominal", "design", "file", "prediction", "fit")
             if getattr(importlib.import_module(f"stereo_bench.kinematics.{m}"), name, None) is value
             and (not hasattr(value, "__module__") or isinstance(value, (str, tuple, int, float, dict))
                  or value.__module__ == f"stereo_bench.kinematics.{m}")]
    assert homes, name


def test_the_simulated_controllers_data_rooms_import_none_of_each_other():
    rooms = {m for m in modules() if m.startswith("drivers.sim.grbl.")}
    assert rooms == {f"drivers.sim.grbl.{m}" for m in ("emulator", "firmware", "planner", "faults")}
    for room in rooms - {"drivers.sim.grbl.emulator"}:
        assert not {t for t in imports()[room] if t.startswith("drivers.sim.grbl")}, room
    assert {t for t in imports()["drivers.sim.grbl.emulator"] if t.startswith("drivers.sim.grbl.")} == \
        rooms - {"drivers.sim.grbl.emulator"}
