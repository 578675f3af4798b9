"""Independent tasks on the machine's cores (fem.processes): the answer of running them in
turn, in order, with the first failure in order."""

from __future__ import annotations

import os
import sys
import time
import warnings

import pytest
from threadpoolctl import threadpool_info

from softforce_cli.fem import processes
from softforce_cli.fem.processes import map_on_cores, worker_count

CORES = len(os.sched_getaffinity(0))


def test_tasks_run_in_worker_processes_and_come_back_in_order():
    parent = os.getpid()
    squares = [1.5 * i * i for i in range(7)]

    def task(i: int) -> tuple[float, int]:
        time.sleep(0.1)  # long enough for every worker to take some
        return 1.5 * i * i, os.getpid()

    results = map_on_cores(task, 7)
    assert [value for value, _ in results] == squares
    workers = {pid for _, pid in results}
    if CORES >= 2:
        assert parent not in workers and len(workers) == worker_count(7) >= 2


def test_progress_counts_the_tasks_as_they_end():
    seen: list[int] = []
    assert map_on_cores(lambda i: 2 * i, 5, seen.append) == [0, 2, 4, 6, 8]
    assert seen == [1, 2, 3, 4, 5]


def test_a_stop_keeps_the_first_results_in_order_and_cancels_the_rest():
    """A stop asked after the second task ends: the tasks not yet handed to a worker are
    cancelled, and the results are the first ones in order that ended (those handed over,
    running or queued for a worker, end too: at most one more per worker and one)."""
    seen: list[int] = []

    def task(i: int) -> int:
        time.sleep(0.05 * (i + 1))
        return i

    results = map_on_cores(task, 20, seen.append, lambda: len(seen) >= 2)
    assert results == list(range(len(results)))
    assert 2 <= len(results) <= 3 + 2 * worker_count(20) < 20


def test_the_first_failure_in_order_is_raised_whichever_ends_first():
    """Task 3 fails at once, task 1 after a while: in turn, task 1's failure comes first."""

    def task(i: int) -> int:
        if i == 1:
            time.sleep(0.3)
            raise ValueError("task 1")
        if i == 3:
            raise ValueError("task 3")
        return i

    with pytest.raises(ValueError, match="task 1"):
        map_on_cores(task, 6)


def test_a_worker_runs_blas_on_one_thread_and_its_own_maps_in_turn():
    if CORES < 2:
        pytest.skip("one core: the tasks run in this process")

    def task(_: int) -> tuple[int, int]:
        blas = [entry["num_threads"] for entry in threadpool_info()
                if entry["user_api"] == "blas"]
        return max(blas), worker_count(4)

    assert map_on_cores(task, 2) == [(1, 1), (1, 1)]
    assert processes._task is None  # the map is over: a new one may fork again


def test_one_task_or_none_runs_here():
    assert worker_count(1) == 1
    assert map_on_cores(lambda i: os.getpid(), 1) == [os.getpid()]
    assert map_on_cores(lambda i: i, 0) == []


def test_a_worker_writes_to_streams_of_its_own(monkeypatch):
    """A stream of the caller that another of its threads held locked when the workers
    forked (a progress bar redrawing) would hang a worker's warning forever: workers write
    to the same files through streams of their own. Here the caller's stream refuses."""
    if CORES < 2:
        pytest.skip("one core: the tasks run in this process")

    class Refusing:
        def write(self, text: str) -> int:
            raise AssertionError("the caller's stream")

        def flush(self) -> None:
            pass

    monkeypatch.setattr(sys, "stderr", Refusing())
    monkeypatch.setattr(sys, "stdout", Refusing())

    def task(i: int) -> int:
        warnings.warn("from a worker", stacklevel=1)
        print("from a worker")
        return i

    assert map_on_cores(task, 2) == [0, 1]


def test_workers_are_as_many_as_the_memory_available_holds(monkeypatch):
    """A worker's solves allocate about what the caller's did: with room for one copy of
    this process' resident memory the tasks run in turn here, with room for two on two
    workers; where the memory cannot be read, the cores alone count."""
    if CORES < 2:
        pytest.skip("one core: the tasks run in this process")
    sizes = {"MemAvailable:": 1_500_000, "VmRSS:": 1_000_000}
    monkeypatch.setattr(processes, "_kilobytes", lambda path, field: sizes[field])
    assert worker_count(8) == 1
    sizes["MemAvailable:"] = 2_100_000
    assert worker_count(8) == 2
    sizes["MemAvailable:"] = None  # unreadable: no limit
    assert worker_count(8) == min(CORES, processes.MAX_WORKERS)
