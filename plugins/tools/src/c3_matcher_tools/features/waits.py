"""How ``features build`` waits for its tasks on Dask: for ever while the cluster has a worker
(a task may be long), and a bounded time while it has none. Dask itself waits for a worker for
ever, saying nothing: a cluster whose workers died, or an existing one none connected to, held
the build until it was stopped by hand. A task whose workers kept dying (``KilledWorker``) is
said in one line as well."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from c3_matcher.errors import C3Error

__all__ = ["WORKERLESS_S", "AskedCluster", "ClusterError", "finished"]

WORKERLESS_S = 60.0
"""How long a build on Dask waits while its cluster has no worker before it stops: a local
cluster restarts a killed worker in a few seconds, and a worker started by hand or by a job
system joins in tens of them; a minute without any means the workers died or none connected."""
_POLL_S = 0.25  # how often a wait with no result ready asks whether the cluster has a worker


class ClusterError(C3Error):
    """The Dask cluster cannot run the build: it has had no worker for its ``workerless_s``, or
    its workers kept dying while running a task. The windows done are kept: a build again goes
    on from them."""


@dataclass(frozen=True)
class AskedCluster:
    """Where a build asked to run: ``workers`` local Dask processes (0: this process), or the
    cluster of the ``scheduler`` address; ``workerless_s``: how long it waits without a worker."""

    workers: int
    scheduler: str | None
    workerless_s: float = WORKERLESS_S

    def name(self) -> str:
        """The cluster as a line names it."""
        if self.scheduler:
            return f"the Dask cluster at {self.scheduler}"
        return "the local Dask cluster"


def finished(client: Any, asked: AskedCluster, futures: list[Any]) -> Iterator[Any]:
    """The results of ``futures`` (on the Dask ``client`` of the cluster ``asked``) as they
    finish, each future let go once its result is here (``futures`` is emptied). A
    :class:`ClusterError` when the cluster has had no worker for ``asked.workerless_s`` while
    none finished, or when Dask gave a task up after its workers died running it, one after
    another (``KilledWorker``)."""
    from dask.distributed import KilledWorker, as_completed

    pending = as_completed(futures)
    futures.clear()
    alone_since: float | None = None
    while not pending.is_empty():
        if not pending.has_ready():
            time.sleep(_POLL_S)
            alone_since = _alone_since(client, asked, alone_since)
            continue
        alone_since = None
        try:
            result = next(pending).result()
        except KilledWorker as exc:
            raise ClusterError(
                f"features build: the workers of {asked.name()} died running a task, one after "
                "another (out of memory? killed?): stopped; the windows done are kept, and a "
                "build again goes on from them"
            ) from exc
        yield result


def _alone_since(client: Any, asked: AskedCluster, since: float | None) -> float | None:
    """When ``client``'s cluster was first found without a worker in this wait (``since``, or
    now), None while it has one; a :class:`ClusterError` naming it once that is
    ``asked.workerless_s`` ago. A scheduler that does not answer has no worker."""
    try:
        workers = len(client.nthreads())
    except Exception:  # the scheduler gone: its connection closed, or refused
        workers = 0
    if workers:
        return None
    now = time.monotonic()
    if since is not None and now - since >= asked.workerless_s:
        raise ClusterError(
            f"features build: {asked.name()} has had no worker for {asked.workerless_s:g} s "
            "(its workers died, or none connected): stopped; the windows done are kept, and a "
            "build again goes on from them"
        )
    return now if since is None else since
