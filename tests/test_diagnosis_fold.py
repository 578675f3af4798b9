"""The fold's valley (diagnosis.fold): where a creeping body that tips over is fitted."""

from functools import partial
from types import SimpleNamespace

import numpy as np
import pytest

from softforce_cli.diagnosis import fold, refit
from softforce_cli.diagnosis.fitting import Candidate
from softforce_cli.diagnosis.hypotheses import Hypothesis
from softforce_cli.diagnosis.refit import ExactModel
from softforce_cli.diagnosis.residuals import Field
from tests.test_diagnosis import CREEP

LOWER, UPPER = CREEP.lower, CREEP.upper
# the study's creep_0.5 (docs/diagnosis.md): four frames at 6 mm, held 0-1.5 s, between
# others; its body tips over in the third, 1.0 s into the hold
HOLDS = np.array([0.0, 0.5, 0.0, 0.5, 0.0, 0.5, 1.0, 1.5, 0.0, 0.5])
TIPS_IN = 6


def tipping_nodes(tips_in: int | None, nodes: int = 5) -> np.ndarray:
    """(t, nodes, 3) mm: a body that drifts 0.2 mm a frame and drops 100 mm in frame
    tips_in (none: never)."""
    frames = np.arange(len(HOLDS))
    drop = np.zeros(len(HOLDS)) if tips_in is None else np.where(frames >= tips_in, -100.0, 0.0)
    z = 0.2 * frames + drop
    return np.broadcast_to(np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)[:, None],
                           (len(HOLDS), nodes, 3)).copy()


@pytest.mark.parametrize(("relaxation", "tau"), [(0.708, 0.836), (0.5, 0.5), (0.2, 3.0)])
def test_the_fold_keeps_the_share_within_creeps_bounds(relaxation, tau):
    """fold_time_constants and relaxation_along_the_fold: every pair relaxes the modulus by
    the given pair's share after the hold; the time constants are even in their logarithm
    from the bound's shortest to the one at which the relaxation reaches its upper bound
    (or the time constant's own bound, where the relaxation does not reach its)."""
    hold = 0.5
    share = relaxation * (1.0 - np.exp(-hold / tau))
    taus = fold.fold_time_constants(share, hold, LOWER, UPPER, 6)
    relaxations = fold.relaxation_along_the_fold(share, hold, taus)
    np.testing.assert_allclose(relaxations * (1.0 - np.exp(-hold / taus)), share, rtol=1e-12)
    np.testing.assert_allclose(np.diff(np.log(taus)), np.log(taus[-1] / taus[0]) / 5)
    assert taus[0] == pytest.approx(0.05)
    assert relaxations[-1] == pytest.approx(0.9)
    assert np.all(np.diff(relaxations) > 0.0)
    assert tau <= taus[-1] * (1.0 + 1e-12)


def test_the_last_standing_frame_is_the_one_the_model_jumps_from():
    """last_standing_hold_s: the hold time of the held frame before the nodes' jump, the
    tipping frame's own where the frame before starts the hold; none where nothing jumps,
    or where the only jump is between recordings."""
    recordings = np.zeros(len(HOLDS), dtype=int)
    assert fold.last_standing_hold_s(tipping_nodes(TIPS_IN), recordings, HOLDS) == 0.5
    assert fold.last_standing_hold_s(tipping_nodes(5), recordings, HOLDS) == 0.5
    assert fold.last_standing_hold_s(tipping_nodes(None), recordings, HOLDS) is None
    # the drop falls at a new recording's first frame: not a frame in a hold
    other = np.where(np.arange(len(HOLDS)) >= 4, 1, 0)
    assert fold.last_standing_hold_s(tipping_nodes(4), other, HOLDS) is None


def made_up_exact(truth_tau: float) -> SimpleNamespace:
    """An exact model whose followed prediction tips in frame TIPS_IN and carries its values
    in one more node; its residual is 5 (share - 0.316) and log(tau / truth_tau) per entry,
    steep across the valley and a parabola in log tau along it."""
    nodes = tipping_nodes(TIPS_IN)

    def followed(_, values):
        carried = np.broadcast_to([values[0], values[1], 0.0], (len(HOLDS), 1, 3))
        return refit.Prediction(np.concatenate([nodes, carried], axis=1),
                                np.arange(len(HOLDS)), len(HOLDS), followed=True)

    def field(prediction):
        a, tau, _ = prediction.positions_mm[0, -1]
        share = a * (1.0 - np.exp(-0.5 / tau))
        residual = np.array([5.0 * (share - 0.316), np.log(tau / truth_tau)])
        return Field(np.zeros(2, int), np.arange(2), residual, np.ones(2))

    exact = SimpleNamespace(contexts=[SimpleNamespace(hold_s=h) for h in HOLDS],
                            recording_of_frame=np.zeros(len(HOLDS), dtype=int),
                            followed=followed, field=field)
    exact.followed_each = partial(ExactModel.followed_each, exact)
    return exact


def mean_square(field, _):
    return float(np.mean(field.mean_mm**2))


def test_the_search_finds_the_valleys_lowest_point_with_the_share_held():
    """search_along_the_fold from a followed fit on the valley, far along it from its
    lowest point (creep_0.5 seed 2's (0.708, 0.836 s)): the lowest point found within 2% in
    the time constant (a parabola along the valley, found exactly by the last step), the
    share of the last standing frame (0.5 s) kept, and the solves counted."""
    exact = made_up_exact(0.5)
    start = np.array([0.708, 0.836])
    at_start = exact.followed(CREEP, start)
    values, prediction, field, solves = fold.search_along_the_fold(
        exact, CREEP, start, at_start, mean_square)
    assert values[1] == pytest.approx(0.5, rel=0.02)
    share = start[0] * (1.0 - np.exp(-0.5 / start[1]))
    assert values[0] * (1.0 - np.exp(-0.5 / values[1])) == pytest.approx(share, rel=1e-9)
    assert mean_square(field, values) < mean_square(exact.field(at_start), start)
    np.testing.assert_array_equal(prediction.positions_mm[0, -1, :2], values)
    assert solves % len(HOLDS) == 0 and solves >= 7 * len(HOLDS)


def test_the_search_keeps_the_fit_where_it_has_no_fold_to_search():
    """The fit itself, its solves counted, at the valley's lowest point already; None
    where the model does not tip, and for a candidate without creep's two parameters
    free."""
    start = np.array([0.708, 0.836])
    lowest = made_up_exact(0.836)
    at_start = lowest.followed(CREEP, start)
    values, prediction, field, solves = fold.search_along_the_fold(
        lowest, CREEP, start, at_start, mean_square)
    np.testing.assert_array_equal(values, start)
    np.testing.assert_array_equal(prediction.positions_mm, at_start.positions_mm)
    assert mean_square(field, values) == mean_square(lowest.field(at_start), start)
    assert solves >= 7 * len(HOLDS)
    standing = made_up_exact(0.5)
    standing_prediction = refit.Prediction(tipping_nodes(None), np.arange(len(HOLDS)), 10,
                                           followed=True)
    assert fold.search_along_the_fold(standing, CREEP, start, standing_prediction,
                                      mean_square) is None
    slack = Candidate((Hypothesis("cable_slack", "north", ("offset_mm",), np.zeros(1),
                                  np.array([-5.0]), np.array([5.0])),))
    assert fold.creep_indices(slack) is None
    assert fold.creep_indices(Candidate((*slack.hypotheses, *CREEP.hypotheses))) == (1, 2)
