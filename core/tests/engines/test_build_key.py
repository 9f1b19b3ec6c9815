"""The build key is recomputed from a manifest's own fields wherever an engine is checked: a
manifest edited after its build (other weights, another version, another option) is refused as
an integrity error naming the file, by the store, ``engines verify`` and at load. It was served
and verified OK: only the key's prefix in the file name was compared with the key the manifest
recorded, never with the fields it is made from."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from c3_matcher.engines.build_key import build_key
from c3_matcher.engines.manifest import (
    EngineIntegrityError,
    check_engine_file,
    manifest_path_for,
    read_manifest,
)
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.spec import TensorSpec
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import EngineError


def _set(path: tuple[str, ...], value: Any) -> Callable[[dict[str, Any]], None]:
    def edit(data: dict[str, Any]) -> None:
        for key in path[:-1]:
            data = data[key]
        data[path[-1]] = value

    return edit


EDITS: dict[str, Callable[[dict[str, Any]], None]] = {
    "weights sha256": _set(("weights", "sha256"), "0" * 64),
    "weights version": _set(("weights", "version"), "9.9.9"),
    "export revision": _set(("exporter", "export_revision"), "99"),
    "exporter": _set(("exporter", "callable"), "elsewhere:export"),
    "a library version": _set(("exporter", "torch"), "0.0.1"),
    "an option": _set(("options", "top_k"), 4096),
    "size multiple": _set(("size_multiple",), 8),
    "an output": lambda d: d["outputs"][0].update(dtype="float16"),
}


@pytest.fixture()
def engine_copy(disk_engine: Path, tmp_path: Path) -> Path:
    """A copy of the real DISK engine and its manifest, in a directory of its own."""
    directory = tmp_path / "engines"
    directory.mkdir()
    shutil.copy2(disk_engine, directory / disk_engine.name)
    shutil.copy2(manifest_path_for(disk_engine), manifest_path_for(directory / disk_engine.name))
    return directory / disk_engine.name


def test_a_real_manifest_recomputes_to_its_own_key(engine_copy: Path) -> None:
    manifest = check_engine_file(engine_copy)
    assert manifest.recomputed_key() == manifest.build_key
    assert engine_copy.stem.endswith(manifest.build_key[:10])


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_a_manifest_edited_after_its_build_is_refused_naming_it(
    engine_copy: Path, edit: str
) -> None:
    manifest_file = manifest_path_for(engine_copy)
    data = json.loads(manifest_file.read_text())
    EDITS[edit](data)
    manifest_file.write_text(json.dumps(data, indent=2))
    with pytest.raises(EngineIntegrityError) as info:
        check_engine_file(engine_copy, check_hash=False)
    assert info.value.path == engine_copy
    assert f"its manifest {manifest_file.name} does not match its build key" in info.value.reason
    store = EngineStore(engine_copy.parent)
    (outcome,) = store.verify()
    assert not outcome.ok and "does not match its build key" in outcome.detail
    (record,) = store.list()
    assert not record.ok
    with pytest.raises(EngineError, match="does not match its build key") as refused:
        store.require("disk", "depth")
    text = str(refused.value)
    assert engine_copy.name in text and "c3-matcher engines build" in text
    with pytest.raises(EngineIntegrityError, match="does not match its build key"):
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(engine_copy)


def test_a_manifest_without_a_field_of_its_key_is_refused(engine_copy: Path) -> None:
    manifest_file = manifest_path_for(engine_copy)
    data = json.loads(manifest_file.read_text())
    del data["exporter"]["export_revision"]
    manifest_file.write_text(json.dumps(data))
    with pytest.raises(EngineError, match="lacks a field of its build key"):
        check_engine_file(engine_copy, check_hash=False)


_GRAPH = dict(
    model="toy",
    variant="tiny",
    kind="extractor",
    precision="fp32",
    input_rule="hw16-k8",
    opset=18,
    inputs=(TensorSpec("image", "float32", (1, 3, "height", "width")),),
    outputs=(TensorSpec("keypoints", "float32", (8, 2)),),
    feature_type=None,
    size_multiple=16,
)
_EXPORTER = {"callable": "toy.export:export", "export_revision": "1", "method": "y"}
_EXPORTER |= {"python": "3.11.0", "torch": "2.0.0"}


def _key(
    graph: dict[str, Any] | None = None,
    options: dict[str, Any] | None = None,
    exporter: dict[str, str] | None = None,
    weights: dict[str, str] | None = None,
) -> str:
    return build_key(
        SimpleNamespace(**{**_GRAPH, **(graph or {})}),
        {"top_k": 8, "descriptor_dim": 4, **(options or {})},
        {**_EXPORTER, **(exporter or {})},
        {"sha256": "ab" * 32, "version": "1.2.3", **(weights or {})},
    )


def test_the_key_of_one_build_stays_the_same() -> None:
    """A change of the key's payload makes every engine stale: it must be deliberate."""
    assert _key() == "6e16291593584bd7117129fcb00e62a79234c08399668e186039754bbef335cf"


@pytest.mark.parametrize(
    "change",
    [
        {"weights": {"version": "1.2.4"}},
        {"weights": {"sha256": "cd" * 32}},
        {"graph": {"kind": "matcher"}},
        {"graph": {"feature_type": "toy"}},
        {"graph": {"size_multiple": 32}},
        {"options": {"top_k": 16}},
        {"exporter": {"export_revision": "2"}},
        {"exporter": {"callable": "toy.export:other"}},
        {"exporter": {"torch": "2.0.1"}},
        {"graph": {"outputs": (TensorSpec("keypoints", "float32", (16, 2)),)}},
    ],
    ids=str,
)
def test_each_build_input_enters_the_key(change: dict[str, Any]) -> None:
    assert _key(**change) != _key()


def test_python_and_the_exporter_record_are_not_library_versions() -> None:
    """A manifest records the library versions beside the exporter's callable, method and
    revision (and Python's version, which the key leaves out)."""
    assert _key(exporter={"python": "3.13.1", "method": "another"}) == _key()


def test_the_real_engines_keys_recompute(built_engines: dict[tuple[str, str], Path]) -> None:
    for path in built_engines.values():
        manifest = read_manifest(path)
        assert manifest.recomputed_key() == manifest.build_key, path.name
