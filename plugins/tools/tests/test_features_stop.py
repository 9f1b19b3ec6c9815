"""Ctrl-C or SIGTERM while ``features build`` starts its local Dask cluster takes effect once
the cluster has started, which is then closed: a cluster stopped half-started left a traceback
from Dask's exit handler."""

from __future__ import annotations

import os
import signal
import time
from typing import Any

import pytest

from c3_matcher_tools.features.cluster import dask_client


class _Cluster:
    """A local cluster whose start is interrupted by ``stop`` part-way; with ``fails``, the
    start then fails (its workers died of the stop: "Nanny failed to start")."""

    def __init__(self, stop: signal.Signals, fails: bool = False, **kwargs: Any) -> None:
        os.kill(os.getpid(), stop)
        time.sleep(0.2)  # the signal arrives here, half-way through the start
        if fails:
            raise RuntimeError("Nanny failed to start.")
        self.started, self.closed = True, False
        MADE.append(self)

    def close(self) -> None:
        self.closed = True


MADE: list[_Cluster] = []


@pytest.mark.parametrize("fails", [False, True], ids=["starts", "fails-to-start"])
@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_during_the_clusters_start_stops_it_whole(
    stop: signal.Signals, fails: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A start the stop made fail is the stop too (it was an internal error), its failure kept
    as the context; the stop signals are taken again once the start is over."""
    import dask.distributed

    def terminate(signum: int, frame: object) -> None:
        raise KeyboardInterrupt  # as the command line's SIGTERM handler does

    previous = signal.signal(signal.SIGTERM, terminate)
    MADE.clear()
    monkeypatch.setattr(dask.distributed, "LocalCluster", lambda **kw: _Cluster(stop, fails, **kw))
    monkeypatch.setattr(dask.distributed, "Client", lambda cluster: pytest.fail("not started"))
    try:
        with pytest.raises(KeyboardInterrupt) as stopped, dask_client(2, None):
            pytest.fail("the block runs after a stop")
        if fails:
            assert isinstance(stopped.value.__context__, RuntimeError)
        else:
            (cluster,) = MADE
            assert cluster.started and cluster.closed
        assert signal.getsignal(signal.SIGTERM) is terminate
        assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == set()
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_the_handlers_are_given_back_when_holding_the_stops_fails(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Multiprocessing's helper process that could not start left the deferring handlers in
    place: every later Ctrl-C was swallowed."""
    from multiprocessing import resource_tracker

    from c3_matcher_tools.features.cluster import stops_deferred

    def cannot_start() -> None:
        raise OSError("cannot start the resource tracker")

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    monkeypatch.setattr(resource_tracker, "ensure_running", cannot_start)
    with pytest.raises(OSError, match="resource tracker"), stops_deferred():
        pytest.fail("the block runs")
    assert {s: signal.getsignal(s) for s in before} == before
    assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == set()
