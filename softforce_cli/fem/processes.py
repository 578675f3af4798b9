"""Independent FE solves on the machine's cores, in forked worker processes.

A quadratic-element solve of the coarse Diamond (26k dofs) is about a second of one core's
work, and Python's threads cannot share it: CHOLMOD's factorisation runs on one thread
(cvxopt's OpenBLAS is built without threads) and holds the interpreter, as the assembly's
numpy loops mostly do. A diagnosis' refit solves every state of a recording again with a
candidate's effect, each state on its own: on this 2-core machine two worker processes
solved six such states in 5.4 s against 7.7-8.4 s in one (1.4-1.6 times: the two share the
memory bus; 2026-11-30, docs/diagnosis.md). A reduced model's training does the same with
each static equilibrium's responses and contact equilibria (fem.reduction.snapshots).

Workers are forked when a map starts, one per core and no more than the available memory
holds at the caller's resident size each: they inherit the caller's models as they are, so
that nothing large is pickled, only each task's index and its result. Each runs BLAS on one
thread, writes to streams of its own and ignores Ctrl-C, which the caller handles: it waits
for the running tasks (one solve each at most) and cancels the others. Where fork is not
available (outside Linux), with one core, or within a worker, the tasks run in turn in the
calling process.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import TypeVar

from softforce_cli.fem.threads import one_blas_thread

Result = TypeVar("Result")
# Workers at most: beyond a few the memory bus, not the cores, limits (two workers on this
# machine's 2 cores solve 1.3-1.6 times as fast as one process).
MAX_WORKERS = 8

_task: Callable[[int], object] | None = None  # the running map's task, which workers inherit


def worker_count(tasks: int) -> int:
    """Worker processes a map of `tasks` tasks uses: one per core this process may run on,
    at most MAX_WORKERS, the tasks, and as many as the memory available holds at this
    process' resident size each (a worker's solves allocate about what the caller's did: a
    fine mesh's factors take gigabytes); 1 (in turn, in this process) without fork or
    within a worker."""
    if _task is not None or "fork" not in multiprocessing.get_all_start_methods():
        return 1
    available = _kilobytes("/proc/meminfo", "MemAvailable:")
    resident = _kilobytes("/proc/self/status", "VmRSS:")
    fits = MAX_WORKERS if available is None or not resident else available // resident
    return max(1, min(tasks, len(os.sched_getaffinity(0)), MAX_WORKERS, fits))


def _kilobytes(path: str, field: str) -> int | None:
    """The number of a "field: N kB" line of a /proc file; None where unreadable."""
    try:
        with open(path) as lines:
            for line in lines:
                if line.startswith(field):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return None


def map_on_cores(task: Callable[[int], Result], count: int,
                 progress: Callable[[int], None] | None = None,
                 stop: Callable[[], bool] | None = None) -> list[Result]:
    """[task(0), ..., task(count - 1)], run in forked worker processes (worker_count);
    progress(done) after each task ends, in this process.

    The results come in order, and so do the tasks' exceptions: the first task in order to
    raise raises here, as it would in turn, and the tasks after it that have not started are
    cancelled. A task's result and exception must pickle. When stop() turns true (asked
    after each task ends), the tasks not yet handed to a worker are cancelled, those handed
    over end (the pool queues one more than its workers), and the results are those of the
    first tasks in order that ended: fewer than `count`.
    """
    global _task
    workers = worker_count(count)
    if workers == 1:
        results = []
        for i in range(count):
            if stop is not None and stop():
                break
            results.append(task(i))
            if progress is not None:
                progress(i + 1)
        return results
    _task = task
    try:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                                 initializer=_start_worker) as pool:
            futures = [pool.submit(_run, i) for i in range(count)]
            try:
                for done, future in enumerate(as_completed(futures), 1):
                    if future.exception() is not None:
                        break  # raised below, after the failures before it in order
                    if progress is not None:
                        progress(done)
                    if stop is not None and stop():
                        for pending in futures:
                            pending.cancel()
                        break
                results = []
                for future in futures:
                    if future.cancelled():
                        break
                    results.append(future.result())
                return results
            except BaseException:
                for future in futures:
                    future.cancel()
                raise
    finally:
        _task = None


def _start_worker() -> None:
    """Ctrl-C is the caller's to handle; and the worker writes (a warning, say) to streams
    of its own on the same files: the caller's may have been locked by another of its
    threads when it forked (a progress bar redrawing), and a lock copied locked is never
    released."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.__stdout__ is not None:
        sys.stdout = open(sys.__stdout__.fileno(), "w", closefd=False)  # noqa: SIM115
    if sys.__stderr__ is not None:
        sys.stderr = open(sys.__stderr__.fileno(), "w", closefd=False)  # noqa: SIM115


def _run(index: int) -> object:
    with one_blas_thread():
        return _task(index)
