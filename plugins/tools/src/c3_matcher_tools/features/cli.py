"""``c3-matcher features build STORE|FLIGHT [--strategy NAME ...] [--window PX] [--stride PX]
[--workers N | --scheduler ADDRESS]`` and ``c3-matcher features info STORE [--verify]``."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from c3_matcher.commands import EXIT_FAILURE, EXIT_OK, CommandRegistry, bounded_float, bounded_int
from c3_matcher.context import CommandContext
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.args import add_strategies_option
from c3_matcher_tools.features.build import WINDOW_PX_RANGE
from c3_matcher_tools.features.command import GivenSettings, build_command, given_settings
from c3_matcher_tools.features.unreadable import Unreadable, not_a_sidecar, unreadable_sidecar
from c3_matcher_tools.features.windows import brief_set_id

if TYPE_CHECKING:
    from c3_matcher.tilestore.features import MapFeatureStore

__all__ = ["DEFAULT_WORKERS", "register_features_command"]

DEFAULT_WORKERS = 2
"""``--workers`` left out: a local Dask cluster of this many processes (where Dask is installed)."""


def register_features_command(commands: CommandRegistry) -> None:
    group = commands.group("features", help="map features computed once on the ground")
    b = group.add(
        "build",
        help="precompute the features of every candidate window on a grid for each strategy's "
        "extractor (Dask), stored beside the store in <STORE>.features.sqlite; resumable",
    )
    b.add_argument(
        "store",
        type=Path,
        help="an MBTiles tile store, or a flight dataset directory (its store; window and "
        "stride default to its candidates' size and grid)",
    )
    add_strategies_option(
        b, "strategy whose extractor to run (repeatable; default: the configured one)"
    )
    _add_build_options(b)
    b.set_defaults(handler=_build)
    i = group.add("info", help="the feature sets stored beside a tile store")
    i.add_argument(
        "store", type=Path, help="an MBTiles tile store, or a flight dataset directory (its store)"
    )
    i.add_argument("--json", action="store_true", help="print the sets as JSON")
    i.add_argument(
        "--verify",
        action="store_true",
        help="read every stored window and check it as the flight does: its checksum and shapes "
        "(damaged) and its tiles' digest against the store's tiles now (stale: a tile changed "
        "since it was built; the flight serves neither); exit 1 when one is damaged or stale, "
        "or a strategy's sets were all built with another extractor engine than the installed "
        "one (features build extracts those again)",
    )
    i.set_defaults(handler=_info)


def _add_build_options(b: argparse.ArgumentParser) -> None:
    """Where ``features build`` runs, which windows and how many per task (each count bounded
    when parsed: a bad one is a usage error naming the option)."""
    where = b.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=bounded_int(0),
        default=None,
        help=f"local Dask cluster of N worker processes (0: in this process, no Dask; default "
        f"{DEFAULT_WORKERS}, or 0 where Dask, the tools' dask extra, is not installed)",
    )
    where.add_argument("--scheduler", default=None, help="an existing Dask scheduler ADDRESS")
    b.add_argument(
        "--window",
        type=bounded_int(*WINDOW_PX_RANGE),
        default=None,
        help="candidate window size, px (default: 256, a store's own tiles; for a flight, "
        "its candidates' size)",
    )
    b.add_argument(
        "--stride",
        type=bounded_int(),
        default=None,
        help="grid step between stored windows, px (default: the window; for a flight, the "
        "grid its candidates lie on); a candidate off the grid is served the nearest "
        "window's features, shifted",
    )
    b.add_argument(
        "--min-coverage",
        type=bounded_float(0.0, 1.0, above=True),
        default=0.5,
        help="store a window when stored tiles cover at least this share of it",
    )
    b.add_argument(
        "--flight-candidates",
        action="store_true",
        help="with a flight dataset: only the windows its recorded candidates use",
    )
    b.add_argument("--batch", type=bounded_int(), default=8, help="candidate windows per task")
    b.add_argument("--json", action="store_true", help="print the report as JSON")


def _build(args: argparse.Namespace, ctx: CommandContext) -> int:
    from c3_matcher_tools.features import build as fb

    path: Path = args.store
    store, window, stride = _store_of(path), args.window, args.stride
    windows = None
    if path.is_dir():
        size, grid = fb.flight_grid(path)
        window = window or size
        stride = stride or (grid if window == size else window)
        if args.flight_candidates:
            windows = fb.flight_windows(path, stride)
    elif args.flight_candidates:
        raise InvalidInputError(
            "--flight-candidates", f"needs a flight dataset (a directory), not the store {path}"
        )
    window = window or fb.DEFAULT_WINDOW_PX
    workers, notice = _workers(args)
    try:
        report = fb.build_features(
            store,
            args.strategy or [ctx.settings.matcher.strategy],
            ctx.settings,
            window_px=window,
            stride_px=stride,
            min_coverage=args.min_coverage,
            windows=windows,
            workers=workers,
            scheduler=args.scheduler,
            batch_size=args.batch,
            progress=_progress(notice, ctx.err),
            plugin_host=ctx.plugin_host,
        )
    except ValueError as exc:  # the build's own refusals, InvalidInputError among them: exit 2
        raise InvalidInputError("features build", " ".join(str(exc).split())) from exc
    if args.json:
        ctx.out(json.dumps(report.__dict__, indent=2))
        return EXIT_OK
    for name, r in report.strategies.items():
        ctx.out(
            f"{name}: {r['extracted']} extracted, {r['skipped']} already done of "
            f"{r['windows']} windows ({r['window_px']} px, stride {r['stride_px']} px) in "
            f"{r['seconds']:.1f} s on {r['cores']} cores: "
            f"{r['windows_per_s_per_core']:.2f} windows/s/core -> {report.sidecar}"
        )
    return EXIT_OK


def _workers(args: argparse.Namespace) -> tuple[int, str | None]:
    """The Dask workers a build runs on: ``--workers`` as given (refused by the build, naming the
    extra, where Dask is not installed), else :data:`DEFAULT_WORKERS`, or 0 (this process) where
    Dask is not installed, with the line that says so."""
    from c3_matcher_tools.extras import install_line, not_installed
    from c3_matcher_tools.features.cluster import DASK_MODULES

    if args.workers is not None or args.scheduler:
        return (DEFAULT_WORKERS if args.workers is None else args.workers), None
    if not_installed(*DASK_MODULES):
        return 0, (
            "features build: dask is not installed: building in this process (for parallel "
            f"workers: {install_line('dask')})"
        )
    return DEFAULT_WORKERS, None


def _progress(first: str | None, err: Callable[[str], None]) -> Callable[[str], None]:
    """A build's progress lines said with ``err`` (a line it cannot write is lost, not the
    build), ``first``, when given, once before them: once the build has checked its input and
    starts (a refused build says its one line alone)."""
    pending = [] if first is None else [first]

    def say(line: str) -> None:
        while pending:
            err(pending.pop())
        err(line)

    return say


def _store_of(path: Path) -> Path:
    """The MBTiles store ``path`` names: itself, or a flight dataset directory's store;
    InvalidInputError (exit 2) naming what it is not."""
    from c3_matcher_tools.dataset.format import is_flight_dataset, load_dataset

    if path.is_dir():
        if not is_flight_dataset(path):
            raise InvalidInputError(
                "STORE", f"{path}: a directory without dataset.json: no store, no dataset"
            )
        path = load_dataset(path).store_path
    if not path.is_file():
        raise InvalidInputError("STORE", f"no such store: {path}")
    return path


def _info(args: argparse.Namespace, ctx: CommandContext) -> int:
    """Print the feature sets stored beside a store, each with whether the installed extractor
    engine built it (:func:`_mark_engines`: the flight is served no other); with --verify each
    window is checked as the flight checks it (its row's checksum and shapes, and its tiles'
    digest against the store's tiles now), each set counting its ``intact``, ``damaged`` and
    ``stale`` windows: exit 1 when one is damaged or stale, or when a strategy has sets but none
    the installed engine built (the flight extracts those instead; a build extracts them
    again). A sidecar that cannot be read (:func:`unreadable_sidecar`), or a directory in its
    place (:func:`not_a_sidecar`), is said, with ``--json`` in a document too."""
    from c3_matcher.tilestore.features import FeatureStoreUnavailableError, sidecar_path
    from c3_matcher.tilestore.mbtiles import MBTilesStore
    from c3_matcher.tilestore.sidecar import SidecarDamagedError

    store = _store_of(args.store)
    MBTilesStore(store).close()  # an MBTiles store (InvalidInputError naming it), not any file
    path = sidecar_path(store)
    flight = args.store if args.store.is_dir() else None
    if path.exists() and not path.is_file():  # the flight ignores it: no sets to read
        return _unread(store, path, not_a_sidecar(path), ctx, as_json=args.json)
    try:
        found = _stored_sets(store, path, verify=args.verify, flight=flight)
    except (SidecarDamagedError, FeatureStoreUnavailableError) as exc:
        said = unreadable_sidecar(exc, args.store, store, path)
        return _unread(store, path, said, ctx, as_json=args.json)
    _mark_engines(found.sets, ctx)
    given = given_settings(args.config)  # the set asked for is these settings'
    _mark_commands(args.store, found, given)
    _print_sets(store, path, found.sets, ctx, as_json=args.json)
    _window_notes(store, path, found, ctx)
    unserved = _engine_notes(path, found, ctx)
    failed = found.damaged or found.stale or (unserved and args.verify)
    return EXIT_FAILURE if failed else EXIT_OK


def _unread(
    store: Path, path: Path, said: Unreadable, ctx: CommandContext, *, as_json: bool
) -> int:
    """Say why the sidecar ``path`` of ``store`` is not read (``said``), with ``as_json`` in
    the document too (its sets: None); the exit status."""
    ctx.err(f"c3-matcher: {said.problem}")
    if as_json:
        _print_document(store, path, None, ctx, said=said)
    return said.status


@dataclass(frozen=True)
class _Found:
    """The sets a sidecar holds (``features info``'s rows), how many windows are damaged and
    stale in all (checked: ``--verify``), and per set id whether it holds only windows of the
    flight asked about (``--flight-candidates`` builds it again; None: no flight asked about)."""

    sets: list[dict[str, object]]
    damaged: int = 0
    stale: int = 0
    flight_only: dict[str, bool | None] | None = None


def _stored_sets(store: Path, path: Path, *, verify: bool, flight: Path | None) -> _Found:
    """Read the sets the sidecar ``path`` of ``store`` holds (none without one), checked when
    ``verify``; ``flight``: the flight directory the user named, whose candidates' windows each
    set is compared with."""
    from c3_matcher.tilestore.features import MapFeatureStore, stored_sets

    if not path.is_file():
        return _Found([])
    with MapFeatureStore(path) as side:
        sets = [dict(s) for s in stored_sets(side)]
        damaged, stale = _verified(store, side, sets) if verify else (0, 0)
        only = None if flight is None else _flight_only(side, sets, flight)
        return _Found(sets, damaged, stale, only)


def _flight_only(
    side: MapFeatureStore, sets: list[dict[str, object]], flight: Path
) -> dict[str, bool | None]:
    """Per set id: whether every window the set holds is one of ``flight``'s candidates' on
    the set's grid (what ``--flight-candidates`` builds)."""
    from c3_matcher_tools.features.build import flight_windows

    only: dict[str, bool | None] = {}
    for s in sets:
        asked = set(flight_windows(flight, int(str(s["stride_px"]))))
        only[str(s["set_id"])] = set(side.done_windows(str(s["set_id"]))) <= asked
    return only


def _mark_commands(given: Path, found: _Found, settings: GivenSettings) -> None:
    """Mark each set with ``command``, the line that builds it, and ``command_note``, what to
    know to run it (:func:`build_command` beside the store
    ``given`` names, under ``settings``) where the flight is not served all it holds: damaged
    or stale windows, a set a stopped build left incomplete (the same line finishes it), or a
    set the flight is never served that no served set replaces; None where nothing needs
    building."""
    for s in found.sets:
        unserved = s["engine_installed"] is not None and not s["served"]
        unfinished = s.get("complete") is False
        needed = (
            s.get("damaged")
            or s.get("stale")
            or unfinished
            or (unserved and not _replacing(found, s))
        )
        command = (
            build_command(
                given, s["strategy"], s["window_px"], s["stride_px"], _only(found, s), settings
            )
            if needed
            else None
        )
        s["command"] = None if command is None else command.line
        s["command_note"] = None if command is None else command.note or None


def _said(s: dict[str, object]) -> str:
    """The command marked on the set ``s`` in words: the line, its note in brackets after it."""
    note = s.get("command_note")
    return f"{s['command']} ({note})" if note else str(s["command"])


def _replacing(found: _Found, s: dict[str, object]) -> dict[str, object] | None:
    """The set the flight is served in place of ``s``: same strategy and window (the last
    listed), None where there is none."""
    key = (s["strategy"], s["window_px"])
    served = (o for o in reversed(found.sets) if o["served"])
    return next((o for o in served if (o["strategy"], o["window_px"]) == key), None)


def _window_notes(store: Path, path: Path, found: _Found, ctx: CommandContext) -> None:
    """Say of each set with damaged or stale windows how many, and the command that extracts
    them again: the one that builds that set (:func:`_mark_commands`)."""
    for s in found.sets:
        why = {
            "damaged": "the flight extracts those instead",
            "stale": f"their tiles changed in {store} since they were built; the flight "
            "extracts those instead",
        }
        for kind, because in why.items():
            if not (count := int(str(s.get(kind, 0)))):
                continue
            ctx.err(
                f"c3-matcher: {path}: {count} {kind} windows in {_named(s)} ({because}); "
                f"extract them again: {_said(s)}."
            )


def _only(found: _Found, s: dict[str, object]) -> bool | None:
    """Whether the set ``s`` holds only the windows of the flight asked about (None: unknown)."""
    return None if found.flight_only is None else found.flight_only.get(str(s["set_id"]))


def _named(s: dict[str, object]) -> str:
    """A set in words: its id (:func:`brief_set_id`), its strategy and window size."""
    return f"set {brief_set_id(s['set_id'])} ({s['strategy']}, {s['window_px']} px windows)"


def _print_document(
    store: Path,
    path: Path,
    sets: list[dict[str, object]] | None,
    ctx: CommandContext,
    *,
    said: Unreadable | None = None,
) -> None:
    """``features info --json``: the store, its sidecar, the sets it holds (None: it cannot be
    read: ``said``, why, and the command that builds them again)."""
    document = {"store": str(store), "sidecar": str(path), "sets": sets}
    problem = {
        "problem": None if said is None else said.problem,
        "command": None if said is None else said.command,
    }
    ctx.out(json.dumps({**document, **problem}, indent=2))


def _print_sets(
    store: Path, path: Path, sets: list[dict[str, object]], ctx: CommandContext, *, as_json: bool
) -> None:
    """Print the stored sets: as JSON (:func:`_print_document`), one line each, or that there
    are none."""
    if as_json:
        _print_document(store, path, sets, ctx)
    elif not sets:
        ctx.out(f"{store}: no precomputed features ({path} absent or empty)")
    else:
        for s in sets:
            ctx.out(", ".join(f"{k}: {_word(v)}" for k, v in s.items() if v is not None))


def _word(value: object) -> object:
    """A set's value as a line of text says it: yes or no for a flag, else the value."""
    return ("yes" if value else "no") if isinstance(value, bool) else value


def _verified(store: Path, side: MapFeatureStore, sets: list[dict[str, object]]) -> tuple[int, int]:
    """Each set's windows read and checked as the flight checks them: its row
    (:meth:`MapFeatureStore.checked_windows`: ``damaged``, the reasons under ``damage``) and its
    tiles' digest against ``store``'s tiles now, computed as a build plans it
    (:func:`~c3_matcher_tools.features.build.window_digests`: ``stale`` when they differ);
    ``intact``: the windows the flight serves. The numbers damaged and stale in all."""
    from c3_matcher_tools.features.build import store_tile_digests, window_digests

    tiles = store_tile_digests(store)
    damaged = stale = 0
    for s in sets:
        fset = side.feature_set(str(s["set_id"]))
        intact, bad = side.checked_windows(fset) if fset else ({}, {})
        now = window_digests(intact, fset.window_px, fset.stride_px, tiles) if fset else {}
        old = [k for k, digest in intact.items() if now[k] != digest]
        s.update(intact=len(intact) - len(old), damaged=len(bad), stale=len(old))
        s["damage"] = {f"{z}/{x}/{y}": why for (z, x, y), why in sorted(bad.items())}
        damaged, stale = damaged + len(bad), stale + len(old)
    return damaged, stale


def _mark_engines(sets: list[dict[str, object]], ctx: CommandContext) -> None:
    """Mark each set with the extractor engine its strategy flies with in this installation
    (``installed_extractor_sha256``, learnt once per strategy), ``engine_installed``: whether
    that engine built it (the flight is served no set another engine built), and ``served``:
    whether it is the set a flight of these settings asks for (its engine, provider,
    photometric normalisation and input rule, upscale included); both None when the installed
    engine cannot be named (``engine_unknown``: why)."""
    from c3_matcher_tools.features.build import installed_extractor

    strategies = sorted({str(s["strategy"]) for s in sets})
    installed = {n: installed_extractor(n, ctx.settings, ctx.plugin_host) for n in strategies}
    for s in sets:
        known = installed[str(s["strategy"])]
        s["installed_extractor_sha256"] = known.sha256
        s["engine_installed"] = (
            None if known.sha256 is None else known.sha256 == s["extractor_sha256"]
        )
        asked = known.asked(int(str(s["window_px"])))
        s["served"] = None if asked is None else asked == s["set_id"]
        s["asked_set_id"] = asked
        if known.sha256 is None:
            s["engine_unknown"] = known.why


def _engine_notes(path: Path, found: _Found, ctx: CommandContext) -> int:
    """Say of each set the flight is not served (:func:`_mark_engines`: another extractor
    engine, or other settings, built it) that it is never served, and what builds the set it is
    served (:func:`_mark_commands`); of each set whose engine cannot be named, why. The number
    of sets not served that no served set (same strategy and window) replaces: the flight
    extracts their candidates."""
    unserved = 0
    for s in found.sets:
        what = _named(s)
        if s["engine_installed"] is None:
            ctx.err(
                f"c3-matcher: {path}: {what}: whether the installed engines serve it cannot be "
                f"told: {str(s['engine_unknown']).rstrip('.')}."
            )
            continue
        if s["served"]:
            continue
        built = f"c3-matcher: {path}: {what} was built " + (
            "with the installed extractor engine but other settings than a flight has here (its "
            "provider, photometric normalisation or input rule, upscale included: the set's "
            f"key {brief_set_id(s['set_id'])}, a flight asks for "
            f"{brief_set_id(s['asked_set_id'])}), so the flight is never served it."
            if s["engine_installed"]
            else f"with another extractor engine (sha256 {str(s['extractor_sha256'])[:12]}...) "
            f"than the installed one ({str(s['installed_extractor_sha256'])[:12]}...), so the "
            "flight is never served it."
        )
        other = _replacing(found, s)
        if other is None:
            unserved += 1
            built += f" The flight extracts those candidates instead; build its set: {_said(s)}."
        else:
            built += f" Set {brief_set_id(other['set_id'])}, which it is served, replaces it."
        ctx.err(
            f"{built} No command removes a single set: its windows keep their space until "
            f"{path.name} is deleted, which removes every set in it."
        )
    return unserved
