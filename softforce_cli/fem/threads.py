"""One BLAS thread for small dense products: a reduced model's, a diagnosis' fits.

numpy and scipy each load an OpenBLAS with its own pool of threads, and on two cores the
pools contend: a reduced model's products are small (r ~ 200 columns; an LU of r x r), so
threads only add wake-ups and spinning. Measured on the coarse Diamond (200 modes): an
update took 24 ms with the pools' two threads and 14 ms on one, an LU of K_r 16 ms against
0.25 ms, a static solve 291 ms against 150 ms with another job on the machine
(docs/reduced_model.md). A diagnosis' fits are thousands of such products (least squares on
60,000 residual entries, Cholesky factors of 200 x 200 contact compliances): the bench's
200-frame diagnosis, its solves cached, took 150 s with two threads and 128 s with one
(2026-11-30). Its solves and the plate's responses (200 right-hand sides a state) keep
their threads: 21 s for those responses with two, 25-26 s with one.
threadpoolctl's controller is made when this module is imported, after numpy and
scipy.linalg, so it sees both libraries (cvxopt's own OpenBLAS, which CHOLMOD's
factorisations use, runs one thread already).

A sensing update enters this context about a dozen times, nested too: it reads and sets the
libraries' thread counts directly (about 2 us, nothing when they are already one) rather than
through threadpoolctl's `limit`, which queries every library's description (13 us).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

import scipy.linalg  # noqa: F401  (numpy's and scipy's BLAS loaded before the controller looks)
from threadpoolctl import ThreadpoolController

_LIBRARIES = [library for library in ThreadpoolController().lib_controllers
              if library.user_api == "blas"]
Result = TypeVar("Result")


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """A context in which BLAS runs on one thread (the counts before restored after)."""
    changed = [(library, count) for library in _LIBRARIES
               if (count := library.get_num_threads()) != 1]
    for library, _ in changed:
        library.set_num_threads(1)
    try:
        yield
    finally:
        for library, count in changed:
            library.set_num_threads(count)


def on_one_blas_thread(function: Callable[..., Result]) -> Callable[..., Result]:
    """`function` run in one_blas_thread()."""

    @functools.wraps(function)
    def wrapped(*args, **kwargs) -> Result:
        with one_blas_thread():
            return function(*args, **kwargs)

    return wrapped
