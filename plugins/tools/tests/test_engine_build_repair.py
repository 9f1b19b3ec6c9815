"""``c3-matcher engines build`` repairs what start-up refuses: a damaged build of a model/variant
beside the valid one it reuses (an older build's file cut short, a steps engine's manifest cut
short) is removed, saying so, and start-up then works; it used to say "valid engine ...
reused", exit 0, and leave the damaged file, so that start-up kept failing. A valid build of
another install beside it is left alone, and one it cannot remove is named (exit 1).

Real engines of disk_lightglue linked into a temporary directory (a damaged file is a private
copy: the shared engine directory is never written); the other builds are the same engines
with manifests of other library versions, as another install's build would be. Nothing is
exported: every engine the build is asked for is already there."""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shutil
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.cli import main
from c3_matcher.engines.manifest import EngineIntegrityError, EngineManifest
from c3_matcher.engines.naming import EngineName, manifest_path_for
from c3_matcher.engines.store import EngineStore

KEYS = (("disk", "depth"), ("lightglue", "disk"), ("lightglue", "disk-steps"))
OLDER = "2020-01-01T00:00:00+00:00"


def _link_or_copy(source: Path, target: Path) -> None:
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


@pytest.fixture()
def engines(engine_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The disk_lightglue engines linked into a directory the command line is pointed at."""
    into = tmp_path / "engines"
    into.mkdir()
    store = EngineStore(engine_dir)
    for key in KEYS:
        source = store.require(*key)
        for path in (source, manifest_path_for(source)):
            _link_or_copy(path, into / path.name)
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(into))
    return into


def _older_build(directory: Path, model: str, variant: str) -> Path:
    """Another, older build of ``model``/``variant`` beside the valid one: the same engine with
    a manifest of other library versions (its build key recomputed, its file named by it)."""
    engine = EngineStore(directory).require(model, variant)
    manifest = EngineManifest.from_json(json.loads(manifest_path_for(engine).read_text()))
    manifest = dataclasses.replace(
        manifest, exporter={**manifest.exporter, "numpy": "0.0-older"}, built_at=OLDER
    )
    key = manifest.recomputed_key()
    name = EngineName.parse(engine.name)
    other = EngineName.from_build_key(
        name.model, name.variant, name.precision, name.input_rule, name.opset, key
    )
    _link_or_copy(engine, directory / other.filename)
    dataclasses.replace(manifest, file=other.filename, build_key=key).write(
        directory / other.manifest_filename
    )
    return directory / other.filename


def _cut_short(path: Path, keep: int) -> None:
    """Keep the first ``keep`` bytes of a private copy (never written through a link)."""
    data = path.read_bytes()
    path.unlink()
    path.write_bytes(data[:keep])


def _build(only: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    status = main(["engines", "build", "--only", only])
    out, err = capsys.readouterr()
    return status, out, err


def test_build_removes_a_damaged_older_build_that_stops_start_up(
    engines: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    damaged = _older_build(engines, "disk", "depth")
    _cut_short(damaged, 1000)
    with pytest.raises(EngineIntegrityError) as refused:  # start-up, as `match` meets it
        EngineStore(engines).require("disk", "depth")
    assert refused.value.path == damaged
    status, out, err = _build("disk/depth", capsys)
    assert status == 0 and "0 built, 1 reused" in out
    assert f"removed damaged engine {damaged.name} (size 1000 B != manifest " in err, err
    assert not damaged.exists() and not manifest_path_for(damaged).exists()
    assert EngineStore(engines).require("disk", "depth").name != damaged.name


def test_build_removes_a_steps_engine_whose_manifest_is_cut_short(
    engines: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    damaged = _older_build(engines, "lightglue", "disk-steps")
    manifest = manifest_path_for(damaged)
    manifest.write_text(manifest.read_text()[:500])  # written by this test: no link
    status, out, err = _build("lightglue/disk-steps", capsys)
    assert status == 0 and "0 built, 1 reused" in out
    assert f"removed damaged engine {damaged.name} (its manifest {manifest.name} is " in err
    assert not damaged.exists() and not manifest.exists()


def test_build_leaves_a_valid_build_of_another_install_alone(
    engines: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    other = _older_build(engines, "disk", "depth")
    status, _, err = _build("disk/depth", capsys)
    assert status == 0 and "removed" not in err
    assert other.exists() and manifest_path_for(other).exists()


def test_a_damaged_build_it_cannot_remove_is_named(
    engines: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    damaged = _older_build(engines, "disk", "depth")
    _cut_short(damaged, 1000)
    real_unlink = pathlib.Path.unlink

    def unlink(self: Path, *args: Any, **kwargs: Any) -> None:
        if self == damaged:
            raise PermissionError(13, "Permission denied", str(self))
        real_unlink(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "unlink", unlink)
    status, out, err = _build("disk/depth", capsys)
    assert status == 1 and out == ""
    last = err.splitlines()[-1]
    assert last.startswith(f"c3-matcher: engine {damaged}: size 1000 B != manifest "), err
    assert "start-up refuses it, and it cannot be removed (PermissionError:" in last
