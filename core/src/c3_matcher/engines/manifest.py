"""The manifest written beside each engine, and the checks that tie an engine file to it.

The manifest is JSON (``<engine stem>.manifest.json``) and records: the file's sha256 and size,
model/variant/precision/input rule/opset, the build key, the weights (distribution, version, path,
sha256), the graph's inputs and outputs (names, dtypes, shapes; a string dimension is a dynamic
axis), the exporter and library versions, the exporter options and the verification figures.
The build key is recomputed from those fields whenever an engine is checked (``build_key``): a
manifest edited after its build no longer matches its key and its engine is refused.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from c3_matcher.engines.build_key import build_key
from c3_matcher.engines.naming import EngineName, manifest_path_for
from c3_matcher.engines.spec import EngineSpec, TensorSpec, file_sha256
from c3_matcher.errors import EngineError
from c3_matcher.json_text import loads_json

__all__ = [
    "MANIFEST_SCHEMA",
    "EngineIntegrityError",
    "EngineManifest",
    "check_engine_file",
    "read_manifest",
]

MANIFEST_SCHEMA = 1


class EngineIntegrityError(EngineError):
    """The engine file is not the one its manifest describes (size or sha256 differ), or the
    manifest no longer matches its build key: either was changed or corrupted after the build.
    Never a reason to fall back to another engine."""


@dataclass(frozen=True, slots=True)
class EngineManifest:
    """The parsed manifest of one engine (see the module docstring for the fields' meaning).

    ``verification`` holds the build-time comparison against the PyTorch reference:
    ``{"passed": bool, "tolerances": {...}, "checks": [{...figures per input...}]}``.
    """

    file: str
    file_sha256: str
    file_bytes: int
    model: str
    variant: str
    kind: str
    precision: str
    input_rule: str
    opset: int
    build_key: str
    weights: Mapping[str, str]
    inputs: tuple[TensorSpec, ...]
    outputs: tuple[TensorSpec, ...]
    exporter: Mapping[str, str]
    options: Mapping[str, Any]
    verification: Mapping[str, Any]
    build_seconds: float
    built_at: str
    feature_type: str | None = None
    size_multiple: int | None = None
    description: str = ""
    schema: int = MANIFEST_SCHEMA
    extra: Mapping[str, Any] = field(default_factory=dict)

    @property
    def weights_sha256(self) -> str:
        return str(self.weights["sha256"])

    @property
    def verification_passed(self) -> bool:
        return bool(self.verification.get("passed", False))

    def other_graph(self, spec: EngineSpec) -> str | None:
        """How this build differs from the graph ``spec`` declares (precision, input rule,
        opset, exporter revision, options), or None when it is a build of that graph."""
        pairs = {
            "precision": (self.precision, spec.precision),
            "input rule": (self.input_rule, spec.input_rule),
            "opset": (self.opset, spec.opset),
            "export revision": (self.exporter.get("export_revision"), str(spec.export_revision)),
            "options": (dict(self.options), dict(spec.options)),
        }
        differ = [
            f"{what} {built} (this install: {declared})"
            for what, (built, declared) in pairs.items()
            if built != declared
        ]
        return "built for another graph: " + "; ".join(differ) if differ else None

    def recomputed_key(self) -> str:
        """The build key of what the manifest says the engine was built from (``build_key``);
        ``KeyError``/``ValueError`` when a field the key needs is missing or malformed."""
        return build_key(self, self.options, self.exporter, self.weights)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (dynamic axes spelled out per tensor for readers)."""
        return {
            "schema": self.schema,
            "file": self.file,
            "file_sha256": self.file_sha256,
            "file_bytes": self.file_bytes,
            "model": self.model,
            "variant": self.variant,
            "kind": self.kind,
            "feature_type": self.feature_type,
            "size_multiple": self.size_multiple,
            "description": self.description,
            "precision": self.precision,
            "input_rule": self.input_rule,
            "opset": self.opset,
            "build_key": self.build_key,
            "weights": dict(self.weights),
            "inputs": [t.to_json() for t in self.inputs],
            "outputs": [t.to_json() for t in self.outputs],
            "dynamic_axes": {
                t.name: {str(i): n for i, n in t.dynamic_axes().items()}
                for t in (*self.inputs, *self.outputs)
                if t.dynamic_axes()
            },
            "exporter": dict(self.exporter),
            "options": dict(self.options),
            "verification": dict(self.verification),
            "build_seconds": self.build_seconds,
            "built_at": self.built_at,
            "extra": dict(self.extra),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> EngineManifest:
        """Parse; ``KeyError``/``ValueError``/``TypeError`` on a malformed manifest (one whose
        ``weights`` lack the ``sha256`` every load records included)."""
        if int(data["schema"]) != MANIFEST_SCHEMA:
            raise ValueError(f"manifest schema {data['schema']} != {MANIFEST_SCHEMA}")
        return cls(
            file=str(data["file"]),
            file_sha256=str(data["file_sha256"]),
            file_bytes=int(data["file_bytes"]),
            model=str(data["model"]),
            variant=str(data["variant"]),
            kind=str(data["kind"]),
            precision=str(data["precision"]),
            input_rule=str(data["input_rule"]),
            opset=int(data["opset"]),
            build_key=str(data["build_key"]),
            weights=_weights(data["weights"]),
            inputs=tuple(TensorSpec.from_json(t) for t in data["inputs"]),
            outputs=tuple(TensorSpec.from_json(t) for t in data["outputs"]),
            exporter={str(k): str(v) for k, v in dict(data["exporter"]).items()},
            options=dict(data["options"]),
            verification=dict(data["verification"]),
            build_seconds=float(data["build_seconds"]),
            built_at=str(data["built_at"]),
            feature_type=None if data.get("feature_type") is None else str(data["feature_type"]),
            size_multiple=(
                None if data.get("size_multiple") is None else int(data["size_multiple"])
            ),
            description=str(data.get("description", "")),
            extra=dict(data.get("extra", {})),
        )

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_json(), indent=2, sort_keys=False) + "\n")


def _weights(value: Any) -> dict[str, str]:
    """A manifest's ``weights``; ``ValueError`` naming ``weights.sha256`` when it is missing or
    empty (the hash of the weights the engine was built from, which every load records)."""
    weights = {str(k): str(v) for k, v in dict(value).items()}
    if not weights.get("sha256"):
        raise ValueError("weights.sha256 is missing: the hash of the weights it was built from")
    return weights


def read_manifest(engine_path: Path) -> EngineManifest:
    """Read the manifest beside ``engine_path``; ``EngineError`` if missing or malformed."""
    manifest_path = manifest_path_for(engine_path)
    if not manifest_path.is_file():
        raise EngineError(engine_path, f"its manifest {manifest_path.name} is missing")
    try:
        return EngineManifest.from_json(loads_json(manifest_path.read_text()))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise EngineError(
            engine_path, f"its manifest {manifest_path.name} is unreadable ({exc})"
        ) from exc


def check_engine_file(engine_path: Path, *, check_hash: bool = True) -> EngineManifest:
    """Check an engine file against the name schema and its manifest.

    Checks: the file exists; its name follows the schema; the manifest names this file and agrees
    with the name's model/variant/precision/rule/opset/hash; its build key is the one recomputed
    from its own fields; the verification passed; the file's size equals the manifest's (free: a
    truncated copy is caught by a listing too); and (with ``check_hash``) its sha256 does.
    Returns the manifest; raises ``EngineError`` naming the file and the build command otherwise
    (``EngineIntegrityError`` for an engine or manifest changed after its build).
    """
    path = Path(engine_path)
    if not path.is_file():
        raise EngineError(path, "file not found")
    try:
        name = EngineName.parse(path.name)
    except ValueError as exc:
        raise EngineError(path, str(exc)) from exc
    manifest = read_manifest(path)
    if manifest.file != path.name:
        raise EngineError(path, f"manifest describes {manifest.file!r}, not this file")
    expected = (name.model, name.variant, name.precision, name.input_rule, name.opset)
    declared = (
        manifest.model,
        manifest.variant,
        manifest.precision,
        manifest.input_rule,
        manifest.opset,
    )
    if expected != declared or not manifest.build_key.startswith(name.short_hash):
        raise EngineError(path, f"file name {expected} disagrees with its manifest {declared}")
    _check_build_key(path, manifest)
    if not manifest.verification_passed:
        raise EngineError(path, "its manifest records a failed verification")
    size = path.stat().st_size
    if size != manifest.file_bytes:
        raise EngineIntegrityError(path, f"size {size} B != manifest {manifest.file_bytes} B")
    if check_hash:
        digest = file_sha256(path)
        if digest != manifest.file_sha256:
            raise EngineIntegrityError(
                path, f"sha256 {digest[:16]}... != manifest {manifest.file_sha256[:16]}..."
            )
    return manifest


def _check_build_key(path: Path, manifest: EngineManifest) -> None:
    """Refuse ``manifest`` when the build key recomputed from its fields (weights, versions,
    exporter, I/O...) is not the key it records (and the file name carries)."""
    manifest_name = manifest_path_for(path).name
    try:
        recomputed = manifest.recomputed_key()
    except (KeyError, ValueError) as exc:
        raise EngineError(
            path, f"its manifest {manifest_name} lacks a field of its build key ({exc})"
        ) from exc
    if recomputed != manifest.build_key:
        raise EngineIntegrityError(
            path,
            f"its manifest {manifest_name} does not match its build key: recomputed from the "
            f"manifest's fields {recomputed[:12]}..., recorded {manifest.build_key[:12]}... (the "
            "manifest was edited after the build, or an earlier c3-matcher whose key covered "
            "less built it)",
        )
