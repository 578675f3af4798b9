"""Sparse assembly with a sparsity pattern computed once per mesh.

Assembling a matrix is then one sparse matrix-vector product, a fixed 0/1 scatter matrix
times the element entries, into the CSR data array: no Python loop over elements, no COO
sort and no temporary copy of the kept entries per assembly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


def element_dofs(elements: np.ndarray) -> np.ndarray:
    """Global dof numbers of each element, node-major: (m, k) -> (m, 3k), dof = 3 node + i."""
    return (3 * elements[:, :, None] + np.arange(3)).reshape(len(elements), -1)


@dataclass(frozen=True)
class ReducedPattern:
    """Where each element stiffness entry lands in the CSR matrix over the free dofs.

    free_dofs : (f,) global dofs kept, sorted; the others are fixed (Dirichlet).
    reduced_index : (3n,) position of each global dof among free_dofs, -1 if fixed.
    slot      : (e,) position in the CSR data array of each kept element entry.
    keep      : (m * 9k^2,) bool, which element entries couple two free dofs.
    indices, indptr : the CSR structure, shape (f, f).
    scatter   : CSR (len(indices), m * 9k^2) of ones, scatter[slot, kept entry] = 1: the
                sum of the element entries landing in each slot, as one product.
    """

    free_dofs: np.ndarray
    reduced_index: np.ndarray
    slot: np.ndarray
    keep: np.ndarray
    indices: np.ndarray
    indptr: np.ndarray
    scatter: sp.csr_matrix

    @classmethod
    def build(cls, elements: np.ndarray, node_count: int,
              fixed_nodes: np.ndarray) -> ReducedPattern:
        """The pattern of elements (m, k) on node_count nodes with fixed_nodes clamped."""
        reduced = np.full(3 * node_count, -1)
        fixed = np.zeros(3 * node_count, dtype=bool)
        fixed[(3 * np.asarray(fixed_nodes)[:, None] + np.arange(3)).ravel()] = True
        free_dofs = np.flatnonzero(~fixed)
        reduced[free_dofs] = np.arange(len(free_dofs))
        dofs = reduced[element_dofs(elements)]
        width = dofs.shape[1]
        rows = np.repeat(dofs, width, axis=1).ravel()
        cols = np.tile(dofs, (1, width)).ravel()
        keep = (rows >= 0) & (cols >= 0)
        keys = rows[keep].astype(np.int64) * len(free_dofs) + cols[keep]
        unique_keys, slot = np.unique(keys, return_inverse=True)
        unique_rows = unique_keys // len(free_dofs)
        indptr = np.searchsorted(unique_rows, np.arange(len(free_dofs) + 1))
        indices = (unique_keys % len(free_dofs)).astype(np.int32)
        slot = slot.ravel()
        # rows sorted by slot, and within a row by entry (a stable sort): the sums run in
        # the same order as a bincount over the entries would
        order = np.argsort(slot, kind="stable")
        entries = np.flatnonzero(keep)[order]
        scatter = sp.csr_matrix(
            (np.ones(len(entries)), entries.astype(np.int64 if len(keep) > 2**31 else np.int32),
             np.concatenate([[0], np.cumsum(np.bincount(slot, minlength=len(unique_keys)))])),
            shape=(len(unique_keys), len(keep)),
        )
        return cls(free_dofs, reduced, slot, keep, indices, indptr.astype(np.int32), scatter)

    @property
    def size(self) -> int:
        return len(self.free_dofs)

    def assemble(self, element_matrices: np.ndarray) -> sp.csr_matrix:
        """CSR (f, f) from element matrices (m, 3k, 3k) in element_dofs order."""
        data = self.scatter @ element_matrices.reshape(-1)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))


def assemble_vector(element_vectors: np.ndarray, dofs: np.ndarray, size: int) -> np.ndarray:
    """Sum element vectors (m, 3k) at their global dofs (m, 3k) into a vector (size,)."""
    return np.bincount(dofs.ravel(), weights=element_vectors.ravel(), minlength=size)
