"""Where a run's candidates' tile features came from (the store's map features, the tile
cache, or their pixels), as its flight-data log says, and the line that says a run whose
store has map features was served none of them, with the build of the set it asks for."""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr.check import read_fdr_log
from c3_matcher.tilestore.features import sidecar_path
from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.run.matcher import FDR_LOG
from c3_matcher_tools.run.records import FlightRun

if TYPE_CHECKING:
    from c3_matcher_tools.features.command import GivenSettings

__all__ = [
    "FDR_LOG",
    "FEATURE_SOURCES",
    "FeatureSources",
    "features_line",
    "read_feature_sources",
    "unserved_line",
]

FEATURE_SOURCES = ("stored", "cached", "extracted")
"""Where a candidate's tile features come from: the store's map features, the tile cache, or
its pixels (``candidate_features`` of the FDR's terminal records)."""
_TERMINAL = ("matcher.frame_done", "matcher.insufficient_inliers")
_UNSERVED = "c3.matcher.stored_features_unserved"  # the WARNING of a store serving no set


@dataclass(frozen=True)
class FeatureSources:
    """What a run's flight-data log says of its candidates' tile features, read from it once
    (for a long flight the log is the largest file a run leaves): ``counts``, how many had
    their features from each of :data:`FEATURE_SOURCES` (and ``none``, when one was dropped
    before it had any); ``unserved``, the set id the run asked for and those its store's sidecar
    held, as the first warning that it was served no stored set says them (None: no warning)."""

    counts: dict[str, int]
    unserved: tuple[str, tuple[str, ...]] | None = None


def read_feature_sources(fdr_log: Path) -> FeatureSources:
    """:class:`FeatureSources` of the run whose flight-data log is ``fdr_log``, from the terminal
    record of each frame and its warnings, in one pass over the log; zeros (and no warning)
    where there is no log."""
    counts = dict.fromkeys(FEATURE_SOURCES, 0)
    unserved: tuple[str, tuple[str, ...]] | None = None
    with contextlib.suppress(InvalidInputError, OSError):  # no log: nothing read
        for record in read_fdr_log(fdr_log):
            if not isinstance(payload := record.get("payload"), Mapping):
                continue
            if record.get("kind") in _TERMINAL:
                for source in map(str, payload.get("candidate_features") or ()):
                    counts[source] = counts.get(source, 0) + 1
            elif unserved is None and payload.get("kind") == _UNSERVED:
                held = tuple(map(str, payload.get("held_set_ids") or ()))
                unserved = str(payload.get("asked_set_id")), held
    return FeatureSources(counts, unserved)


def features_line(counts: Mapping[str, int]) -> str:
    """The candidates counted by where their features came from, in words."""
    shown = [*FEATURE_SOURCES, *(k for k in counts if k not in FEATURE_SOURCES)]
    return "candidate features: " + ", ".join(f"{counts.get(k, 0)} {k}" for k in shown)


def unserved_line(
    dataset: FlightDataset,
    run: FlightRun,
    sources: FeatureSources,
    settings: GivenSettings,
) -> str | None:
    """The line that says a run whose store has map features (a sidecar) was served none of
    them (``sources``: :func:`read_feature_sources` of its flight-data log, which counts them
    and says the set it asked for and those held), with the command that builds the set it asks for
    under ``settings`` (the run's ``--config`` and environment); None when it was served some,
    has none to be served, runs with ``[matcher] stored_features`` off, or flies a strategy
    whose tiles are always extracted (its backend names no extractor engine)."""
    from c3_matcher_tools.features.command import build_command
    from c3_matcher_tools.features.windows import brief_set_id, flight_grid

    sidecar = sidecar_path(dataset.store_path)
    engines = run.backend.get("engines") or {}
    extractor = (engines.get("extractor") or {}) if isinstance(engines, Mapping) else {}
    counts = sources.counts
    if (
        counts.get("stored", 0)
        or not sum(counts.values())
        or not run.settings.get("stored_features")
        or not extractor.get("file_sha256")
        or not sidecar.is_file()
    ):
        return None
    window, grid = flight_grid(dataset.root)
    command = build_command(dataset.root, run.strategy, window, grid, None, settings)
    why = f"it holds no set for {run.strategy} as it ran here, or none of these windows"
    if (sets := sources.unserved) is not None:
        held = ", ".join(map(brief_set_id, sets[1])) or "none"
        why = f"it holds no set {brief_set_id(sets[0])}, the one this run asks for; it holds {held}"
    return (
        f"c3-matcher: {sidecar}: no candidate of this run was served the store's map features "
        f"({why}): each was extracted (or taken from the tile cache), so the run's times are "
        f"extraction's. `c3-matcher {settings.option()}features info {dataset.root}` names the "
        f"sets it holds; build the one this run asks for: {command}."
    )
