"""Adaptive LightGlue: the numpy exit/pruning driver on a fake graph, the
torch-free import, and the real DISK steps engine against the single-graph engine."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from loguru import logger
from numpy.typing import NDArray

from c3_matcher.engines.lightglue import OnnxLightGlueRuntime, steps_engines_beside
from c3_matcher.engines.lightglue_adaptive import AdaptiveLightGlue, confidence_threshold
from c3_matcher.engines.lightglue_specs import (
    STEPS_OPTION,
    steps_engine_spec,
    steps_io,
    steps_specs,
)
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.spec import EngineSpec, WeightsRef, matcher_spec
from c3_matcher.features import PairSide


class FakeSteps:
    """A steps 'graph' in numpy: state = descriptors (column 0 carries a point id); token
    confidence and matchability per layer come from tables indexed by point id; the head matches
    point i of set 0 to point i of set 1 (by id) with score 0.9."""

    def __init__(self, conf: NDArray[np.float32], match: NDArray[np.float32]) -> None:
        self.conf, self.match = conf, match  # (layers, points)
        self.layers_run: list[int] = []

    def __call__(self, feeds: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[Any]]:
        out: dict[str, NDArray[Any]] = {}
        out["proj0"], out["proj1"] = feeds["desc0"], feeds["desc1"]
        s0, s1 = feeds["state0"], feeds["state1"]
        layer = int(feeds["layer"][0])
        if s0.shape[1] > 1 or s0[0, 0, 0] != 0:  # a real layer call (not the dummy row)
            self.layers_run.append(layer)
        ids0, ids1 = s0[0, :, 0].astype(int), s1[0, :, 0].astype(int)
        out["out0"], out["out1"] = s0, s1
        out["confidence0"] = self.conf[layer, ids0 % self.conf.shape[1]]
        out["confidence1"] = self.conf[layer, ids1 % self.conf.shape[1]]
        out["matchability0"] = self.match[layer, ids0 % self.match.shape[1]]
        out["matchability1"] = self.match[layer, ids1 % self.match.shape[1]]
        f0, f1 = feeds["final0"][0, :, 0].astype(int), feeds["final1"][0, :, 0].astype(int)
        where = {int(v): j for j, v in enumerate(f1)}
        out["matches0"] = np.array([where.get(int(v), -1) for v in f0], np.int64)
        out["mscores0"] = np.where(out["matches0"] > -1, 0.9, 0.0).astype(np.float32)
        return out


def _points(n: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    desc = np.zeros((n, 4), np.float32)
    desc[:, 0] = np.arange(n)
    return np.zeros((n, 2), np.float32), desc


def _driver(fake: FakeSteps, depth: float, width: float, layers: int = 4) -> AdaptiveLightGlue:
    return AdaptiveLightGlue(
        fake,
        n_layers=layers,
        input_dim=4,
        descriptor_dim=4,
        depth_confidence=depth,
        width_confidence=width,
    )


def test_early_exit_when_confident() -> None:
    n = 10
    conf = np.full((4, n), 0.5, np.float32)
    conf[1] = 0.99  # every token confident after layer 1
    fake = FakeSteps(conf, np.ones((4, n), np.float32))
    k, d = _points(n)
    result = _driver(fake, 0.95, -1).match(k, k, d, d)
    assert result.layers == 2 and fake.layers_run == [0, 1]
    assert np.array_equal(result.matches0, np.arange(n))


def test_pruning_keeps_matchable_or_unconfident_points_and_maps_back() -> None:
    n = 10
    conf = np.full((4, n), 0.99, np.float32)
    conf[:, 3] = 0.1  # unconfident: never pruned, and the exit test never passes
    match = np.ones((4, n), np.float32)
    match[0, [2, 3, 7]] = 0.001  # unmatchable at layer 0
    fake = FakeSteps(conf, match)
    k, d = _points(n)
    result = _driver(fake, 0.999, 0.99).match(k, k, d, d)
    assert result.kept0 == [10, 8, 8, 8] and result.kept1 == [10, 8, 8, 8]
    expected = np.arange(n)
    expected[[2, 7]] = -1
    assert np.array_equal(result.matches0, expected)
    assert result.layers == 4
    assert np.all(result.mscores0[[2, 7]] == 0)


def test_a_pair_with_too_few_confident_matches_stops_with_no_matches() -> None:
    """The fake head matches every kept point with score 0.9: the test after layer 1 counts
    them; a pair with fewer than ``exit_matches`` stops there with no matches."""
    n = 10
    fake = FakeSteps(np.full((4, n), 0.5, np.float32), np.ones((4, n), np.float32))
    k, d = _points(n)

    def driver(exit_matches: int, confidence: float = 0.3) -> AdaptiveLightGlue:
        return AdaptiveLightGlue(
            fake,
            n_layers=4,
            input_dim=4,
            descriptor_dim=4,
            exit_matches=exit_matches,
            exit_after=1,
            exit_confidence=confidence,
        )

    stopped = driver(11).match(k, k, d, d)
    assert stopped.unmatchable and stopped.layers == 2 and stopped.matched == 10
    assert fake.layers_run == [0, 1]
    assert np.all(stopped.matches0 == -1) and np.all(stopped.mscores0 == 0)
    kept = driver(10).match(k, k, d, d)  # at the count: it runs on, as without the test
    assert not kept.unmatchable and kept.layers == 4 and kept.matched == 10
    assert np.array_equal(kept.matches0, np.arange(n))
    unsure = driver(1, confidence=0.95).match(k, k, d, d)  # 0.9 is not above 0.95
    assert unsure.unmatchable and unsure.matched == 0
    assert driver(0).match(k, k, d, d).matched is None  # off: no test, no head call
    with pytest.raises(ValueError, match="exit_matches"):
        AdaptiveLightGlue(fake, n_layers=4, input_dim=4, descriptor_dim=4, exit_matches=-1)


def test_a_side_pruned_to_no_point_stops_the_layers() -> None:
    """Every point of one image unmatchable after layer 0: the layers ran on over an empty side
    (time only: no match can come of it); upstream stops, and so does the driver now."""
    n = 6
    conf = np.full((4, 100 + n), 0.99, np.float32)
    conf[:, 0] = 0.1  # set 0 keeps an unconfident point, so the exit test never passes
    match = np.ones((4, 100 + n), np.float32)
    match[:, 100:] = 0.001  # set 1's points (ids 100..105) all unmatchable
    fake = FakeSteps(conf, match)
    k, d = _points(n)
    d1 = d.copy()
    d1[:, 0] += 100
    result = _driver(fake, 0.999, 0.99).match(k, k, d, d1)
    assert result.layers == 1 and fake.layers_run == [0]
    assert result.kept1 == [n, 0] and np.all(result.matches0 == -1)


def test_both_rules_off_run_every_layer_on_every_point() -> None:
    n = 6
    fake = FakeSteps(np.ones((3, n), np.float32), np.zeros((3, n), np.float32))
    k, d = _points(n)
    result = _driver(fake, -1, -1, layers=3).match(k, k, d, d)
    assert result.layers == 3 and result.kept0 == [n] and fake.layers_run == [0, 1, 2]


def test_empty_side_and_bad_settings() -> None:
    fake = FakeSteps(np.ones((2, 1), np.float32), np.ones((2, 1), np.float32))
    k, d = _points(3)
    result = _driver(fake, 0.95, 0.99, layers=2).match(k, k[:0], d, d[:0])
    assert result.layers == 0 and np.all(result.matches0 == -1)
    with pytest.raises(ValueError):
        _driver(fake, 1.5, 0.99)


def test_thresholds_are_upstreams() -> None:
    assert confidence_threshold(0, 9) == np.float32(0.9)
    assert abs(float(confidence_threshold(8, 9)) - (0.8 + 0.1 * np.exp(-32 / 9))) < 1e-7


def test_adaptive_runtime_imports_without_torch() -> None:
    code = (
        "import sys\n"
        "for name in ('torch', 'kornia', 'onnxscript'):\n"
        "    sys.modules[name] = None\n"
        "import c3_matcher.engines.lightglue_adaptive\n"
        "import c3_matcher.engines.lightglue\n"
        "import c3_matcher.engines.lightglue_specs as m\n"
        "assert callable(m.steps_engine_spec)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def disk_steps_engine(built_engines: dict[tuple[str, str], Path]) -> Path:
    return built_engines[("lightglue", "disk-steps")]


def test_disk_steps_engine_agrees_with_the_single_graph(
    disk_steps_engine: Path,
    lightglue_engine: Path,
    disk_engine: Path,
    gorinchem: NDArray[np.uint8],
) -> None:
    """Every layer on every point through the steps engine equals the single graph exactly;
    adaptive exits early on an overlapping pair and keeps almost every match."""
    from c3_matcher.engines.extract import run_extractor

    inference = OnnxInferenceRuntime(["CPUExecutionProvider"])
    disk_id = inference.load_engine(disk_engine)
    rgb0 = np.ascontiguousarray(gorinchem[0:480, 0:640])
    rgb1 = np.ascontiguousarray(gorinchem[200:712, 256:768])
    f0, f1 = (
        run_extractor(inference, disk_id, x, np.ones(x.shape[:2], bool), 1024) for x in (rgb0, rgb1)
    )
    args = (
        PairSide(f0.keypoints, f0.descriptors, (640, 480)),
        PairSide(f1.keypoints, f1.descriptors, (512, 512)),
    )

    full = OnnxLightGlueRuntime(inference, mode="full")
    full.load("disk", lightglue_engine)
    ref = full.match_pair(*args, feature_type="disk")

    steps_full = OnnxLightGlueRuntime(inference, mode="full")
    steps_full.load("disk", disk_steps_engine)
    got = steps_full.match_pair(*args, feature_type="disk")
    assert steps_full.last_run["mode"] == "steps-full" and steps_full.last_run["layers"] == 9
    assert np.array_equal(got.matches, ref.matches)
    assert np.abs(got.scores - ref.scores).max() < 1e-4

    lean = OnnxInferenceRuntime(["CPUExecutionProvider"])
    lean_runtime = OnnxLightGlueRuntime(lean, mode="adaptive")
    lean_runtime.load("disk", lightglue_engine)  # the strategy names the full engine...
    loaded = [lean.engine_path(i).name for i in lean.session_providers]
    assert loaded == [disk_steps_engine.name]  # ...and only the steps engine beside it is loaded
    lean_runtime.load("disk", lightglue_engine)  # again (a second root over the same helpers):
    assert [lean.engine_path(i).name for i in lean.session_providers] == loaded  # nothing more
    assert lean_runtime.match_pair(*args, feature_type="disk").matches.shape[0] > 0

    adaptive = OnnxLightGlueRuntime(inference, mode="adaptive")
    adaptive.load("disk", lightglue_engine)
    adaptive.load("disk", disk_steps_engine)
    fast = adaptive.match_pair(*args, feature_type="disk")
    assert adaptive.last_run["mode"] == "adaptive" and adaptive.last_run["layers"] < 9
    a, b = set(map(tuple, fast.matches.tolist())), set(map(tuple, ref.matches.tolist()))
    assert len(a & b) / len(b) > 0.8, (len(a), len(b), len(a & b))


def _steps_of(feature_type: str, revision: int | None = None) -> EngineSpec:
    """A plugin's declared steps engine for ``feature_type`` (its exporter at ``revision``)."""
    full = matcher_spec(
        model="glue",
        variant=feature_type,
        weights=WeightsRef("none", "none"),
        exporter="toy_plugin.export:export_full",
        feature_type=feature_type,
        descriptor_dim=4,
        options=(("input_dim", 4), ("n_layers", 2), ("pruning", "off")),
        description="",
    )
    steps = steps_engine_spec(full, exporter="toy_plugin.export:steps", description="")
    if revision is None:
        return steps
    return dataclasses.replace(steps, export_revision=revision)


def test_only_a_steps_engine_of_the_declared_graph_is_run(
    make_tiny_engine: Callable[..., Path], tmp_path: Path
) -> None:
    """A steps engine built by an older exporter is not run (it was, being found beside)."""
    declared = _steps_of("toy")
    full = make_tiny_engine(
        tmp_path / "engines", variant="toy", feature_type="toy", options={"pruning": "off"}
    )
    built = make_tiny_engine(
        full.parent,
        variant="toy-steps",
        export_revision=declared.export_revision,
        options=dict(declared.options),
        feature_type="toy",
        input_rule=declared.input_rule,
    )
    assert steps_engines_beside(full, "toy", declared) == [built]
    stale = _steps_of("toy", revision=declared.export_revision + 1)
    assert steps_engines_beside(full, "toy", stale) == []
    assert steps_engines_beside(full, "toy") == [built]  # nothing declared: any build


def test_steps_engines_are_found_by_manifest_not_by_name(
    make_tiny_engine: Callable[..., Path], tmp_path: Path
) -> None:
    directory = tmp_path / "engines"
    full = make_tiny_engine(
        directory, variant="toy", feature_type="toy", options={"pruning": "off"}
    )
    make_tiny_engine(directory, variant="toy-steps", feature_type="toy")  # steps by name only
    declared = make_tiny_engine(
        directory, variant="other", feature_type="toy", options=dict([STEPS_OPTION])
    )
    assert steps_engines_beside(full, "toy") == [declared]
    assert steps_engines_beside(full, "else") == []


def test_missing_steps_engine_warned_only_where_a_plugin_declares_one(
    make_tiny_engine: Callable[..., Path], tmp_path: Path
) -> None:
    full = make_tiny_engine(tmp_path / "engines", variant="toy", feature_type="toy")
    seen: list[dict[str, Any]] = []
    sink = logger.add(lambda m: seen.append(dict(m.record["extra"])), level="WARNING")
    try:
        for declared in (None, {"other": _steps_of("other")}, {"toy": _steps_of("toy")}):
            inference = OnnxInferenceRuntime(["CPUExecutionProvider"])
            runtime = OnnxLightGlueRuntime(inference, mode="adaptive", steps_specs=declared)
            runtime.load("toy", full)
            assert runtime.feature_types == ("toy",)
    finally:
        logger.remove(sink)
    warned = [e for e in seen if e.get("kind") == "c3.lightglue.no_steps_engine"]
    assert warned == [{"kind": "c3.lightglue.no_steps_engine", "feature_type": "toy"}]


def test_steps_spec_of_a_full_spec_and_the_declared_feature_types() -> None:
    full = matcher_spec(
        model="glue",
        variant="toy",
        weights=WeightsRef("none", "none"),
        exporter="toy_plugin.export:export_full",
        feature_type="toy",
        descriptor_dim=4,
        options=(("input_dim", 4), ("n_layers", 2), ("pruning", "off")),
        description="",
    )
    steps = steps_engine_spec(
        full, exporter="toy_plugin.export:export_steps", description="", descriptor_dim=8
    )
    assert (steps.key, steps.exporter, steps.weights) == (
        "glue/toy-steps",
        "toy_plugin.export:export_steps",
        full.weights,
    )
    assert (steps.inputs, steps.outputs) == steps_io(4, 8)
    assert (steps.option("n_layers"), steps.option("pruning")) == (2, "steps")
    assert steps_specs([steps, full]) == {"toy": steps}
    assert steps_specs([full]) == {}


def test_unmatchable_exit_on_real_pairs(
    disk_steps_engine: Path,
    lightglue_engine: Path,
    disk_engine: Path,
    gorinchem: NDArray[np.uint8],
) -> None:
    """DISK steps engine on real imagery: a pair of two different places (Gorinchem against
    Zurich) stops after two layers with no matches; an overlapping pair passes the test and
    gives exactly the matches it gives without it."""
    from c3_matcher.engines.extract import run_extractor
    from conftest import read_rgb

    inference = OnnxInferenceRuntime(["CPUExecutionProvider"])
    disk_id = inference.load_engine(disk_engine)
    zurich = read_rgb("open_orthophotos/swissimage_zurich_1091-322_00_0p5m.tif")
    images = {
        "frame": np.ascontiguousarray(gorinchem[0:480, 0:640]),
        "tile": np.ascontiguousarray(gorinchem[200:712, 256:768]),
        "elsewhere": np.ascontiguousarray(zurich[0:512, 256:768]),
    }
    feats = {
        name: run_extractor(inference, disk_id, rgb, np.ones(rgb.shape[:2], bool), 1024)
        for name, rgb in images.items()
    }

    def pair(other: str, exit_matches: int) -> tuple[Any, dict[str, Any]]:
        runtime = OnnxLightGlueRuntime(inference, mode="adaptive", exit_matches=exit_matches)
        runtime.load("disk", lightglue_engine)
        f0, f1 = feats["frame"], feats[other]
        raw = runtime.match_pair(
            PairSide(f0.keypoints, f0.descriptors, (640, 480)),
            PairSide(f1.keypoints, f1.descriptors, (512, 512)),
            feature_type="disk",
        )
        return raw, runtime.last_run

    same, same_run = pair("tile", 16)
    plain, plain_run = pair("tile", 0)
    assert not same_run["unmatchable"] and same_run["matched"] >= 16
    assert plain_run["matched"] is None and same_run["layers"] == plain_run["layers"]
    assert np.array_equal(same.matches, plain.matches) and len(same.matches) > 100
    assert np.array_equal(same.scores, plain.scores)

    other, other_run = pair("elsewhere", 16)
    assert other_run["unmatchable"] and other_run["layers"] == 2 and other_run["matched"] < 16
    assert other.matches.shape == (0, 2)


@pytest.mark.parametrize(
    "options",
    [
        {"input_dim": 4, "descriptor_dim": 4},
        {"input_dim": 4, "descriptor_dim": 4, "n_layers": 0},
        {"input_dim": 4, "descriptor_dim": 4, "n_layers": "9"},
    ],
)
def test_a_steps_engine_without_its_layer_count_is_refused_by_name(
    make_tiny_engine: Callable[..., Path], tmp_path: Path, options: dict[str, Any]
) -> None:
    """Loaded directly, a steps engine whose manifest lacks a usable ``n_layers`` is an
    ``EngineError`` naming the file and the option (it was a bare ``KeyError``)."""
    from c3_matcher.errors import EngineError

    steps = make_tiny_engine(
        tmp_path,
        variant="toy-steps",
        feature_type="toy",
        options={**options, STEPS_OPTION[0]: STEPS_OPTION[1]},
    )
    runtime = OnnxLightGlueRuntime(OnnxInferenceRuntime(["CPUExecutionProvider"]), mode="full")
    with pytest.raises(EngineError, match=r"options\.n_layers .*not a positive whole number"):
        runtime.load("toy", steps)
