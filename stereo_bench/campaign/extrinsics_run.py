"""The extrinsics source of a campaign run: what it prepared from the visits, recorded, and read back for a resume
or a replay (each source's own steps are its strategy object, :mod:`stereo_bench.campaign.extrinsics`;
:mod:`stereo_bench.campaign.sources` is the math).

- :class:`Prepared`: what a source's ``prepare`` (analysis thread, after the visits) made: the kinematic rig
  model fitted to the design's views in one joint adjustment, or the intrinsics ``nominal`` extrinsics use
  from one visit's views. It is recorded (:meth:`Prepared.drafts`: the model's TOML as a ``kinematic_model``
  event's side file, or a ``calibration`` event of the visit).
- :func:`session_sources` / :func:`recorded_sources`: what a run starts with (a model file, a calibration
  directory's intrinsics) and what a recording holds (a resume does not visit the design again; a replay
  takes a model file's copy from the session, never from outside it).

Intrinsics: ``kinematic`` extrinsics use the intrinsics of the model's joint fit (refined on every view of
the design: 108 views determine them better than any one configuration's 12, and they are consistent with
the fitted chain); ``nominal`` extrinsics use ``calib_dir``'s when given (a lens calibration the user
trusts, with its covariance), else one stereo calibration at the first configuration (12 views: the same
calibration a per-config run makes there, whose joint intrinsics carry their covariance into the budget).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivers.files import MAX_TOML_BYTES, read_regular_file
from stereo_bench.campaign.analysis import ConfigurationAnalysis
from stereo_bench.campaign.documents import (
    CalibrationEvent,
    CalibrationFiles,
    Draft,
    IntrinsicsEvent,
    KinematicModelEvent,
    event_draft,
)
from stereo_bench.kinematics import KinematicFileError, KinematicModel, model_from_toml, model_toml
from stereo_bench.vision.calibio import MAX_CALIBRATION_FILE_BYTES
from stereo_bench.vision.calibrate import StereoCalibration

MODEL_FILE = "kinematic_model.toml"
INTRINSICS_FILE = "intrinsics.yml"


@dataclass
class Prepared:
    """What the extrinsics source needs before the configurations: a kinematic model, nominal's intrinsics."""

    kinematic_model: KinematicModel | None = None
    nominal_intrinsics: StereoCalibration | None = None
    error: str | None = None
    record: dict[str, Any] = field(default_factory=dict)  # the kinematic_model event's data
    calibration: tuple[str, ConfigurationAnalysis] | None = None  # (visit id, its calibration): an intrinsics visit's
    calibration_note: str = "intrinsics of nominal extrinsics"  # what that calibration is for (its event says)
    # An intrinsics visit's calibration (intrinsics with their covariance): nominal's intrinsics, or the lens
    # calibration a fixed-board fit takes as its prior (issue 25).
    lens: StereoCalibration | None = None

    def drafts(self, board: str) -> list[Draft]:
        """The documents that record it (nothing for a source given before the run)."""
        out = []
        if self.record:
            files = {} if self.kinematic_model is None else {MODEL_FILE: model_toml(self.kinematic_model).encode()}
            out.append(Draft(KinematicModelEvent, config_id=None, data=self.record, files=files))
        if self.calibration is not None:
            visit_id, analysis = self.calibration
            out.append(Draft(CalibrationEvent, config_id=visit_id, calibration=CalibrationFiles(
                analysis.calib, analysis.rect, board=board, extra={"purpose": self.calibration_note})))
        return out


# --------------------------------------------------------------------------------------------------
# Before the run, and from a recording


RIG_CONFIG_KIND, RIG_CONFIG_FILE = "rig_config", "rig.toml"  # the copy of [rig] config_file in a session


def session_sources(config) -> list[Draft]:
    """Documents recording the sources a run starts with from outside the session (a model file, the rig's
    ``config_file`` (a plain ``rig_config`` event with the file's copy), the intrinsics
    of ``calib_dir`` in every mode that reads them: nominal, and ``intrinsics = "held"``), so a replay reads them
    from inside it and replays after ``calib_dir`` has moved. (``fixed`` mode records its whole calibration.)"""
    extrinsics = config.extrinsics
    drafts = []
    if extrinsics.kinematic_file is not None:
        path = Path(extrinsics.kinematic_file)
        drafts.append(Draft(KinematicModelEvent, config_id=None, data={"source": "file", "path": str(path)},
                            files={MODEL_FILE: read_regular_file(
                                path, what="kinematic model file", max_bytes=MAX_TOML_BYTES)}))
    if config.rig.config_file is not None:  # the rig's axis mapping and limits: a replay needs them too
        path = Path(config.rig.config_file)
        drafts.append(event_draft(RIG_CONFIG_KIND, config_id=None, data={"path": str(path)},
                                  files={RIG_CONFIG_FILE: read_regular_file(
                                      path, what="rig configuration file", max_bytes=MAX_TOML_BYTES)}))
    if extrinsics.calib_dir is not None and extrinsics.source().copies_calib_dir_intrinsics:
        path = Path(extrinsics.calib_dir)
        drafts.append(Draft(IntrinsicsEvent, config_id=None, data={"source": "calib_dir", "path": str(path)},
                            files={INTRINSICS_FILE: read_regular_file(
                                path / INTRINSICS_FILE, what="calibration file",
                                max_bytes=MAX_CALIBRATION_FILE_BYTES)}))
    return drafts


def recorded_sources(reader, *, sources: tuple[str, ...], image_size: tuple[int, int],
                     intrinsics_visits: Sequence[str] = ()) -> Prepared:
    """The kinematic model (from the ``kinematic_model`` events whose source is in ``sources``) and nominal's
    intrinsics (a ``calib_dir`` copy, or the calibration of an intrinsics visit) a recording holds.

    A resume takes ``("file", "design")`` (the design is not visited again); a replay ``("file",)`` (it fits
    the design's recorded views again and must find the recorded model). ``intrinsics_visits``: the config ids
    of the plan's intrinsics visits, whose recorded calibration (with ``"design"`` in ``sources``) is nominal's
    intrinsics and a fixed-board fit's lens prior (``lens``).
    """
    from stereo_bench.campaign.documents import CalibrationEvent, IntrinsicsEvent, KinematicModelEvent
    from stereo_bench.campaign.session import SessionError
    from stereo_bench.vision.calibio import read_intrinsics, read_intrinsics_covariance

    prepared = Prepared()
    for event in reader.events(kind=KinematicModelEvent, attempt=None):
        relative = event.files.get(MODEL_FILE)
        if event.data.source in sources and relative:
            try:
                prepared.kinematic_model = model_from_toml(reader.read_bytes(relative).decode("utf-8"),
                                                           str(reader.path(relative)))
            except KinematicFileError as error:
                raise SessionError(str(error)) from None
    for event in reader.events(kind=IntrinsicsEvent, attempt=None):
        relative = event.files.get(INTRINSICS_FILE)
        if relative:
            path = reader.path(relative)
            K1, D1, K2, D2, size = read_intrinsics(path)
            prepared.nominal_intrinsics = _intrinsics_calibration(K1, D1, K2, D2, size or image_size,
                                                                  read_intrinsics_covariance(path))
    if "design" in sources:
        for config_id in intrinsics_visits:
            if reader.events(kind=CalibrationEvent, config_id=config_id, attempt=None):
                prepared.nominal_intrinsics = prepared.lens = reader.calibration(config_id)
    return prepared


def _intrinsics_calibration(K1, D1, K2, D2, image_size, covariance) -> StereoCalibration:
    """Intrinsics as a calibration (R, T are replaced by each configuration's nominal ones)."""
    return StereoCalibration(K1=K1, D1=D1, K2=K2, D2=D2, R=np.eye(3), T=np.array([-1.0, 0.0, 0.0]),
                             image_size=tuple(image_size), mode="intrinsics", covariance=covariance,
                             covariance_note="" if covariance is not None else "the intrinsics file has no covariance")


def intrinsics_from_dir(calib_dir: Path, image_size: tuple[int, int]) -> StereoCalibration:
    """``calib_dir``'s intrinsics (and their covariance, if stored) as a calibration for nominal extrinsics."""
    from stereo_bench.vision.calibio import read_intrinsics, read_intrinsics_covariance

    K1, D1, K2, D2, size = read_intrinsics(calib_dir)
    return _intrinsics_calibration(K1, D1, K2, D2, size or image_size, read_intrinsics_covariance(calib_dir))


__all__ = ["Prepared", "intrinsics_from_dir", "recorded_sources", "session_sources"]
