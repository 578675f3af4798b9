"""Energy-conserving sampling and weighting (ECSW): which elements a reduced model evaluates.

Training asks for weights w >= 0, as few nonzero as possible, such that the weighted sum of
element contributions reproduces the reduced internal forces (and tangent actions) of every
training state:

    min |C w - b|   subject to w >= 0,   stopped once |C w - b| <= tolerance |b|,

with C[(state, mode), e] = V_e^T g_e(x_state) (Farhat, Chapman and Avery, IJNME 2015), each
state's rows measured in the energy of the displacement error they cause (energy_weight). That is
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
import scipy.linalg.blas

from softforce_cli.fem.element import deformation_gradients, gradient_operators
from softforce_cli.fem.model import FEModel

# Relative residual of the weighted element sums over the training set: 1e-3 keeps the
# sampled forces and tangents of the training states within about 0.1% of the exact
# projection's, measured in the energy of the displacement they cause (energy_weight).
ECSW_TOLERANCE = 1e-3
# The element pass (the first of two: elements, then single points among theirs) fits this
# much tighter, so that the point pass can reach the tolerance with a subset of its points.
POINT_TOLERANCE_FACTOR = 0.5


def energy_weight(stiffness: np.ndarray, held_rows: np.ndarray) -> np.ndarray | None:
    """(r - c, r) M = L^-1 N^T such that |M df|^2 = df^T dq, the energy of the displacement
    error dq (r,) that a reduced force error df (r,) N causes at a state of reduced tangent
    K (r, r) N/mm with the rows H (c, r) held (taut displacement-controlled cables): dq is the
    solution of [K H^T; H 0] [dq; dl] = [df; 0], N (r, r - c) an orthonormal basis of H's
    null space, L L^T = N^T K N. None where N^T K N is not positive definite (a state past
    its stability: no energy norm).

    A force error along a stiff direction moves the body little and one along a soft
    direction much: the Diamond, held by its cables near its apex-tipping instability, has a
    held reduced tangent whose eigenvalues span five orders of magnitude. Fitting the forces
    in this norm rather than their own puts the sampling's points where they hold the shape
    (docs/reduced_model.md, "ECSW in the energy norm").
    """
    null = scipy.linalg.null_space(held_rows) if len(held_rows) else np.eye(len(stiffness))
    try:
        factor = np.linalg.cholesky(null.T @ stiffness @ null)
    except np.linalg.LinAlgError:
        return None
    return scipy.linalg.solve_triangular(factor, null.T, lower=True)


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


def point_operators(model: FEModel, basis: np.ndarray, elements: np.ndarray,
                    gradients: np.ndarray | None = None) -> np.ndarray:
    """(s, q, 9, r) G = B V_e: vec(dF) per unit reduced coordinate at quadrature points of
    elements (s,) with shape gradients (s, q, k, 3); by default every point of their whole
    rule (a P2-P0 element's lambda points included)."""
    if gradients is None:
        gradients = model.shape_gradients[elements]
    local = basis[model.element_dofs[elements]]  # (s, 3k, r)
    return gradient_operators(gradients) @ local[:, None]


def _point_terms(model: FEModel, elements: np.ndarray, positions_mm: np.ndarray,
                 with_tangent: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P (p, 9), A (p, 9, 9) or (p,) energy densities, weights (p,) mm^3) at every quadrature
    point p of elements (s,), point-major within each element."""
    F = deformation_gradients(positions_mm, model.tets[elements],
                              model.shape_gradients[elements])
    s, q = F.shape[:2]
    points = np.tile(np.arange(q), s)
    first, second = model.constitutive_at(F.reshape(-1, 3, 3), points, with_tangent)
    stress = (first if with_tangent else second).reshape(-1, 9)
    return stress, (second if with_tangent else first), model.law_weights_mm3[elements].ravel()


def point_force_contributions(model: FEModel, operators: np.ndarray, elements: np.ndarray,
                              positions_mm: np.ndarray) -> np.ndarray:
    """(r, s q) w_p G_p^T vec P_p: each quadrature point's share of the reduced internal
    forces at (n, 3), for the points of elements (s,) with their operators (s, q, 9, r)."""
    stress, _, weights = _point_terms(model, elements, positions_mm, with_tangent=False)
    G = operators.reshape(-1, 9, operators.shape[-1])
    return np.einsum("pir,pi->rp", G, stress * weights[:, None])


def point_tangent_contributions(model: FEModel, operators: np.ndarray, elements: np.ndarray,
                                positions_mm: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(d * r, s q), direction-major: w_p G_p^T A_p G_p Q, each quadrature point's share of
    the reduced tangent applied to reduced directions Q (r, d)."""
    _, tangent, weights = _point_terms(model, elements, positions_mm, with_tangent=True)
    G = operators.reshape(-1, 9, operators.shape[-1])
    moved = tangent @ (G @ directions) * weights[:, None, None]  # (p, 9, d)
    return np.einsum("pir,pid->drp", G, moved).reshape(-1, len(G))


# sparse_nnls forms C^T C up front for up to this many columns (1.2 GB in float64)
GRAM_COLUMNS = 12_000


def sparse_nnls(C: np.ndarray, b: np.ndarray, tolerance: float = ECSW_TOLERANCE,
                max_elements: int | None = None,
                progress: Callable[[int, int], None] | None = None) -> Sampling:
    """Lawson-Hanson NNLS on C (rows, m), b (rows,), stopped at |C w - b| <= tolerance |b|
    or max_elements nonzero weights. With tolerance 0 it is scipy.optimize.nnls's optimum.

    Works on inner products only: with d = C^T b and the columns M = C^T C_P of the active
    set P, the gradient is d - M w, and at the active set's least squares weights (G w = d_P,
    G = M[P]) |C w - b|^2 = b.b - w.d_P, so an iteration costs one column of C^T C, not a
    pass over C[:, P].
    """
    m = C.shape[1]
    limit = m if max_elements is None else min(max_elements, m)
    bb = float(b @ b)
    target = tolerance**2 * bb
    d = C.T @ b
    # every iteration needs one column of C^T C: a product reading all of C (a GB on the
    # coarse Diamond), memory-bound; thousands of iterations make the whole Gram matrix,
    # formed once at the BLAS's full speed, several times cheaper
    products = C.T @ C if m <= GRAM_COLUMNS else None
    scale = 1e-14 * float(np.abs(d).max(initial=0.0))
    active: list[int] = []
    slots: list[int] = []  # each active column's slot in `entered`
    entered = _EnteredColumns(m, limit)
    factor = _GramCholesky()
    weights = np.zeros(0)
    residual2 = bb
    for _ in range(3 * m):
        if residual2 <= target or len(active) >= limit:
            break
        gradient = d - entered.product()
        gradient[active] = -np.inf
        best = int(np.argmax(gradient))
        if gradient[best] <= scale:
            break  # optimal: no element lowers the residual
        slot = entered.add(products[:, best] if products is not None else C.T @ C[:, best])
        active.append(best)
        slots.append(slot)
        factor.append(entered.columns[active, slot], float(d[best]))
        weights = np.append(weights, 0.0)
        while True:
            trial = factor.solve()
            if np.all(trial > 0.0):
                weights = trial
                break
            # step from the feasible weights towards trial until one weight reaches zero
            falling = trial <= 0.0
            step = np.min(weights[falling] / (weights[falling] - trial[falling]))
            weights = weights + step * (trial - weights)
            keep = weights > 1e-14 * max(float(weights.max(initial=0.0)), 1e-300)
            keep[np.argmin(np.where(falling, weights, np.inf))] = False
            for leaving in np.flatnonzero(~keep)[::-1]:
                entered.release(slots[leaving])
                factor.remove(int(leaving))
            index = np.flatnonzero(keep)
            active = [active[i] for i in index]
            slots = [slots[i] for i in index]
            weights = weights[index]
            if not active:
                break
        entered.weights[slots] = weights
        residual2 = max(bb - float(weights @ d[active]), 0.0) if active else bb
        if progress is not None:
            progress(len(active), limit)
    order = np.argsort(active)
    residual = b - C[:, active] @ weights if active else b
    return Sampling(np.asarray(active, dtype=np.int64)[order], weights[order],
                    float(np.linalg.norm(residual) / max(np.sqrt(bb), 1e-300)))


class _EnteredColumns:
    """The columns C^T c_j (m,) of C^T C of every column j that entered the active set, each
    in a slot of a buffer that grows by doubling, with its weight. A column that leaves
    frees its slot (weight 0) for the next one: compacting the (m, s) buffer at every exit
    would copy hundreds of MB each time."""

    def __init__(self, m: int, limit: int) -> None:
        self.limit = limit
        self.columns = np.empty((m, min(limit, 64)))
        self.weights = np.zeros(self.columns.shape[1])
        self.used = 0
        self.free: list[int] = []

    def product(self) -> np.ndarray:
        """(m,) C^T C w for the active weights w."""
        return self.columns[:, :self.used] @ self.weights[:self.used]

    def add(self, column: np.ndarray) -> int:
        """Store a column that enters (weight 0 until set); returns its slot."""
        if self.free:
            slot = self.free.pop()
        else:
            if self.used == self.columns.shape[1]:
                grow = min(self.used, self.limit)
                self.columns = np.hstack([self.columns, np.empty((len(self.columns), grow))])
                self.weights = np.r_[self.weights, np.zeros(grow)]
            slot, self.used = self.used, self.used + 1
        self.columns[:, slot] = column
        return slot

    def release(self, slot: int) -> None:
        """A column left the active set: its slot is reused by the next one."""
        self.weights[slot] = 0.0
        self.free.append(slot)


class _GramCholesky:
    """The active columns' least squares G w = d_P through the Cholesky factor G = R^T R (R
    upper), grown a column at a time and shrunk by Givens rotations (O(s^2) per column in or
    out instead of a new O(s^3) factorisation: with ~3,000 active columns the difference is
    minutes). It keeps z = R^-T d_P along, growing it with R and rotating it with R's rows,
    so that a solve is one back substitution R w = z instead of two triangular solves. A
    column that is (numerically) dependent on the others switches to least squares on the
    Gram matrix until the next reset.

    R lives in the top left corner of a C-ordered buffer whose rest is the identity (zeros
    off the diagonal): the triangular solves run on the whole buffer, whose transpose BLAS
    reads in place, where a solve on the (s, s) corner, not contiguous, first copies it (13
    against 1.8 ms at s = 2,500 on this machine; at 1e-3 on the coarse Diamond the solves
    took 72 s of the ECSW's 290 s, the copies most of it). The buffer grows by an eighth at
    least, so the padding costs at most 1.27 times the corner's reads.
    """

    def __init__(self) -> None:
        self.factor = np.eye(64)
        self.forward = np.zeros(64)  # z, zero past the active columns
        self.rights: list[float] = []  # d_P, in the active columns' order
        self.size = 0
        self.gram: np.ndarray | None = None  # kept only while R is not valid

    def append(self, column: np.ndarray, right: float) -> None:
        """Add the new active column's Gram entries (s + 1,), its diagonal entry last, and
        its entry of d."""
        s = self.size
        self.rights.append(right)
        if self.gram is not None:
            grown = np.zeros((s + 1, s + 1))
            grown[:s, :s] = self.gram
            grown[s, :], grown[:, s] = column, column
            self.gram, self.size = grown, s + 1
            return
        if s + 1 > len(self.factor):
            self._reserve(s + 1)
        padded = np.zeros(len(self.factor))
        padded[:s] = column[:s]
        above = self._solve(padded, transposed=True)[:s]
        pivot = float(column[s] - above @ above)
        if pivot <= 1e-12 * max(float(column[s]), 1e-300):
            R = self.factor[:s, :s]
            gram = R.T @ R
            self.gram = np.block([[gram, column[:s, None]], [column[None, :s], column[s:]]])
            self.size = s + 1
            return
        self.factor[:s, s] = above
        self.factor[s, :s] = 0.0
        self.factor[s, s] = np.sqrt(pivot)
        self.forward[s] = (right - above @ self.forward[:s]) / self.factor[s, s]
        self.size = s + 1

    def remove(self, index: int) -> None:
        """Drop active column `index`: its row and column leave the Gram matrix."""
        s = self.size
        del self.rights[index]
        if self.gram is not None:
            self.reset(np.delete(np.delete(self.gram, index, axis=0), index, axis=1))
            return
        R, z = self.factor, self.forward
        # without column `index`, R is upper Hessenberg from there: rotate each subdiagonal
        # entry into the row above (rows are contiguous: a rotation is two row operations),
        # and z with it (R^T z = d_P holds for the remaining columns through each rotation)
        R[:s, index:s - 1] = R[:s, index + 1:s].copy()
        for i in range(index, s - 1):
            a, b = R[i, i], R[i + 1, i]
            norm = float(np.hypot(a, b))
            if norm == 0.0:
                continue
            c, t = a / norm, b / norm
            top, low = R[i, i:s - 1].copy(), R[i + 1, i:s - 1]
            R[i, i:s - 1] = c * top + t * low
            R[i + 1, i:s - 1] = c * low - t * top
            z[i], z[i + 1] = c * z[i] + t * z[i + 1], c * z[i + 1] - t * z[i]
        # the freed last row and column back to the identity's (the solves read R's upper
        # triangle only: what the rotations left below the diagonal is never read)
        R[:s, s - 1] = 0.0
        R[s - 1, s - 1] = 1.0
        z[s - 1] = 0.0
        self.size = s - 1

    def reset(self, gram: np.ndarray) -> None:
        """Refactor from a whole Gram matrix (s, s) of the active columns."""
        self.size = len(gram)
        try:
            R = scipy.linalg.cholesky(gram, lower=False, check_finite=False)
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
            self.gram = np.array(gram)
            return
        self.factor, self.forward = np.eye(64), np.zeros(64)
        self._reserve(self.size)
        self.factor[: self.size, : self.size] = R
        rights = np.zeros(len(self.factor))
        rights[: self.size] = self.rights
        self.forward = self._solve(rights, transposed=True)
        self.gram = None

    def solve(self) -> np.ndarray:
        """The active columns' least squares weights, through the normal equations (a
        tolerance of 1e-3 needs far less than their lost digits)."""
        if self.gram is not None:
            return np.linalg.lstsq(self.gram, np.asarray(self.rights), rcond=None)[0]
        return self._solve(self.forward, transposed=False)[: self.size]

    def _reserve(self, size: int) -> None:
        """Room for `size` columns: the buffer regrown by an eighth at least, its new part
        the identity's."""
        capacity = len(self.factor)
        if size <= capacity:
            return
        grown = max(size, capacity + capacity // 8)
        factor = np.eye(grown)
        factor[:capacity, :capacity] = self.factor
        forward = np.zeros(grown)
        forward[:capacity] = self.forward
        self.factor, self.forward = factor, forward

    def _solve(self, right: np.ndarray, transposed: bool) -> np.ndarray:
        """x (capacity,) with R x = right, or R^T x = right when transposed, on the whole
        buffer (right zero past the active columns, so x is too). The buffer's transpose
        is Fortran-ordered: BLAS reads it as the lower triangular R^T, without a copy."""
        return scipy.linalg.blas.dtrsv(self.factor.T, right, lower=1,
                                       trans=0 if transposed else 1)
