"""Hyperelastic laws: strain energy density, first Piola-Kirchhoff stress and its tangent.

Every function is vectorised over (m, 3, 3) deformation gradients; stresses are in MPa
(N/mm^2) and tangents are A[m, i, j, k, l] = dP_ij / dF_kl. The three laws agree to first
order at F = I, so their small-strain responses are identical.

Every law is linear in the Lame parameters, psi = psi_mu + psi_lambda: `part` evaluates the
whole law ("all") or only its mu or lambda terms, which an element may integrate with
different quadrature rules (P2-P0 integrates the lambda terms at one point per element).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

LAWS = ("linear", "corotational", "neo-hookean")
PARTS = ("all", "mu", "lambda")

EYE = np.eye(3)
# Fourth-order tensors as (9, 9) matrices over (i, j) x (k, l): d_ik d_jl, d_il d_jk, d_ij d_kl.
IDENTITY9 = np.eye(9)
TRANSPOSE9 = np.einsum("il,jk->ijkl", EYE, EYE).reshape(9, 9)
TRACE9 = np.outer(EYE.ravel(), EYE.ravel())
# Scaled Newton iterations for the polar factor converge quadratically; this many reach
# round-off for stretches up to 10x (Higham, "Computing the polar decomposition", 1986).
POLAR_ITERATIONS = 12
# Near the polar factor a Newton step's error is about half its square over the smallest
# singular value: after a step smaller than this, the iterate is at round-off, and one more
# step (a fifth of the iteration's time on the Diamond) would only confirm it.
POLAR_CONVERGED_STEP = 1e-8

# Law = (F, lam, mu, with_tangent) -> (energy density (m,), P (m, 3, 3), A (m, 9, 9) or None)
Law = Callable[[np.ndarray, float, float, bool], tuple[np.ndarray, np.ndarray, np.ndarray | None]]


def lame_parameters(young_modulus_mpa: float, poisson_ratio: float) -> tuple[float, float]:
    """(lambda, mu) in MPa from Young's modulus (MPa) and Poisson's ratio."""
    lam = young_modulus_mpa * poisson_ratio / ((1 + poisson_ratio) * (1 - 2 * poisson_ratio))
    mu = young_modulus_mpa / (2 * (1 + poisson_ratio))
    return lam, mu


@dataclass(frozen=True)
class Material:
    """An isotropic hyperelastic material.

    law               : one of LAWS.
    young_modulus_mpa : Young's modulus E in MPa (0.18 for the Diamond's silicone).
    poisson_ratio     : nu, in [0, 0.5).
    """

    law: str
    young_modulus_mpa: float
    poisson_ratio: float

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f"unknown law {self.law!r}; expected one of {', '.join(LAWS)}")

    @property
    def lame(self) -> tuple[float, float]:
        return lame_parameters(self.young_modulus_mpa, self.poisson_ratio)

    def _lame_of(self, part: str) -> tuple[float, float]:
        lam, mu = self.lame
        parts = {"all": (lam, mu), "mu": (0.0, mu), "lambda": (lam, 0.0)}
        if part not in parts:
            raise ValueError(f"unknown part {part!r}; expected one of {', '.join(PARTS)}")
        return parts[part]

    def energy_and_stress(self, F: np.ndarray, part: str = "all") -> tuple[np.ndarray, np.ndarray]:
        """Energy density (m,) MPa (= mJ/mm^3) and P (m, 3, 3) MPa at F (m, 3, 3)."""
        energy, stress, _ = _LAWS[self.law](F, *self._lame_of(part), False)
        return energy, stress

    def stress(self, F: np.ndarray) -> np.ndarray:
        """P (m, 3, 3) MPa at deformation gradients F (m, 3, 3)."""
        return self.energy_and_stress(F)[1]

    def energy_density(self, F: np.ndarray) -> np.ndarray:
        """Strain energy per reference volume (m,) in mJ/mm^3 (= MPa)."""
        return self.energy_and_stress(F)[0]

    def stress_and_tangent(self, F: np.ndarray, part: str = "all"
                           ) -> tuple[np.ndarray, np.ndarray]:
        """P (m, 3, 3) MPa and A (m, 3, 3, 3, 3) MPa at deformation gradients F (m, 3, 3)."""
        _, stress, tangent = _LAWS[self.law](F, *self._lame_of(part), True)
        return stress, tangent.reshape(len(F), 3, 3, 3, 3)

    def evaluate(self, F: np.ndarray, part: str = "all") -> LawEvaluation:
        """The law at F (m, 3, 3): energy density and P now, and the tangent A as
        shift I + sum_j d_j z_j z_j^T (TangentFactors) when first asked for, from the same
        polar decomposition: the corotational law's has 4 terms past its shift 2 mu, the
        other laws' are A's 9 eigenpairs."""
        lam, mu = self._lame_of(part)
        if self.law == "corotational":
            R, S, trace, energy, stress = _corotational_stress(F, lam, mu)
            return LawEvaluation(energy, stress,
                                 lambda: _corotational_factors(R, S, trace, lam, mu))
        law = _LAWS[self.law]
        energy, stress, _ = law(F, lam, mu, False)
        return LawEvaluation(energy, stress, lambda: _eigen_factors(law(F, lam, mu, True)[2]))


class LawEvaluation:
    """A law at some deformation gradients: energy density (m,) MPa and P (m, 3, 3) MPa,
    and the tangent's factors (TangentFactors), formed when first asked for. A reduced
    static solve evaluates every configuration it tries and takes the tangent at those it
    steps from: the corotational law's polar decomposition, its costliest part, is then
    computed once per configuration."""

    def __init__(self, energy: np.ndarray, stress: np.ndarray,
                 factors: Callable[[], TangentFactors]) -> None:
        self.energy = energy
        self.stress = stress
        self._form_factors = factors

    @cached_property
    def factors(self) -> TangentFactors:
        return self._form_factors()


def _eigen_factors(tangent: np.ndarray) -> TangentFactors:
    """A (m, 9, 9) as its 9 eigenpairs (no shift)."""
    # an inverted Neo-Hookean point has a NaN tangent (the solver backtracks): keep NaN
    finite = np.isfinite(tangent).all(axis=(1, 2))
    values, vectors = np.full((len(tangent), 9), np.nan), np.full((len(tangent), 9, 9), np.nan)
    values[finite], vectors[finite] = np.linalg.eigh(tangent[finite])
    return TangentFactors(np.zeros(len(tangent)), vectors.transpose(0, 2, 1), values)


@dataclass(frozen=True)
class TangentFactors:
    """A tangent A (m, 9, 9) MPa = shift I + sum_j d_j z_j z_j^T, for sums of B^T A B that
    exploit it (a rank-k update per point instead of a 9 x 9 product).

    shift        : (m,) MPa.
    rows         : z (m, k, 9).
    coefficients : d (m, k) MPa, of either sign (A may be indefinite).
    """

    shift: np.ndarray
    rows: np.ndarray
    coefficients: np.ndarray

    def dense(self) -> np.ndarray:
        """A (m, 9, 9) MPa."""
        inner = self.rows.transpose(0, 2, 1) @ (self.coefficients[:, :, None] * self.rows)
        return self.shift[:, None, None] * IDENTITY9 + inner


def _linear(F, lam, mu, with_tangent):
    """Small-strain elasticity: psi = lam/2 tr(e)^2 + mu e:e, e = sym(F) - I."""
    strain = 0.5 * (F + F.transpose(0, 2, 1)) - EYE
    trace = np.trace(strain, axis1=1, axis2=2)
    energy = 0.5 * lam * trace**2 + mu * np.einsum("mij,mij->m", strain, strain)
    stress = lam * trace[:, None, None] * EYE + 2 * mu * strain
    tangent = None
    if with_tangent:
        tangent = np.broadcast_to(lam * TRACE9 + mu * (IDENTITY9 + TRANSPOSE9), (len(F), 9, 9))
    return energy, stress, tangent


def _cofactor_indices() -> tuple[np.ndarray, ...]:
    """Row indices (a, b, c, d) of a 3 x 3 matrix stored as nine rows (row-major) such that
    cofactor_ij = x_a x_b - x_c x_d: x_(i+1)(j+1) x_(i+2)(j+2) - x_(i+1)(j+2) x_(i+2)(j+1),
    indices mod 3."""
    i, j = np.divmod(np.arange(9), 3)
    return tuple(3 * ((i + p) % 3) + (j + q) % 3 for p, q in ((1, 1), (2, 2), (1, 2), (2, 1)))


_COFACTOR_A, _COFACTOR_B, _COFACTOR_C, _COFACTOR_D = _cofactor_indices()


def _cofactors(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cofactor matrices (= det X^-T) and determinants of matrices stored as (9, m) rows."""
    # four gathers of all nine components: the update's polar iteration calls this on a few
    # hundred points, where numpy's per-call cost, not the arithmetic, sets the time
    cofactors = (x.take(_COFACTOR_A, axis=0) * x.take(_COFACTOR_B, axis=0)
                 - x.take(_COFACTOR_C, axis=0) * x.take(_COFACTOR_D, axis=0))
    return cofactors, (x[:3] * cofactors[:3]).sum(axis=0)


def inverse_transpose(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F^-T (m, 3, 3) and det F (m,), by cofactors."""
    cofactors, det = _cofactors(F.reshape(-1, 9).T)
    return (cofactors / det).T.reshape(-1, 3, 3), det


def polar_decomposition(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F = R S with R a proper rotation and S symmetric, (m, 3, 3) each.

    Scaled Newton iteration X <- (g X + X^-T / g) / 2, g = |det X|^(-1/3), on elements with
    det F > 0 (components stored as nine contiguous rows, for speed); inverted elements go
    through the SVD with the smallest singular value negated, so R stays a rotation and the
    element is pushed back rather than reflected.
    """
    X = np.ascontiguousarray(F.reshape(-1, 9).T)
    upright = _cofactors(X)[1] > 0  # det F by cofactors: LAPACK's det per 3 x 3 is slower
    if not upright.all():
        X = np.ascontiguousarray(X[:, upright])
    for _ in range(POLAR_ITERATIONS):
        cofactors, det = _cofactors(X)
        scale = np.abs(det) ** (-1.0 / 3.0)
        updated = 0.5 * (scale * X + cofactors / (scale * det))
        change = np.abs(updated - X).max(initial=0.0)
        X = updated
        if change < POLAR_CONVERGED_STEP:
            break
    R = np.empty_like(F, dtype=float)
    R[upright] = X.T.reshape(-1, 3, 3)
    if not upright.all():
        U, _, Vt = np.linalg.svd(F[~upright])
        U[:, :, 2] *= np.where(np.linalg.det(U @ Vt) < 0, -1.0, 1.0)[:, None]
        R[~upright] = U @ Vt
    S = R.transpose(0, 2, 1) @ F
    return R, 0.5 * (S + S.transpose(0, 2, 1))


# The Levi-Civita symbol eps[i, j, k], and for each (i, k) the j with eps_ijk != 0 and its
# sign: contracting eps with a matrix's columns is then a signed gather, not a sum.
LEVI_CIVITA = np.zeros((3, 3, 3))
LEVI_CIVITA[0, 1, 2] = LEVI_CIVITA[1, 2, 0] = LEVI_CIVITA[2, 0, 1] = 1.0
LEVI_CIVITA[0, 2, 1] = LEVI_CIVITA[2, 1, 0] = LEVI_CIVITA[1, 0, 2] = -1.0
_MIDDLE_INDEX = np.abs(LEVI_CIVITA).argmax(axis=1)
_MIDDLE_SIGN = LEVI_CIVITA.sum(axis=1)


def _corotational(F, lam, mu, with_tangent):
    """Corotational linear elasticity with polar rotations: P = R C:(S - I).

    P is the gradient of psi = mu |S - I|^2 + lam/2 tr(S - I)^2, so the tangent below is the
    exact, symmetric Hessian (Newton converges quadratically, and the compliance matrices are
    the true linearisation rather than SOFA's R K0 R^T approximation). The rotation's
    derivative is dR = R [w]x with (tr S I - S) w = axial(R^T dF - dF^T R), which gives
    dR_ij/dF_kl = R_ip eps_pjs M^-1_sr eps_rql R_kq, M = tr S I - S.
    """
    m = len(F)
    R, S, trace, energy, stress = _corotational_stress(F, lam, mu)
    if not with_tangent:
        return energy, stress, None
    coupling_inv, left = _rotation_terms(R, S, trace)
    eps_R = (R[:, :, _MIDDLE_INDEX] * _MIDDLE_SIGN).transpose(0, 2, 1, 3)  # eps_rql R_kq
    right = coupling_inv @ eps_R.reshape(m, 3, 9)
    rotation_derivative = left @ right  # (m, 9, 9): rows (i, j), columns (k, l)
    flat_R = R.reshape(m, 9)
    tangent = (
        2 * mu * IDENTITY9
        + (lam * trace - 2 * mu)[:, None, None] * rotation_derivative
        + lam * flat_R[:, :, None] * flat_R[:, None, :]
    )
    return energy, stress, tangent


def _corotational_stress(F, lam, mu):
    """(R, S, tr(S - I), energy density, P) of the corotational law at F (m, 3, 3)."""
    R, S = polar_decomposition(F)
    strain = S - EYE
    trace = np.trace(strain, axis1=1, axis2=2)
    energy = 0.5 * lam * trace**2 + mu * np.einsum("mij,mij->m", strain, strain)
    stress = 2 * mu * (F - R) + lam * trace[:, None, None] * R
    return R, S, trace, energy, stress


def _rotation_terms(R, S, trace):
    """(M^-1 (m, 3, 3), L (m, 9, 3)) with dR_ij/dF_kl = L M^-1 L^T: M = tr S I - S and
    L[(i, j), s] = R_ip eps_pjs (since eps_rql R_kq = L[(k, l), r], the derivative is
    symmetric, of rank 3)."""
    # M is singular only for degenerate stretches (two singular values summing to zero).
    coupling = (trace + 3.0)[:, None, None] * EYE - S
    coupling_inv = inverse_transpose(coupling)[0]  # symmetric, so transpose is harmless
    left = (R @ LEVI_CIVITA.reshape(3, 9)).reshape(len(R), 9, 3)  # [(i, j), s]
    return coupling_inv, left


def _corotational_factors(R, S, trace, lam, mu):
    """TangentFactors of the corotational law at polar factors R, S (m, 3, 3) with
    trace = tr(S - I) (m,): its tangent is 2 mu I + (lam tr - 2 mu) L M^-1 L^T
    + lam vec R vec R^T (_corotational's three terms), and with M^-1 = U D U^T (U unit lower
    triangular) the factors are 2 mu, the columns of L U with coefficients
    (lam tr - 2 mu) D, and vec R with lam."""
    m = len(R)
    coupling_inv, left = _rotation_terms(R, S, trace)
    unit, diagonal = _ldl3(coupling_inv)
    rows = np.empty((m, 4, 9))
    rows[:, :3] = (left @ unit).transpose(0, 2, 1)
    rows[:, 3] = R.reshape(m, 9)
    coefficients = np.empty((m, 4))
    coefficients[:, :3] = (lam * trace - 2 * mu)[:, None] * diagonal
    coefficients[:, 3] = lam
    return TangentFactors(np.full(m, 2 * mu), rows, coefficients)


def _ldl3(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A = U diag(d) U^T for symmetric A (m, 3, 3): U (m, 3, 3) unit lower triangular and
    d (m, 3), in closed form (Cholesky's recurrence without square roots).

    Used on M^-1, which is positive definite wherever it is finite (M's eigenvalues are sums
    of two of S's, and the polar decomposition negates only the smallest singular value of
    an inverted element), where this recurrence is as stable as Cholesky's; a singular M
    gives non-finite factors, as it gives a non-finite dense tangent.
    """
    a = A.reshape(-1, 9).T
    d0 = a[0]
    l10, l20 = a[3] / d0, a[6] / d0
    d1 = a[4] - l10 * l10 * d0
    l21 = (a[7] - l20 * l10 * d0) / d1
    d2 = a[8] - l20 * l20 * d0 - l21 * l21 * d1
    unit = np.zeros_like(A)
    unit[:, 0, 0] = unit[:, 1, 1] = unit[:, 2, 2] = 1.0
    unit[:, 1, 0], unit[:, 2, 0], unit[:, 2, 1] = l10, l20, l21
    return unit, np.stack([d0, d1, d2], axis=1)


def _neo_hookean(F, lam, mu, with_tangent):
    """Compressible Neo-Hookean: psi = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2."""
    m = len(F)
    F_inv_T, J = inverse_transpose(F)
    log_J = np.log(np.where(J > 0, J, np.nan))  # NaN marks inversion; the solver backtracks
    energy = 0.5 * mu * (np.einsum("mij,mij->m", F, F) - 3) - mu * log_J + 0.5 * lam * log_J**2
    stress = mu * (F - F_inv_T) + (lam * log_J)[:, None, None] * F_inv_T
    if not with_tangent:
        return energy, stress, None
    flat = F_inv_T.reshape(m, 9)
    # d(F^-T)_ij / dF_kl = -F^-T_il F^-T_kj
    swapped = (F_inv_T[:, :, None, None, :] * F_inv_T.transpose(0, 2, 1)[:, None, :, :, None])
    swapped = swapped.reshape(m, 9, 9)
    tangent = (
        mu * IDENTITY9
        + (mu - lam * log_J)[:, None, None] * swapped
        + lam * flat[:, :, None] * flat[:, None, :]
    )
    return energy, stress, tangent


_LAWS: dict[str, Law] = {
    "linear": _linear,
    "corotational": _corotational,
    "neo-hookean": _neo_hookean,
}
