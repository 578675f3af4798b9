"""A report's tables re-exported as CSV or JSON, with the columns a user picks."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from softforce_cli.report.loading import ReportError, RunFolder, Table
from softforce_cli.report.truth import TruthReport

# Columns that count things: written as integers, not as the CSV reader's floats.
INTEGER_COLUMNS = frozenset({"frame", "contact", "feature", "contacts", "points_kept",
                             "features_matched", "features_hidden", "features_rejected",
                             "robot_points", "object_points"})


def available_tables(folder: RunFolder, truth: TruthReport | None) -> dict[str, Table]:
    """Table name -> Table: contacts and frames of a sense run, truth (one row per located
    contact) when there is a ground truth, effects (one row per fitted parameter) of a
    diagnosis."""
    tables: dict[str, Table] = {}
    if folder.sense is not None:
        tables["contacts"] = folder.sense.contacts
        tables["frames"] = folder.sense.frames
    if truth is not None:
        paired = truth.comparison.paired
        tables["truth"] = Table({
            "frame": np.array([p.frame for p in paired], dtype=float),
            "kind": np.array([p.kind for p in paired], dtype=str),
            "true_force_n": np.array([p.true_force_n for p in paired]),
            "estimated_force_n": np.array([p.estimated_force_n for p in paired]),
            "relative_error": np.array([p.relative_error for p in paired]),
            "location_error_mm": np.array([p.location_error_mm for p in paired]),
        })
    if folder.diagnose is not None:
        rows = []
        for e in folder.diagnose.diagnosis.effects:
            for p in e.parameters or (None,):  # an effect with no parameter: one row
                fitted = (math.nan, math.nan, math.nan, "") if p is None else (p.value, *p.ci95,
                                                                             p.unit)
                rows.append((e.name, e.target or "", "" if p is None else p.name, *fitted,
                             e.heldout_rms_before_mm, e.heldout_rms_after_mm))
        names = ("effect", "target", "parameter", "value", "ci95_lo", "ci95_hi", "unit",
                 "heldout_rms_before_mm", "heldout_rms_after_mm")
        text = {"effect", "target", "parameter", "unit"}
        tables["effects"] = Table({
            name: np.array([r[i] for r in rows], dtype=str if name in text else float)
            for i, name in enumerate(names)})
    return tables


def select_columns(table: Table, name: str, columns: Sequence[str] | None) -> Table:
    """The table with only `columns`, in that order; ReportError naming an unknown one."""
    if not columns:
        return table
    unknown = [c for c in columns if c not in table.names]
    if unknown:
        raise ReportError(f"--columns: the {name} table has no column {unknown[0]!r}; its "
                          f"columns are {','.join(table.names)}")
    return Table({c: table[c] for c in columns})


def table_text(table: Table, fmt: str) -> str:
    """CSV (header, then one line per row; empty for NaN) or a JSON list of row objects."""
    records = [{name: _value(name, table[name][i]) for name in table.names}
               for i in range(len(table))]
    if fmt == "json":
        return json.dumps(records, indent=1) + "\n"
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(table.names)
    for record in records:
        writer.writerow("" if v is None else v for v in record.values())
    return buffer.getvalue()


def _value(name: str, value: Any) -> Any:
    if isinstance(value, str | np.str_):
        return str(value)
    number = float(value)
    if not math.isfinite(number):
        return None
    return int(number) if name in INTEGER_COLUMNS else number
