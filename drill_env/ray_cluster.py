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
    """Refuse, within about twice ``timeout`` seconds, a Ray address ``HOST:PORT`` (or
    ``ray://HOST:PORT``) where no Ray cluster answers: nothing accepts a connection, or what
    does never answers Ray's first request (the cluster id; for ``ray://``, the client server's
    ping), or answers it as something else (a proxy, another service). Ray itself waits many
    minutes before it gives up. ``auto`` and addresses without a port are left to Ray. A
    Ctrl-C during the wait stops it at once (:class:`KeyboardInterrupt`)."""
    import socket

    target = address.split("://", 1)[-1]
    host, sep, port = target.rpartition(":")
    if not sep or not port.isdigit():
        return
    host = host.strip("[]") or "127.0.0.1"
    advice = (
        "start the cluster (`ray start --head`) or give its address, or leave --ray-address out for a "
        "local Ray instance"
    )
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except OSError as exc:
        reason = (
            f"no answer within {timeout:g} s" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        )
        raise ValueError(f"ray_address: nothing answers at {address} ({reason}); {advice}") from None
    problem = _ray_answer(f"{host}:{port}", client=address.startswith("ray://"), timeout=timeout)
    if problem is not None:
        raise ValueError(f"ray_address: no Ray cluster answers at {address} ({problem}); {advice}")


def _ray_answer(target: str, *, client: bool, timeout: float) -> str | None:
    """Ask ``target`` the first question Ray asks a cluster (the GCS's cluster id; a Ray
    client server's ping) and wait at most ``timeout`` s: None if a Ray cluster answered
    (also one that wants a token), else what went wrong. Polls, so a Ctrl-C stops the wait
    within 0.1 s (a blocking gRPC call would hold it for the whole timeout)."""
    import time

    try:
        import grpc  # type: ignore[import-untyped]

        if client:
            from ray.core.generated import ray_client_pb2 as pb
            from ray.core.generated import ray_client_pb2_grpc as pb_grpc
        else:
            from ray.core.generated import gcs_service_pb2 as pb  # type: ignore[no-redef]
            from ray.core.generated import gcs_service_pb2_grpc as pb_grpc  # type: ignore[no-redef]
    except ImportError:  # no Ray (said by ray_cluster) or a Ray without these modules: left to Ray
        return None
    channel = grpc.insecure_channel(target)
    try:
        if client:
            request = pb.ClusterInfoRequest(type=pb.ClusterInfoType.PING)  # type: ignore[attr-defined]
            call = pb_grpc.RayletDriverStub(channel).ClusterInfo.future(request, timeout=timeout)
        else:
            request = pb.GetClusterIdRequest()  # type: ignore[attr-defined]
            call = pb_grpc.NodeInfoGcsServiceStub(channel).GetClusterId.future(request, timeout=timeout)  # type: ignore[attr-defined]
        try:
            while not call.done():
                time.sleep(0.05)
        except BaseException:  # Ctrl-C: stop the call, then let it end the command
            call.cancel()
            raise
        code = call.code()
        if code in (grpc.StatusCode.OK, grpc.StatusCode.UNAUTHENTICATED, grpc.StatusCode.PERMISSION_DENIED):
            return None  # a Ray cluster (one with token authentication refuses a bare request)
        if code == grpc.StatusCode.DEADLINE_EXCEEDED:
            return f"it accepts a connection but does not answer Ray's request within {timeout:g} s"
        if code == grpc.StatusCode.UNIMPLEMENTED:
            return f"what answers is not a Ray cluster: {call.details() or 'the request is unknown'}"
        return f"{code.name.lower()}: {call.details() or 'no details'}"
    finally:
        channel.close()


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
