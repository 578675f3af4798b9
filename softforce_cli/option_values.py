"""Comma-separated numbers given on the command line ("--actuation 5,5,0,0"), parsed once for
every command; light to import, so that `model solve` does not load the sensing stack."""

from __future__ import annotations

import numpy as np


def parse_numbers(text: str) -> np.ndarray | None:
    """"1, 2,3" -> (n,) float64 (empty items skipped); None when an item is not a finite
    number: the comma-separated values of a command-line option."""
    try:
        values = np.array([float(v) for v in text.split(",") if v.strip()], dtype=float)
    except ValueError:
        return None
    return values if np.all(np.isfinite(values)) else None
