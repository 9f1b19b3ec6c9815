"""Engine directories the engine tests damage: real engines linked (else copied) into a
temporary directory, never the shared engine directory itself, and another build of an engine
made beside it, its manifest consistent with the changes (build key recomputed, file named by
it)."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.engines.manifest import EngineManifest
from c3_matcher.engines.naming import EngineName, manifest_path_for
from c3_matcher.engines.store import EngineStore
from c3_matcher.fdr import InMemoryFdr

DISK = ("disk", "depth")
FULL = ("lightglue", "disk")
STEPS = ("lightglue", "disk-steps")
STRATEGY_ENGINES = (DISK, FULL, STEPS)
"""The default strategy's engines: its extractor, single-graph LightGlue and steps LightGlue."""


def link_or_copy(source: Path, target: Path) -> None:
    """``target`` a hard link to ``source`` (else a copy: another file system)."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def strategy_engines(
    engine_dir: Path, into: Path, keys: Iterable[tuple[str, str]] = STRATEGY_ENGINES
) -> dict[tuple[str, str], Path]:
    """The engines of ``keys`` (file + manifest) served from ``engine_dir``, linked into
    ``into`` (made here); each key's engine file there."""
    into.mkdir()
    store = EngineStore(engine_dir)
    found = {}
    for key in keys:
        source = store.require(*key)
        for path in (source, manifest_path_for(source)):
            link_or_copy(path, into / path.name)
        found[key] = into / source.name
    return found


def other_build(
    engine: Path, *, into: Path | None = None, build_key: str | None = None, **changes: Any
) -> Path:
    """Another build of ``engine``, in ``into`` (default: beside it): its manifest with
    ``changes``, consistent with them (build key recomputed, file named by it) unless
    ``build_key`` records another (an earlier c3-matcher's, whose key covered less), its file a
    link to (else a copy of) it."""
    manifest = EngineManifest.from_json(json.loads(manifest_path_for(engine).read_text()))
    manifest = dataclasses.replace(manifest, **changes)
    key = build_key or manifest.recomputed_key()
    name = EngineName.parse(engine.name)
    other = EngineName.from_build_key(
        name.model, name.variant, name.precision, name.input_rule, name.opset, key
    )
    there = (into or engine.parent) / other.filename
    link_or_copy(engine, there)
    dataclasses.replace(manifest, file=other.filename, build_key=key).write(
        there.with_name(other.manifest_filename)
    )
    return there


def exporter_of(engine: Path) -> dict[str, Any]:
    """The ``exporter`` block of ``engine``'s manifest (the versions its build key covers)."""
    manifest = EngineManifest.from_json(json.loads(manifest_path_for(engine).read_text()))
    return dict(manifest.exporter)


def start_up(engines: Path, mode: str) -> dict[str, Any]:
    """Compose (and close) the default strategy on the engines in ``engines`` with LightGlue in
    ``mode`` (``adaptive`` or ``full``), as start-up does; the helpers it was given."""
    settings = C3Settings(
        matcher={"strategy": "disk_lightglue"},
        engines={"directory": engines, "providers": ["CPUExecutionProvider"]},
        lightglue={"mode": mode},
    )
    helpers = {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()}
    compose_root(settings, helpers, configure_logs=False).close()
    return helpers
