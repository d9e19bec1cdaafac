"""Result rows laid out like the paper's tables, as plain lists and CSV (pure: no I/O, no pandas).

- :func:`distance_baseline_tables`: the paper's Table 1 — the measured square per baseline B (rows)
  and object distance Z (columns), one table per angle α (and tilt).
- :func:`alpha_tables`: the paper's Table 2 — the measured square per α (columns), one row per
  (B, Z) (the paper has one: B = 100 mm, Z = 500 mm).

A cell is a :class:`Cell`: a measured value, or the status that explains why there is none
(``infeasible``, ``failed``, ``limit``: outside the rig's soft limits, ``not run``: planned but the
session stopped before it). A grid position that no configuration has is left empty. Values are the
mean measured square in mm; a measurement made on a partial view (part of the target outside one
view) is marked with :data:`PARTIAL_MARK`. Below each value the page shows the error ± U (the expanded
uncertainty of the row's budget); a row without a budget (sessions before issue 12) shows ± its
propagated σ instead, marked as image noise only (:meth:`Cell.error_text`).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

PARTIAL_MARK = "†"
#: After U when the budget has unknown components (U leaves them out: a lower bound).
INCOMPLETE_MARK = "*"
#: Statuses a result row can have, plus "not run" (in the plan, no result recorded).
STATUSES = ("measured", "failed", "infeasible", "limit", "not run")
NOT_RUN = "not run"


def finite_number(value: object) -> float | None:
    """A finite float, or None (missing, NaN, text)."""
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def uncertainty_decimals(*values: float | None, minimum: int = 4, maximum: int = 7) -> int:
    """Decimals that give the smallest positive of ``values`` two significant digits (within [minimum, maximum]).

    An uncertainty is stated to two significant digits and the value to the same decimal place (GUM 7.2.6):
    0.0025 -> 4, 0.000043 -> 6.
    """
    positive = [abs(v) for v in values if v is not None and math.isfinite(v) and v != 0]
    if not positive:
        return minimum
    return int(min(maximum, max(minimum, 1 - math.floor(math.log10(min(positive))))))


def format_value(value: float) -> str:
    """'26.9195'-style: axis values without needless zeros (100.0 -> '100', 87.5 -> '87.5')."""
    return f"{value:g}"


@dataclass(frozen=True)
class Cell:
    """One configuration's result in a table (``status`` 'empty': no configuration at this position)."""

    status: str
    config_id: str | None = None
    square_mm: float | None = None
    error_mm: float | None = None
    sigma_mm: float | None = None
    partial: bool = False
    reason: str | None = None
    expanded_mm: float | None = None  # U of the row's uncertainty budget; None: no budget recorded
    budget_complete: bool = True  # False: some component unknown, U leaves it out

    @classmethod
    def from_row(cls, row: Mapping[str, object], *, expanded_mm: float | None = None,
                 budget_complete: bool = True) -> Cell:
        """The cell of a result row; ``expanded_mm`` (U) and ``budget_complete`` from its budget (collect.budget_of)."""
        status = str(row.get("status") or NOT_RUN)
        measured = status == "measured"
        return cls(
            status=status, config_id=str(row.get("config_id")) if row.get("config_id") is not None else None,
            square_mm=finite_number(row.get("square_mean_mm")) if measured else None,
            error_mm=finite_number(row.get("error_mm")) if measured else None,
            sigma_mm=finite_number(row.get("sigma_mm")) if measured else None,
            partial=measured and is_partial(row),
            reason=str(row["reason"]) if row.get("reason") else None,
            expanded_mm=finite_number(expanded_mm) if measured else None,
            budget_complete=budget_complete,
        )

    @property
    def measured(self) -> bool:
        return self.status == "measured" and self.square_mm is not None

    def text(self, digits: int = 4) -> str:
        """What the cell shows: '26.9195' (partial: '26.9195†'), the status word, or '' (empty)."""
        if self.status == "empty":
            return ""
        if self.measured:
            assert self.square_mm is not None
            return f"{self.square_mm:.{digits}f}" + (PARTIAL_MARK if self.partial else "")
        return self.status

    def error_text(self, digits: int = 4, *, pm: str = "±") -> str:
        """The error and its uncertainty: '+0.0013 ± 0.0050' (± U); '+0.0013 ± 0.0050*' when the budget has
        unknown components; '+0.0013 ± 0.0002 (σ noise)' without a budget; '' when not measured. At least
        ``digits`` decimals, more when the uncertainty needs them for two significant digits."""
        if not self.measured or self.error_mm is None:
            return ""
        u = self.expanded_mm if self.expanded_mm is not None else self.sigma_mm
        digits = uncertainty_decimals(u, minimum=digits)
        error = f"{self.error_mm:+.{digits}f}"
        if self.expanded_mm is not None:
            return f"{error} {pm} {self.expanded_mm:.{digits}f}" + ("" if self.budget_complete else INCOMPLETE_MARK)
        if self.sigma_mm is not None:
            return f"{error} {pm} {self.sigma_mm:.{digits}f} ({'σ' if pm == '±' else 'sigma'} noise)"
        return error

    def csv_value(self) -> str:
        """Machine-readable: the full-precision value when measured, else the status word."""
        if self.status == "empty":
            return ""
        if self.measured:
            return repr(self.square_mm)
        return self.status


EMPTY = Cell(status="empty")


def is_partial(row: Mapping[str, object]) -> bool:
    """Was the target only partly in both views (measured fraction, else the predicted one, below 1)?"""
    fraction = finite_number(row.get("fraction_in_both_measured"))
    if fraction is None:
        fraction = finite_number(row.get("fraction_in_both"))
    return fraction is not None and fraction < 1.0 - 1e-9


@dataclass
class Table:
    """A 2-D table: ``cells[i][j]`` at row value ``row_values[i]``, column value ``column_values[j]``."""

    key: str  # file-name-safe identifier, e.g. 'table1_A90'
    title: str
    row_label: str  # e.g. 'B (mm)'
    column_label: str  # e.g. 'Z (mm)'
    row_values: list[float]
    column_values: list[float]
    cells: list[list[Cell]]
    row_names: list[str] = field(default_factory=list)  # overrides format_value(row value) when given
    note: str = ""

    def row_name(self, i: int) -> str:
        return self.row_names[i] if self.row_names else format_value(self.row_values[i])

    def header(self) -> list[str]:
        return [f"{self.row_label} \\ {self.column_label}"] + [format_value(v) for v in self.column_values]

    def text_rows(self, digits: int = 4) -> list[list[str]]:
        """Header, then one list of strings per row, as displayed."""
        return [self.header()] + [[self.row_name(i)] + [c.text(digits) for c in row]
                                  for i, row in enumerate(self.cells)]

    def csv_rows(self) -> list[list[str]]:
        return [self.header()] + [[self.row_name(i)] + [c.csv_value() for c in row] for i, row in enumerate(self.cells)]

    def to_csv(self) -> str:
        return rows_to_csv(self.csv_rows())

    def error_csv(self) -> str:
        """The same grid with 'error +- U' in each measured cell (ASCII '+-': spreadsheets read it in any
        encoding); without a budget 'error +- sigma (sigma noise)'."""
        rows = [self.header()] + [[self.row_name(i)] + [c.error_text(pm="+-") if c.measured else c.csv_value()
                                                        for c in row] for i, row in enumerate(self.cells)]
        return rows_to_csv(rows)

    def has_uncertainty(self) -> bool:
        """Does any measured cell carry U?"""
        return any(c.expanded_mm is not None for row in self.cells for c in row if c.measured)

    def statuses(self) -> dict[str, int]:
        """How many cells have each status (empty cells not counted)."""
        counts: dict[str, int] = {}
        for row in self.cells:
            for cell in row:
                if cell.status != "empty":
                    counts[cell.status] = counts.get(cell.status, 0) + 1
        return counts


def rows_to_csv(rows: Iterable[Sequence[object]]) -> str:
    """CSV text (RFC 4180, '\\n' line ends) of rows of values."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    for row in rows:
        writer.writerow(["" if value is None else value for value in row])
    return buffer.getvalue()


def with_plan(rows: Sequence[Mapping[str, object]], plan: Sequence[Mapping[str, object]] | None) -> list[dict]:
    """Result rows in plan order, with a 'not run' row for each planned configuration that has no result.

    Rows whose config_id is not in the plan (should not happen) are kept, after the planned ones.
    """
    by_id = {str(row.get("config_id")): dict(row) for row in rows}
    out: list[dict] = []
    for entry in plan or []:
        config_id = str(entry.get("config_id"))
        if config_id in by_id:
            out.append(by_id.pop(config_id))
        else:
            out.append({
                "config_id": config_id, "baseline_mm": entry.get("baseline_mm"),
                "distance_mm": entry.get("distance_mm"), "alpha_deg": entry.get("alpha_deg"),
                "toe_in_deg": entry.get("toe_in_deg"), "tilt_deg": entry.get("tilt_deg", 0.0),
                "fraction_in_both": entry.get("fraction_in_both"), "status": NOT_RUN,
                "reason": "planned, but the session stopped before this configuration",
            })
    out.extend(by_id.values())
    return out


def _axis(rows: Iterable[Mapping[str, object]], key: str) -> list[float]:
    return sorted({value for row in rows if (value := finite_number(row.get(key))) is not None})


def _group(rows: Iterable[Mapping[str, object]], key: Callable[[Mapping[str, object]], tuple]) -> dict[tuple, list]:
    groups: dict[tuple, list] = {}
    for row in rows:
        groups.setdefault(key(row), []).append(row)
    return dict(sorted(groups.items(), key=lambda item: tuple(-math.inf if v is None else v for v in item[0])))


#: (expanded U in mm or None, budget complete) of a result row; the default: no budget.
UncertaintyOf = Callable[[Mapping[str, object]], tuple[float | None, bool]]


def _no_uncertainty(row: Mapping[str, object]) -> tuple[float | None, bool]:
    return None, True


def _cell(row: Mapping[str, object], uncertainty: UncertaintyOf) -> Cell:
    expanded, complete = uncertainty(row)
    return Cell.from_row(row, expanded_mm=expanded, budget_complete=complete)


def _grid(rows: Sequence[Mapping[str, object]], row_key: str, column_key: str,
          uncertainty: UncertaintyOf) -> tuple[list, list, list]:
    row_values, column_values = _axis(rows, row_key), _axis(rows, column_key)
    cells = [[EMPTY for _ in column_values] for _ in row_values]
    for row in rows:
        r, c = finite_number(row.get(row_key)), finite_number(row.get(column_key))
        if r is None or c is None:
            continue
        cells[row_values.index(r)][column_values.index(c)] = _cell(row, uncertainty)
    return row_values, column_values, cells


def _angle_tag(alpha: float | None, tilt: float | None) -> tuple[str, str]:
    """('A90', 'α = 90 deg') with the tilt appended when it is not 0."""
    key = f"A{format_value(alpha)}" if alpha is not None else "A"
    text = f"α = {format_value(alpha)} deg" if alpha is not None else "α unknown"
    if tilt:
        key += f"_T{format_value(tilt)}"
        text += f", tilt {format_value(tilt)} deg"
    return key.replace(".", "p").replace("-", "m"), text


def distance_baseline_tables(rows: Sequence[Mapping[str, object]], *, prefix: str = "",
                             uncertainty: UncertaintyOf = _no_uncertainty) -> list[Table]:
    """The paper's Table 1 layout: measured square (mm) per B (rows) and Z (columns), one table per α (and tilt).

    Only made for groups with more than one B or more than one Z (a single cell is no table).
    ``uncertainty``: (U, complete) of a row, for the cells' error ± U.
    """
    tables = []
    groups = _group(rows, lambda row: (finite_number(row.get("alpha_deg")), finite_number(row.get("tilt_deg")) or 0.0))
    for (alpha, tilt), group in groups.items():
        row_values, column_values, cells = _grid(group, "baseline_mm", "distance_mm", uncertainty)
        if len(row_values) < 2 and len(column_values) < 2:
            continue
        tag, text = _angle_tag(alpha, tilt)
        tables.append(Table(
            key=f"{prefix}table1_{tag}", title=f"Measured square (mm) per baseline B and distance Z, {text}",
            row_label="B (mm)", column_label="Z (mm)", row_values=row_values, column_values=column_values,
            cells=cells,
        ))
    return tables


def alpha_tables(rows: Sequence[Mapping[str, object]], *, prefix: str = "",
                 uncertainty: UncertaintyOf = _no_uncertainty) -> list[Table]:
    """The paper's Table 2 layout: measured square (mm) per α (columns), one row per (B, Z), one table per tilt.

    Only made when some (B, Z) has more than one α. ``uncertainty``: as for :func:`distance_baseline_tables`.
    """
    tables = []
    for (tilt,), group in _group(rows, lambda row: (finite_number(row.get("tilt_deg")) or 0.0,)).items():
        by_bz = _group(group, lambda row: (finite_number(row.get("baseline_mm")),
                                           finite_number(row.get("distance_mm"))))
        if not any(len({finite_number(r.get("alpha_deg")) for r in members}) > 1 for members in by_bz.values()):
            continue
        column_values = _axis(group, "alpha_deg")
        cells, names, keys = [], [], []
        for (baseline, distance), members in by_bz.items():
            line = [EMPTY for _ in column_values]
            for row in members:
                alpha = finite_number(row.get("alpha_deg"))
                if alpha is not None:
                    line[column_values.index(alpha)] = _cell(row, uncertainty)
            cells.append(line)
            names.append(f"B = {format_value(baseline or 0)} mm, Z = {format_value(distance or 0)} mm")
            keys.append(float(len(keys)))
        tag = "" if not tilt else f"_T{format_value(tilt)}".replace(".", "p").replace("-", "m")
        tilt_text = "" if not tilt else f", tilt {format_value(tilt)} deg"
        tables.append(Table(
            key=f"{prefix}table2{tag}", title=f"Measured square (mm) per angle α between baseline and optical axis"
                                              f"{tilt_text}",
            row_label="B, Z", column_label="α (deg)", row_values=keys, column_values=column_values, cells=cells,
            row_names=names,
        ))
    return tables


def status_counts(rows: Iterable[Mapping[str, object]]) -> dict[str, int]:
    """How many configurations have each status, in :data:`STATUSES` order (then any other)."""
    counts: dict[str, int] = {}
    for row in rows:
        status = str(row.get("status") or NOT_RUN)
        counts[status] = counts.get(status, 0) + 1
    order = {status: i for i, status in enumerate(STATUSES)}
    return dict(sorted(counts.items(), key=lambda item: (order.get(item[0], len(order)), item[0])))


__all__ = [
    "EMPTY", "INCOMPLETE_MARK", "NOT_RUN", "PARTIAL_MARK", "STATUSES", "Cell", "Table", "UncertaintyOf",
    "alpha_tables", "distance_baseline_tables", "format_value", "is_partial", "rows_to_csv", "status_counts",
    "uncertainty_decimals", "with_plan",
]
