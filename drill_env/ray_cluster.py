"""A Ray cluster for the commands that spread their work over one (``benchmark --backend ray``,
``discrepancy-study --backend ray``): joined when running or at an address, started locally
otherwise, and shut down at the end only if it was started here."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

# how long a Ray address may take to accept a connection before it is called unreachable [s]
CONNECT_TIMEOUT_S = 10.0


def check_ray_address(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Refuse, within ``timeout`` seconds, a Ray address ``HOST:PORT`` (or ``ray://HOST:PORT``)
    where nothing accepts a connection: Ray itself waits many minutes before it gives up.
    ``auto`` and addresses without a port are left to Ray."""
    import socket

    target = address.split("://", 1)[-1]
    host, sep, port = target.rpartition(":")
    if not sep or not port.isdigit():
        return
    host = host.strip("[]") or "127.0.0.1"
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except OSError as exc:
        reason = (
            f"no answer within {timeout:g} s" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        )
        raise ValueError(
            f"ray_address: nothing answers at {address} ({reason}); start the cluster "
            "(`ray start --head`) or give its address, or leave --ray-address out for a local Ray instance"
        ) from None


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
            check_ray_address(address)
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
