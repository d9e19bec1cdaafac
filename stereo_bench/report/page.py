"""What the report page shows: image references and one session's tables and figures (data only).

Shared by :mod:`stereo_bench.report.build`, which fills them while writing the files, and
:mod:`stereo_bench.report.html`, which renders them; neither imports the other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from stereo_bench.report.answer import Answer
from stereo_bench.report.collect import SessionReport
from stereo_bench.report.tables import Table


@dataclass
class ImageRef:
    src: str  # relative to the report directory, '/'-separated
    width: int
    height: int
    alt: str
    caption: str = ""


@dataclass
class SessionPage:
    """What the page shows of one session, with the report-relative paths of its files."""

    session: SessionReport
    tables1: list[tuple[Table, str]] = field(default_factory=list)
    tables2: list[tuple[Table, str]] = field(default_factory=list)
    error_figures: list[ImageRef] = field(default_factory=list)
    comparison: ImageRef | None = None
    calibration: ImageRef | None = None
    calibration_csv: str = ""
    images: dict[str, list[ImageRef]] = field(default_factory=dict)
    image_notes: dict[str, list[str]] = field(default_factory=dict)
    error_csvs: dict[str, str] = field(default_factory=dict)  # table key -> its 'error +- U' CSV
    budget_csv: str = ""  # "" when the session records no budget
    normalised: ImageRef | None = None
    structure_csv: str = ""
    deviation: ImageRef | None = None
    deviation_reference: str = ""  # 'truth' or 'nominal'
    answer: Answer | None = None  # the first screen: how the error depends on B, Z and alpha, and the paper's numbers
    answer_figure: ImageRef | None = None


@dataclass
class StructuralSection:
    """The structural-error section over all sessions: the paper's Figures 8, 9, 11 per extrinsics source."""

    figures: list[ImageRef] = field(default_factory=list)
    sources: list[str] = field(default_factory=list)  # extrinsics modes with a measured square
    missing: list[str] = field(default_factory=list)  # per-config, kinematic, nominal: not in any session
    csv: str = ""
    duplicates: int = 0  # same configuration and source in several sessions: the first given is drawn
