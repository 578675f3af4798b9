"""Energy-conserving sampling and weighting (ECSW): which elements a reduced model evaluates.

Training asks for weights w >= 0, as few nonzero as possible, such that the weighted sum of
element contributions reproduces the reduced internal forces (and tangent actions) of every
training state:

    min |C w - b|   subject to w >= 0,   stopped once |C w - b| <= tolerance |b|,

with C[(state, mode), e] = V_e^T g_e(x_state) (Farhat, Chapman and Avery, IJNME 2015). That is
Lawson and Hanson's active-set NNLS (the algorithm of scipy.optimize.nnls) stopped early: it
adds one element at a time, so stopping at the tolerance leaves a few hundred of them.
scipy's compiled nnls only returns the exact optimum (up to one element per row), so the loop
is here, with the Gram matrix of the active columns grown one column at a time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from softforce_cli.fem.model import FEModel

# Relative residual of the weighted element sums over the training set: 1e-3 keeps the
# reduced forces and tangents within 0.1% of the exact projection on the training states.
ECSW_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Sampling:
    """ECSW result: elements (s,) int64, weights (s,) > 0, relative residual achieved."""

    elements: np.ndarray
    weights: np.ndarray
    relative_residual: float


def force_contributions(model: FEModel, basis: np.ndarray, positions_mm: np.ndarray
                        ) -> np.ndarray:
    """(r, m) V_e^T g_e(x): each element's share of the reduced internal forces at (n, 3)."""
    everything = np.arange(len(model.tets))
    _, forces, _ = model.element_terms(positions_mm, everything, with_tangent=False)
    local = basis[model.element_dofs]  # (m, 3k, r)
    return np.einsum("mar,ma->rm", local, forces)


def tangent_contributions(model: FEModel, basis: np.ndarray, positions_mm: np.ndarray,
                          directions: np.ndarray) -> np.ndarray:
    """(d * r, m), direction-major: V_e^T K_e(x) V_e Q, each element's share of the reduced
    tangent applied to reduced directions Q (r, d), at positions (n, 3)."""
    everything = np.arange(len(model.tets))
    _, _, stiffness = model.element_terms(positions_mm, everything, with_tangent=True)
    local = basis[model.element_dofs]  # (m, 3k, r)
    moved = stiffness @ (local @ directions)  # (m, 3k, d)
    return np.einsum("mar,mad->drm", local, moved).reshape(-1, len(model.tets))


def sparse_nnls(C: np.ndarray, b: np.ndarray, tolerance: float = ECSW_TOLERANCE,
                max_elements: int | None = None,
                progress: Callable[[int, int], None] | None = None) -> Sampling:
    """Lawson-Hanson NNLS on C (rows, m), b (rows,), stopped at |C w - b| <= tolerance |b|
    or max_elements nonzero weights. With tolerance 0 it is scipy.optimize.nnls's optimum.

    Works on inner products only: with d = C^T b and the columns M = C^T C_P of the active
    set P, the gradient is d - M w and |C w - b|^2 = b.b - 2 w.d_P + w.G w (G = M[P]), so an
    iteration costs one product C^T c_j, not a pass over C[:, P].
    """
    m = C.shape[1]
    limit = m if max_elements is None else min(max_elements, m)
    bb = float(b @ b)
    target = tolerance**2 * bb
    d = C.T @ b
    scale = 1e-14 * float(np.abs(d).max(initial=0.0))
    active: list[int] = []
    cross = np.zeros((m, 0))  # C^T C[:, active]
    weights = np.zeros(0)
    residual2 = bb
    for _ in range(3 * m):
        if residual2 <= target or len(active) >= limit:
            break
        gradient = d - cross @ weights
        gradient[active] = -np.inf
        best = int(np.argmax(gradient))
        if gradient[best] <= scale:
            break  # optimal: no element lowers the residual
        active.append(best)
        cross = np.column_stack([cross, C.T @ C[:, best]])
        weights = np.append(weights, 0.0)
        while True:
            gram = cross[active]
            trial = _solve_gram(gram, d[active])
            if np.all(trial > 0.0):
                weights = trial
                break
            # step from the feasible weights towards trial until one weight reaches zero
            falling = trial <= 0.0
            step = np.min(weights[falling] / (weights[falling] - trial[falling]))
            weights = weights + step * (trial - weights)
            keep = weights > 1e-14 * max(float(weights.max(initial=0.0)), 1e-300)
            keep[np.argmin(np.where(falling, weights, np.inf))] = False
            index = np.flatnonzero(keep)
            active = [active[i] for i in index]
            cross = cross[:, index]
            weights = weights[index]
            if not active:
                break
        gram = cross[active]
        residual2 = max(bb - 2 * weights @ d[active] + weights @ gram @ weights, 0.0)
        if progress is not None:
            progress(len(active), limit)
    order = np.argsort(active)
    residual = b - C[:, active] @ weights if active else b
    return Sampling(np.asarray(active, dtype=np.int64)[order], weights[order],
                    float(np.linalg.norm(residual) / max(np.sqrt(bb), 1e-300)))


def _solve_gram(gram: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Least squares on the active columns through their Gram matrix (normal equations;
    a tolerance of 1e-3 needs far less than their lost digits)."""
    try:
        factor = scipy.linalg.cho_factor(gram, check_finite=False)
        return scipy.linalg.cho_solve(factor, right, check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return np.linalg.lstsq(gram, right, rcond=None)[0]
