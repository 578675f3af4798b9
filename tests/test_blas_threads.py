"""The reduced model's one-BLAS-thread context, read back through threadpoolctl's own query."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from softforce_cli.fem.reduction.threads import on_one_blas_thread, one_blas_thread


def blas_threads() -> dict[str, int]:
    """{library path: its thread count} of every BLAS loaded."""
    return {library["filepath"]: library["num_threads"] for library in threadpool_info()
            if library["user_api"] == "blas"}


def test_one_blas_thread_limits_every_blas_nested_and_restores_the_counts():
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        assert 2 in before.values()  # numpy's and scipy's OpenBLAS run two threads here
        with one_blas_thread():
            assert set(blas_threads().values()) == {1}
            with one_blas_thread():
                assert set(blas_threads().values()) == {1}
            assert set(blas_threads().values()) == {1}  # the inner context keeps the outer's
        assert blas_threads() == before


def test_a_wrapped_function_runs_on_one_thread_and_restores_after_an_error():
    @on_one_blas_thread
    def failing() -> None:
        assert set(blas_threads().values()) == {1}
        raise ValueError("inside")

    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        with pytest.raises(ValueError, match="inside"):
            failing()
        assert blas_threads() == before
