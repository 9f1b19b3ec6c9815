"""Where ``features build`` runs its tasks: a local Dask cluster, an existing one, or this
process; started whole when Ctrl-C or SIGTERM comes while it starts, its worker processes
deaf to both (this process stops them), and closed on exit. A stop that comes while a build
runs is noted (:func:`stops_noted`): the build ends with it even where Dask took it and went
on, and Dask's records of the teardown it causes are dropped (:func:`dask_client`)."""

from __future__ import annotations

import logging
import os
import signal
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, field
from typing import Any

from c3_matcher_tools.extras import install_line, not_installed

__all__ = [
    "DASK_MODULES",
    "Stops",
    "cores_of",
    "dask_client",
    "needs_dask",
    "stops_deferred",
    "stops_noted",
]

DASK_MODULES = ("dask", "distributed")
"""What the tools' ``dask`` extra installs (``dask[distributed]``): a cluster's workers."""

# The local cluster's scheduler serves no dashboard (nothing reads it); its HTTP server (health,
# metrics) listens on a free loopback port: never on 8787, which another build, or any Dask,
# may hold (Dask warned "Port 8787 is already in use" and moved).
_SCHEDULER_HTTP = "127.0.0.1:0"


@contextmanager
def stops_deferred() -> Iterator[None]:
    """Ctrl-C or SIGTERM while the block runs takes effect when it ends (its handler is called
    then), so what the block starts is whole when it is stopped; a block that failed meanwhile
    is stopped as well (the stop is what the user asked for, its failure the stop's doing).
    The threads the block starts, and the processes they start, never take either signal:
    they are held back there for good (a terminal's Ctrl-C reaches its whole process group,
    and a Dask worker took it as its own: a traceback, and a cluster that failed to start);
    whoever started them stops them. A signal this process ignores stays ignored; signals are
    left alone off the main thread."""
    caught: list[signal.Signals] = []
    try:
        previous = {
            s: signal.signal(s, lambda n, _: caught.append(signal.Signals(n)))
            for s in _STOPS
            if signal.getsignal(s) is not signal.SIG_IGN  # a job started in the background
        }
    except ValueError:  # not the main thread
        yield
        return
    held: set[int | signal.Signals] | None = None
    try:
        held = _hold_stops()
        yield
    finally:
        if held is not None:  # a stop held back is caught here
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
        for s, handler in previous.items():
            signal.signal(s, handler)
        if caught:
            _stop(caught[0], previous[caught[0]])


_STOPS = (signal.SIGINT, signal.SIGTERM)


def _hold_stops() -> set[int | signal.Signals]:
    """Hold Ctrl-C and SIGTERM back in this thread, and so in every thread and process started
    from it, until the mask returned is set again; in this process they are caught by the
    threads that do not hold them, or once the mask is set again. Multiprocessing's resource
    tracker is started first: its start, with the first process spawned, lets both through
    again in the thread that starts it, and so in the next process that thread starts."""
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    return signal.pthread_sigmask(signal.SIG_BLOCK, _STOPS)


def _stop(stop: signal.Signals, handler: Any) -> None:
    """Take ``stop`` as its handler ``handler`` would have (the command line's raises
    KeyboardInterrupt), and raise KeyboardInterrupt whatever it does."""
    if callable(handler):
        handler(stop, None)
    raise KeyboardInterrupt


@dataclass(slots=True)
class Stops:
    """The stops (Ctrl-C, SIGTERM) that came while a build ran (:func:`stops_noted`), and the
    handlers they were taken with: filled in as they come, by the signal handler (not frozen)."""

    caught: list[signal.Signals] = field(default_factory=list)
    handlers: dict[signal.Signals, Any] = field(default_factory=dict)

    def came(self) -> bool:
        return bool(self.caught)

    def check(self) -> None:
        """Take the first stop that came again, as its handler does (KeyboardInterrupt): a
        stop that Dask took and went on from (the build's results still arriving) ends the
        build all the same, never as one that finished."""
        if self.caught:
            _stop(self.caught[0], self.handlers.get(self.caught[0]))


@contextmanager
def stops_noted() -> Iterator[Stops]:
    """Ctrl-C or SIGTERM while the block runs is noted in the :class:`Stops` it is given and
    taken at once by its handler, as before; a stop the block survived (taken where a library
    swallowed it) is taken again when the block ends, as is one the block failed after (its
    failure kept as the context). A signal this process ignores stays ignored; signals are
    left alone off the main thread."""
    stops = Stops()

    def note(number: int, frame: Any) -> None:
        stop = signal.Signals(number)
        stops.caught.append(stop)
        _stop(stop, stops.handlers.get(stop))

    try:
        for s in _STOPS:
            if signal.getsignal(s) is not signal.SIG_IGN:  # a job started in the background
                stops.handlers[s] = signal.signal(s, note)
    except ValueError:  # not the main thread
        pass
    try:
        yield stops
    except BaseException as exc:
        if not isinstance(exc, KeyboardInterrupt):  # a failure after a stop: the stop's doing
            stops.check()
        raise
    else:
        stops.check()
    finally:
        for s, handler in stops.handlers.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)


@contextmanager
def dask_client(workers: int, scheduler: str | None, stops: Stops | None = None) -> Iterator[Any]:
    """A Dask client (``scheduler``'s, or a local cluster of ``workers`` processes with one
    thread each and no dashboard), or None to run the tasks in this process; closed on exit,
    Dask's records dropped from the moment one of ``stops`` comes (:func:`_hushed`)."""
    if not (workers > 0 or scheduler):
        yield None
        return
    if not_installed(*DASK_MODULES):
        asked = f"--scheduler {scheduler}" if scheduler else f"--workers {workers}"
        raise ValueError(needs_dask(asked))
    from dask.distributed import Client, LocalCluster

    with ExitStack() as closes:  # the client, then the cluster, then Dask heard again
        hush = closes.enter_context(_hushed(stops or Stops()))
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
                closes.callback(_closed, hush, cluster.close)  # also when the start was stopped
            client = Client(cluster)
        closes.callback(_closed, hush, client.close)
        if not scheduler:  # the workers' own records of their close dropped in them first
            closes.callback(_closed, hush, _workers_silenced, client)
        yield client


def needs_dask(asked: str) -> str:
    """What a build ``asked`` to run on Dask workers (``--workers N``, ``--scheduler ADDRESS``)
    is told where Dask is not installed: the extra that brings it, and the build in this
    process that needs none."""
    return (
        f"{asked} runs the build on Dask workers, and Dask is not installed: "
        f"{install_line('dask')}, or build in this process with --workers 0"
    )


@contextmanager
def _hushed(stops: Stops) -> Iterator[Callable[[], None]]:
    """Dask's and tornado's records in this process dropped once one of ``stops`` came or the
    cluster closes (the call yielded says it does): a build stopped or failed leaves tasks
    running and results not gathered, and Dask told of each as it stopped and the cluster went
    down (a call cancelled, results lost, a client already gone), some with a traceback; the
    build says what happened, in one line."""
    closed: list[bool] = []

    def heard(record: logging.LogRecord) -> bool:
        return not (closed or stops.came())

    handlers = {*logging.getLogger("distributed").handlers, *logging.getLogger("tornado").handlers}
    for handler in handlers:
        handler.addFilter(heard)
    try:
        yield lambda: closed.append(True)
    finally:
        for handler in handlers:
            handler.removeFilter(heard)


def _closed(hush: Callable[[], None], close: Callable[..., object], *args: Any) -> None:
    """``close(*args)`` with Dask's records in this process dropped (``hush``, :func:`_hushed`)."""
    hush()
    close(*args)


def _workers_silenced(client: Any) -> None:
    """Dask's records dropped in the workers of ``client`` (:func:`_silenced`) before they are
    closed; a worker that cannot be reached any more is closed as it is."""
    with suppress(Exception):
        client.run(_silenced, on_error="ignore")


def _silenced() -> None:
    """In a worker of the local cluster, as the build closes it: Dask's records dropped (a task
    cancelled by the close, a heartbeat to the scheduler gone first); the build says why it
    ended, in one line."""
    for handler in logging.getLogger("distributed").handlers:
        handler.addFilter(_nothing)


def _nothing(record: logging.LogRecord) -> bool:
    return False


def cores_of(client: Any, workers: int) -> int:
    if client is None:
        return 1
    try:
        info = client.scheduler_info()["workers"]
        return max(1, sum(int(w.get("nthreads", 1)) for w in info.values()))
    except Exception:
        return max(1, workers or (os.cpu_count() or 1))
