"""Where a reduced model's static solve starts: its training equilibria, moved to first order.

A solve from rest to a pulled Diamond takes 9-15 Newton iterations, most of them spent
folding the body from far away. A reduced model was trained at static equilibria spread
over the actuation box; it keeps them in its own coordinates, with their first-order
response to the cable inputs, and a solve given no start begins at the nearest one moved
to first order:

    q_0 = q_k + J_k (u - u_k),   k = argmin_k |(u - u_k) / (box width)|,

which Newton's method finishes in 3-7 iterations on the Diamond, against 8-13 from rest
(`benchmarks/bench_reduced.py --starts`, 16 random actuations).
J_k = dq/du at equilibrium k, from the saddle-point system of eq. 4-5 with every
displacement-controlled cable taut (the side a pull goes):

    Z = K^-1 (H V)^T,   W = H V Z,
    dq/du_d = Z_d W_dd^-1,   dq/dT_f = Z_f - Z_d W_dd^-1 W_df

for displacement-controlled cables d and force-controlled cables f.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.statics import solve_equilibrium

if TYPE_CHECKING:  # reduced_model keeps a StartLibrary
    from softforce_cli.fem.reduction.reduced_model import ReducedModel


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


def start_library(model: ReducedModel, controls: tuple[str, ...], actuations: np.ndarray,
                  positions_mm: np.ndarray, scale: np.ndarray) -> StartLibrary:
    """The reduced model's own equilibria at training actuations (k, a), each solved from
    the full model's equilibrium there (k, n, 3) mm, with their sensitivities; `scale` (a,)
    the distance unit per cable."""
    space = model.coordinates
    coordinates, sensitivities = [], []
    for values, positions in zip(actuations, positions_mm, strict=True):
        inputs = CableInputs(controls, values)
        equilibrium = solve_equilibrium(model, inputs, start_mm=positions)
        state = equilibrium.state
        factor = space.factorize(state.tangent(equilibrium.cable_tensions_n))
        _, rows = state.cables()
        responses = factor.solve(rows.T)
        coordinates.append(state.q)
        sensitivities.append(input_sensitivities(rows, responses,
                                                 inputs.displacement_controlled))
    return StartLibrary(np.asarray(actuations, dtype=float), np.array(coordinates),
                        np.array(sensitivities), np.asarray(scale, dtype=float))
