"""An engine changed after its build (cut short, edited) stops start-up with
``EngineIntegrityError`` naming it: the store never skips it for another build of the same
graph. Other problems of a build (a failed verification) still leave the choice to the valid
builds beside it.

Tiny engines for the store itself; the real engines of disk_lightglue, linked into a temporary
directory (the changed one is a private copy: the shared engine directory is never written),
for start-up."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.engines.manifest import EngineIntegrityError
from c3_matcher.engines.store import EngineStore
from c3_matcher.fdr import InMemoryFdr

from .copies import DISK, exporter_of, other_build, strategy_engines

OLDER = "2026-01-01T00:00:00+00:00"
NEWER = "2026-06-01T00:00:00+00:00"
OLD_LIBRARIES = {"torch": "0.0-older"}


def _cut_short(path: Path) -> None:
    """Keep the first half of a private copy (an interrupted copy to the flight computer)."""
    data = path.read_bytes()
    path.unlink()  # never write through a link to a shared file
    path.write_bytes(data[: len(data) // 2])


def test_a_cut_short_newest_build_is_refused_not_replaced_by_an_older_one(
    make_tiny_engine: Callable[..., Path], tmp_path: Path
) -> None:
    directory = tmp_path / "engines"
    older = make_tiny_engine(directory, versions=OLD_LIBRARIES, built_at=OLDER)
    newest = make_tiny_engine(directory, built_at=NEWER)
    assert older.name != newest.name  # two builds of one graph (other library versions)
    store = EngineStore(directory)
    assert store.require("toy", "tiny") == newest
    _cut_short(newest)
    with pytest.raises(EngineIntegrityError) as info:
        store.require("toy", "tiny")
    assert info.value.path == newest and "size" in info.value.reason
    older.unlink()  # alone, it is refused the same way (not "no valid engine")
    with pytest.raises(EngineIntegrityError):
        store.require("toy", "tiny")


def test_an_unusable_build_is_still_passed_over_for_a_valid_one(
    make_tiny_engine: Callable[..., Path], tmp_path: Path
) -> None:
    directory = tmp_path / "engines"
    older = make_tiny_engine(directory, versions=OLD_LIBRARIES, built_at=OLDER)
    make_tiny_engine(directory, built_at=NEWER, passed=False)
    assert EngineStore(directory).require("toy", "tiny") == older


def _older_build_beside(engine: Path) -> Path:
    """A copy of ``engine`` as an older build of its graph: made with other library versions
    (another build key, so another file name), its manifest consistent with them."""
    return other_build(engine, exporter={**exporter_of(engine), **OLD_LIBRARIES}, built_at=OLDER)


def test_start_up_stops_on_a_cut_short_extractor_with_an_older_build_beside_it(
    engine_dir: Path, tmp_path: Path
) -> None:
    """The disk_lightglue engines, plus an older build of the same DISK graph (another build
    key, e.g. an older exporter toolchain): the newest cut short must stop start-up, not run
    the older one."""
    into = tmp_path / "engines"
    newest = strategy_engines(engine_dir, into)[DISK]
    _older_build_beside(newest)
    assert EngineStore(into).require("disk", "depth") == newest  # the newest build is served
    _cut_short(newest)
    settings = C3Settings(
        matcher={"strategy": "disk_lightglue"},
        engines={"directory": into, "providers": ["CPUExecutionProvider"]},
    )
    helpers = {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()}
    with pytest.raises(EngineIntegrityError) as info:
        compose_root(settings, helpers, configure_logs=False).close()
    assert info.value.path == newest
