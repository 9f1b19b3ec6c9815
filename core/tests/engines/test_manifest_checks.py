"""Start-up checks of an engine against its manifest (tiny synthetic engines, no PyTorch)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.engines.naming import manifest_path_for
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.spec import EngineSpec, TensorSpec, WeightsRef
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import EngineError

BUILD = "c3-matcher engines build"


def _assert_names_file_and_command(exc: EngineError, path: Path) -> None:
    text = str(exc)
    assert path.name in text
    assert BUILD in text


def test_valid_engine_loads_and_runs(tiny_engine: Path) -> None:
    runtime = OnnxInferenceRuntime(["CPUExecutionProvider"])
    engine_id = runtime.load_engine(tiny_engine)
    assert runtime.load_engine(tiny_engine) == engine_id  # idempotent
    x = np.arange(5, dtype=np.float32)[None]
    out = runtime.run(engine_id, {"x": x})
    np.testing.assert_array_equal(out["y"], x)
    assert runtime.manifest(engine_id).weights_sha256 == "cd" * 32


def test_tampered_file_is_a_startup_error(tiny_engine: Path) -> None:
    data = bytearray(tiny_engine.read_bytes())
    data[-1] ^= 0xFF
    tiny_engine.write_bytes(bytes(data))
    with pytest.raises(EngineError, match="sha256") as info:
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(tiny_engine)
    _assert_names_file_and_command(info.value, tiny_engine)


def test_wrong_io_names_are_a_startup_error(
    tmp_path: Path, make_tiny_engine: Callable[..., Path]
) -> None:
    path = make_tiny_engine(tmp_path, inputs=(TensorSpec("image", "float32", (1, "n")),))
    with pytest.raises(EngineError, match="graph inputs") as info:
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(path)
    _assert_names_file_and_command(info.value, path)


def test_wrong_io_dtype_and_shape_are_startup_errors(
    tmp_path: Path, make_tiny_engine: Callable[..., Path]
) -> None:
    bad_dtype = make_tiny_engine(tmp_path / "a", outputs=(TensorSpec("y", "int64", (1, "n")),))
    with pytest.raises(EngineError, match="dtype"):
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(bad_dtype)
    bad_shape = make_tiny_engine(tmp_path / "b", inputs=(TensorSpec("x", "float32", (1, 7)),))
    with pytest.raises(EngineError, match="shape"):
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(bad_shape)


def test_missing_manifest_and_missing_file(tiny_engine: Path) -> None:
    manifest_path_for(tiny_engine).unlink()
    with pytest.raises(EngineError, match="manifest") as info:
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(tiny_engine)
    _assert_names_file_and_command(info.value, tiny_engine)
    missing = tiny_engine.with_name("toy_tiny_fp32_any_op18_0000000000.onnx")
    with pytest.raises(EngineError, match="not found"):
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(missing)


def test_name_off_schema_is_refused(tiny_engine: Path) -> None:
    renamed = tiny_engine.with_name("toy.onnx")
    tiny_engine.rename(renamed)
    with pytest.raises(EngineError, match="schema"):
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(renamed)


def test_manifest_disagreeing_with_name_is_refused(tiny_engine: Path) -> None:
    path = manifest_path_for(tiny_engine)
    data = json.loads(path.read_text())
    data["variant"] = "other"
    path.write_text(json.dumps(data))
    with pytest.raises(EngineError, match="disagrees"):
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(tiny_engine)


def test_failed_verification_is_refused(
    tmp_path: Path, make_tiny_engine: Callable[..., Path]
) -> None:
    path = make_tiny_engine(tmp_path, passed=False)
    with pytest.raises(EngineError, match="failed verification"):
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(path)


def test_store_require_missing_names_pattern_and_command(tmp_path: Path) -> None:
    with pytest.raises(EngineError) as info:
        EngineStore(tmp_path / "nothing").require("disk", "depth")
    text = str(info.value)
    assert "disk_depth_*" in text and BUILD in text and "--only disk/depth" in text


def test_store_require_list_verify(tiny_engine: Path) -> None:
    store = EngineStore(tiny_engine.parent)
    assert store.require("toy", "tiny") == tiny_engine
    with pytest.raises(EngineError, match="installed weights"):
        store.require("toy", "tiny", weights_sha256="ef" * 32)
    records = store.list()
    assert [r.path for r in records] == [tiny_engine] and records[0].ok
    assert all(o.ok for o in store.verify())
    tiny_engine.write_bytes(tiny_engine.read_bytes() + b"\0")
    outcome = store.verify()[0]
    assert not outcome.ok and "size" in outcome.detail


def test_a_truncated_engine_is_not_listed_ok_nor_taken(tiny_engine: Path) -> None:
    """The size is free to check: ``engines list`` showed a cut copy ``[ok]`` and ``require``
    handed it to the runtime, which failed on it at load."""
    store = EngineStore(tiny_engine.parent)
    tiny_engine.write_bytes(tiny_engine.read_bytes()[:-10])
    (record,) = store.list()
    assert not record.ok and "size" in (record.problem or "")
    with pytest.raises(EngineError, match="size"):
        store.require("toy", "tiny")


@pytest.mark.parametrize("sha256", [None, ""])
def test_a_manifest_without_the_weights_hash_is_refused_where_it_is_read(
    tiny_engine: Path, sha256: str | None
) -> None:
    """It used to be listed ok and taken, then fail the load with a bare KeyError('sha256')
    (after the session was built, where the load is logged)."""
    path = manifest_path_for(tiny_engine)
    data = json.loads(path.read_text())
    if sha256 is None:
        del data["weights"]["sha256"]
    else:
        data["weights"]["sha256"] = sha256
    path.write_text(json.dumps(data))
    store = EngineStore(tiny_engine.parent)
    (record,) = store.list()
    assert not record.ok and "weights.sha256 is missing" in (record.problem or "")
    with pytest.raises(EngineError, match="weights.sha256 is missing"):
        store.require("toy", "tiny")
    with pytest.raises(EngineError, match="weights.sha256 is missing") as info:
        OnnxInferenceRuntime(["CPUExecutionProvider"]).load_engine(tiny_engine)
    _assert_names_file_and_command(info.value, tiny_engine)


def test_an_engine_directory_beginning_with_a_tilde_is_under_the_users_home(
    tiny_engine: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("HOME", str(tiny_engine.parent.parent))
    store = EngineStore(Path("~") / tiny_engine.parent.name)
    assert store.directory == tiny_engine.parent
    assert store.require("toy", "tiny") == tiny_engine


def _toy_spec(export_revision: int, **options: int | float | str) -> EngineSpec:
    return EngineSpec(
        model="toy",
        variant="tiny",
        weights=WeightsRef("none", "none"),
        exporter="tests:none",
        kind="extractor",
        inputs=(TensorSpec("x", "float32", (1, "n")),),
        outputs=(TensorSpec("y", "float32", (1, "n")),),
        input_rule="any",
        options=tuple(options.items()),
        export_revision=export_revision,
    )


def test_store_require_spec_runs_only_the_graph_the_install_declares(
    make_tiny_engine: Callable[..., Path], tmp_path: Path
) -> None:
    """A build by an older exporter (or with other options) is named and never run, even when
    it is the newest: the newest build of any graph used to win."""
    engines = tmp_path / "engines"
    old = make_tiny_engine(engines, export_revision=1, options={"top_k": 8})
    store = EngineStore(engines)
    with pytest.raises(EngineError) as info:
        store.require_spec(_toy_spec(2, top_k=8))
    text = str(info.value)
    assert f"{old.name}: built for another graph: export revision 1 (this install: 2)" in text
    assert "--only toy/tiny" in text
    with pytest.raises(
        EngineError, match=r"options \{'top_k': 8\} \(this install: \{'top_k': 16\}\)"
    ):
        store.require_spec(_toy_spec(1, top_k=16))
    assert store.require_spec(_toy_spec(1, top_k=8)) == old
    new = make_tiny_engine(
        engines,
        export_revision=2,
        options={"top_k": 8},
        built_at="2025-01-01T00:00:00+00:00",
    )  # built before the old one
    assert store.require_spec(_toy_spec(2, top_k=8)) == new
    assert store.require_spec(_toy_spec(1, top_k=8)) == old
    assert store.require("toy", "tiny") == old  # without a spec: the newest build


def test_run_errors(tiny_engine: Path) -> None:
    runtime = OnnxInferenceRuntime(["CPUExecutionProvider"])
    engine_id = runtime.load_engine(tiny_engine)
    with pytest.raises(KeyError, match="not loaded"):
        runtime.run("nope", {"x": np.zeros((1, 1), np.float32)})
    with pytest.raises(ValueError, match="feeds"):
        runtime.run(engine_id, {"z": np.zeros((1, 1), np.float32)})
