"""Every command's ``--help`` answers on its own: no other flag is needed to read it (issue 24)."""

from __future__ import annotations

import argparse

import pytest

from stereo_bench.cli import build_parser, main
from stereo_bench.cli.rig import ACTIONS, CALIBRATE_KINEMATICS


def _commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every command path of the parser tree, e.g. ('campaign', 'run')."""
    found = [prefix]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += _commands(sub, (*prefix, name))
    return found


COMMANDS = _commands(build_parser())
# rig's actions are parsed by the rig command itself (one connection runs several): each has its own --help.
RIG_ACTIONS = [("rig", action) for action in (*ACTIONS, CALIBRATE_KINEMATICS)]


def test_the_walk_finds_the_commands():
    assert ("campaign", "run") in COMMANDS and ("rig",) in COMMANDS and ("live",) in COMMANDS
    assert len(COMMANDS) > 15, COMMANDS


@pytest.mark.parametrize("command", COMMANDS + RIG_ACTIONS, ids=lambda c: " ".join(c) or "stereo-bench")
def test_help_needs_no_other_flag(command, capsys):
    try:
        code = main([*command, "--help"])
    except SystemExit as done:  # a command that parses its own options (rig calibrate-kinematics): as the CLI exits
        code = done.code or 0
    out, err = capsys.readouterr()
    assert code == 0, (command, err)
    assert "usage:" in out + err, (command, out, err)
    assert "error" not in err.lower(), err
