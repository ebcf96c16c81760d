"""Worker pools for CPU-bound steps written as much in Python loops as in numpy.

Threads do not run such steps in parallel: the loops hold the GIL. Measured on stages II-IV of 4
cameras x 3000 frames x 5 persons on 2 cores: the cameras' ground trajectories took 2.3 s in two
threads and 2.0-2.3 s one after the other, 1.1-1.2 s in two forked processes; the six camera
pairs 4.1, 4.7-5.3 and 3.2-3.4 s.

:class:`WorkerPool` forks its workers, which inherit the (large) inputs through the fork instead
of having them pickled; only the tasks' arguments and results cross between processes. Where a
process cannot fork (Windows, macOS's default, a daemonic process such as a Celery prefork
worker, which may not have children) it runs the same tasks in threads.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")

# the inputs a forked worker inherited (set in the worker only, never in the caller's process,
# so that pools of concurrent callers in threads cannot mix them up)
_SHARED: list[Any] = []


def can_fork() -> bool:
    """Whether this process may fork worker processes: the platform has ``fork`` (Linux) and
    the process is not daemonic (a daemonic process may not have children)."""
    return ("fork" in multiprocessing.get_all_start_methods()
            and not multiprocessing.current_process().daemon)


def die_with_parent() -> None:
    """Linux: have the kernel kill this process when its parent dies.

    A job process the service kills (cancelled, or its worker shutting down), or a caller
    killed otherwise, leaves no orphan behind: a pool's worker would wait on its task queue
    forever. Elsewhere this does nothing.
    """
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _inherit(shared: Any, caller: int) -> None:
    die_with_parent()
    if os.getppid() != caller:  # the caller died before the line above took effect
        os._exit(1)
    _SHARED[:] = [shared]


def _call(fn: Callable[..., T], *args: Any) -> T:
    return fn(_SHARED[0], *args)


class WorkerPool:
    """Runs ``fn(shared, *args)`` tasks on ``n_workers`` forked processes, or threads.

    Parameters
    ----------
    n_workers : int
        Workers; 1 runs the tasks in one thread.
    shared : object
        Inputs every task receives first. Forked workers inherit it (no copy is pickled);
        threads get the object itself.
    processes : bool
        Fork worker processes where this process can (:func:`can_fork`); else threads.

    Notes
    -----
    Each task's function and arguments must pickle (a module-level function, small
    arguments), and so must its result and any exception it raises. The workers are forked
    when the pool starts: ``shared`` is read as it is then. Tasks cannot call back into the
    caller's process (progress callbacks, locks): report from the futures instead.
    """

    def __init__(self, n_workers: int, shared: Any, *, processes: bool = True) -> None:
        self.forked = processes and n_workers > 1 and can_fork()
        self._shared = shared
        self._pool: Executor
        if self.forked:
            self._pool = ProcessPoolExecutor(n_workers,
                                             mp_context=multiprocessing.get_context("fork"),
                                             initializer=_inherit,
                                             initargs=(shared, os.getpid()))
        else:
            self._pool = ThreadPoolExecutor(n_workers)

    def submit(self, fn: Callable[..., T], *args: Any) -> Future[T]:
        """``fn(shared, *args)`` in a worker."""
        if self.forked:
            return self._pool.submit(_call, fn, *args)
        return self._pool.submit(fn, self._shared, *args)

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc: object) -> None:
        # an error leaves the tasks not started yet unrun
        self._pool.shutdown(wait=True, cancel_futures=exc[0] is not None)
