"""Scoring sense.json against a recording's truth (estimation.truth_errors), on hand-made
documents whose errors are known."""

from __future__ import annotations

import numpy as np
import pytest

from softforce_cli.estimation.truth_errors import compare_with_truth


def _true(point, magnitude, kind="probe"):
    return {"point_mm": point, "magnitude_n": magnitude, "kind": kind}


def _estimate(point, force):
    return {"position_mm": point, "force_n": force}


TRUTH = {"frames": [
    {"index": 0, "contacts": []},
    {"index": 1, "contacts": [_true([0, 0, 100], 0.2)]},
    {"index": 2, "contacts": [_true([0, 0, 100], 0.2), _true([50, 0, 80], 0.1)]},
    {"index": 3, "contacts": [_true([0, 0, 100], 0.2)]},
]}
SENSE = {"frames": [
    {"frame": 0, "status": "ok", "contacts": [_estimate([0, 50, 90], 0.03)]},
    {"frame": 1, "status": "ok", "contacts": [_estimate([3, 4, 100], 0.25)]},
    # the second true contact has only an estimate 30 mm off: missed, and that estimate a
    # phantom (it pushes 0.12 N); a third estimate reads no force
    {"frame": 2, "status": "ok", "contacts": [_estimate([0, 0, 106], 0.19),
                                              _estimate([80, 0, 80], 0.12),
                                              _estimate([0, -60, 80], 0.0)]},
    {"frame": 3, "status": "fewmatches", "contacts": []},
]}


def test_contacts_pair_within_20_mm_and_phantoms_push_more_than_50_millinewtons():
    comparison = compare_with_truth(SENSE, TRUTH)
    assert [(p.frame, p.true_force_n, p.estimated_force_n) for p in comparison.paired] == [
        (1, 0.2, 0.25), (2, 0.2, 0.19)]
    assert [p.location_error_mm for p in comparison.paired] == pytest.approx([5.0, 6.0])
    assert comparison.relative_errors() == pytest.approx([0.25, 0.05])
    assert comparison.missed == ((2, 0.1),)
    assert comparison.phantoms == ((0, 0.03), (2, 0.12), (2, 0.0))
    summary = comparison.summary()
    # skipped frames are not scored; 3 true contacts in the 3 scored frames, 2 located
    assert summary["frames"] == 3 and summary["true_contacts"] == 3
    assert summary["located_fraction"] == pytest.approx(2 / 3, abs=1e-4)
    assert summary["phantoms"] == 1 and summary["max_phantom_n"] == 0.12
    assert summary["intensity_error_median"] == pytest.approx(0.15)
    assert summary["location_error_max_mm"] == pytest.approx(6.0)


def test_an_object_seen_as_two_contacts_adds_their_forces():
    """One probe seen as two clusters 10 mm apart, the QP giving one of them no force (the
    424x240 scenario of docs/sensing_studies.md): the nearer estimate is paired, the other is a part
    of the same contact, not a phantom, and their force vectors add."""
    truth = {"frames": [{"index": 0, "contacts": [_true([52, 1, 58], 0.15)]}]}
    sense = {"frames": [{"frame": 0, "status": "ok", "contacts": [
        {"position_mm": [47, 5, 63], "force_n": 0.0, "force_vector_n": [0, 0, 0]},
        {"position_mm": [47, -5, 63], "force_n": 0.147, "force_vector_n": [0.06, 0, -0.1342]},
    ]}]}
    comparison = compare_with_truth(sense, truth)
    assert comparison.phantoms == () and comparison.split == 1
    [pair] = comparison.paired
    assert pair.estimated_force_n == pytest.approx(np.hypot(0.06, 0.1342))
    assert pair.location_error_mm == pytest.approx(np.sqrt(25 + 16 + 25))
