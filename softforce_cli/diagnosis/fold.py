"""The fold's valley: where a fit of a creeping body that tips over within a hold lies.

A creeping body's modulus relaxes within a hold by the share a (1 - exp(-hold / tau))
(model.effects). When the share passes what the body's fold allows, it tips over. A model
followed frame by frame (refit.ExactModel.followed) fits such a recording well only where
it tips in the frame the body tipped and, in the last frame the body stood, relaxes it by
the share that left it nearest the fold: along a narrow valley of pairs (a, tau) with one
share at that frame's hold time. On the study's creep_0.5 (seed 2) the pairs (0.4, 0.3 s),
(0.5, 0.5 s) and (0.708, 0.836 s) all relax the body by 0.32 after its last standing
frame's 0.5 s, and fit the recording 7-47 times better than pairs that tip the model a
frame early or late (docs/diagnosis.md, limits). A Gauss-Newton refit crosses the valley
well, since it is steep across, but does not move along it, since its first-order model is
the standing body's: search_along_the_fold looks for the valley's lowest point from a
followed fit, over the time constants with the share held.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from softforce_cli.diagnosis.fitting import Candidate
from softforce_cli.diagnosis.jumps import JUMP_FACTOR, MIN_HOLDS
from softforce_cli.diagnosis.residuals import Field
from softforce_cli.errors import SolverError

if TYPE_CHECKING:
    from softforce_cli.diagnosis.refit import ExactModel, Prediction

# Time constants first tried along the valley, evenly in their logarithm over those the
# bounds allow; the best is then refined by the midpoints to its neighbours and a parabola.
FOLD_POINTS = 6
# Two time constants closer than this in their logarithm (1%) are one.
SAME_LOG_TAU = 0.01


def creep_indices(candidate: Candidate) -> tuple[int, int] | None:
    """The indices of creep's relaxation and time constant among the candidate's values,
    None without both free."""
    offset = 0
    for hypothesis in candidate.hypotheses:
        free = hypothesis.free
        if hypothesis.name == "viscoelastic_creep" and {"relaxation", "time_constant_s"} <= set(
                free):
            return offset + free.index("relaxation"), offset + free.index("time_constant_s")
        offset += len(free)
    return None


def last_standing_hold_s(positions_mm: np.ndarray, recordings: np.ndarray,
                         hold_s: np.ndarray) -> float | None:
    """s: the hold time of the last frame in which a followed model stands before it tips
    over (the held frame its nodes jumped from), or of the tipping frame where that one
    starts its hold; None where no held frame's nodes move more than JUMP_FACTOR times the
    median such motion (as jumps.jumps_in_holds judges the recording's points).

    positions_mm : (t, n, 3) mm, the followed model's nodes per frame.
    recordings   : (t,) each frame's recording.
    hold_s       : (t,) s, each frame's time since the inputs last changed (0: they did).
    """
    moved = np.sqrt(np.mean(np.sum(np.diff(positions_mm, axis=0) ** 2, axis=2), axis=1))
    held = (np.diff(recordings) == 0) & (np.asarray(hold_s)[1:] > 0.0)
    if held.sum() < MIN_HOLDS:
        return None
    standing = int(np.argmax(np.where(held, moved, -1.0)))
    if moved[standing] <= JUMP_FACTOR * np.median(moved[held]):
        return None
    return float(hold_s[standing] if hold_s[standing] > 0.0 else hold_s[standing + 1])


def relaxation_along_the_fold(share: float, hold_s: float, time_constants_s: np.ndarray
                              ) -> np.ndarray:
    """(m,) the relaxations that, with the time constants (m,) s, relax the modulus by
    `share` after hold_s: share / (1 - exp(-hold_s / tau))."""
    return share / -np.expm1(-hold_s / np.asarray(time_constants_s, dtype=float))


def fold_time_constants(share: float, hold_s: float, lower: np.ndarray, upper: np.ndarray,
                        count: int) -> np.ndarray:
    """(count,) s: time constants evenly spread in their logarithm over those whose
    relaxation along the fold (relaxation_along_the_fold) is within creep's bounds
    lower, upper (2,): (relaxation, time constant). The relaxation rises with the time
    constant, so its upper bound caps the longest; the shortest is the bound's."""
    if share >= upper[0]:
        longest = float(lower[1])
    else:
        longest = max(float(lower[1]),
                      min(float(upper[1]), -hold_s / np.log1p(-share / upper[0])))
    return np.exp(np.linspace(np.log(lower[1]), np.log(longest), count))


def search_along_the_fold(exact: ExactModel, candidate: Candidate, values: np.ndarray,
                          prediction: Prediction,
                          objective: Callable[[Field, np.ndarray], float],
                          stop_requested: Callable[[], bool] = lambda: False
                          ) -> tuple[np.ndarray, Prediction, Field, int] | None:
    """The lowest point of the fold's valley through the followed fit at values (k,)
    (`prediction`) by `objective`: (its values, prediction, field, the FE solves the search
    took), the fit itself where no point of the valley fits better; None where the
    candidate has no free creep or the model does not tip. Its other parameters are held.
    FOLD_POINTS time constants over the valley are followed (ExactModel.followed_each, on
    the cores), then the midpoints between the best and its neighbours, then the vertex of
    the parabola through the best three (in the time constant's logarithm), each batch only
    while no stop is requested."""
    indices = creep_indices(candidate)
    if indices is None:
        return None
    a, t = indices
    hold = last_standing_hold_s(prediction.positions_mm[prediction.of_frame],
                                exact.recording_of_frame,
                                np.array([context.hold_s for context in exact.contexts]))
    if hold is None:
        return None
    share = float(values[a] * -np.expm1(-hold / values[t]))
    if share <= 0.0:
        return None
    bounds = np.array([candidate.lower[[a, t]], candidate.upper[[a, t]]])
    here = exact.field(prediction)
    # per log time constant: (objective, values, prediction, field)
    tried = {float(np.log(values[t])): (objective(here, values), values, prediction, here)}
    solves = 0

    def on_the_fold(log_taus: list[float]) -> None:
        nonlocal solves
        log_taus = [u for u in log_taus
                    if min(abs(u - v) for v in tried) > SAME_LOG_TAU]
        taus = np.exp(log_taus)
        points = []
        for tau, relaxation in zip(taus, relaxation_along_the_fold(share, hold, taus),
                                   strict=True):
            point = values.copy()
            point[a], point[t] = min(relaxation, bounds[1, 0]), tau
            points.append(point)
        for u, point, followed in zip(log_taus, points,
                                      exact.followed_each(candidate, points), strict=True):
            if isinstance(followed, SolverError):
                continue
            solves += followed.solves
            field = exact.field(followed)
            tried[u] = (objective(field, point), point, followed, field)

    def best() -> tuple[list[float], int]:
        order = sorted(tried)
        return order, int(np.argmin([tried[u][0] for u in order]))

    on_the_fold(list(np.log(fold_time_constants(share, hold, bounds[0], bounds[1],
                                                FOLD_POINTS))))
    if not stop_requested():
        order, k = best()
        on_the_fold([0.5 * (order[k] + order[j]) for j in (k - 1, k + 1)
                     if 0 <= j < len(order)])
    order, k = best()
    if not stop_requested() and 0 < k < len(order) - 1:
        u = np.array(order[k - 1:k + 2])
        curvature, slope, _ = np.polyfit(u, [tried[v][0] for v in u], 2)
        if curvature > 0.0:
            on_the_fold([float(np.clip(-slope / (2.0 * curvature), u[0], u[2]))])
    order, k = best()
    _, found, followed, field = tried[order[k]]
    return found, followed, field, solves
