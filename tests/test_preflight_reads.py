"""Inputs resolved once by one preflight (issue 21 item 4): from `campaign run` to the first move, each input file
(the campaign TOML, the rig's config_file, calib_dir's files) is read from disk once, however many checks and parsers
take it (was: the campaign file 1, rig config_file 2, calib_dir's intrinsics.yml 9 times)."""

from __future__ import annotations

import collections
import shutil
from pathlib import Path

import pytest

import drivers.files as files
from stereo_bench.campaign.runner import CampaignRunner
from stereo_bench.cli import main
from tests.campaigns import SMALL


@pytest.mark.parametrize("mode", ["nominal", "fixed"])
def test_campaign_run_reads_each_input_file_once_before_the_first_move(small_reference, tmp_path, monkeypatch,
                                                                      mode):
    shutil.copytree(next((small_reference / "calib").glob("*/a1")), tmp_path / "cal")
    (tmp_path / "rig.toml").write_text("# the default mapping and limits\n")
    (tmp_path / "plan.toml").write_text(SMALL.replace("[rig]\n", '[rig]\nconfig_file = "rig.toml"\n')
                                        + f'\n[extrinsics]\nmode = "{mode}"\ncalib_dir = "cal"\n')
    reads: collections.Counter[Path] = collections.Counter()
    at_first_move: dict[Path, int] = {}
    read_from_disk = files._read_from_disk

    def counting(path, **kwargs):
        reads[Path(path).resolve()] += 1
        return read_from_disk(path, **kwargs)

    real_move = CampaignRunner._move

    def move(self, configuration):
        if not at_first_move:
            at_first_move.update(reads)
        return real_move(self, configuration)

    monkeypatch.setattr(files, "_read_from_disk", counting)
    monkeypatch.setattr(CampaignRunner, "_move", move)
    assert main(["campaign", "run", str(tmp_path / "plan.toml"), "--out", str(tmp_path / "s"), "--yes",
                 "--quiet"]) == 0
    inputs = {path.relative_to(tmp_path.resolve()).as_posix(): n for path, n in at_first_move.items()
              if path.is_relative_to(tmp_path.resolve()) and not path.is_relative_to((tmp_path / "s").resolve())}
    calib_files = {"cal/intrinsics.yml"} | ({"cal/extrinsics.yml"} if mode == "fixed" else set())
    assert inputs == {"plan.toml": 1, "rig.toml": 1, **{name: 1 for name in calib_files}}


def test_outside_a_read_once_scope_every_read_goes_to_the_disk(tmp_path):
    path = tmp_path / "f.toml"
    path.write_text("a = 1\n")
    with files.read_once():
        assert files.read_toml(path, what="test") == {"a": 1}
        path.write_text("a = 2\n")
        assert files.read_toml(path, what="test") == {"a": 1}  # the preflight's snapshot: one read
        with pytest.raises(files.InputFileError, match="too large|bytes"):
            files.read_regular_file(path, what="test", max_bytes=2)  # still checked against each caller's bound
    assert files.read_toml(path, what="test") == {"a": 2}
