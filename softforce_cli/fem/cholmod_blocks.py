"""Many right-hand sides in one pass through a CHOLMOD factor, on cvxopt's own CHOLMOD.

cvxopt's `cholmod.solve` hands CHOLMOD one column at a time, so k right-hand sides read the
factor 2k times. CHOLMOD's own solve takes them together, supernode by supernode with dense
block products. On the coarse P2 Diamond (26k dofs, 4.2 million entries in L; 2026-11-30,
this 2-core machine) a column cost 9.5 ms through cvxopt whatever the count, and 1.7-1.9 ms
in blocks of 32 to 128; a Newton step's 5 columns 21 ms against 39-47 ms.

`blocked_solver()` calls `cholmod_l_solve` of the very library cvxopt's extension loaded
(found in this process' memory map, so that the factor's layout is that library's) on the
factor inside cvxopt's capsule, with a CHOLMOD workspace of its own. It checks itself once
against cvxopt's solve on a small matrix; where anything is missing or differs (not Linux,
another build of cvxopt), it is None and the caller keeps cvxopt's column-by-column solve.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np
from cvxopt import cholmod, spmatrix
from cvxopt import matrix as dense

# Columns solved together: past about 64 the block outgrows the caches (200 at once cost
# 3.0 ms a column against 1.8).
BLOCK_COLUMNS = 64
CAPSULE_NAME = b"CHOLMOD FACTOR D L"  # cvxopt's name for a real factor of a lower triangle
CHOLMOD_A, CHOLMOD_REAL, CHOLMOD_DOUBLE = 0, 1, 0
COMMON_BYTES = 1 << 16  # more than any CHOLMOD's cholmod_common (about 3 kB in 3.x)

Solver = Callable[[object, np.ndarray], np.ndarray]


class _Dense(ctypes.Structure):
    """CHOLMOD's cholmod_dense: a column-major matrix with leading dimension d."""

    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t),
                ("nzmax", ctypes.c_size_t), ("d", ctypes.c_size_t),
                ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("xtype", ctypes.c_int), ("dtype", ctypes.c_int)]


@functools.cache
def blocked_solver() -> Solver | None:
    """solve(factor, rhs (n, k)) -> (n, k): A^-1 rhs for a numeric factor of cvxopt's
    cholmod, all columns together; None where it cannot be had (module docstring)."""
    try:
        solve = _bind(_loaded_cholmod())
        return solve if _agrees(solve) else None
    except (OSError, AttributeError, ValueError, ArithmeticError):
        return None


def _loaded_cholmod() -> Path:
    """The libcholmod that cvxopt's extension loaded, from the process' memory map."""
    with open("/proc/self/maps") as maps:
        for line in maps:
            path = line.split(maxsplit=5)[-1].strip()
            if Path(path).name.startswith("libcholmod"):
                return Path(path)
    raise OSError("no libcholmod mapped")


def _bind(path: Path) -> Solver:
    # PyDLL keeps the interpreter lock through a call, as cvxopt's own solve does: one
    # workspace serves every call, which threads must not share at once
    library = ctypes.PyDLL(str(path))
    library.cholmod_l_start.argtypes = [ctypes.c_void_p]
    library.cholmod_l_solve.restype = ctypes.POINTER(_Dense)
    library.cholmod_l_solve.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(_Dense),
                                        ctypes.c_void_p]
    library.cholmod_l_free_dense.argtypes = [ctypes.POINTER(ctypes.POINTER(_Dense)),
                                             ctypes.c_void_p]
    common = ctypes.create_string_buffer(COMMON_BYTES)
    if not library.cholmod_l_start(common):
        raise OSError("cholmod_l_start failed")
    pointer = ctypes.pythonapi.PyCapsule_GetPointer
    pointer.restype, pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]

    def solve(factor: object, rhs: np.ndarray) -> np.ndarray:
        lower = pointer(factor, CAPSULE_NAME)  # raises ValueError for another capsule
        size, count = rhs.shape
        solution = np.empty((size, count), order="F")
        for first in range(0, count, BLOCK_COLUMNS):
            block = np.asfortranarray(rhs[:, first:first + BLOCK_COLUMNS], dtype=float)
            columns = block.shape[1]
            given = _Dense(size, columns, size * columns, size, block.ctypes.data, None,
                           CHOLMOD_REAL, CHOLMOD_DOUBLE)
            result = library.cholmod_l_solve(CHOLMOD_A, lower, ctypes.byref(given), common)
            if not result:
                raise ArithmeticError("CHOLMOD's solve failed")
            try:
                out = result.contents
                values = np.ctypeslib.as_array(ctypes.cast(out.x, ctypes.POINTER(ctypes.c_double)),
                                               shape=(columns, out.d))
                solution[:, first:first + columns] = values[:, :size].T
            finally:
                library.cholmod_l_free_dense(ctypes.byref(result), common)
        return solution

    return solve


def _agrees(solve: Solver) -> bool:
    """Whether `solve` gives cvxopt's answer on a small positive definite system."""
    matrix = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    rows, columns = np.tril_indices(3)
    lower = spmatrix(matrix[rows, columns], rows.tolist(), columns.tolist(), (3, 3))
    factor = cholmod.symbolic(lower, uplo="L")
    cholmod.numeric(lower, factor)
    rhs = np.arange(6.0).reshape(3, 2) + 1.0
    expected = dense(rhs)
    cholmod.solve(factor, expected)
    return bool(np.allclose(solve(factor, rhs), np.array(expected), rtol=1e-12, atol=0.0))
