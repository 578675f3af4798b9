"""Where a reduced model's static solve starts: its own equilibria, moved to first order.

A solve from rest to a pulled Diamond takes 9-15 Newton iterations, most of them spent
folding the body from far away. A reduced model keeps equilibria spread over its actuation
box in its own coordinates, with their first-order response to the cable inputs, and a
solve given no start begins at the nearest one moved to first order:

    q_0 = q_k + J_k (u - u_k),   k = argmin_k |(u - u_k) / (box width)|.

They are the training equilibria (the full model's, solved again on the basis) and a grid
of `levels` inputs per cable across the box, solved one from the next along a path that
changes one cable by one grid step at a time (`serpentine_grid`). From the 12 training
equilibria alone Newton's method took 3-7 iterations on the coarse Diamond (median 5); from
a grid of 4 levels (256 equilibria) 3-4 (median 3), as from 5 levels (625), for 16 random
actuations (`benchmarks/bench_reduced.py --starts`; docs/reduced_model.md).

J_k = dq/du at equilibrium k, from the saddle-point system of eq. 4-5 with the
displacement-controlled cables that pull there held (a slack one neither holds nor moves
anything):

    Z = K^-1 (H V)^T,   W = H V Z,
    dq/du_d = Z_d W_dd^-1,   dq/dT_f = Z_f - Z_d W_dd^-1 W_df

for displacement-controlled cables d and force-controlled cables f.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from softforce_cli.errors import ModelError
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.statics import Equilibrium, SolverError, solve_equilibrium

if TYPE_CHECKING:  # reduced_model keeps a StartLibrary
    from softforce_cli.fem.reduction.reduced_model import ReducedModel

# Training stops when the reduced model's equilibrium at one of its own training actuations
# is this fraction of the training's largest shape away from the full model's. A sampling
# whose points no longer hold the body gives such an equilibrium or none (on the test beam
# at ECSW 0.6: 19 mm on a 9 mm shape); a usable one is within a few percent (the Diamond at
# 3e-2: 0.7%), and one in between warns after validation (train.VALIDATION_WARNING_FRACTION).
TRAINED_EQUILIBRIUM_LIMIT = 0.5


@dataclass(frozen=True)
class StartLibrary:
    """Equilibria of a reduced model to start its static solves from.

    inputs        : (k, a) cable inputs of each equilibrium (control units: mm or N).
    coordinates   : (k, r) its reduced coordinates q.
    sensitivities : (k, r, a) dq/du there (per mm or N of each cable's input).
    scale         : (a,) the distance unit per cable (the training box's width).
    """

    inputs: np.ndarray
    coordinates: np.ndarray
    sensitivities: np.ndarray
    scale: np.ndarray

    def first(self, count: int) -> StartLibrary:
        """The library of its first `count` equilibria (the training's come first)."""
        return StartLibrary(self.inputs[:count], self.coordinates[:count],
                            self.sensitivities[:count], self.scale)

    def predict(self, values: np.ndarray) -> np.ndarray:
        """(r,) q predicted at cable inputs (a,): the nearest equilibrium, to first order."""
        offsets = np.asarray(values, dtype=float) - self.inputs
        nearest = int(np.argmin(np.linalg.norm(offsets / self.scale, axis=1)))
        return self.coordinates[nearest] + self.sensitivities[nearest] @ offsets[nearest]


def input_sensitivities(rows: np.ndarray, responses: np.ndarray, controlled: np.ndarray
                        ) -> np.ndarray:
    """(c, a) dq/du from the cables' rows H T (a, c), their responses Z = K^-1 (H T)^T (c, a)
    and which are displacement-controlled (a,) bool (module docstring)."""
    compliance = rows @ responses  # W (a, a)
    held = np.flatnonzero(controlled)
    if not len(held):
        return responses
    # lstsq: a cable whose points are all clamped has a zero row and holds nothing
    tension_per_input = np.linalg.lstsq(compliance[np.ix_(held, held)],
                                        np.eye(len(held)), rcond=None)[0]
    out = responses - responses[:, held] @ tension_per_input @ compliance[held]
    out[:, held] = responses[:, held] @ tension_per_input
    return out


MAX_GRID_STARTS = 4096  # 4 levels for up to 6 cables, 3 for 7: minutes of training


def grid_levels(levels: int, cables: int) -> int:
    """The grid levels per cable for `levels` asked: fewer when levels^cables would pass
    MAX_GRID_STARTS."""
    while levels > 1 and levels**cables > MAX_GRID_STARTS:
        levels -= 1
    return levels


def serpentine_grid(low: np.ndarray, high: np.ndarray, levels: int) -> np.ndarray:
    """(levels^a, a) the grid of `levels` values per cable over the box [low, high] (a,),
    ordered so that consecutive points differ in one cable by one grid step."""
    steps = np.linspace(0.0, 1.0, levels)
    order = np.zeros((1, 0), dtype=int)
    for _ in range(len(low)):
        # each new cable's column: the grid so far forward, backward, forward, ...
        order = np.vstack([np.column_stack([order if level % 2 == 0 else order[::-1],
                                            np.full(len(order), level)])
                           for level in range(levels)])
    return low + steps[order] * (high - low)


def start_library(model: ReducedModel, controls: tuple[str, ...], actuations: np.ndarray,
                  positions_mm: np.ndarray, low: np.ndarray, high: np.ndarray, levels: int
                  ) -> StartLibrary:
    """The reduced model's own equilibria at the training actuations (k, a), each solved
    from the full model's equilibrium there (k, n, 3) mm, and on a grid of `levels` per
    cable over the box [low, high] (a,), each solved from the one before (a grid point
    that does not solve is left out and the next starts from the library); with their
    sensitivities. Distances between inputs are in box widths. ModelError when the model
    finds no equilibrium at a training actuation, or one more than TRAINED_EQUILIBRIUM_LIMIT
    of the training's largest shape from the full model's (a sampling too loose for the
    robot)."""
    from softforce_cli.fem.reduction.reduced_model import ReducedModelWarning  # (a cycle)

    with warnings.catch_warnings():
        # a corner of the box may fold the body past the training's shapes: still the
        # reduced model's own equilibrium there, the start its solves want
        warnings.simplefilter("ignore", ReducedModelWarning)
        return _solved_library(model, controls, actuations, positions_mm, low, high, levels)


def _solved_library(model: ReducedModel, controls: tuple[str, ...], actuations: np.ndarray,
                    positions_mm: np.ndarray, low: np.ndarray, high: np.ndarray, levels: int
                    ) -> StartLibrary:
    """start_library's solves."""
    scale = np.maximum(np.asarray(high, float) - low, 1e-9)
    inputs = CableInputs(controls, np.zeros(len(controls)))
    retrain = ("its sampling is too loose for this robot; retrain with a smaller ECSW "
               "tolerance (--ecsw-tolerance) or more modes")
    sampled = f"the reduced model ({len(model.reduction.points)} sampled points)"
    try:
        solved = [solve_equilibrium(model, CableInputs(controls, values), start_mm=positions)
                  for values, positions in zip(actuations, positions_mm, strict=True)]
    except SolverError:
        raise ModelError(f"{sampled} finds no equilibrium at one of its own training "
                         f"actuations: {retrain}") from None
    # an equilibrium far from the full model's is as broken as none: which of the two a
    # broken sampling gives is up to Newton's path (round-off decides it)
    rest = model.rest_nodes_mm
    shape = float(np.sqrt(np.mean(np.sum((positions_mm - rest) ** 2, axis=2), axis=1)).max())
    off = max(float(np.sqrt(np.mean(np.sum((e.positions_mm - x) ** 2, axis=1))))
              for e, x in zip(solved, positions_mm, strict=True))
    if off > TRAINED_EQUILIBRIUM_LIMIT * shape:
        raise ModelError(f"{sampled} is {off:.2g} mm RMS off its full model at one of its own "
                         f"training actuations ({100 * off / shape:.0f}% of their largest "
                         f"shape, {shape:.3g} mm): {retrain}")
    entries = [_entry(equilibrium, inputs) for equilibrium in solved]
    library = _library(np.asarray(actuations, dtype=float), entries, scale)
    if levels < 2:
        return library
    trained = dataclasses.replace(model, reduction=dataclasses.replace(model.reduction,
                                                                        starts=library))
    grid, grid_entries, last = [], [], None
    for values in serpentine_grid(low, high, levels):
        try:
            last = solve_equilibrium(trained, CableInputs(controls, values), start=last)
        except SolverError:
            last = None
            continue
        grid.append(values)
        grid_entries.append(_entry(last, inputs))
    return _library(np.vstack([library.inputs, *grid]), entries + grid_entries, scale)


def _entry(equilibrium: Equilibrium, inputs: CableInputs) -> tuple[np.ndarray, np.ndarray]:
    """(q (r,), dq/du (r, a)) of a reduced equilibrium, the cables' controls those of
    `inputs`. A slack displacement-controlled cable (no tension) stays slack for a small
    change of any input: it holds nothing and its own input moves nothing."""
    state = equilibrium.state
    factor = state.space.factorize(state.tangent(equilibrium.cable_tensions_n))
    _, rows = state.cables()
    held = inputs.held(equilibrium.cable_tensions_n)
    slack = inputs.displacement_controlled & ~held
    sensitivities = input_sensitivities(rows, factor.solve(rows.T), held)
    sensitivities[:, slack] = 0.0
    return state.q, sensitivities


def _library(inputs: np.ndarray, entries: list[tuple[np.ndarray, np.ndarray]],
             scale: np.ndarray) -> StartLibrary:
    return StartLibrary(inputs, np.array([q for q, _ in entries]),
                        np.array([dq for _, dq in entries]), np.asarray(scale, dtype=float))
