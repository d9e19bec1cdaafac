"""The layering rules of docs/ARCHITECTURE.md, enforced on the source: the next forbidden import fails here.

Every ``import`` and ``from ... import`` of the two packages is read with ``ast`` (top level, inside
functions and under TYPE_CHECKING alike), resolved to the module it names, and checked against the rules.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("stereo_bench", "drivers")

# Modules anything may import: the conventions (leaf modules) and small helpers with no dependencies.
LEAVES = {"stereo_bench", "stereo_bench.geometry", "stereo_bench.targets", "stereo_bench.atomic",
          "stereo_bench.executors", "stereo_bench.frames", "stereo_bench.paths"}
# stereo_bench's layers, lowest first: a module may import its own layer and the ones below it.
LAYERS = [
    ("vision", {"stereo_bench.vision"}),
    # the kinematic rig model: pure math on the conventions and vision's calibration; campaigns and the CLI use it
    ("kinematics", {"stereo_bench.kinematics"}),
    ("models", {"stereo_bench.campaign", "stereo_bench.errormodel"}),
    ("report", {"stereo_bench.report"}),
    ("live", {"stereo_bench.live"}),  # the live page: a subscriber and operator of campaigns, served by the CLI
    ("cli", {"stereo_bench.cli", "stereo_bench.__main__"}),
]
# The one library module that may import the simulators (the simulated-bench factory); the CLI, which
# wires everything, may too (sim-controller serves the emulator, vision render draws with the renderer).
SIMULATOR_USERS = {"stereo_bench.campaign.bench"}
# Simulator schemas: pure pydantic data describing a simulator (no simulator code), which a campaign config
# embeds, so any module may import them; they import no project module, so nothing of the simulators
# comes with them.
SIMULATOR_SCHEMAS = {"drivers.sim.profile"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


@cache
def modules() -> dict[str, Path]:
    return {_module_name(path): path for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))}


@cache
def imports() -> dict[str, set[str]]:
    """module -> the project modules it imports (``from pkg import sub`` resolves to ``pkg.sub``)."""
    known = modules()
    graph: dict[str, set[str]] = {}
    for name, path in known.items():
        found: set[str] = set()
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + [base]).strip(".")
                for alias in node.names:
                    found.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base)
        graph[name] = {target for target in found if target.split(".")[0] in PACKAGES and target != name}
    return graph


def _in(module: str, prefixes: set[str]) -> bool:
    return any(module == prefix or module.startswith(prefix + ".") for prefix in prefixes)


def _layer(module: str) -> int | None:
    for index, (_, prefixes) in enumerate(LAYERS):
        if _in(module, prefixes):
            return index
    return None


def violations(graph: dict[str, set[str]] | None = None) -> list[str]:
    found = []
    for module, targets in sorted((graph or imports()).items()):
        for target in sorted(targets):
            edge = f"{module} imports {target}"
            if module in SIMULATOR_SCHEMAS:
                found.append(f"{edge}: {module} is a simulator schema (pure data): it imports no project module")
            if module.startswith("drivers"):
                if target.startswith("stereo_bench") and not (
                        module.startswith("drivers.sim") and target in {"stereo_bench.geometry",
                                                                         "stereo_bench.targets"}):
                    found.append(f"{edge}: drivers/ never imports the app (drivers/sim: only geometry, targets)")
                if target.startswith("drivers.sim") and not module.startswith("drivers.sim"):
                    found.append(f"{edge}: only the simulators import the simulators")
                continue
            if module in LEAVES and target.startswith(PACKAGES) and target not in LEAVES:
                found.append(f"{edge}: {module} is a leaf module")
            if target.startswith("drivers.sim") and target not in SIMULATOR_SCHEMAS and module not in SIMULATOR_USERS \
                    and _layer(module) != len(LAYERS) - 1:
                found.append(f"{edge}: outside the CLI only {', '.join(sorted(SIMULATOR_USERS))} imports drivers.sim")
            here, there = _layer(module), _layer(target)
            if here is not None and there is not None and there > here:
                found.append(f"{edge}: {LAYERS[here][0]} must not import the {LAYERS[there][0]} layer above it")
            if _in(module, {"stereo_bench.campaign"}) and _in(target, {"stereo_bench.errormodel"}) or \
                    _in(module, {"stereo_bench.errormodel"}) and _in(target, {"stereo_bench.campaign"}):
                found.append(f"{edge}: campaign and errormodel are independent")
    return found


def cycles(graph: dict[str, set[str]] | None = None) -> list[list[str]]:
    """Import cycles between modules (each found once, from its smallest module name)."""
    graph = graph or imports()
    found: list[list[str]] = []
    for start in sorted(graph):
        stack = [(start, [start])]
        seen = set()
        while stack:
            node, path = stack.pop()
            for target in graph.get(node, ()):
                if target == start:
                    if min(path) == start:
                        found.append(path + [start])
                elif target not in seen and target in graph:
                    seen.add(target)
                    stack.append((target, path + [target]))
    return found


def test_every_module_follows_the_layering_rules():
    assert violations() == []


def test_no_two_modules_import_each_other():
    assert cycles() == []


def test_the_checker_sees_forbidden_imports():
    """The rules are not vacuous: planting the imports issue 8 found (and others) makes them fail."""
    planted = {module: set(targets) for module, targets in imports().items()}
    planted["stereo_bench.campaign.plan"].add("drivers.sim.grbl.emulator")
    planted["stereo_bench.report.html"].add("stereo_bench.report.build")
    planted["drivers.rig.rig"].add("stereo_bench.campaign.config")
    planted["drivers.sim.render"].add("stereo_bench.vision.detect")
    planted["stereo_bench.vision.detect"].add("stereo_bench.campaign.plan")
    planted["stereo_bench.geometry"].add("stereo_bench.vision.calibrate")
    planted["drivers.sim.profile"].add("drivers.sim.mechanics")
    planted["drivers.sim.profile"].add("stereo_bench.geometry")
    planted["stereo_bench.campaign.config"].add("drivers.sim.bench")
    found = "\n".join(violations(planted))
    for edge in ("stereo_bench.campaign.plan imports drivers.sim.grbl.emulator",
                 "drivers.rig.rig imports stereo_bench.campaign.config",
                 "drivers.sim.render imports stereo_bench.vision.detect",
                 "stereo_bench.vision.detect imports stereo_bench.campaign.plan",
                 "stereo_bench.geometry imports stereo_bench.vision.calibrate",
                 "drivers.sim.profile imports drivers.sim.mechanics",
                 "drivers.sim.profile imports stereo_bench.geometry",
                 "stereo_bench.campaign.config imports drivers.sim.bench"):
        assert edge in found
    assert ["stereo_bench.report.build", "stereo_bench.report.html", "stereo_bench.report.build"] in cycles(planted)


@pytest.mark.parametrize("module", ["stereo_bench.campaign.plan", "stereo_bench.campaign.runner",
                                    "stereo_bench.campaign.execute", "stereo_bench.campaign.presenters",
                                    *(f"stereo_bench.campaign.plan.{name}" for name in (
                                        "configurations", "duration", "feasibility", "steps", "summary", "timing")),
                                    *(f"stereo_bench.campaign.execute.{name}" for name in (
                                        "control", "options", "planned", "replay", "run"))])
def test_the_campaign_reaches_the_simulators_only_through_the_bench_factory(module):
    assert not any(target.startswith("drivers.sim") for target in imports()[module])


def test_the_campaign_config_takes_the_simulated_bench_profile_from_its_schema_module_only():
    """[sim] is validated with the simulator's own schema, and that is all the config imports of drivers.sim."""
    assert {t for t in imports()["stereo_bench.campaign.config"] if t.startswith("drivers.sim")} == SIMULATOR_SCHEMAS
    assert imports()["drivers.sim.profile"] == set()


def test_the_kinematic_model_is_a_layer_between_vision_and_the_campaign():
    """kinematics may use vision (calibration, pixel locking) and the leaves; campaigns and the CLI use it."""
    assert [name for name, _ in LAYERS].index("kinematics") == [name for name, _ in LAYERS].index("vision") + 1
    planted = {module: set(targets) for module, targets in imports().items()}
    planted["stereo_bench.kinematics.fit"].add("stereo_bench.campaign.config")
    planted["stereo_bench.vision.calibrate"].add("stereo_bench.kinematics.model")
    found = "\n".join(violations(planted))
    assert "stereo_bench.kinematics.fit imports stereo_bench.campaign.config: kinematics must not import" in found
    assert "stereo_bench.vision.calibrate imports stereo_bench.kinematics.model: vision must not import" in found
    assert any(target.startswith("stereo_bench.kinematics") for target in imports()["stereo_bench.campaign.sources"])


#: The one room above the others: the fixed-board fit (issue 25) is the joint fit with one shared board pose, and
#: stands on the fit's projection, PnP, start and solver and on the design's configurations.
KINEMATICS_UPPER_ROOMS = {"stereo_bench.kinematics.fixed_board": {"stereo_bench.kinematics.model",
                                                                  "stereo_bench.kinematics.fit",
                                                                  "stereo_bench.kinematics.design"}}


def test_the_kinematics_rooms_stand_on_its_model_alone():
    """Inside the package each room imports only ``model`` of its siblings (the face, __init__, imports them all),
    but the upper room (KINEMATICS_UPPER_ROOMS), which nothing in the package imports."""
    rooms = [m for m in modules() if m.startswith("stereo_bench.kinematics.")]
    assert "stereo_bench.kinematics.model" in rooms and len(rooms) >= 5
    for room in rooms:
        siblings = {t for t in imports()[room] if t.startswith("stereo_bench.kinematics")}
        assert siblings <= KINEMATICS_UPPER_ROOMS.get(room, {"stereo_bench.kinematics.model"}), room
        assert not siblings & set(KINEMATICS_UPPER_ROOMS), room
