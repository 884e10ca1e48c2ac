"""A Ray cluster for the commands that spread their work over one (``benchmark --backend ray``,
``discrepancy-study --backend ray``): joined when running or at an address, started locally
otherwise, and shut down at the end only if it was started here."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def ray_cluster(workers: int | None, address: str | None) -> Iterator[Any]:
    """The ``ray`` module, initialised: the running instance, the cluster at ``address``, or a
    local instance of ``workers`` CPUs (default: every core), which is shut down on exit."""
    try:
        import ray
    except ImportError:
        raise ValueError("backend: 'ray' needs Ray; install it with `pip install drill-env[ray]`") from None
    started = False
    if not ray.is_initialized():
        if address:
            ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
        else:
            ray.init(
                num_cpus=workers or os.cpu_count() or 1,
                ignore_reinit_error=True,
                log_to_driver=False,
                include_dashboard=False,
            )
        started = True
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()
