"""After the extractor engines are built again (an upgrade refuses the old ones), the sets stored
for the old engine are keyed by its file's sha256, which the flight no longer asks for: they are
never served. ``features info`` (plain and ``--verify``, text and JSON) says of each set whether
the installed engine built it; of one it did not, that it is not served, the command that builds
the set for the installed engine, and that no command removes a single set. ``--verify`` exits 1
while a strategy has sets but none of the installed engine (its candidates are extracted in
flight: what the check is for), 0 once the installed engine's set replaces it.

The engine changes as a rebuild changes it: a copy of the engine folder whose XFeat extractor
file differs (the same graph saved again, its manifest naming the new file's sha256 and size),
which the engine store accepts and the flight loads."""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import onnx
import pytest

from c3_matcher.engines.manifest import read_manifest
from c3_matcher.engines.naming import manifest_path_for
from c3_matcher.engines.spec import file_sha256
from c3_matcher_tools.features.windows import brief_set_id


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    from c3_matcher.cli import main

    capsys.readouterr()
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err.strip()


def _rebuilt(engines: Path, to: Path) -> str:
    """A copy of ``engines`` at ``to`` whose XFeat extractor is another file (saved again with
    another doc string, its manifest updated as a build writes it); its sha256."""
    shutil.copytree(engines, to)
    (path,) = to.glob("xfeat_default_*.onnx")
    model = onnx.load(str(path))
    model.doc_string = "built again"
    onnx.save(model, str(path))
    manifest = read_manifest(path)
    sha = file_sha256(path)
    assert sha != manifest.file_sha256
    dataclasses.replace(manifest, file_sha256=sha, file_bytes=path.stat().st_size).write(
        manifest_path_for(path)
    )
    return sha


@pytest.mark.slow
def test_sets_of_another_extractor_engine_are_named_as_never_served(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    flight = small_flight("engine-changed")
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    build = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
    assert _run(capsys, *build, "--flight-candidates")[0] == 0
    code, out, err = _run(capsys, "features", "info", str(flight), "--verify", "--json")
    (built,) = json.loads(out)["sets"]
    assert (code, built["engine_installed"], err) == (0, True, "")
    assert built["command"] is None  # served whole: nothing to build
    assert built["installed_extractor_sha256"] == built["extractor_sha256"]

    sha = _rebuilt(engine_dir, tmp_path / "engines")
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(tmp_path / "engines"))
    code, out, err = _run(capsys, "features", "info", str(flight), "--verify", "--json")
    (old,) = json.loads(out)["sets"]
    assert code == 1, err
    assert (old["set_id"], old["engine_installed"]) == (built["set_id"], False)
    assert old["installed_extractor_sha256"] == sha
    assert old["intact"] == old["windows"] > 0 and old["stale"] == old["damaged"] == 0
    rebuild = (
        f"c3-matcher features build {flight} --strategy xfeat --window {old['window_px']} "
        f"--stride {old['stride_px']}"
    )
    assert len(err.splitlines()) == 1, err
    assert f"set {brief_set_id(old['set_id'])} (xfeat, {old['window_px']} px windows)" in err
    assert "was built with another extractor engine" in err
    assert f"than the installed one ({sha[:12]}...), so the flight is never served it." in err
    assert rebuild in err and "No command removes a single set" in err
    assert old["command"].startswith(rebuild) and f"build its set: {old['command']}" in err
    assert "(" not in old["command"]  # a line a script runs as it is; what to know: its note
    code, out, text_err = _run(capsys, "features", "info", str(flight))  # plain: said, exit 0
    assert (code, text_err) == (0, err), text_err
    assert "engine_installed: no" in out and f"installed_extractor_sha256: {sha}" in out

    monkeypatch.setenv("C3_MATCHER_MATCHER__PHOTOMETRIC", "clahe")  # another set id but engine
    assert _run(capsys, *build, "--flight-candidates")[0] == 0
    monkeypatch.delenv("C3_MATCHER_MATCHER__PHOTOMETRIC")
    code, out, err = _run(capsys, "features", "info", str(flight), "--verify", "--json")
    assert code == 1 and rebuild in err and "replaces it" not in err, err  # clahe serves no "none"

    assert _run(capsys, *build, "--flight-candidates")[0] == 0  # for the installed engine
    code, out, err = _run(capsys, "features", "info", str(flight), "--verify", "--json")
    sets = {s["set_id"]: s for s in json.loads(out)["sets"] if ":clahe:" not in s["set_id"]}
    assert code == 0, err
    replaced = sets.pop(old["set_id"])
    assert replaced["engine_installed"] is False and replaced["command"] is None  # replaced
    ((new_id, new),) = sets.items()
    assert new["engine_installed"] is True and new["extractor_sha256"] == sha
    assert f"Set {brief_set_id(new_id)}, which it is served, replaces it." in err, err
    assert rebuild not in err
