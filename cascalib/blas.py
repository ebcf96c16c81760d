"""One BLAS thread while a stage of the cascade computes.

cascalib's linear algebra is many thin products (the ``(16, 4C) @ (4C, N)`` GEMM of every
batched triangulation, rotations of N points) whose cost is memory traffic, not arithmetic.
OpenBLAS splits each of them over every core all the same, and its threads spin while they wait
for the next one, taking CPU from the stages' own threads (stage V's clock search runs its
cameras in parallel, stages II-IV their camera pairs) and from other jobs on the machine.
Measured on 4 cameras x 3000 frames x 5 persons (simulated terrace, 2 cores), default OpenBLAS
threads -> one, results identical to the last digit:

- stage V alone, eight runs each, alternating: 28.6 -> 23.2 s CPU, wall unchanged within this
  machine's noise (20.8 -> 21.0 s mean; the same run varies by +-2 s);
- two stage V jobs at once (what the service's worker pool does on 2 cores), twice each: each
  job 31.0-34.3 -> 24.9-28.7 s wall, the pair done in 34.4 / 36.5 -> 30.9 / 29.8 s;
- stages I and II-IV, three runs each: 3.7 -> 2.2 s and 6.8 -> 5.9 s CPU, wall 2.4 -> 2.2 s and
  4.1 -> 3.9 s; the clock search alone 2.1 s serial and in threads, with one BLAS thread 2.2 s
  serial and 1.4 s in threads;
- ``triangulate_poses`` (``cascalib triangulate``, every frame with a known rig), four runs
  each, alternating: 2.17 -> 1.35 s CPU, wall 1.45 -> 1.35 s mean.

The limit holds only while a decorated function runs (threadpoolctl restores the library's own
setting after it), so a program that calls cascalib keeps its BLAS threads for its own work.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from threadpoolctl import threadpool_limits

__all__ = ["one_blas_thread"]

F = TypeVar("F", bound=Callable[..., object])


def one_blas_thread(func: F) -> F:
    """Decorate ``func`` to run with the BLAS libraries limited to one thread (see the module
    docstring for why and what it saves)."""
    return threadpool_limits.wrap(limits=1, user_api="blas")(func)  # type: ignore[no-any-return]
