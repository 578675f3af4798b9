"""The hyper-reduced tangent K_r = sum_p w_p G_p^T A_p G_p, assembled from factored A_p.

With A_p = a_p I + sum_j d_pj z_pj z_pj^T (materials.TangentFactors), the sum splits into

    K_r = sum_p w_p a_p G_p^T G_p  +  H+^T H+  -  H-^T H-,
    rows of H: h_pj = sqrt(w_p |d_pj|) G_p^T z_pj (r,), in H+ or H- by the sign of d_pj,

where the first term only changes with the material (it is formed once and kept) and the
others are two symmetric rank-k updates (BLAS syrk: half a GEMM's flops, and on these cores
twice as fast as the GEMM of the plain sum, whose transposed operand OpenBLAS handles
slowly) over k s rows instead of 9 s: the corotational law has k = 4. The rows and their
products run in `dtype` (float32 by default: half the memory traffic and twice the flops of
float64); the tangent only sets Newton's rate and the compliance W (relative error ~1e-7 on
K_r, docs/reduced_model.md), while the forces, which set Newton's answer, stay float64
(ReducedCoordinates).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from softforce_cli.fem.materials import TangentFactors

# Precision of the per-update products (the constant shift term is always float64).
TANGENT_DTYPE = np.float32


class ReducedTangent:
    """sum_p w_p G_p^T A_p G_p for fixed operators G (s, 9, r) and weights w (s,) mm^3.

    The factors of A come in pieces over consecutive slices of the points (a P2-P0 model's
    mu and lambda points, evaluated with different parts of the law).
    """

    def __init__(self, operators: np.ndarray, weights: np.ndarray,
                 dtype: type = TANGENT_DTYPE) -> None:
        self.operators = operators
        self.weights = weights
        self.dtype = dtype
        self.low = np.ascontiguousarray(operators, dtype=dtype)  # (s, 9, r)
        self._shift: np.ndarray | None = None
        self._shift_term: np.ndarray | None = None

    @property
    def size(self) -> int:
        return self.operators.shape[-1]

    def shift_term(self, shift: np.ndarray) -> np.ndarray:
        """(r, r) sum_p w_p a_p G_p^T G_p in float64 for shifts a (s,) MPa, formed again only
        when the shifts change (they are material constants)."""
        if self._shift is None or not np.array_equal(shift, self._shift):
            scaled = (self.weights * shift)[:, None, None] * self.operators
            r = self.size
            term = self.operators.reshape(-1, r).T @ scaled.reshape(-1, r)
            # symmetric to the last bit, so that K_r, to which the syrk terms add exactly
            # symmetric products, is too (no symmetrisation per update)
            self._shift_term = 0.5 * (term + term.T)
            self._shift = shift.copy()
        return self._shift_term

    def __call__(self, pieces: list[tuple[slice, TangentFactors]]) -> np.ndarray:
        """(r, r) N/mm, symmetric: the reduced tangent for the factors of A over each slice
        of the points (together covering all s of them, in order)."""
        shift = np.concatenate([factors.shift for _, factors in pieces])
        total = self.shift_term(shift).copy()
        for where, factors in pieces:
            scale = np.sqrt(self.weights[where, None] * np.abs(factors.coefficients))
            rows = (scale[:, :, None] * factors.rows).astype(self.dtype)
            for sign, H in _signed_rows(rows, self.low[where], factors.coefficients < 0.0):
                # numpy computes a.T @ a of one C-ordered array with syrk, and mirrors its
                # triangle: the product is exactly symmetric
                product = H.T @ H
                if sign > 0:
                    total += product
                else:
                    total -= product
        return total


def _signed_rows(rows: np.ndarray, operators: np.ndarray, negative: np.ndarray
                 ) -> Iterator[tuple[int, np.ndarray]]:
    """(sign, H) pairs: the rows h_pj = rows_pj G_p (k s, r) grouped by the sign of their
    coefficients, from rows (s, k, 9), operators G (s, 9, r) and the mask negative (s, k).

    A factor keeps its sign at every point in the common case (the corotational law's three
    rotation terms are negative wherever tr(S - I) < 2 mu / lam, its volume term always
    positive): the product writes each factor's rows contiguously, factors of one sign next
    to each other, so those groups are views of it; only factors whose sign varies (an
    eigen-factored Neo-Hookean tangent) are split row by row.
    """
    r = operators.shape[-1]
    always, never = negative.all(axis=0), ~negative.any(axis=0)
    mixed = ~(always | never)
    order = np.concatenate([np.flatnonzero(never), np.flatnonzero(always), np.flatnonzero(mixed)])
    H = np.empty((len(order), len(rows), r), dtype=rows.dtype)  # (k, s, r)
    # one pass over G for every factor, as fast as the plain (s, k, r) product
    np.matmul(rows[:, order], operators, out=H.transpose(1, 0, 2))
    positive_end, negative_end = np.cumsum([never.sum(), always.sum()])
    if positive_end > 0:
        yield 1, H[:positive_end].reshape(-1, r)
    if negative_end > positive_end:
        yield -1, H[positive_end:negative_end].reshape(-1, r)
    if mixed.any():
        varying = H[negative_end:].reshape(-1, r)
        flags = negative[:, mixed].T.ravel()  # in H's (factor, point) order
        # np.compress copies rows twice as fast as boolean indexing
        yield 1, np.compress(~flags, varying, axis=0)
        yield -1, np.compress(flags, varying, axis=0)


def plain_tangent(operators: np.ndarray, weights: np.ndarray, tangents: np.ndarray
                  ) -> np.ndarray:
    """(r, r) sum_p w_p G_p^T A_p G_p, term by term: the reference ReducedTangent is
    checked and timed against. operators G (s, 9, r), weights (s,), tangents A (s, 9, 9)."""
    r = operators.shape[-1]
    weighted = (weights[:, None, None] * tangents) @ operators
    return operators.reshape(-1, r).T @ weighted.reshape(-1, r)
