"""Where ``features build`` runs its tasks: a local Dask cluster, an existing one, or this
process; started whole when Ctrl-C or SIGTERM comes while it starts, and closed on exit."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["cores_of", "dask_client", "stops_deferred"]

# The local cluster's scheduler serves no dashboard (nothing reads it); its HTTP server (health,
# metrics) listens on a free loopback port: never on 8787, which another build, or any Dask,
# may hold (Dask warned "Port 8787 is already in use" and moved).
_SCHEDULER_HTTP = "127.0.0.1:0"


@contextmanager
def stops_deferred() -> Iterator[None]:
    """Ctrl-C or SIGTERM while the block runs takes effect when it ends (its handler is called
    then), so what the block starts is whole when it is stopped; signals are left alone off
    the main thread."""
    caught: list[signal.Signals] = []
    try:
        previous = {
            s: signal.signal(s, lambda n, _: caught.append(signal.Signals(n))) for s in _STOPS
        }
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if caught:
        handler = previous[caught[0]]
        if callable(handler):
            handler(caught[0], None)  # raises KeyboardInterrupt, as it would have
        raise KeyboardInterrupt


_STOPS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def dask_client(workers: int, scheduler: str | None) -> Iterator[Any]:
    """A Dask client (``scheduler``'s, or a local cluster of ``workers`` processes with one
    thread each and no dashboard), or None to run the tasks in this process; closed on exit."""
    if not (workers > 0 or scheduler):
        yield None
        return
    from dask.distributed import Client, LocalCluster

    cluster: Any = None
    try:
        if scheduler:
            client = Client(scheduler)
        else:
            with stops_deferred():  # a cluster stopped half-started cannot be closed cleanly
                cluster = LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    scheduler_kwargs={"dashboard_address": _SCHEDULER_HTTP},
                )
            client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        if cluster is not None:
            cluster.close()


def cores_of(client: Any, workers: int) -> int:
    if client is None:
        return 1
    try:
        info = client.scheduler_info()["workers"]
        return max(1, sum(int(w.get("nthreads", 1)) for w in info.values()))
    except Exception:
        return max(1, workers or (os.cpu_count() or 1))
