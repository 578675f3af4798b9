"""The one-BLAS-thread context (a reduced model's products, a diagnosis' fits), read back through
threadpoolctl's own query."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from softforce_cli.fem.threads import on_one_blas_thread, one_blas_thread


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


def test_a_diagnosis_fits_on_one_thread(monkeypatch, sample_robot):
    """diagnose_observations' fits (the screening's and refits' thousands of small products)
    run on one BLAS thread, read back as the screening starts; the FE solves before them
    keep the threads."""
    from softforce_cli.diagnosis import pipeline
    from softforce_cli.diagnosis.solves import SolveCache

    seen = {}

    def stage(name, returned=None):
        def record(*args, **kwargs):
            seen[name] = blas_threads()
            if returned is None:
                raise pipeline.DiagnosisError("stopped at the screening")
            return returned
        return record

    def states(result):
        result.states = SimpleNamespace(actuation=None)
        return ()

    monkeypatch.setattr(pipeline, "_states", states)
    monkeypatch.setattr(pipeline, "solve_states", stage("solves", returned=object()))
    monkeypatch.setattr(pipeline, "_nominal", stage("nominal", returned=object()))
    monkeypatch.setattr(pipeline, "_screen_hypotheses", stage("screening"))
    with (threadpool_limits(limits=2, user_api="blas"),
          pytest.raises(pipeline.DiagnosisError, match="screening")):
        pipeline.diagnose_observations(sample_robot, None, SolveCache(None))
    assert 2 in seen["solves"].values() and 2 in seen["nominal"].values()
    assert set(seen["screening"].values()) == {1}
