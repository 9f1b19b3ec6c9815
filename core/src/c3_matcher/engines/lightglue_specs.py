"""LightGlue's engines declared as data: the single graph ``lightglue/<feature_type>`` and its
steps engine ``lightglue/<feature_type>-steps`` (names, I/O, options), for the plugins that
declare them and the run time that finds them among the manifests. Plain data: no PyTorch, no
ONNX Runtime.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from c3_matcher.engines.spec import EngineSpec, TensorSpec, WeightsRef, matcher_spec
from c3_matcher.errors import EngineError

__all__ = [
    "LIGHTGLUE_LAYERS",
    "STEPS_OPTION",
    "STEPS_SIZES",
    "UPSTREAM_DEPTH_CONFIDENCE",
    "UPSTREAM_WIDTH_CONFIDENCE",
    "lightglue_engine_specs",
    "lightglue_spec",
    "steps_engine_spec",
    "steps_io",
    "steps_size",
    "steps_specs",
]

LIGHTGLUE_LAYERS = 9
"""Layers of upstream LightGlue (its pretrained weights for every extractor)."""
UPSTREAM_DEPTH_CONFIDENCE = 0.95
"""Upstream LightGlue's early-exit confidence (``depth_confidence``), its default."""
UPSTREAM_WIDTH_CONFIDENCE = 0.99
"""Upstream LightGlue's point-pruning confidence (``width_confidence``), its default."""
STEPS_OPTION = ("pruning", "steps")
"""The engine option that marks a steps engine (``steps_engine_spec``)."""


def lightglue_spec(
    feature_type: str,
    *,
    weights: WeightsRef,
    exporter: str,
    descriptor_dim: int,
    description: str,
    export_revision: int = 2,
) -> EngineSpec:
    """The ``EngineSpec`` ``lightglue/<feature_type>`` of upstream LightGlue for one extractor:
    ``LIGHTGLUE_LAYERS`` layers over ``descriptor_dim``-wide descriptors, adaptive pruning off
    (the match threshold is applied at run time). Export revision 2: fused attention (ONNX
    Runtime MultiHeadAttention)."""
    return matcher_spec(
        model="lightglue",
        variant=feature_type,
        weights=weights,
        exporter=exporter,
        feature_type=feature_type,
        descriptor_dim=descriptor_dim,
        options=(
            ("input_dim", descriptor_dim),
            ("n_layers", LIGHTGLUE_LAYERS),
            ("pruning", "off"),
        ),
        description=description,
        export_revision=export_revision,
    )


def steps_io(
    input_dim: int, descriptor_dim: int
) -> tuple[tuple[TensorSpec, ...], tuple[TensorSpec, ...]]:
    """Declared (inputs, outputs) of a steps engine, in the order its graph has them (the
    three sub-graphs: ``lightglue_adaptive``'s docstring)."""
    c = descriptor_dim
    inputs = (
        TensorSpec("desc0", "float32", (1, "num_desc0", input_dim)),
        TensorSpec("desc1", "float32", (1, "num_desc1", input_dim)),
        TensorSpec("kpts0", "float32", (1, "num_state0", 2)),
        TensorSpec("kpts1", "float32", (1, "num_state1", 2)),
        TensorSpec("state0", "float32", (1, "num_state0", c)),
        TensorSpec("state1", "float32", (1, "num_state1", c)),
        TensorSpec("layer", "int64", (1,)),
        TensorSpec("final0", "float32", (1, "num_final0", c)),
        TensorSpec("final1", "float32", (1, "num_final1", c)),
        TensorSpec("final_layer", "int64", (1,)),
    )
    outputs = (
        TensorSpec("proj0", "float32", (1, "num_desc0", c)),
        TensorSpec("proj1", "float32", (1, "num_desc1", c)),
        TensorSpec("out0", "float32", (1, "num_state0", c)),
        TensorSpec("out1", "float32", (1, "num_state1", c)),
        TensorSpec("confidence0", "float32", ("num_state0",)),
        TensorSpec("confidence1", "float32", ("num_state1",)),
        TensorSpec("matchability0", "float32", ("num_state0",)),
        TensorSpec("matchability1", "float32", ("num_state1",)),
        TensorSpec("matches0", "int64", ("num_final0",)),
        TensorSpec("mscores0", "float32", ("num_final0",)),
    )
    return inputs, outputs


def steps_engine_spec(
    full: EngineSpec, *, exporter: str, description: str, descriptor_dim: int = 256
) -> EngineSpec:
    """The ``EngineSpec`` of the steps engine of the single-graph LightGlue ``full`` (same model,
    weights, feature type, ``input_dim`` and ``n_layers``; variant ``"<feature_type>-steps"``,
    option ``STEPS_OPTION``, by which ``OnnxLightGlueRuntime`` finds it among the manifests).
    ``descriptor_dim`` is the transformer's width; the early-exit and pruning settings are
    upstream LightGlue's defaults (``UPSTREAM_*_CONFIDENCE``). The plugin that declares it names
    its own ``exporter`` (``"module:callable"``); a feature type whose plugin declares none runs
    its full graph."""
    feature_type = str(full.feature_type)
    input_dim = int(full.option("input_dim"))
    n_layers = int(full.option("n_layers"))
    inputs, outputs = steps_io(input_dim, descriptor_dim)
    return EngineSpec(
        model=full.model,
        variant=f"{feature_type}-steps",
        weights=full.weights,
        exporter=exporter,
        kind="matcher",
        inputs=inputs,
        outputs=outputs,
        input_rule="kpdyn",
        options=(
            ("input_dim", input_dim),
            ("descriptor_dim", descriptor_dim),
            ("n_layers", n_layers),
            STEPS_OPTION,
            ("depth_confidence", UPSTREAM_DEPTH_CONFIDENCE),
            ("width_confidence", UPSTREAM_WIDTH_CONFIDENCE),
        ),
        export_revision=2,  # 2: fused attention (ONNX Runtime MultiHeadAttention)
        feature_type=feature_type,
        description=description,
    )


def lightglue_engine_specs(
    feature_type: str, *, weights: WeightsRef, exporters: str, descriptor_dim: int
) -> tuple[EngineSpec, EngineSpec]:
    """Upstream LightGlue for the features ``feature_type`` as its two engines: the single graph
    ``lightglue/<feature_type>`` (``lightglue_spec``) and its steps engine
    ``lightglue/<feature_type>-steps`` (early exit and point pruning, on ONNX Runtime).
    ``exporters`` is the plugin's build-time module holding ``export_lightglue_<feature_type>``
    and ``export_lightglue_<feature_type>_steps``."""
    exporter = f"{exporters}:export_lightglue_{feature_type}"
    label = feature_type.upper()
    full = lightglue_spec(
        feature_type,
        weights=weights,
        exporter=exporter,
        descriptor_dim=descriptor_dim,
        description=f"LightGlue for {label}, {LIGHTGLUE_LAYERS} layers, no adaptive pruning, "
        "threshold applied at run time",
    )
    steps = steps_engine_spec(
        full,
        exporter=f"{exporter}_steps",
        description=f"LightGlue for {label} in steps: upstream early exit and point pruning",
    )
    return full, steps


def steps_specs(specs: Collection[EngineSpec]) -> dict[str, EngineSpec]:
    """The steps engines among ``specs`` (the ``EngineSpec``s the plugins declare, hook
    ``c3_matcher_engine_specs``), by the feature type they match."""
    return {
        str(spec.feature_type): spec
        for spec in specs
        if spec.feature_type and dict(spec.options).get(STEPS_OPTION[0]) == STEPS_OPTION[1]
    }


STEPS_SIZES = ("n_layers", "input_dim", "descriptor_dim")
"""The sizes a steps engine's manifest records in its options (its drivers need them)."""


def steps_size(path: Path, options: Mapping[str, Any], name: str) -> int:
    """A steps engine's positive whole-number size ``name`` from its manifest's options."""
    value = options.get(name)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise EngineError(
            path,
            f"its manifest's options.{name} is {value!r}, not a positive whole number "
            f"(a steps engine records {', '.join(STEPS_SIZES)}); rebuild it",
        )
    return value
