"""Contact force intensities by the QP of the paper's eq. 11-14.

    min_lam  1/2 |W_el lam + delta_e_free^N - delta_c^N|^2 + 1/2 rho |lam_f|^2      (11), (12)
    s.t.     lam_a = lam_a^r                               force-controlled cables  (13)
             W_aa lam_a + W_af lam_f + delta_a_free = delta_a^r   taut displacement ones (14)
             lam_a = 0                                      slack displacement ones
             lam_f >= 0                                     unilateral contacts
             mu lam_n >= |(lam_t1, lam_t2)|                 friction cones

lam = [lam_a, lam_f]: cable tensions (N) then contact force intensities (N). W_el = [W_ea^N
W_ef^N] projects them on the normals of the matched feature points (mm/N). The Tikhonov term
rho keeps the problem well posed when two contacts sit close together (their columns of W_ef
nearly coincide); it is relative to the mean squared column norm of W_ef, so it has no unit
and does not depend on the robot's stiffness.

A contact in a friction cone has three columns, along its inward normal and two tangents
(lam_n, lam_t1, lam_t2): Coulomb's law bounds the tangential force by mu times the normal
one, a second-order cone, which Clarabel handles as it does the sign bounds.

A cable can pull but not push: a displacement-controlled cable whose attachment comes closer
than its input asks goes slack (no tension) instead of holding its length with a negative
tension, as the paper's eq. 14 alone would have it. Which cables are taut is an active set,
the one the FE statics uses (fem.statics): release the cables that would push, hold again
those that would be stretched beyond their input, until neither happens. On a robot whose
cables all stay taut (the Diamond under gravity) this is eq. 14 itself; on a finger with
antagonistic cables, the slack ones pushed with up to 3.2 N and its probes read 85% off
(median) instead of 17% (docs/sensing_studies.md, "Other robots").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import clarabel
import numpy as np
import scipy.sparse as sp

from softforce_cli.errors import SolverError

# Relative Tikhonov weight on the contact forces: small enough to move an intensity by less
# than 0.1% when contacts are well separated (measured on the sample probes), large enough to
# split a pair of coincident contacts evenly instead of arbitrarily.
RELATIVE_REGULARIZATION = 1e-6
# Interior-point tolerances: forces to about a micronewton.
CLARABEL_TOLERANCE = 1e-10
# A taut cable's tension below -this pushes (slack it); a slack one's end further than this
# beyond its input is stretched (hold it): round-off of the QP's solution, not physics.
SLACK_TOLERANCE_N = 1e-7
SLACK_TOLERANCE_MM = 1e-7


@dataclass(frozen=True)
class IntensityProblem:
    """The linearised model projected on the matched features' normals (eq. 10).

    W_ea (e, a) mm/N, W_ef (e, f) mm/N: normal motion of the e matched features per unit cable
    tension and per unit contact force; delta_e_free (e,) mm and observed_mm (e,) mm: free and
    observed normal coordinates (x . n); W_aa (a, a), W_af (a, f) mm/N and delta_a_free (a,) mm
    for the cables (eq. 4); unilateral (f,) bool: columns whose force may only push (>= 0);
    cones (k, 3) int: the (normal, tangent, tangent) columns of each contact in a friction
    cone, with friction_coefficient mu (their columns are not also unilateral: the cone
    makes the normal force >= 0).
    """

    W_ea: np.ndarray
    W_ef: np.ndarray
    delta_e_free: np.ndarray
    observed_mm: np.ndarray
    W_aa: np.ndarray
    W_af: np.ndarray
    delta_a_free: np.ndarray
    unilateral: np.ndarray
    cones: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int64))
    friction_coefficient: float = 0.0

    def feasible(self, contact_forces_n: np.ndarray) -> bool:
        """Whether forces (f,) satisfy the sign bounds and the friction cones."""
        forces = contact_forces_n
        cones = np.asarray(self.cones, dtype=np.int64).reshape(-1, 3)
        tangential = np.linalg.norm(forces[cones[:, 1:]], axis=1)
        return bool(np.all(forces[self.unilateral] >= 0.0)
                    and np.all(self.friction_coefficient * forces[cones[:, 0]] >= tangential))


@dataclass(frozen=True)
class Intensities:
    """cable_tensions_n (a,), contact_forces_n (f,), residual_mm (e,) normal fit residual
    W_el lam + delta_free - delta_c per matched feature."""

    cable_tensions_n: np.ndarray
    contact_forces_n: np.ndarray
    residual_mm: np.ndarray

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residual_mm**2))) if len(self.residual_mm) else 0.0


def solve_intensities(
    problem: IntensityProblem,
    control: tuple[str, ...],
    actuation: np.ndarray,
    regularization: float = RELATIVE_REGULARIZATION,
) -> Intensities:
    """Cable tensions and contact forces of eq. 11-14 for the cables' inputs actuation (a,)
    (mm for displacement control, N for force control, per `control`)."""
    a, f = problem.W_ea.shape[1], problem.W_ef.shape[1]
    W = np.hstack([problem.W_ea, problem.W_ef])
    rhs = problem.observed_mm - problem.delta_e_free
    rho = regularization * float(np.mean(problem.W_ef**2)) * len(rhs) if f else 0.0
    Q = W.T @ W + np.diag(np.r_[np.zeros(a), np.full(f, rho)])
    c = -W.T @ rhs
    actuation = np.asarray(actuation, dtype=float)
    displacement = np.array([kind == "displacement" for kind in control], dtype=bool)
    cable_rows = np.hstack([problem.W_aa, problem.W_af])
    taut = displacement.copy()
    for _ in range(2 ** int(displacement.sum())):
        lam = _qp_with_taut(problem, Q, c, actuation, displacement, taut)
        gap = cable_rows @ lam + problem.delta_a_free - actuation  # > 0: shorter than asked
        pushing = taut & (lam[:a] < -SLACK_TOLERANCE_N)
        stretched = displacement & ~taut & (gap < -SLACK_TOLERANCE_MM)
        if not pushing.any() and not stretched.any():
            break
        taut = (taut & ~pushing) | stretched
    return Intensities(lam[:a], lam[a:], W @ lam - rhs)


def _qp_with_taut(problem: IntensityProblem, Q: np.ndarray, c: np.ndarray,
                  actuation: np.ndarray, displacement: np.ndarray,
                  taut: np.ndarray) -> np.ndarray:
    """lam of the QP with the displacement-controlled cables `taut` (a,) bool held at their
    inputs (eq. 14) and the others slack (zero tension)."""
    a = problem.W_ea.shape[1]
    A, b = _actuation_rows(problem, actuation, displacement, taut)
    lam = _equality_qp(Q, c, A, b)
    if lam is None or not problem.feasible(lam[a:]):
        cones = a + np.asarray(problem.cones, dtype=np.int64).reshape(-1, 3)
        lam = _bounded_qp(Q, c, A, b, a + np.flatnonzero(problem.unilateral), cones,
                          problem.friction_coefficient)
    lam[:a][displacement & ~taut] = 0.0  # exactly, not the solver's round-off
    return lam


def _actuation_rows(
    problem: IntensityProblem, actuation: np.ndarray, displacement: np.ndarray,
    taut: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Equality rows A lam = b: eq. 14 for the taut displacement-controlled cables, eq. 13
    for the force-controlled ones, zero tension for the slack ones."""
    a, f = problem.W_ea.shape[1], problem.W_ef.shape[1]
    held = displacement & taut
    A = np.where(held[:, None], np.hstack([problem.W_aa, problem.W_af]),
                 np.hstack([np.eye(a), np.zeros((a, f))]))
    b = np.where(held, actuation - problem.delta_a_free, np.where(displacement, 0.0, actuation))
    return A, b


def _equality_qp(Q: np.ndarray, c: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The KKT solution ignoring the sign bounds, or None when the KKT system is singular."""
    n, m = len(c), len(b)
    kkt = np.block([[Q, A.T], [A, np.zeros((m, m))]])
    try:
        solution = np.linalg.solve(kkt, np.r_[-c, b])
    except np.linalg.LinAlgError:
        return None
    return solution[:n] if np.all(np.isfinite(solution)) else None


def _bounded_qp(
    Q: np.ndarray, c: np.ndarray, A: np.ndarray, b: np.ndarray, nonnegative: np.ndarray,
    friction_cones: np.ndarray | None = None, friction_coefficient: float = 0.0,
) -> np.ndarray:
    """The QP with lam[nonnegative] >= 0 and, for each row (n, t1, t2) of friction_cones
    (k, 3), mu lam[n] >= |(lam[t1], lam[t2])|, by Clarabel (an interior-point method)."""
    n = len(c)
    friction_cones = np.zeros((0, 3), np.int64) if friction_cones is None else friction_cones
    identity = np.eye(n)
    bound_rows = -identity[nonnegative]
    # Clarabel's constraints are A x + s = b, s in a cone: s = (mu lam_n, lam_t1, lam_t2)
    # lies in the second-order cone when mu lam_n >= |(lam_t1, lam_t2)|
    scale = np.array([friction_coefficient, 1.0, 1.0])
    cone_rows = -(identity[friction_cones] * scale[None, :, None]).reshape(-1, n)
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = CLARABEL_TOLERANCE
    cones = [clarabel.ZeroConeT(len(b))]
    cones += [clarabel.NonnegativeConeT(len(nonnegative))] if len(nonnegative) else []
    cones += [clarabel.SecondOrderConeT(3) for _ in range(len(friction_cones))]
    solver = clarabel.DefaultSolver(
        sp.triu(sp.csc_matrix(Q), format="csc"), c,
        sp.csc_matrix(np.vstack([A, bound_rows, cone_rows])),
        np.r_[b, np.zeros(len(nonnegative) + len(cone_rows))], cones, settings,
    )
    solution = solver.solve()
    if solution.status not in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved):
        raise SolverError(f"the force intensity QP failed ({solution.status})")
    lam = np.array(solution.x)
    lam[nonnegative] = np.maximum(lam[nonnegative], 0.0)
    return lam
