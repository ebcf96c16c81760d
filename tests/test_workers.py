"""Worker pools: forked processes that inherit their inputs, or threads."""

from __future__ import annotations

import multiprocessing
import os

import numpy as np
import pytest

from cascalib.errors import InputError
from cascalib.workers import WorkerPool, can_fork

needs_fork = pytest.mark.skipif(not can_fork(), reason="this platform cannot fork")


def _row_sum(shared: np.ndarray, k: int) -> tuple[float, int]:
    return float(shared[k].sum()), os.getpid()


def _fail(shared: np.ndarray, k: int) -> None:
    raise InputError(f"row {k} is bad", camera=f"cam{k}", frame=k)


@pytest.mark.parametrize("processes", [True, False])
def test_tasks_get_the_shared_inputs_and_their_results_come_back(processes: bool) -> None:
    shared = np.arange(40.0).reshape(8, 5)
    with WorkerPool(2, shared, processes=processes) as pool:
        got = [f.result() for f in [pool.submit(_row_sum, k) for k in range(8)]]
    assert [s for s, _ in got] == [float(r.sum()) for r in shared]
    pids = {p for _, p in got}
    if pool.forked:  # other processes did the work
        assert os.getpid() not in pids
    else:
        assert pids == {os.getpid()}


@needs_fork
def test_processes_are_used_where_the_process_can_fork() -> None:
    assert WorkerPool(2, None).forked
    assert not WorkerPool(1, None).forked  # one worker: a thread
    assert not WorkerPool(2, None, processes=False).forked


@pytest.mark.parametrize("processes", [True, False])
def test_a_tasks_error_reaches_the_caller_with_its_fields(processes: bool) -> None:
    with WorkerPool(2, None, processes=processes) as pool:
        fut = pool.submit(_fail, 3)
        with pytest.raises(InputError) as err:
            fut.result()
    assert (err.value.message, err.value.camera, err.value.frame) == ("row 3 is bad", "cam3", 3)
    assert str(err.value) == "camera 'cam3', frame 3: row 3 is bad"


def _in_daemon(queue: multiprocessing.Queue) -> None:
    with WorkerPool(2, np.ones((2, 2))) as pool:
        queue.put((pool.forked, pool.submit(_row_sum, 1).result()[0]))


@needs_fork
def test_a_daemonic_process_runs_the_tasks_in_threads() -> None:
    """A daemonic process (a Celery prefork worker) may not have children."""
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    proc = ctx.Process(target=_in_daemon, args=(queue,), daemon=True)
    proc.start()
    forked, total = queue.get(timeout=60)
    proc.join(timeout=60)
    assert (forked, total) == (False, 2.0)
