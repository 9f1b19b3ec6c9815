"""Precompute a tile store's map features for one or more strategies, on Dask.

The store holds candidate WINDOWS, not tiles (see :mod:`c3_matcher.tilestore.features` for why
and for the sidecar format): every ``window_px`` square window of WORLD px on a ``stride_px``
grid that stored tiles cover to at least ``min_coverage`` (or an explicit list of grid windows,
e.g. those a recorded flight's candidates use) is stitched from the store, prepared exactly as
the flight prepares a candidate (``FramePreprocessor.prepare_tile`` under the configured
``[matcher] photometric``) and run through the strategy's own ``FeatureBackend.extract`` (the
engine and provider the flight loads) with a budget of the engine's whole top-K. The client is
the single writer of the sidecar (``<store>.features.sqlite``): idempotent and resumable,
windows already stored for the same set with the same tiles are skipped.

Cluster: ``dask.distributed.LocalCluster(n_workers=workers, threads_per_worker=1)`` by default,
or ``Client(scheduler)`` for an existing cluster (its workers need this environment and read
access to the store path). ``workers=0`` runs in this process, without Dask; where Dask (the
tools' ``dask`` extra) is not installed, workers are refused naming it
(:func:`.cluster.needs_dask`). The local cluster serves no dashboard and takes no fixed port
(:mod:`.cluster`): builds of different stores run side by side. A cluster that has had no
worker for a minute (its workers died, or none connected), or whose workers kept dying while
running a task, ends the build in one line (:mod:`.waits`); the windows done are kept.

One build of a store at a time (:mod:`.lock`): a build holds the store's build lock while it
runs, and a second one is refused at once (``BuildRunningError``, a ValueError) rather than
computing the same windows again; the sidecar's readers never take it.

Damage: every row already stored for a set is read and verified (checksum, shapes) before it
counts as done; a damaged row is said (naming the sidecar and the window) and extracted again
(or dropped when this build does not cover its window). A sidecar SQLite itself finds damaged,
when opened or later, is moved aside (never deleted) and the build starts again on a new one.
A set is marked complete only when a build of it finished: incomplete while one runs.
"""

from __future__ import annotations

import sqlite3
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from c3_matcher.config import C3Settings
from c3_matcher.errors import C3Error
from c3_matcher.plugins.manager import PluginHost
from c3_matcher.tilestore.features import (
    FeatureSet,
    MapFeatureStore,
    covered_tiles,
    sidecar_path,
    stored_tile_digest,
    window_digest,
)
from c3_matcher.tilestore.files import open_failure, set_aside
from c3_matcher.tilestore.geo import TILE_PX
from c3_matcher.tilestore.sidecar import SidecarDamagedError
from c3_matcher_tools.features.cluster import Stops, cores_of, dask_client, stops_noted
from c3_matcher_tools.features.lock import BuildRunningError, build_lock
from c3_matcher_tools.features.waits import WORKERLESS_S, AskedCluster, ClusterError, finished
from c3_matcher_tools.features.windows import (
    WindowKey,
    brief_set_id,
    flight_grid,
    flight_windows,
    grid_windows,
)
from c3_matcher_tools.features.worker import (
    NotStorableError,
    ProcessBackends,
    SetFacts,
    check_window,
    extract_window_features,
    open_source,
    photometric_of,
    set_facts,
    set_facts_task,
    task,
)

__all__ = [
    "WINDOW_PX_RANGE",
    "BuildReport",
    "BuildRunningError",
    "ClusterError",
    "InstalledExtractor",
    "build_features",
    "extract_window_features",
    "flight_grid",
    "flight_windows",
    "grid_windows",
    "installed_extractor",
    "store_tile_digests",
    "window_digests",
]

DEFAULT_WINDOW_PX = TILE_PX  # the store's own tiles as the candidates
WINDOW_PX_RANGE = (16, 8192)  # the window sizes a set can be built with, px
DEFAULT_MIN_COVERAGE = 0.5


@dataclass
class BuildReport:
    store: str
    sidecar: str
    strategies: dict[str, dict[str, Any]] = field(default_factory=dict)


def _batches(items: list[WindowKey], size: int) -> Iterator[list[WindowKey]]:
    for i in range(0, len(items), size):
        yield items[i : i + size]


def build_features(
    store: Path,
    strategies: Sequence[str],
    settings: C3Settings,
    *,
    window_px: int = DEFAULT_WINDOW_PX,
    stride_px: int | None = None,
    min_coverage: float = DEFAULT_MIN_COVERAGE,
    windows: Sequence[WindowKey] | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    batch_size: int = 8,
    progress: Callable[[str], None] | None = None,
    plugin_host: PluginHost | None = None,
    workerless_s: float = WORKERLESS_S,
) -> BuildReport:
    """Precompute ``store``'s map features for each strategy (see the module docstring):
    ``window_px`` windows on a ``stride_px`` grid (default: ``window_px``), every window the
    store covers to ``min_coverage``, or only ``windows`` (zoom, gx, gy) when given.
    ``plugin_host``: the process's (default: discovered now). On Dask, a cluster without a
    worker for ``workerless_s`` seconds, or whose workers keep dying, ends the build with a
    :class:`ClusterError`."""
    say = progress or (lambda line: print(line, file=sys.stderr, flush=True))
    stride = int(stride_px or window_px)
    low, high = WINDOW_PX_RANGE
    if not low <= window_px <= high or not 1 <= stride <= window_px:
        raise ValueError(
            f"window must be in [{low}, {high}] px and stride in [1, window]: {window_px}, {stride}"
        )
    if not 0.0 < min_coverage <= 1.0:
        raise ValueError(f"min_coverage must be in (0, 1], got {min_coverage}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if not workerless_s > 0:
        raise ValueError(f"workerless_s must be > 0, got {workerless_s}")
    store, path = Path(store), sidecar_path(Path(store))
    with build_lock(store, path):  # another build of the store running: refused at once
        plan = _plan(store, windows, window_px, stride, min_coverage)
        host = _host(plugin_host)
        resolved = _resolved(settings, strategies, host)
        job = _Job(store, host, resolved, window_px, stride, batch_size, say)
        return _built(job, plan, path, AskedCluster(workers, scheduler, workerless_s))


def _built(
    job: _Job, plan: dict[WindowKey, str | None], path: Path, asked: AskedCluster
) -> BuildReport:
    """Build each of ``job``'s strategies' sets of ``plan`` in the sidecar ``path``, moved aside
    and built anew once when it is found damaged. Every strategy's set facts are learnt first,
    so a strategy refused (:class:`NotStorableError`, or a window its input rule would pad or
    resize: :func:`check_window`) leaves the sidecar untouched."""
    report, new = BuildReport(str(job.store), str(path)), False
    with stops_noted() as stops, dask_client(asked.workers, asked.scheduler, stops) as client:
        local = ProcessBackends(job.host)  # this process's, when it runs the tasks itself
        runner = _Runner(client, local, cores_of(client, asked.workers), stops, asked)
        facts = {s: _set_facts(job, s, runner) for s in job.settings_json}
        for strategy, known in facts.items():  # a window the flight never serves: refused
            check_window(known.input_rule, job.window_px, strategy)
        while True:
            try:
                with _open_sidecar(path) as sidecar:
                    for strategy, known in facts.items():
                        built = _build_set(job, strategy, known, plan, sidecar, runner)
                        report.strategies[strategy] = built
                return report
            except SidecarDamagedError as exc:  # when opened or while building: closed now
                if new:
                    raise ValueError(f"{exc}: damaged while it was built (check the disk)") from exc
                _move_aside(path, exc, job.say)
                new = True
            except sqlite3.OperationalError as exc:  # a lock held past the timeout, a full disk
                raise ValueError(f"{path}: cannot be written: {exc}") from exc


def _open_sidecar(path: Path) -> MapFeatureStore:
    """The sidecar ``path`` open for writing (``SidecarDamagedError`` when it is not an SQLite
    database, or a damaged one: :func:`build_features` moves it aside and starts a new one). A
    path that cannot be opened (a directory, no permission, a lock held past the timeout) is a
    ValueError naming it."""
    try:
        return MapFeatureStore(path, writable=True)
    except sqlite3.OperationalError as exc:  # why, as the readers say it (SQLite's words else)
        why = open_failure(path, "a features sidecar") if path.exists() else None
        raise ValueError(f"{path}: cannot be opened for writing: {why or exc}") from exc


def _move_aside(path: Path, exc: SidecarDamagedError, say: Callable[[str], None]) -> None:
    """Move the damaged sidecar ``path`` aside (renamed, never deleted: :func:`set_aside`),
    saying so: its features are a cache of what this build computes again, which no reader can
    use as it is."""
    aside = set_aside(path)
    say(
        f"features: {exc}: moved aside to {aside} (delete it when it is not needed) and "
        "building a new sidecar"
    )


@dataclass(frozen=True)
class _Job:
    """One build: the store, the plugin host of this process (the strategies resolved on it,
    the backends this process builds itself built on it), each strategy's settings (resolved
    for it, as JSON for the workers), window and stride (px), windows per task and where
    progress lines go."""

    store: Path
    host: PluginHost
    settings_json: Mapping[str, str]
    window_px: int
    stride_px: int
    batch_size: int
    say: Callable[[str], None]


@dataclass(frozen=True)
class _Runner:
    """Where a build's tasks run: ``client``'s workers (None: this process, its backends held in
    ``local``), with ``cores`` threads in all; ``stops``: the Ctrl-C or SIGTERM that ends it;
    ``asked``: the cluster asked for."""

    client: Any
    local: ProcessBackends
    cores: int
    stops: Stops
    asked: AskedCluster


def _host(host: PluginHost | None) -> PluginHost:
    """``host``, the process's plugin host its command was given, or one discovered now (a
    caller without a command): discovered once per build, never again per backend."""
    from c3_matcher.compose import build_plugin_host

    return host if host is not None else build_plugin_host()


def _resolved(settings: C3Settings, strategies: Sequence[str], host: PluginHost) -> dict[str, str]:
    """Each strategy's settings as it flies them (its own defaults where the configuration
    leaves a setting unset), as JSON, from ``host``'s plugins."""
    from c3_matcher.compose import strategy_settings

    for s in strategies:  # one unknown or not linked here: refused before any worker starts
        host.resolve(s)
    return {s: strategy_settings(settings, s, host).model_dump_json() for s in strategies}


@dataclass(frozen=True)
class InstalledExtractor:
    """The extractor engine a strategy flies with in this installation: its file's sha256 (the
    flight is served only the sets that engine built), or None and why it cannot be named (the
    strategy's plugin is not installed, its engine is missing or refused); with the facts and
    photometric normalisation that key the sets a flight asks for (:meth:`asked`)."""

    sha256: str | None
    why: str = ""
    facts: SetFacts | None = None
    photometric: str = ""

    def asked(self, window_px: int) -> str | None:
        """The id of the set of ``window_px`` windows a flight of these settings asks for."""
        return None if self.facts is None else self.facts.set_id(self.photometric, window_px)


def installed_extractor(
    strategy: str, settings: C3Settings, host: PluginHost | None = None
) -> InstalledExtractor:
    """``strategy``'s extractor engine under ``settings``, learnt as a build learns the set it
    builds (its backend loaded in this process: :func:`set_facts`)."""
    try:
        plugins = _host(host)
        settings_json = _resolved(settings, [strategy], plugins)[strategy]
        facts = set_facts(strategy, settings_json, ProcessBackends(plugins))
        return InstalledExtractor(facts.extractor_sha256, "", facts, photometric_of(settings_json))
    except (C3Error, ValueError, OSError, RuntimeError) as exc:
        return InstalledExtractor(None, " ".join(str(exc).split()))


def _plan(
    store: Path,
    windows: Sequence[WindowKey] | None,
    window_px: int,
    stride: int,
    min_coverage: float,
) -> dict[WindowKey, str | None]:
    """Every window to build (sorted), each with the digest of the stored tiles it covers.
    Given ``windows``, only the tiles they cover are read (a few windows of a large store read
    a few tiles); else every tile is, the grid being made of them."""
    if windows is not None:
        with open_source(str(store)) as source:
            if not source.zooms():
                raise ValueError(f"{store}: the store holds no tiles: nothing to build")
        todo = sorted(set(windows))
        if not todo:
            raise ValueError(f"{store}: no window to build")
        covered = {k for w in todo for k in _covered(w, window_px, stride)}
        return window_digests(todo, window_px, stride, store_tile_digests(store, covered))
    digests = store_tile_digests(store)
    tiles = set(digests)
    if not tiles:
        raise ValueError(f"{store}: the store holds no tiles: nothing to build")
    todo = grid_windows(tiles, window_px, stride, min_coverage)
    if not todo:
        raise ValueError(
            f"{store}: no {window_px} px window to build (none on the {stride} px grid is "
            f"covered to {min_coverage:g} by its {len(tiles)} tiles)"
        )
    return window_digests(todo, window_px, stride, digests)


def _covered(window: WindowKey, window_px: int, stride: int) -> list[tuple[int, int, int]]:
    """The tiles (zoom, x, y) the ``window_px`` grid window (zoom, gx, gy) of a ``stride`` px
    grid covers (:func:`covered_tiles`)."""
    z, gx, gy = window
    return covered_tiles(z, (gx * stride, gy * stride), (window_px, window_px))


def store_tile_digests(
    store: Path, keys: Iterable[tuple[int, int, int]] | None = None
) -> dict[tuple[int, int, int], str | None]:
    """Each tile the store lists (zoom, x, y), or each of ``keys`` when given (only those are
    read), with its digest as the worker and the flight compute it (:func:`stored_tile_digest`:
    None for a tile stored with NULL data, or not stored)."""
    with open_source(str(store)) as source:
        if keys is None:
            keys = {(z, x, y) for z in source.zooms() for x, y in source.tiles(z)}
        return {k: stored_tile_digest(source, k) for k in keys}


def window_digests(
    windows: Iterable[WindowKey],
    window_px: int,
    stride: int,
    digests: Mapping[tuple[int, int, int], str | None],
) -> dict[WindowKey, str | None]:
    """Each ``window_px`` window (zoom, gx, gy) of a ``stride`` px grid with the digest of the
    tiles it covers (``digests``, :func:`store_tile_digests`; a tile not there is missing): the
    ``window_digest`` the worker stores for it and the flight compares before serving it."""
    return {w: window_digest(_covered(w, window_px, stride), digests.get) for w in windows}


def _set_facts(job: _Job, strategy: str, runner: _Runner) -> SetFacts:
    """What keys ``strategy``'s set, learnt from its backend (in a worker, when there are)."""
    if runner.client is None:
        return set_facts(strategy, job.settings_json[strategy], runner.local)
    facts = runner.client.submit(set_facts_task, strategy, job.settings_json[strategy], pure=False)
    known: SetFacts | str
    (known,) = finished(runner.client, runner.asked, [facts])
    if isinstance(known, str):
        raise NotStorableError(known)
    return known


def _feature_set(job: _Job, strategy: str, facts: SetFacts, sidecar: MapFeatureStore) -> FeatureSet:
    """``strategy``'s set in the sidecar (created when new; a set built with another stride is
    refused; nothing is written to a sidecar holding it before its rows are verified)."""
    photometric = photometric_of(job.settings_json[strategy])
    keyed = facts.keyed(photometric, job.window_px)
    set_id = facts.set_id(photometric, job.window_px)
    existing = sidecar.feature_set(set_id)
    if existing is not None:
        if existing.stride_px != job.stride_px:
            raise ValueError(
                f"{sidecar.path}: set {brief_set_id(set_id)} was built with a stride of "
                f"{existing.stride_px} px, not {job.stride_px}; remove the sidecar first"
            )
        return existing
    new = FeatureSet(
        set_id,
        *keyed,
        job.stride_px,
        facts.descriptor_dim,
        strategy,
        descriptor_dtype=facts.descriptor_dtype,
    )
    sidecar.ensure_set(new)
    return new


def _build_set(
    job: _Job,
    strategy: str,
    facts: SetFacts,
    plan: dict[WindowKey, str | None],
    sidecar: MapFeatureStore,
    runner: _Runner,
) -> dict[str, Any]:
    """Extract and store the windows of ``plan`` not yet done for ``strategy``; its report."""
    fset = _feature_set(job, strategy, facts, sidecar)
    set_id = fset.set_id
    done, damaged = sidecar.checked_windows(fset)
    if damaged:
        _refuse_damaged(job, strategy, sidecar, set_id, damaged, plan)
    todo = [k for k in plan if done.get(k) != plan[k]]
    skipped = len(plan) - len(todo)
    if todo:  # not complete until this build is
        sidecar.mark(set_id, complete=False, windows=len(done))
    job.say(
        f"features {strategy}: {len(plan)} windows of {job.window_px} px "
        f"(stride {job.stride_px} px), {skipped} already done, {len(todo)} to extract "
        f"({brief_set_id(set_id)})"
    )
    started = time.perf_counter()
    busy_s = 0.0
    written = 0
    settings_json = job.settings_json[strategy]
    args = (str(job.store.resolve()), strategy, settings_json, job.window_px, job.stride_px)
    for rows, seconds in _results(runner, args, _batches(todo, job.batch_size)):
        sidecar.put_windows(set_id, rows)
        busy_s += seconds
        written += len(rows)
        elapsed = time.perf_counter() - started
        job.say(
            f"features {strategy}: {written}/{len(todo)} windows, "
            f"{written / max(elapsed, 1e-9):.2f} windows/s"
        )
    elapsed = time.perf_counter() - started
    sidecar.mark(set_id, complete=True, windows=len(sidecar.done_windows(set_id)))
    return {
        "set_id": set_id,
        "window_px": job.window_px,
        "stride_px": job.stride_px,
        "windows": len(plan),
        "skipped": skipped,
        "extracted": written,
        "seconds": elapsed,
        "worker_seconds": busy_s,
        "cores": runner.cores,
        "windows_per_s": written / elapsed if elapsed > 0 else 0.0,
        "windows_per_s_per_core": (written / elapsed / runner.cores) if elapsed > 0 else 0.0,
    }


def _results(
    runner: _Runner, args: tuple[str, str, str, int, int], batches: Iterator[list[WindowKey]]
) -> Iterator[Any]:
    """Each batch's task run (on the runner's workers, or here), its result as it finishes;
    none after a stop came (:meth:`Stops.check`), nor the end of them: a stop that Dask took
    while the results were collected, and went on from, ends the build all the same."""
    client = runner.client
    if client is None:
        done: Iterator[Any] = (task(*args, b, runner.local) for b in batches)
    else:
        futures = [client.submit(task, *args, b, pure=False) for b in batches]
        done = finished(client, runner.asked, futures)
    for result in done:
        runner.stops.check()
        yield result
    runner.stops.check()


def _refuse_damaged(
    job: _Job,
    strategy: str,
    sidecar: MapFeatureStore,
    set_id: str,
    damaged: Mapping[WindowKey, str],
    plan: Mapping[WindowKey, str | None],
) -> None:
    """Say which stored windows of a set are damaged: extracted again when ``plan`` holds
    them, else dropped (never left to be served)."""
    listed = sorted(damaged.items())
    shown = "; ".join(f"{z}/{gx}/{gy}: {why}" for (z, gx, gy), why in listed[:5])
    more = f"; and {len(listed) - 5} more" if len(listed) > 5 else ""
    dropped = [k for k in damaged if k not in plan]
    job.say(
        f"features {strategy}: {sidecar.path}: {len(listed)} stored windows of set "
        f"{brief_set_id(set_id)} damaged ({len(listed) - len(dropped)} extracted again, "
        f"{len(dropped)} dropped): {shown}{more}"
    )
    sidecar.drop_windows(set_id, dropped)
