"""Every engine a strategy declares is verified at start-up, whichever it runs: the extractor,
the full LightGlue graph (which adaptive mode, the CPU default, does not load) and the steps
graph (which full mode does not load). A file changed after its build stops ``compose_root``
with ``EngineIntegrityError`` naming it; a missing file is named, not a glob pattern.

Real engines of the disk_lightglue strategy, linked into a temporary directory (the tampered
one is a private copy: the shared engine directory is never written)."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.engines.manifest import EngineIntegrityError
from c3_matcher.engines.naming import MANIFEST_SUFFIX, manifest_path_for
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import EngineError

from .copies import DISK, FULL, STEPS, start_up, strategy_engines


def _tamper(path: Path) -> None:
    """Change one byte in the middle of a private copy (same size: only the sha256 differs)."""
    data = bytearray(path.read_bytes())
    path.unlink()  # never write through the link to the shared file
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(
    ("mode", "kind"),
    [
        ("adaptive", DISK),
        ("adaptive", FULL),  # not loaded in adaptive mode: verified all the same
        ("adaptive", STEPS),  # used to fall back to the full graph with a warning
        ("full", FULL),
        ("full", STEPS),  # not loaded in full mode: verified all the same
    ],
    ids=lambda v: "-".join(v) if isinstance(v, tuple) else v,
)
def test_a_tampered_engine_of_any_kind_stops_start_up(engine_dir, tmp_path, mode, kind):
    engines = strategy_engines(engine_dir, tmp_path / "engines")
    _tamper(engines[kind])
    with pytest.raises(EngineIntegrityError) as info:
        start_up(tmp_path / "engines", mode)
    assert info.value.path == engines[kind].resolve() or info.value.path == engines[kind]
    assert "sha256" in info.value.reason


def test_untampered_engines_start_in_both_modes(engine_dir, tmp_path):
    strategy_engines(engine_dir, tmp_path / "engines")
    for mode in ("adaptive", "full"):
        start_up(tmp_path / "engines", mode)


def test_a_missing_engine_is_named_when_its_manifest_is_there(engine_dir, tmp_path):
    engines = strategy_engines(engine_dir, tmp_path / "engines")
    engines[FULL].unlink()
    with pytest.raises(EngineError) as info:
        start_up(tmp_path / "engines", "adaptive")
    assert info.value.path == engines[FULL]
    assert f"{engines[FULL].name}: file not found" in str(info.value)
    assert "*" not in str(info.value.path)


def test_store_names_the_file_a_manifest_describes(tiny_engine: Path):
    tiny_engine.unlink()
    assert manifest_path_for(tiny_engine).name.endswith(MANIFEST_SUFFIX)
    with pytest.raises(EngineError) as info:
        EngineStore(tiny_engine.parent).require("toy", "tiny")
    assert info.value.path == tiny_engine
