"""The build key: one hex sha256 over everything that defines an engine's graph.

``c3-matcher engines build`` reuses an engine only when its key equals the key of what this
install would export; the engine's file name carries the key's first characters and its manifest
the whole key. Every check of an engine (``manifest.check_engine_file``: loading, listing,
``engines verify``, reuse by a build) recomputes the key from the manifest's own fields, so a
manifest edited after its build (other weights, another version) is refused, not served.

The key covers what the graph declares (model, variant, kind, precision, input rule, opset,
inputs and outputs, feature type, size multiple: the names an ``EngineSpec`` declares and an
``EngineManifest`` records alike), the exporter's options, callable and revision, the weights
(their sha256, and the version of the distribution that ships them: its Python code defines the
exported network as much as the weights do) and the versions of the libraries that shape an
exported graph (a manifest records them beside the exporter; Python's is left out).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any, Protocol

from c3_matcher.engines.spec import TensorSpec

__all__ = ["NOT_LIBRARIES", "DeclaredGraph", "build_key"]

NOT_LIBRARIES = frozenset({"python", "callable", "method", "export_revision"})
"""Keys of a manifest's ``exporter`` record that are not the version of a graph-shaping library
(the key covers the callable and the revision as fields of their own)."""

_GRAPH = ("model", "variant", "kind", "precision", "input_rule", "opset")
_GRAPH_OPTIONAL = ("feature_type", "size_multiple")


class DeclaredGraph(Protocol):
    """What a spec declares and a manifest records of a graph, under the same names."""

    @property
    def model(self) -> str: ...
    @property
    def inputs(self) -> tuple[TensorSpec, ...]: ...
    @property
    def outputs(self) -> tuple[TensorSpec, ...]: ...


def build_key(
    graph: DeclaredGraph,
    options: Mapping[str, Any],
    exporter: Mapping[str, str],
    weights: Mapping[str, str],
) -> str:
    """The build key (hex sha256) of ``graph`` exported with ``options`` by ``exporter`` (a
    manifest's exporter record: ``callable``, ``export_revision`` and the library versions) from
    ``weights`` (``sha256`` and the shipping distribution's ``version``); equal keys mean an
    equal graph may be reused. ``KeyError``/``ValueError`` when a field is missing or bad."""
    payload: dict[str, Any] = {name: getattr(graph, name) for name in _GRAPH + _GRAPH_OPTIONAL}
    payload |= {
        "options": [list(o) for o in options.items()],
        "export_revision": int(exporter["export_revision"]),
        "exporter": exporter["callable"],
        "weights_sha256": weights["sha256"],
        "weights_version": weights["version"],
        "inputs": [t.to_json() for t in graph.inputs],
        "outputs": [t.to_json() for t in graph.outputs],
        "versions": {k: v for k, v in exporter.items() if k not in NOT_LIBRARIES},
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()
