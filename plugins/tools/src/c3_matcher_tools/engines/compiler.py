"""The engine compiler: export, verify and store the engines that plugins declare.

``build_engines(specs, directory)`` builds each ``EngineSpec`` whose valid engine is not already
in ``directory`` (same build key, ``c3_matcher.engines.build_key``: the spec's graph, export
parameters, revision and exporter, the weights' sha256 and their distribution's version, the
library versions), or every one with ``force=True``. Per engine: resolve the weights, call the
spec's exporter (export + verification against the PyTorch reference on real imagery), check the
graph's I/O against the spec, name the dynamic axes as declared, hash, write the manifest, move
both into place atomically, and remove superseded builds of the same model/variant. A reused
engine's damaged siblings (builds of its model/variant changed after their build or that cannot
be read, which start-up refuses whatever their age) are removed, saying so. A failed
verification or check raises ``EngineBuildError`` and keeps no file. One build at a time writes
a directory: a second one (a demo and the tests started together) waits, saying so, and then
reuses what the first built.

PyTorch is imported only through the exporters (build time); this module itself imports without
it, so ``ensure_engines`` can be called from any test or tool.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import errno
import importlib
import importlib.metadata
import os
import platform
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from loguru import logger

from c3_matcher.atomic import held_directory
from c3_matcher.engines.build_key import build_key
from c3_matcher.engines.manifest import EngineManifest, check_engine_file
from c3_matcher.engines.naming import EngineName, manifest_path_for
from c3_matcher.engines.spec import EngineSpec, file_sha256
from c3_matcher.engines.store import damage
from c3_matcher.errors import C3Error, EngineError, InvalidInputError, describe
from c3_matcher_tools.extras import check_engine_build, install_line

if TYPE_CHECKING:
    from c3_matcher_tools.engines.export import ExportReport, ExportRequest

__all__ = [
    "BuildOutcome",
    "EngineBuildError",
    "build_engines",
    "ensure_engines",
    "library_versions",
    "select_specs",
]

_VERSIONED = ("torch", "onnx", "onnxscript", "onnxruntime", "kornia", "numpy")

# failures only a write has, said of the file written when the error names none
_WRITE_FAULTS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


class EngineBuildError(C3Error):
    """Building ``spec_key`` failed (export error, failed verification or I/O check)."""

    def __init__(self, spec_key: str, reason: str) -> None:
        self.spec_key = spec_key
        self.reason = reason
        super().__init__(f"engine build {spec_key} failed: {reason}; no engine was kept")


@dataclass(frozen=True, slots=True)
class BuildOutcome:
    """One engine after ``build_engines``: ``reused`` when a valid build was already there."""

    spec: EngineSpec
    path: Path
    manifest: EngineManifest
    reused: bool
    seconds: float


def library_versions() -> dict[str, str]:
    """Versions of the libraries that shape an exported graph (read from metadata, no import)."""
    versions = {"python": platform.python_version()}
    for name in _VERSIONED:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not-installed"
    return versions


def select_specs(specs: Sequence[EngineSpec], only: Sequence[str] | None) -> list[EngineSpec]:
    """The specs named by ``only`` (``"model/variant"``), or all. An unknown name is the
    caller's bad input (``InvalidInputError`` on ``--only``, listing the known names); a spec
    declared twice is the plugins' fault (``ValueError``)."""
    keys = [s.key for s in specs]
    duplicates = sorted({k for k in keys if keys.count(k) > 1})
    if duplicates:
        raise ValueError(f"engine specs declared more than once: {', '.join(duplicates)}")
    if not only:
        return list(specs)
    unknown = [o for o in only if o not in keys]
    if unknown:
        raise InvalidInputError(
            "--only",
            f"unknown engine {', '.join(unknown)}: choose one of {', '.join(keys) or '(none)'}",
        )
    return [s for s in specs if s.key in set(only)]


def _load_exporter(spec: EngineSpec) -> Callable[[Any], Any]:
    module_name, _, attr = spec.exporter.partition(":")
    try:
        module = importlib.import_module(module_name)
        exporter = getattr(module, attr)
    except (ImportError, AttributeError) as exc:
        raise EngineBuildError(
            spec.key,
            f"cannot import exporter {spec.exporter} ({exc}); engine builds need the build-time "
            f"extra: {install_line('engine-build')}",
        ) from exc
    if not callable(exporter):
        raise EngineBuildError(spec.key, f"exporter {spec.exporter} is not callable")
    return exporter


def _finish_graph(path: Path, spec: EngineSpec) -> None:
    """Give the graph's dynamic input/output axes the spec's names (e.g. ``height``) and drop
    the exporter's debugging metadata: each node's Python stack trace with the build machine's
    source paths, and the export's shape constraints, written in hash-seed order. ONNX Runtime
    never reads it; without it one graph is the same bytes on every machine, checkout and run."""
    import onnx

    model = onnx.load(str(path))
    declared = {t.name: t for t in (*spec.inputs, *spec.outputs)}
    for value in (*model.graph.input, *model.graph.output):
        tensor = declared.get(value.name)
        if tensor is None:
            continue
        for axis, dim in enumerate(value.type.tensor_type.shape.dim):
            if axis < len(tensor.shape) and isinstance(tensor.shape[axis], str):
                dim.dim_param = str(tensor.shape[axis])
    del model.metadata_props[:]
    _drop_graph_metadata(model.graph)
    for function in model.functions:
        del function.metadata_props[:]
        _drop_node_metadata(function.node)
    onnx.save(model, str(path))


def _drop_graph_metadata(graph: Any) -> None:
    """Clear the metadata of ``graph``, its values and its nodes (subgraphs included)."""
    del graph.metadata_props[:]
    for value in (*graph.input, *graph.output, *graph.value_info):
        del value.metadata_props[:]
    _drop_node_metadata(graph.node)


def _drop_node_metadata(nodes: Any) -> None:
    for node in nodes:
        del node.metadata_props[:]
        node.doc_string = ""
        for attribute in node.attribute:
            for subgraph in (
                *([attribute.g] if attribute.HasField("g") else []),
                *attribute.graphs,
            ):
                _drop_graph_metadata(subgraph)


_SCRATCH_PREFIX = ".build-"


@contextlib.contextmanager
def _scratch(directory: Path, stem: str) -> Iterator[Path]:
    scratch = directory / f"{_SCRATCH_PREFIX}{stem}-{os.getpid()}"
    scratch.mkdir(parents=True)  # an earlier build's was removed: see _remove_abandoned
    try:
        yield scratch
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _remove_abandoned(directory: Path, log: Callable[[str], None]) -> None:
    """Remove the scratch folders of builds killed before they could clean up (out of memory,
    SIGKILL, power lost): called with ``directory`` held, so no build of it is running."""
    for scratch in sorted(directory.glob(f"{_SCRATCH_PREFIX}*")):
        if scratch.is_dir():
            shutil.rmtree(scratch, ignore_errors=True)
            log(f"removed {scratch.name}, left by a build that was stopped before it finished")


def _existing(path: Path, key: str, log: Callable[[str], None]) -> EngineManifest | None:
    """The valid engine at ``path`` built with build key ``key``, or None (saying why a file
    that is there is not reused: changed after its build, a manifest that no longer matches its
    key, a failed verification)."""
    if not path.is_file():
        return None
    try:
        manifest = check_engine_file(path, check_hash=True)
    except EngineError as exc:
        log(f"{path.name} is not reused: {exc.reason}")
        return None
    return manifest if manifest.build_key == key else None


def _other_builds(directory: Path, spec: EngineSpec, keep: Path) -> list[Path]:
    """The engine files of ``spec``'s model/variant in ``directory`` but ``keep``."""
    others = []
    for other in sorted(directory.glob(EngineName.glob_for(spec.model, spec.variant))):
        try:
            parsed = EngineName.parse(other.name)
        except ValueError:
            continue
        if (parsed.model, parsed.variant) == (spec.model, spec.variant) and other.name != keep.name:
            others.append(other)
    return others


def _remove_superseded(
    directory: Path, spec: EngineSpec, keep: Path, log: Callable[[str], None]
) -> None:
    for other in _other_builds(directory, spec, keep):
        other.unlink(missing_ok=True)
        manifest_path_for(other).unlink(missing_ok=True)
        log(f"removed superseded engine {other.name}")


def _remove_damaged(
    directory: Path, spec: EngineSpec, keep: Path, log: Callable[[str], None]
) -> None:
    """Remove the builds of ``spec``'s model/variant beside the reused ``keep`` that were
    changed after their build or cannot be read (``damage``): start-up refuses any of them,
    whatever its age, naming this build as the remedy. Valid builds are left as they are.
    ``EngineError`` naming one that cannot be removed."""
    for other in _other_builds(directory, spec, keep):
        found = damage(other)
        if found is None:
            continue
        try:
            other.unlink(missing_ok=True)
            manifest_path_for(other).unlink(missing_ok=True)
        except OSError as exc:
            raise EngineError(
                other,
                f"{found.reason}: start-up refuses it, and it cannot be removed ({describe(exc)})",
                None,
            ) from exc
        log(f"removed damaged engine {other.name} ({found.reason})")


@dataclass(frozen=True, slots=True)
class _Identity:
    """What names one build of a spec: its resolved weights, their sha256 and the version of the
    distribution that ships them, the build key, and the engine's name and path (``target``) in
    the directory."""

    weights_path: Path
    weights_sha256: str
    weights_version: str
    key: str
    name: EngineName
    target: Path


def _build_one(
    spec: EngineSpec,
    directory: Path,
    *,
    force: bool,
    images: Callable[[], tuple[Any, ...]],
    versions: dict[str, str],
    log: Callable[[str], None],
) -> BuildOutcome:
    """Reuse ``spec``'s valid engine in ``directory`` (unless ``force``; removing the damaged
    builds beside it), or export it in a scratch folder, verify and check it, move it and its
    manifest into place and remove the builds it supersedes."""
    start = time.perf_counter()
    ident = _identify(spec, directory, versions)
    target = ident.target
    if not force:
        manifest = _existing(target, ident.key, log)
        if manifest is not None:
            log(f"{spec.key}: valid engine {target.name} reused")
            _remove_damaged(directory, spec, target, log)
            return BuildOutcome(spec, target, manifest, True, time.perf_counter() - start)
    from c3_matcher_tools.engines.export import ExportRequest

    exporter = _load_exporter(spec)
    log(f"{spec.key}: building {target.name}")
    with _scratch(directory, ident.name.stem) as scratch:
        candidate = scratch / ident.name.filename
        request = ExportRequest(spec, ident.weights_path, candidate, images(), log)
        report = _export(spec, exporter, request)
        _check_graph(candidate, spec)
        seconds = time.perf_counter() - start
        manifest = _manifest(spec, ident, candidate, report, versions, seconds)
        manifest_tmp = scratch / ident.name.manifest_filename
        try:
            manifest.write(manifest_tmp)
        except OSError as exc:
            why = describe(_naming(exc, manifest_tmp))
            raise EngineBuildError(spec.key, f"its manifest cannot be written: {why}") from exc
        candidate.replace(target)
        manifest_tmp.replace(directory / ident.name.manifest_filename)
    _remove_superseded(directory, spec, target, log)
    log(f"{spec.key}: built {target.name} in {seconds:.1f} s")
    logger.bind(
        kind="c3.engines.built", engine=spec.key, file=str(target), seconds=round(seconds, 2)
    ).info("engine {} built", spec.key)
    return BuildOutcome(spec, target, manifest, False, seconds)


def _identify(spec: EngineSpec, directory: Path, versions: dict[str, str]) -> _Identity:
    """``spec``'s weights resolved and hashed (missing weights fail the build), its build key
    and its engine's name in ``directory``."""
    try:
        weights_path = spec.weights.resolve()
    except FileNotFoundError as exc:
        raise EngineBuildError(spec.key, str(exc)) from exc
    weights_sha = file_sha256(weights_path)
    weights_version = spec.weights.version()
    weights = _weights_record(spec, weights_sha, weights_version)
    key = build_key(spec, dict(spec.options), _exporter_record(spec, versions), weights)
    name = EngineName.from_build_key(
        spec.model, spec.variant, spec.precision, spec.input_rule, spec.opset, key
    )
    return _Identity(
        weights_path, weights_sha, weights_version, key, name, directory / name.filename
    )


def _export(
    spec: EngineSpec, exporter: Callable[[Any], Any], request: ExportRequest
) -> ExportReport:
    """Run the spec's exporter (export and verification); any error, or a verification that
    did not pass, fails the build."""
    try:
        report: ExportReport = exporter(request)
    except EngineBuildError:
        raise
    except Exception as exc:
        why = describe(_naming(exc, request.output_path))
        raise EngineBuildError(spec.key, f"export failed: {why}") from exc
    if not report.passed:
        raise EngineBuildError(
            spec.key, "verification failed: " + "; ".join(report.failures or ("no figures",))
        )
    return report


def _check_graph(candidate: Path, spec: EngineSpec) -> None:
    """Name the graph's dynamic axes as the spec declares and drop the exporter's debugging
    metadata, then check its inputs and outputs against the spec; any error fails the build."""
    try:
        from c3_matcher_tools.engines.export.onnx_export import check_onnx_io

        _finish_graph(candidate, spec)
        check_onnx_io(candidate, spec.inputs, spec.outputs)
    except Exception as exc:
        raise EngineBuildError(
            spec.key, f"graph I/O check failed: {_naming(exc, candidate)}"
        ) from exc


def _naming(exc: Exception, written: Path) -> Exception:
    """``exc``, or for a write that failed naming no file (a full disk, a file-size limit:
    ``onnx.save`` names none) the same ``OSError`` naming ``written``, the file being written
    (in the scratch folder of the engine directory)."""
    if isinstance(exc, OSError) and exc.filename is None and exc.errno in _WRITE_FAULTS:
        return OSError(exc.errno, exc.strerror, str(written))
    return exc


def _manifest(
    spec: EngineSpec,
    ident: _Identity,
    candidate: Path,
    report: ExportReport,
    versions: dict[str, str],
    seconds: float,
) -> EngineManifest:
    """The manifest of the engine exported to ``candidate``: what it is, what it was built from
    and with, how it verified, and when (``built_at``, now) and in how long it was built."""
    return EngineManifest(
        file=ident.name.filename,
        file_sha256=file_sha256(candidate),
        file_bytes=candidate.stat().st_size,
        model=spec.model,
        variant=spec.variant,
        kind=spec.kind,
        precision=spec.precision,
        input_rule=spec.input_rule,
        opset=spec.opset,
        build_key=ident.key,
        weights=_weights_record(spec, ident.weights_sha256, ident.weights_version),
        inputs=spec.inputs,
        outputs=spec.outputs,
        exporter=_exporter_record(spec, versions),
        options=dict(spec.options),
        verification=report.to_json(),
        build_seconds=round(seconds, 2),
        built_at=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        feature_type=spec.feature_type,
        size_multiple=spec.size_multiple,
        description=spec.description,
    )


def _weights_record(spec: EngineSpec, sha256: str, version: str) -> dict[str, str]:
    """The manifest's ``weights``: which file of which distribution's version, and its hash."""
    return {
        "distribution": spec.weights.distribution,
        "version": version,
        "path": spec.weights.path,
        "sha256": sha256,
    }


def _exporter_record(spec: EngineSpec, versions: dict[str, str]) -> dict[str, str]:
    """The manifest's ``exporter``: the callable, how it exports, its revision, and the
    versions of the libraries that shape the graph."""
    return {
        "callable": spec.exporter,
        "method": "torch.onnx.export(dynamo=True, external_data=False)",
        "export_revision": str(spec.export_revision),
        **versions,
    }


def build_engines(
    specs: Sequence[EngineSpec],
    directory: Path,
    *,
    force: bool = False,
    only: Sequence[str] | None = None,
    imagery: Sequence[Path] | None = None,
    log: Callable[[str], None] | None = None,
) -> list[BuildOutcome]:
    """Build (or reuse) the engines of ``specs`` (``only``: a subset by ``"model/variant"``) in
    ``directory``, verifying each on ``imagery`` (default: the packaged real orthophoto).

    Raises ``EngineBuildError`` at the first failed engine (engines built before it are kept),
    ``InvalidInputError`` naming what a build needs that is not installed, before anything is
    made (the engine-build extra, the weights: without them no engine is reused either).
    """
    say = log or (lambda _line: None)
    selected = select_specs(specs, only)
    check_engine_build(selected)  # the engine-build extra and the weights: before anything
    directory = Path(directory).expanduser()
    directory.mkdir(parents=True, exist_ok=True)
    versions = library_versions()
    cache: list[tuple[Any, ...]] = []

    def images() -> tuple[Any, ...]:
        if not cache:
            from c3_matcher_tools.engines.export import (
                default_verification_imagery,
                load_verification_images,
            )

            paths = tuple(imagery) if imagery else default_verification_imagery()
            cache.append(load_verification_images(paths))
        return cache[0]

    outcomes = []
    waiting = f"waiting for another engines build in {directory} to finish"
    with held_directory(directory, when_busy=lambda: say(waiting)):  # then reuses its engines
        _remove_abandoned(directory, say)
        for index, spec in enumerate(selected, start=1):
            say(f"[{index}/{len(selected)}] {spec.key}")
            outcomes.append(
                _build_one(spec, directory, force=force, images=images, versions=versions, log=say)
            )
    return outcomes


def ensure_engines(
    specs: Sequence[EngineSpec],
    directory: Path,
    *,
    log: Callable[[str], None] | None = None,
) -> dict[tuple[str, str], Path]:
    """Build what is missing (verified on the packaged real orthophoto), reuse what is valid;
    ``{(model, variant): engine path}``."""
    outcomes = build_engines(specs, directory, log=log)
    return {(o.spec.model, o.spec.variant): o.path for o in outcomes}
