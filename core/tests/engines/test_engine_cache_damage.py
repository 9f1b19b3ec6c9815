"""A damaged engine set as a user meets it: a steps engine whose manifest is cut short, of
another schema or unreadable (or whose file cannot be read) stops start-up with
``EngineIntegrityError`` naming it and why, in both LightGlue modes (it used to be passed over:
the full graph ran, with a warning that no steps engine was there); a steps engine of another
graph, or none, still warns and runs the full graph. A damaged older build beside a valid one
stops start-up too, naming the build command that removes it. ``engines verify`` gives an engine
it cannot read a FAIL row and goes on, and ``--json`` prints its document for an empty or
missing directory.

Real engines of disk_lightglue (or all the built ones), linked into a temporary directory; a
damaged file is a private copy (the shared engine directory is never written). A file without
read permission is made without root's help: opening it raises EACCES, what a user without
read permission gets."""

from __future__ import annotations

import errno
import json
import pathlib
from pathlib import Path
from typing import Any

import pytest
from loguru import logger

from c3_matcher.cli import main
from c3_matcher.compose import build_plugin_host
from c3_matcher.engines.manifest import EngineIntegrityError
from c3_matcher.engines.naming import manifest_path_for
from c3_matcher.engines.store import EngineStore

from .copies import DISK, STEPS, exporter_of, link_or_copy, other_build, start_up, strategy_engines

MODES = ("adaptive", "full")


def _rewrite(path: Path, text: str) -> None:
    """Give ``path`` new contents as a private copy (never written through a link)."""
    path.unlink()
    path.write_text(text)


def _refuse_reading(monkeypatch: pytest.MonkeyPatch, target: Path) -> None:
    """Opening ``target`` raises EACCES from now on, as for a user without read permission."""
    real_open = pathlib.Path.open

    def path_open(self: Path, *args: Any, **kwargs: Any) -> Any:
        if self.resolve() == target.resolve():
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real_open(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "open", path_open)


def _cut_short(manifest: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    _rewrite(manifest, manifest.read_text()[:500])
    return "is unreadable ("


def _other_schema(manifest: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    _rewrite(manifest, json.dumps({**json.loads(manifest.read_text()), "schema": 2}))
    return "manifest schema 2 != 1"


def _unreadable(manifest: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    _refuse_reading(monkeypatch, manifest)
    return "Permission denied"


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize(
    "damage", [_cut_short, _other_schema, _unreadable], ids=lambda f: f.__name__
)
def test_a_damaged_steps_manifest_stops_start_up_naming_it(
    engine_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage: Any, mode: str
) -> None:
    engines = strategy_engines(engine_dir, tmp_path / "engines")
    manifest = manifest_path_for(engines[STEPS])
    why = damage(manifest, monkeypatch)
    with pytest.raises(EngineIntegrityError) as info:
        start_up(tmp_path / "engines", mode)
    assert info.value.path == engines[STEPS]
    assert manifest.name in info.value.reason and why in info.value.reason, info.value.reason
    assert "c3-matcher engines build --only lightglue/disk-steps" in str(info.value)


@pytest.mark.parametrize("mode", MODES)
def test_a_steps_engine_that_cannot_be_read_stops_start_up_naming_it(
    engine_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, mode: str
) -> None:
    engines = strategy_engines(engine_dir, tmp_path / "engines")
    _refuse_reading(monkeypatch, engines[STEPS])
    with pytest.raises(EngineIntegrityError) as info:
        start_up(tmp_path / "engines", mode)
    assert info.value.path == engines[STEPS]
    assert info.value.reason == "cannot open (permission denied)"


def _warnings_of(engines: Path) -> list[str]:
    """The ``kind`` of each WARNING an adaptive start-up over ``engines`` logs."""
    seen: list[str] = []
    sink = logger.add(lambda m: seen.append(str(m.record["extra"].get("kind"))), level="WARNING")
    try:
        start_up(engines, "adaptive")
    finally:
        logger.remove(sink)
    return seen


def _remove(engine: Path) -> None:
    engine.unlink()
    manifest_path_for(engine).unlink()


def test_a_steps_engine_of_another_graph_or_none_still_warns_and_runs_the_full_graph(
    engine_dir: Path, tmp_path: Path
) -> None:
    """The documented cases (docs/decisions.md): not refused, a warning naming the build."""
    engines = strategy_engines(engine_dir, tmp_path / "other")
    steps = engines[STEPS]
    other_build(steps, exporter={**exporter_of(steps), "export_revision": "1"})  # older exporter
    _remove(steps)
    assert "c3.lightglue.no_steps_engine" in _warnings_of(tmp_path / "other")
    engines = strategy_engines(engine_dir, tmp_path / "none")
    _remove(engines[STEPS])
    assert "c3.lightglue.no_steps_engine" in _warnings_of(tmp_path / "none")


def test_a_damaged_older_build_stops_start_up_naming_the_command_that_removes_it(
    engine_dir: Path, tmp_path: Path
) -> None:
    """Any build of a model/variant changed after it was made is refused, whatever its age (a
    manifest's ``built_at`` is no part of its build key): the error names the build of that
    model/variant, which removes it (plugins/tools' test_engine_build_repair.py)."""
    engines = strategy_engines(engine_dir, tmp_path / "engines")
    disk = engines[DISK]
    older = other_build(
        disk,
        exporter={**exporter_of(disk), "numpy": "0.0-older"},
        built_at="2020-01-01T00:00:00+00:00",
    )
    data = older.read_bytes()
    older.unlink()  # never written through the link
    older.write_bytes(data[:1000])  # an interrupted copy of an earlier install
    with pytest.raises(EngineIntegrityError) as info:
        EngineStore(tmp_path / "engines").require(*DISK)
    assert info.value.path == older and "size 1000 B" in info.value.reason
    assert str(info.value).endswith("build it with `c3-matcher engines build --only disk/depth`")


# -- engines verify ---------------------------------------------------------------------------
def _all_engines(engine_dir: Path, into: Path) -> list[Path]:
    """Every built engine (file + manifest) linked into ``into``; the engine files."""
    into.mkdir()
    for path in sorted(engine_dir.iterdir()):
        if path.is_file() and not path.name.startswith("."):
            link_or_copy(path, into / path.name)
    return sorted(into.glob("*.onnx"))


def test_verify_fails_an_engine_it_cannot_read_and_goes_on(
    engine_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    files = _all_engines(engine_dir, tmp_path / "engines")
    victim = next(p for p in files if p.name.startswith("disk_depth_"))
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(tmp_path / "engines"))
    _refuse_reading(monkeypatch, victim)
    assert main(["engines", "verify"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert f"FAIL {victim.name}: cannot open (permission denied)" in out
    assert sum(line.startswith("OK ") for line in out) == len(files) - 1, out
    assert main(["engines", "verify", "--json"]) == 1
    rows = json.loads(capsys.readouterr().out)["engines"]
    assert [r["path"] for r in rows if not r["ok"]] == [str(victim)]


@pytest.mark.parametrize("there", [True, False], ids=["empty", "missing"])
def test_verify_json_of_a_directory_without_engines_lists_every_one_missing(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    there: bool,
) -> None:
    directory = tmp_path / "engines"
    if there:
        directory.mkdir()
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(directory))
    assert main(["engines", "verify", "--json"]) == 1
    captured = capsys.readouterr()
    document = json.loads(captured.out)
    assert document["directory"] == str(directory)
    declared = {spec.key for spec in build_plugin_host().engine_specs()}
    rows = document["engines"]
    assert len(rows) == len(declared) and declared
    assert all(set(r) == {"path", "ok", "detail", "command"} and r["ok"] is False for r in rows)
    assert all(r["detail"].startswith("missing: no valid ") for r in rows)
    assert all(r["command"].startswith("c3-matcher engines build --only ") for r in rows)
    assert {r["detail"].split()[3] for r in rows} == declared
    assert captured.err.startswith(f"c3-matcher: no engines in {directory}")
