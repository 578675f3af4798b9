"""Proper orthogonal decomposition: a reduced basis from displacement snapshots, by SVD.

Snapshots mix static displacements (mm) and unit-force responses (mm/N); each column is
scaled to unit norm first so that every load case counts alike, whatever its units or size.
The basis keeps the leading left singular vectors until they hold a fraction 1 - tolerance of
the snapshots' energy (sum of squared singular values); with unit columns, a snapshot's
relative projection error is then at most sqrt(tolerance * columns), and in practice the
largest one is reported by `projection_errors`.
"""

from __future__ import annotations

import numpy as np

# Energy left out of the basis: 1e-6 keeps every trained response within a few percent
# (docs/reduced_model.md: modes vs accuracy).
ENERGY_TOLERANCE = 1e-6


def normalized_columns(snapshots: np.ndarray) -> np.ndarray:
    """(d, c) -> (d, c) each nonzero column scaled to unit Euclidean norm (zero ones dropped)."""
    norms = np.linalg.norm(snapshots, axis=0)
    keep = norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300)
    return snapshots[:, keep] / norms[keep]


def pod_basis(snapshots: np.ndarray, tolerance: float = ENERGY_TOLERANCE,
              max_modes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal basis (d, r) of snapshots (d, c) and the singular values (c,).

    r is the smallest count whose modes hold 1 - tolerance of the normalised snapshots'
    energy, capped at max_modes.
    """
    columns = normalized_columns(np.asarray(snapshots, dtype=float))
    # the Gram route: c is a few hundred while d is tens of thousands
    gram = columns.T @ columns
    values, vectors = np.linalg.eigh(gram)
    order = np.argsort(values)[::-1]
    values, vectors = np.clip(values[order], 0.0, None), vectors[:, order]
    singular = np.sqrt(values)
    captured = np.cumsum(values) / values.sum()
    count = int(np.searchsorted(captured, 1.0 - tolerance) + 1)
    count = min(count, int(np.sum(singular > 1e-10 * singular[0])))
    if max_modes is not None:
        count = min(count, max_modes)
    basis = columns @ (vectors[:, :count] / singular[:count])
    # one re-orthogonalisation: the Gram route loses half the digits of tiny modes
    basis, _ = np.linalg.qr(basis)
    basis[~np.any(columns != 0.0, axis=1)] = 0.0  # keep clamped dofs exactly clamped
    return basis, singular


def projection_errors(basis: np.ndarray, snapshots: np.ndarray) -> np.ndarray:
    """(c,) relative error |u - V V^T u| / |u| of each snapshot column (d, c)."""
    columns = normalized_columns(np.asarray(snapshots, dtype=float))
    residual = columns - basis @ (basis.T @ columns)
    return np.linalg.norm(residual, axis=0)
