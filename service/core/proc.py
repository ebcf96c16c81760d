"""Process names that ``ps``, ``top`` and the tests can tell apart (Linux; elsewhere a no-op)."""

from __future__ import annotations

__all__ = ["name_process"]


def name_process(name: str) -> None:
    """Set this process's name as ``ps -o comm`` shows it (at most 15 bytes kept)."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(15, name.encode()[:15] + b"\0", 0, 0, 0)  # PR_SET_NAME
    except (OSError, AttributeError):
        pass


#: Imported once by the fork server (missing modules are skipped by multiprocessing); the
#: first ties the fork server's life to the API process.
PRELOAD = ("service.core.forkserver_guard", "service.worker.runner", "service.inputs",
           "service.uploads", "cascalib.formats", "cascalib.pipeline")


def start_forkserver() -> None:
    """Start the fork server of job and validator processes now, from this (main) thread.

    It imports :data:`PRELOAD` while the API starts serving, so a process starts in
    milliseconds; and since the kernel kills it when its parent thread ends, it must be
    started by the thread that lives as long as the API.
    """
    import multiprocessing
    from multiprocessing import forkserver

    multiprocessing.get_context("forkserver").set_forkserver_preload(list(PRELOAD))
    forkserver.ensure_running()
