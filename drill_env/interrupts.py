"""Ctrl-C in long runs: worker pools stopped at once, never drained.

A :class:`concurrent.futures.ProcessPoolExecutor` that is shut down normally runs every
queued task first, and at interpreter exit waits for the running ones: an interrupted
benchmark or study would go on for minutes. :func:`stop_pool` cancels what is queued and
ends the worker processes; what the caller already wrote stays written (a benchmark
resumes from its CSV).
"""

from __future__ import annotations

import contextlib
from concurrent.futures import ProcessPoolExecutor

__all__ = ["stop_pool"]


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel the queued tasks of ``pool`` and end its worker processes now."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.terminate()
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.join(timeout=1.0)
