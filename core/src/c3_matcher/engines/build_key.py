"""The build key: one hex sha256 over everything that defines an engine's graph.

``c3-matcher engines build`` reuses an engine only when its key equals the key of what this
install would export; the engine's file name carries the key's first characters and its manifest
the whole key. Every check of an engine (``manifest.check_engine_file``: loading, listing,
``engines verify``, reuse by a build) recomputes the key from the manifest's own fields, so a
manifest edited after its build (other weights, another version) is refused, not served.

The key covers what the spec declares (model, variant, kind, precision, input rule, opset,
exporter callable, options and revision, inputs and outputs, feature type, size multiple), the
weights (their sha256, and the version of the distribution that ships them: its Python code
defines the exported network as much as the weights do) and the versions of the libraries that
shape an exported graph (a manifest records them beside the exporter; Python's is left out).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from c3_matcher.engines.spec import EngineSpec, TensorSpec

__all__ = ["NOT_LIBRARIES", "BuildInputs"]

NOT_LIBRARIES = frozenset({"python", "callable", "method", "export_revision"})
"""Keys of a manifest's ``exporter`` record that are not the version of a graph-shaping library
(the key covers the callable and the revision as fields of their own)."""


@dataclass(frozen=True, slots=True)
class BuildInputs:
    """What one build of an engine is made from; ``key()`` is its build key."""

    model: str
    variant: str
    kind: str
    precision: str
    input_rule: str
    opset: int
    options: tuple[tuple[str, Any], ...]
    export_revision: int
    exporter: str
    weights_sha256: str
    weights_version: str
    inputs: tuple[TensorSpec, ...]
    outputs: tuple[TensorSpec, ...]
    feature_type: str | None
    size_multiple: int | None
    versions: Mapping[str, str]

    @classmethod
    def of_spec(
        cls,
        spec: EngineSpec,
        weights_sha256: str,
        weights_version: str,
        versions: Mapping[str, str],
    ) -> BuildInputs:
        """A build of ``spec`` from weights ``weights_sha256`` (shipped by version
        ``weights_version`` of ``spec.weights.distribution``) with library ``versions``."""
        return cls(
            model=spec.model,
            variant=spec.variant,
            kind=spec.kind,
            precision=spec.precision,
            input_rule=spec.input_rule,
            opset=spec.opset,
            options=tuple(spec.options),
            export_revision=spec.export_revision,
            exporter=spec.exporter,
            weights_sha256=weights_sha256,
            weights_version=weights_version,
            inputs=spec.inputs,
            outputs=spec.outputs,
            feature_type=spec.feature_type,
            size_multiple=spec.size_multiple,
            versions=versions,
        )

    def key(self) -> str:
        """The build key (hex sha256): equal keys mean an equal graph may be reused."""
        payload = {
            "model": self.model,
            "variant": self.variant,
            "kind": self.kind,
            "precision": self.precision,
            "input_rule": self.input_rule,
            "opset": self.opset,
            "options": [list(o) for o in self.options],
            "export_revision": self.export_revision,
            "exporter": self.exporter,
            "weights_sha256": self.weights_sha256,
            "weights_version": self.weights_version,
            "inputs": [t.to_json() for t in self.inputs],
            "outputs": [t.to_json() for t in self.outputs],
            "feature_type": self.feature_type,
            "size_multiple": self.size_multiple,
            "versions": {k: v for k, v in self.versions.items() if k not in NOT_LIBRARIES},
        }
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()
