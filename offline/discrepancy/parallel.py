"""Independent re-simulations over the machine's cores, with a result that does not depend on the
number of workers (issue 24: the time of a diagnosis is its re-simulations of the drive, and the
candidate fits, the held-out refits of each fold and the null's linearisation points do not
depend on one another).

:func:`map_tasks` runs ``fn`` on each task in forked worker processes (``workers > 1``) or in
this process (``workers == 1``, or already inside a worker: no nested pools), and returns the
results in task order, so the caller combines them exactly as a serial loop would. A task draws
no random numbers (the caller draws them before, in the serial order) and reads the model only
through its re-simulations, which are deterministic: the result is bit for bit that of the serial
loop whatever the worker count or the order the workers finish in.

The model's memory of re-simulations (a drive model's cache and its count of re-simulations,
:meth:`offline.discrepancy.drive.diagnosis.DriveModel.work_since`) is carried back: each worker
starts from a copy of the parent's (fork), returns what its task added, and the parent takes
those in task order, counting a re-simulation once where two tasks ran the same one (where the
serial loop would have found it in the cache). A model without that protocol is used as it is.

Fork is the start method (the tasks are closures over the diagnosis's state, which fork passes
without pickling); where it is not available (Windows, macOS default), the tasks run serially.
"""

from __future__ import annotations

import multiprocessing
import os
from typing import Any, Callable, Sequence, TypeVar

__all__ = ["map_tasks", "available_workers"]

T = TypeVar("T")
R = TypeVar("R")

_JOB: tuple[Callable[[Any], Any], Sequence[Any], Any] | None = None
"""The running job, set in the parent just before the pool forks (the workers inherit it)."""
_IN_WORKER = False


def available_workers() -> int:
    """The cores this process may run on (the CLI's default worker count)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


def _worker_start() -> None:
    global _IN_WORKER
    _IN_WORKER = True


def _run(i: int) -> tuple[Any, Any]:
    assert _JOB is not None
    fn, tasks, model = _JOB
    mark = model.work_mark() if hasattr(model, "work_mark") else None
    out = fn(tasks[i])
    return out, (model.work_since(mark) if mark is not None else None)


def map_tasks(fn: Callable[[T], R], tasks: Sequence[T], workers: int = 1, model: Any = None,
              cost: Sequence[float] | None = None) -> list[R]:
    """``[fn(t) for t in tasks]``, over up to ``workers`` processes (module notes).

    Parameters
    ----------
    fn : callable
        One task; its result must pickle (numpy arrays, dataclasses of them).
    tasks : sequence
    workers : int
        Processes (1: this process, serially).
    model : object, optional
        The model the tasks re-simulate with; when it offers ``work_mark()``,
        ``work_since(mark)`` and ``absorb(work)``, what the workers re-simulated is carried back
        into it in task order.
    cost : sequence of float, optional
        Expected cost of each task: the workers take the costliest first (the last task to finish
        then is a short one); the results stay in task order.

    Returns
    -------
    list
        ``fn(t)`` for each task, in task order.
    """
    global _JOB
    tasks = list(tasks)
    if workers < 1:
        raise ValueError(f"workers = {workers}: expected at least 1")
    if (workers == 1 or len(tasks) < 2 or _IN_WORKER
            or "fork" not in multiprocessing.get_all_start_methods()):
        return [fn(t) for t in tasks]
    order = list(range(len(tasks)))
    if cost is not None:
        order.sort(key=lambda i: -float(cost[i]))
    _JOB = (fn, tasks, model)
    pool = multiprocessing.get_context("fork").Pool(min(workers, len(tasks)), initializer=_worker_start)
    try:
        done = pool.map(_run, order, chunksize=1)
        pool.close()  # the workers exit and are reaped (their CPU time counts in the parent's children)
    finally:
        _JOB = None
        pool.terminate()
        pool.join()
    results: list[Any] = [None] * len(tasks)
    work: list[Any] = [None] * len(tasks)
    for i, (out, w) in zip(order, done):
        results[i], work[i] = out, w
    if hasattr(model, "absorb"):
        for w in work:
            model.absorb(w)
    return results
