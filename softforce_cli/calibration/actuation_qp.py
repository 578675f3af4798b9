"""The bounded actuation QP of eq. 8-9: cable tensions that best match the observed markers.

    min_lam  1/2 |W_ea lam + delta_e_free - delta_tran|^2   (8), or 1/2 lam^T Q lam + c^T lam (9)
    s.t.     lam >= 0                                   cables only pull
             min <= lam <= max                          force-controlled cables (N)
             min <= W_aa lam + delta_a_free <= max      displacement-controlled cables (mm, eq. 4)

The unknown is always the tension vector lam; displacement bounds become linear constraints
through eq. 4, so one QP serves force, displacement and mixed control. A problem whose
unconstrained least-squares solution is feasible (the usual case) is solved exactly by lstsq;
otherwise Clarabel solves it and the answer is polished on its active set. Bounds that no
tensions meet are relaxed minimally and reported, never silently.
"""

from __future__ import annotations

from dataclasses import dataclass

import clarabel
import numpy as np
import scipy.sparse as sp

from softforce_cli.errors import CalibrationError
from softforce_cli.model.config import CableSpec

# A constraint row is violated beyond round-off when G lam - h exceeds this (relative to 1+|h|);
# a row is active when its slack is below ACTIVE_TOLERANCE (interior-point answers approach
# the boundary to about 1e-9 at Clarabel's tolerances set below).
FEASIBILITY_TOLERANCE = 1e-9
ACTIVE_TOLERANCE = 1e-6
CLARABEL_TOLERANCE = 1e-10


@dataclass(frozen=True)
class ActuationBounds:
    """Each cable's control mode and input bounds, in its control units.

    names   : cable names, robot file order.
    control : per cable, "displacement" (bounds on the shortening, mm) or "force" (N).
    lower   : (a,) float64; may be -inf.
    upper   : (a,) float64; may be +inf.
    """

    names: tuple[str, ...]
    control: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def from_specs(cls, specs: tuple[CableSpec, ...]) -> ActuationBounds:
        bounds = cls(
            tuple(s.name for s in specs), tuple(s.control for s in specs),
            np.array([s.min for s in specs], dtype=float),
            np.array([s.max for s in specs], dtype=float),
        )
        bounds.check()
        return bounds

    @property
    def displacement(self) -> np.ndarray:
        """(a,) bool, True for displacement-controlled cables."""
        return np.array([c == "displacement" for c in self.control], dtype=bool)

    def check(self) -> None:
        """CalibrationError for bounds no cable tension can meet on its own."""
        for i, name in enumerate(self.names):
            if self.lower[i] > self.upper[i]:
                raise CalibrationError(f"cable {name!r}: min {self.lower[i]:g} > max "
                                       f"{self.upper[i]:g}; fix the bounds in the robot file")
            if self.control[i] == "force" and self.upper[i] < 0:
                raise CalibrationError(
                    f"cable {name!r} is force-controlled with max {self.upper[i]:g} N < 0, but a "
                    "cable can only pull; set max >= 0 in the robot file")


def constraint_rows(
    W_aa: np.ndarray, delta_a_free: np.ndarray, bounds: ActuationBounds
) -> tuple[np.ndarray, np.ndarray, list[int], np.ndarray]:
    """The feasible set as G lam <= h: G (r, a), h (r,), the cable index of each row, and
    (r,) bool whether the row is a user bound (False: lam >= 0, cables only pull)."""
    a = len(bounds.names)
    eye = np.eye(a)
    rows, limits, cables, user = [], [], [], []

    def add(row: np.ndarray, limit: float, cable: int, from_user: bool) -> None:
        if np.isfinite(limit):
            rows.append(row)
            limits.append(limit)
            cables.append(cable)
            user.append(from_user)

    for i in range(a):
        if bounds.control[i] == "force":
            add(-eye[i], -max(bounds.lower[i], 0.0), i, bounds.lower[i] > 0)
            add(eye[i], bounds.upper[i], i, True)
        else:
            add(-eye[i], 0.0, i, False)
            add(W_aa[i], bounds.upper[i] - delta_a_free[i], i, True)
            add(-W_aa[i], delta_a_free[i] - bounds.lower[i], i, True)
    return (np.array(rows, dtype=float).reshape(len(rows), a), np.array(limits, dtype=float),
            cables, np.array(user, dtype=bool))


@dataclass(frozen=True)
class ActuationSolution:
    """tensions_n (a,) N; bound_violation (a,) >= 0: how far (mm or N) each cable's bounds had
    to be relaxed for the linearised constraints to hold (all 0 when they hold as given)."""

    tensions_n: np.ndarray
    bound_violation: np.ndarray


def solve_actuation_qp(
    W_ea: np.ndarray,
    delta_e_free: np.ndarray,
    target_mm: np.ndarray,
    W_aa: np.ndarray,
    delta_a_free: np.ndarray,
    bounds: ActuationBounds,
) -> ActuationSolution:
    """Cable tensions solving eq. 9 for the linearised model (eq. 3-4).

    W_ea (3k, a) mm/N, delta_e_free (3k,) mm, target_mm (3k,) the observed markers in the robot
    frame (delta_tran), W_aa (a, a) mm/N, delta_a_free (a,) mm. When no tensions meet every
    bound, the bounds are relaxed by the least total amount that makes them hold (elastic
    mode) and the relaxation is reported: far from equilibrium a linearisation may conflict
    with bounds that the converged configuration meets, so the caller decides at the end.
    """
    G, h, cables, relaxable = constraint_rows(W_aa, delta_a_free, bounds)
    rhs = target_mm - delta_e_free
    violation = np.zeros(len(bounds.names))
    tensions = np.linalg.lstsq(W_ea, rhs, rcond=None)[0]
    if _feasible(G, h, tensions):
        return ActuationSolution(tensions, violation)
    Q, c = W_ea.T @ W_ea, -W_ea.T @ rhs
    solution = _clarabel_qp(Q, c, G, h)
    if solution is None:
        relaxation = _least_violation(G, h, relaxable)
        np.maximum.at(violation, cables, relaxation)
        h = h + relaxation * (1.0 + 1e-9)
        solution = _clarabel_qp(Q, c, G, h)
        if solution is None:
            raise CalibrationError("the actuation QP found no tensions even with relaxed cable "
                                   "bounds; check the robot file's cables")
    polished = _polish(W_ea, rhs, G, h, solution)
    if polished is not None and _objective(W_ea, rhs, polished) <= _objective(
            W_ea, rhs, solution) + 1e-12 * (1.0 + rhs @ rhs):
        solution = polished
    return ActuationSolution(solution, violation)


def _feasible(G: np.ndarray, h: np.ndarray, tensions: np.ndarray) -> bool:
    return bool(np.all(G @ tensions - h <= FEASIBILITY_TOLERANCE * (1.0 + np.abs(h))))


def _objective(W: np.ndarray, rhs: np.ndarray, tensions: np.ndarray) -> float:
    return float(np.sum((W @ tensions - rhs) ** 2))


def _settings() -> clarabel.DefaultSettings:
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = CLARABEL_TOLERANCE
    settings.tol_feas = CLARABEL_TOLERANCE
    return settings


def _clarabel_qp(Q: np.ndarray, c: np.ndarray, G: np.ndarray, h: np.ndarray) -> np.ndarray | None:
    """argmin 1/2 x^T Q x + c^T x s.t. G x <= h, or None when infeasible."""
    solver = clarabel.DefaultSolver(
        sp.triu(sp.csc_matrix(Q), format="csc"), c, sp.csc_matrix(G), h,
        [clarabel.NonnegativeConeT(len(h))], _settings(),
    )
    solution = solver.solve()
    status = solution.status
    if status in (clarabel.SolverStatus.PrimalInfeasible,
                  clarabel.SolverStatus.AlmostPrimalInfeasible):
        return None
    if status not in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved):
        raise CalibrationError(f"the actuation QP failed ({status}); check the robot's cable "
                               "bounds and the marker positions")
    return np.array(solution.x)


def _polish(W: np.ndarray, rhs: np.ndarray, G: np.ndarray, h: np.ndarray,
            tensions: np.ndarray) -> np.ndarray | None:
    """Exact least squares with the constraints active at `tensions` held as equalities."""
    active = h - G @ tensions < ACTIVE_TOLERANCE * (1.0 + np.abs(h))
    if not active.any():
        candidate = np.linalg.lstsq(W, rhs, rcond=None)[0]
    else:
        A = G[active]
        a = W.shape[1]
        kkt = np.block([[W.T @ W, A.T], [A, np.zeros((len(A), len(A)))]])
        solved = np.linalg.lstsq(kkt, np.concatenate([W.T @ rhs, h[active]]), rcond=None)[0]
        candidate = solved[:a]
    return candidate if _feasible(G, h, candidate) else None


def _least_violation(G: np.ndarray, h: np.ndarray, relaxable: np.ndarray) -> np.ndarray:
    """(r,) >= 0: the least total relaxation s of the relaxable rows of G lam <= h that some
    lam meets (an LP); the other rows (cables only pull) hold as they are."""
    r, a = G.shape
    k = int(relaxable.sum())
    pick = np.zeros((r, k))
    pick[np.flatnonzero(relaxable), np.arange(k)] = 1.0
    # min sum(s) s.t. G lam - P s <= h, -s <= 0, over (lam, s).
    A = sp.csc_matrix(np.block([[G, -pick], [np.zeros((k, a)), -np.eye(k)]]))
    solver = clarabel.DefaultSolver(
        sp.csc_matrix((a + k, a + k)), np.concatenate([np.zeros(a), np.ones(k)]), A,
        np.concatenate([h, np.zeros(k)]), [clarabel.NonnegativeConeT(r + k)], _settings(),
    )
    solution = solver.solve()
    if solution.status not in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved):
        raise CalibrationError(f"the cable bounds' feasibility check failed ({solution.status})")
    return pick @ np.maximum(np.array(solution.x)[a:], 0.0)
