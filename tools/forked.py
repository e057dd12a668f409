"""Independent tasks in forked worker processes, results in order: the fits of a log, the replays of its plants.

    results = forked_map(fit_one, tasks, on_done=bar.update)

Each task is a call ``function(task)``; the workers are forked, so the function and the tasks need not be
picklable (a closure over a parsed log is fine), only the results are. Where fork is not available, or a
worker dies (a thread pool the parent had started does not survive fork), the tasks run here instead.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

_JOB: tuple[Callable[[Any], Any], Sequence[Any]] | None = None  # what the forked workers run, by index


def _run(index: int) -> Any:
    assert _JOB is not None
    function, tasks = _JOB
    return function(tasks[index])


def forked_map(function: Callable[[Any], Any], tasks: Sequence[Any], workers: int | None = None,
               on_done: Callable[[], None] | None = None) -> list[Any]:
    """``[function(t) for t in tasks]`` over ``workers`` forked processes (default: the CPUs this process
    may use); ``on_done`` is called after each task finishes."""
    global _JOB
    workers = min(workers or len(os.sched_getaffinity(0)), len(tasks))
    try:
        context = multiprocessing.get_context("fork")
    except ValueError:  # no fork on this platform
        workers = 1
    if workers > 1:
        _JOB = (function, tasks)
        try:
            with ProcessPoolExecutor(workers, mp_context=context) as pool:
                results = []
                for result in pool.map(_run, range(len(tasks))):
                    results.append(result)
                    if on_done is not None:
                        on_done()
                return results
        except BrokenProcessPool:
            pass
        finally:
            _JOB = None
    results = []
    for task in tasks:
        results.append(function(task))
        if on_done is not None:
            on_done()
    return results
