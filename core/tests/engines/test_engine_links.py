"""Engines deployed as symbolic links (the manifests in the engine directory, each ``.onnx`` a
link into a blob store elsewhere) start as they verify: the manifest, and the steps engine
beside a full LightGlue graph, are looked for beside the link, not beside its target. A
missing steps engine is named by the model and variant to build.

Real engines of disk_lightglue, linked (never written: the shared engine directory is only
read)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from loguru import logger

from c3_matcher.compose import build_plugin_host
from c3_matcher.engines.lightglue import OnnxLightGlueRuntime
from c3_matcher.engines.lightglue_specs import steps_specs
from c3_matcher.engines.naming import manifest_path_for
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.store import EngineStore

from .copies import start_up

STRATEGY = (("disk", "depth"), ("lightglue", "disk"), ("lightglue", "disk-steps"))


def _linked(engine_dir: Path, tmp_path: Path, keys: tuple[tuple[str, str], ...]) -> Path:
    """``tmp_path/engines``: the manifests of ``keys``, each engine a symbolic link to its file
    in ``tmp_path/blobs`` (a hard link to the built engine, else a copy; no manifest there)."""
    links, blobs = tmp_path / "engines", tmp_path / "blobs"
    links.mkdir()
    blobs.mkdir()
    store = EngineStore(engine_dir)
    for key in keys:
        source = store.require(*key)
        try:
            os.link(source, blobs / source.name)
        except OSError:
            shutil.copy2(source, blobs / source.name)
        (links / source.name).symlink_to(blobs / source.name)
        shutil.copy2(manifest_path_for(source), links / manifest_path_for(source).name)
    return links


@pytest.mark.parametrize("mode", ["adaptive", "full"])
def test_linked_engines_start_up(engine_dir: Path, tmp_path: Path, mode: str) -> None:
    links = _linked(engine_dir, tmp_path, STRATEGY)
    assert all(o.ok for o in EngineStore(links).verify())
    helpers = start_up(links, mode)
    kind = "disk-steps" if mode == "adaptive" else "disk"
    served = helpers["c3_lightglue_runtime"].serving_engine("disk")
    assert served == links / EngineStore(links).require("lightglue", kind).name


def test_the_runtime_loads_an_engine_through_its_link(engine_dir: Path, tmp_path: Path) -> None:
    links = _linked(engine_dir, tmp_path, STRATEGY[:1])
    (link,) = links.glob("*.onnx")
    runtime = OnnxInferenceRuntime(["CPUExecutionProvider"])
    engine_id = runtime.load_engine(link)
    assert runtime.engine_path(engine_id) == link
    assert runtime.manifest(engine_id).file == link.name


def test_a_missing_steps_engine_is_named_by_its_model(engine_dir: Path, tmp_path: Path) -> None:
    links = _linked(engine_dir, tmp_path, STRATEGY[1:2])  # the full graph, no steps engine
    (full,) = links.glob("*.onnx")
    declared = steps_specs(build_plugin_host().engine_specs())
    runtime = OnnxLightGlueRuntime(
        OnnxInferenceRuntime(["CPUExecutionProvider"]), mode="adaptive", steps_specs=declared
    )
    said: list[str] = []
    sink = logger.add(lambda m: said.append(str(m.record["message"])), level="WARNING")
    try:
        assert runtime.load("disk", full) == full  # no steps engine: the full graph runs
    finally:
        logger.remove(sink)
    spec = declared["disk"]
    advice = [line for line in said if "no steps engine" in line]
    assert advice and f"--only {spec.model}/{spec.variant})" in advice[0], said
    assert "<model>" not in advice[0]
