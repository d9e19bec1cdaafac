"""The extrinsics sources' registry (issue 21 item 2): one strategy object per ``[extrinsics] mode``, and the
config's list of names agreeing with the modules of ``stereo_bench/campaign/extrinsics``."""

from __future__ import annotations

import inspect

import pytest

from stereo_bench.campaign.config import EXTRINSICS_MODES, ExtrinsicsSection
from stereo_bench.campaign.extrinsics import SOURCES, ExtrinsicsSource, extrinsics_source
from stereo_bench.campaign.sources import SOURCE_NAMES


def test_the_registry_and_the_config_name_the_same_sources():
    assert set(SOURCES) == set(EXTRINSICS_MODES)
    assert len(EXTRINSICS_MODES) == len(set(EXTRINSICS_MODES))


@pytest.mark.parametrize("mode", EXTRINSICS_MODES)
def test_each_source_implements_the_protocol(mode):
    cls = SOURCES[mode]
    assert issubclass(cls, ExtrinsicsSource) and not inspect.isabstract(cls)
    assert cls.name == mode
    assert cls.used in SOURCE_NAMES
    assert cls.used not in cls.compared_with and set(cls.compared_with) <= set(SOURCE_NAMES)
    source = extrinsics_source(mode)
    assert isinstance(source, cls)
    section = ExtrinsicsSection(mode=mode, calib_dir="calib" if mode == "fixed" else None)
    assert section.source().name == mode
    assert isinstance(source.describe(section), str) and source.describe(section)
    assert source.visit_purpose(section) in (None, "kinematic", "intrinsics")
    assert "intrinsics.yml" in source.calib_dir_files()


def test_the_sources_answer_what_the_mode_names_said():
    """What the ``mode == ...`` branches decided, asked of the objects (the behaviours the digests hold)."""
    per_config, kinematic = ExtrinsicsSection(), ExtrinsicsSection(mode="kinematic")
    nominal, fixed = ExtrinsicsSection(mode="nominal"), ExtrinsicsSection(mode="fixed", calib_dir="calib")
    assert [s.source().calibrates_each_configuration for s in (per_config, kinematic, nominal, fixed)] == [
        True, False, False, False]
    assert [s.source().visit_purpose(s) for s in (per_config, kinematic, nominal, fixed)] == [
        None, "kinematic", "intrinsics", None]
    assert kinematic.source().visit_purpose(ExtrinsicsSection(mode="kinematic", kinematic_file="m.toml")) is None
    assert nominal.source().visit_purpose(ExtrinsicsSection(mode="nominal", calib_dir="calib")) is None
    assert [s.source().needs_calibration_views(s) for s in (per_config, kinematic, nominal, fixed)] == [
        True, False, True, False]
    assert fixed.source().calib_dir_files() == ("intrinsics.yml", "extrinsics.yml")
    assert [s.source().copies_calib_dir_intrinsics for s in (per_config, kinematic, nominal, fixed)] == [
        True, True, True, False]
    with pytest.raises(ValueError, match="needs calib_dir"):
        ExtrinsicsSection(mode="fixed")


def test_an_unknown_name_is_refused_in_one_line():
    with pytest.raises(ValueError, match="unknown extrinsics mode 'self-calibrating'; known: "):
        extrinsics_source("self-calibrating")
