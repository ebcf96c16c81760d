"""Worker pools: forked processes that inherit their inputs, or threads."""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import time

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


_CALLER = """
import os, sys, time
from cascalib.workers import WorkerPool

def pid(shared, k):
    return os.getpid()

pool = WorkerPool(2, None)
print(*sorted({pool.submit(pid, k).result() for k in range(4)}), flush=True)
time.sleep(120)  # killed here, the pool still open
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"  # a zombie has died
    except FileNotFoundError:
        return False


@needs_fork
@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_the_workers_die_with_a_killed_caller() -> None:
    """A caller killed outright (a cancelled service job's process gets SIGKILL) leaves no
    worker waiting on its task queue forever."""
    caller = subprocess.Popen([sys.executable, "-c", _CALLER], stdout=subprocess.PIPE, text=True)
    assert caller.stdout is not None
    workers = [int(p) for p in caller.stdout.readline().split()]
    assert workers and caller.pid not in workers
    assert all(_alive(p) for p in workers)
    caller.kill()
    caller.wait(timeout=30)
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in workers), workers
