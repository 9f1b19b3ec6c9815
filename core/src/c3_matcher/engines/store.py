"""The engine directory: find the engine of a model/variant, list and verify what is there.

Imports without PyTorch (run time). The compiler keeps one engine per model/variant in a
directory (it removes superseded builds); should several remain, the newest valid one wins.
"""

from __future__ import annotations

import builtins
from dataclasses import dataclass
from pathlib import Path

from c3_matcher.engines.lightglue_specs import STEPS_OPTION
from c3_matcher.engines.manifest import (
    EngineIntegrityError,
    EngineManifest,
    check_engine_file,
    read_manifest,
)
from c3_matcher.engines.naming import (
    ENGINE_SUFFIX,
    MANIFEST_SUFFIX,
    EngineName,
    manifest_path_for,
)
from c3_matcher.engines.spec import EngineSpec
from c3_matcher.errors import EngineError

__all__ = [
    "BUILD_COMMAND",
    "TOOLS_DISTRIBUTION",
    "EngineRecord",
    "EngineStore",
    "MissingEngineError",
    "VerifyOutcome",
    "checkout_root",
    "damage",
    "default_engine_dir",
    "intact_engine",
    "steps_engines_beside",
    "unreadable_engine",
    "usable_directory",
]

BUILD_COMMAND = "c3-matcher engines build"
TOOLS_DISTRIBUTION = "c3-matcher-tools"
"""The ground tools, which add ``BUILD_COMMAND`` (and every ground command): never in flight."""


class MissingEngineError(EngineError):
    """No valid engine of a model/variant in the engine directory. The ground tools build it;
    a flight computer, which has no tools, takes the engines a ground machine built: the
    message names both."""

    def __init__(self, path: Path, reason: str, command: str, directory: Path) -> None:
        super().__init__(path, reason, command)
        self.directory = directory
        self.args = (
            f"{self.args[0]} (the ground tools, {TOOLS_DISTRIBUTION}), or copy the engines a "
            f"ground machine built into {directory}",
        )


CHECKOUT_ENGINE_DIR = ".engines"
WORKSPACE_MARKER = ("buildflags", "matrix.toml")


def checkout_root() -> Path | None:
    """The source checkout this package runs from, or ``None`` when it is installed from a wheel.

    A checkout is recognised by the package's own location: ``<root>/core/src/c3_matcher`` (an
    editable install, as ``scripts/setup`` makes) with ``<root>/buildflags/matrix.toml`` beside
    it. Nothing else (the working directory, environment variables) plays a part.
    """
    package = Path(__file__).resolve().parents[1]
    src = package.parent
    if src.name != "src" or src.parent.name != "core":
        return None
    root = src.parent.parent
    return root if root.joinpath(*WORKSPACE_MARKER).is_file() else None


def default_engine_dir() -> Path:
    """The default ``[engines] directory``: one place per installation, whatever the working
    directory.

    From a source checkout (editable install): ``<checkout>/.engines``, where ``scripts/setup``,
    ``scripts/demo``, ``scripts/test`` and ``c3-matcher engines build`` put the engines, beside
    the checkout's ``.venv``. Installed from wheels: ``engines`` in c3-matcher's user cache
    directory (``$XDG_CACHE_HOME/c3-matcher/engines``, else ``~/.cache/c3-matcher/engines``:
    ``c3_matcher.user_dirs``).
    """
    root = checkout_root()
    if root is not None:
        return root / CHECKOUT_ENGINE_DIR
    from c3_matcher.user_dirs import user_cache_dir

    return user_cache_dir() / "engines"


def usable_directory(path: Path) -> Path:
    """``path`` when it can be a directory (it is one, or it does not exist yet and nothing
    above it is a file); ``ValueError`` saying which file is in the way otherwise (a setting
    such as ``[engines] directory`` is refused with it, not by the first command that writes
    there)."""
    for place in (path, *path.parents):
        try:
            if not place.exists():
                continue
            is_dir = place.is_dir()
        except OSError:  # not readable from here: the command that uses it says why
            break
        if not is_dir:
            where = "" if place == path else f" ({place} is a file)"
            raise ValueError(f"{path} is not a directory{where}")
        break
    return path


@dataclass(frozen=True, slots=True)
class EngineRecord:
    """One ``*.onnx`` file in the directory: its manifest, or the problem that prevents reading
    it (``problem`` is ``None`` when the name and manifest check out; the hash is checked only by
    ``EngineStore.verify`` and at load time) and the command that builds it anew (``command``)."""

    path: Path
    manifest: EngineManifest | None
    problem: str | None
    command: str | None = None

    @property
    def ok(self) -> bool:
        return self.problem is None


@dataclass(frozen=True, slots=True)
class VerifyOutcome:
    """Result of re-hashing one engine against its manifest; a failure's ``command`` builds it
    anew (None: no build names it)."""

    path: Path
    ok: bool
    detail: str
    command: str | None = None


class EngineStore:
    """Engines in ``directory`` (which need not exist yet; a leading ``~`` is the user's home)."""

    def __init__(self, directory: Path) -> None:
        self._directory = Path(directory).expanduser()

    @property
    def directory(self) -> Path:
        return self._directory

    def _files(self, pattern: str = f"*{ENGINE_SUFFIX}") -> list[Path]:
        if not self._directory.is_dir():
            return []
        return sorted(p for p in self._directory.glob(pattern) if p.is_file())

    def require_spec(self, spec: EngineSpec) -> Path:
        """The engine an installed plugin declares as ``spec``: the newest valid build of its
        model/variant with the same graph (precision, input rule, opset, exporter options and
        revision). A build of another graph (an older exporter, other options) is named in the
        error, never run: what this install measured is its own graph."""
        return self.require(spec.model, spec.variant, graph=spec)

    def require(
        self,
        model: str,
        variant: str,
        *,
        weights_sha256: str | None = None,
        graph: EngineSpec | None = None,
    ) -> Path:
        """The engine file of ``model``/``variant`` (newest valid build; with ``weights_sha256``,
        only one built from those weights; with ``graph``, only a build of that graph).

        Raises ``MissingEngineError`` naming ``c3-matcher engines build`` (or a ground machine's
        engines to copy) when there is none, and the missing file when a manifest there
        describes one (else the file pattern looked for).
        A build changed after it was made (``EngineIntegrityError``: a file cut short, a
        manifest edited) stops the search, naming it and the build that removes it; never
        skipped for another build, whatever its age (``built_at`` is no part of the build key:
        a damaged build's age cannot be believed). ``load_engine`` checks the file hash.
        """
        pattern = EngineName.glob_for(model, variant)
        expected = self._directory / pattern
        problems: list[str] = []
        valid: list[tuple[str, Path]] = []
        for path in self._files(pattern):
            try:
                name = EngineName.parse(path.name)
            except ValueError:
                continue
            if (name.model, name.variant) != (model, variant):
                continue
            try:
                manifest = check_engine_file(path, check_hash=False)
            except EngineIntegrityError as exc:  # refused, never passed over for another build
                raise EngineIntegrityError(path, exc.reason, _build_only(model, variant)) from exc
            except EngineError as exc:
                problems.append(f"{path.name}: {exc.reason}")
                continue
            if weights_sha256 is not None and manifest.weights_sha256 != weights_sha256:
                problems.append(
                    f"{path.name}: built from weights {manifest.weights_sha256[:12]}..., "
                    f"installed weights are {weights_sha256[:12]}..."
                )
                continue
            other = manifest.other_graph(graph) if graph is not None else None
            if other:
                problems.append(f"{path.name}: {other}")
                continue
            valid.append((manifest.built_at, path))
        if not valid:
            raise self._missing(model, variant, problems, expected)
        return max(valid)[1]

    def _missing(
        self, model: str, variant: str, problems: builtins.list[str], expected: Path
    ) -> MissingEngineError:
        """No valid ``model``/``variant`` engine here: the ``problems`` of the builds there, and
        any file whose manifest is there without it (named; else ``expected``, the pattern)."""
        missing = self._engines_without_file(model, variant)
        problems += [f"{p.name}: file not found (its manifest is there)" for p in missing]
        detail = f" ({'; '.join(problems)})" if problems else ""
        return MissingEngineError(
            missing[-1] if missing else expected,
            f"no valid {model}/{variant} engine in {self._directory}{detail} (the [engines] "
            "directory setting, or C3_MATCHER_ENGINES__DIRECTORY, says where to look)",
            _build_only(model, variant),
            self._directory,
        )

    def _engines_without_file(self, model: str, variant: str) -> builtins.list[Path]:
        """The engine files of ``model``/``variant`` whose manifest is there but not the file."""
        missing = []
        for manifest_file in self._files(f"{model}_{variant}_*{MANIFEST_SUFFIX}"):
            engine = manifest_file.with_name(
                manifest_file.name.removesuffix(MANIFEST_SUFFIX) + ENGINE_SUFFIX
            )
            try:
                name = EngineName.parse(engine.name)
            except ValueError:
                continue
            if (name.model, name.variant) == (model, variant) and not engine.is_file():
                missing.append(engine)
        return missing

    def list(self) -> list[EngineRecord]:
        """Every ``*.onnx`` file in the directory, with its manifest or its problem."""
        records: list[EngineRecord] = []
        for path in self._files():
            try:
                EngineName.parse(path.name)
                manifest = read_manifest(path)
                check_engine_file(path, check_hash=False)
            except (ValueError, EngineError) as exc:
                reason = exc.reason if isinstance(exc, EngineError) else str(exc)
                try:
                    partial: EngineManifest | None = read_manifest(path)
                except EngineError:
                    partial = None
                records.append(EngineRecord(path, partial, reason, _rebuild(path)))
                continue
            records.append(EngineRecord(path, manifest, None))
        return records

    def verify(self) -> builtins.list[VerifyOutcome]:
        """Re-hash every engine and compare with its manifest; a manifest whose engine file is
        missing, or an engine file that cannot be read, is a failure too (one outcome each)."""
        outcomes: builtins.list[VerifyOutcome] = []
        for manifest_file in self._files(f"*{MANIFEST_SUFFIX}"):
            engine = manifest_file.with_name(
                manifest_file.name.removesuffix(MANIFEST_SUFFIX) + ENGINE_SUFFIX
            )
            if not engine.is_file():
                said = f"engine file missing (manifest {manifest_file.name})"
                outcomes.append(VerifyOutcome(engine, False, said, _rebuild(engine)))
        for path in self._files():
            try:
                manifest = intact_engine(path)
            except EngineError as exc:
                outcomes.append(VerifyOutcome(path, False, exc.reason, _rebuild(path)))
                continue
            outcomes.append(VerifyOutcome(path, True, f"sha256 {manifest.file_sha256[:16]}... ok"))
        return outcomes


def _build_only(model: str, variant: str) -> str:
    """The command that builds ``model``/``variant`` (and removes its damaged builds)."""
    return f"{BUILD_COMMAND} --only {model}/{variant}"


def _rebuild(path: Path) -> str | None:
    """``_build_only`` of the model/variant ``path`` is named as a build of; None otherwise."""
    try:
        name = EngineName.parse(path.name)
    except ValueError:
        return None
    return _build_only(name.model, name.variant)


def intact_engine(path: Path) -> EngineManifest:
    """``check_engine_file`` of ``path``, its sha256 included; an engine file that cannot be
    read (no read permission, an I/O error) is ``EngineIntegrityError`` too (``"cannot open
    (permission denied)"``): it cannot be shown to be the file its manifest describes, and is
    never passed over for another engine."""
    try:
        return check_engine_file(path)
    except OSError as exc:
        raise unreadable_engine(path, exc) from exc


def unreadable_engine(path: Path, exc: OSError) -> EngineIntegrityError:
    """The refusal of the engine file ``path``, which could not be read (``exc``)."""
    from c3_matcher.tilestore.files import cannot_open

    return EngineIntegrityError(path, cannot_open(exc))


def _manifest_damage(path: Path, name: EngineName) -> EngineIntegrityError | None:
    """The refusal of the build ``path`` (named ``name``) when its manifest is there but cannot
    be read (cut short, of another schema, without read permission); None when it reads, or is
    not there."""
    if not manifest_path_for(path).is_file():
        return None
    try:
        read_manifest(path)
    except EngineError as exc:
        return EngineIntegrityError(path, exc.reason, _build_only(name.model, name.variant))
    return None


def damage(path: Path) -> EngineIntegrityError | None:
    """What stops start-up in the build at ``path``: a file or manifest changed after the build
    or that cannot be read (size, sha256 or build key other than recorded; a manifest cut short,
    of another schema or without read permission), naming the build of its model/variant; None
    for an intact build, or one start-up passes over (a failed verification, no manifest, a name
    outside the schema)."""
    try:
        name = EngineName.parse(path.name)
    except ValueError:
        return None
    found = _manifest_damage(path, name)
    if found is not None:
        return found
    try:
        intact_engine(path)
    except EngineIntegrityError as exc:
        return EngineIntegrityError(path, exc.reason, _build_only(name.model, name.variant))
    except EngineError:
        return None
    return None


def steps_engines_beside(
    engine_path: Path, feature_type: str, graph: EngineSpec | None = None
) -> list[Path]:
    """The steps engines for ``feature_type`` in ``engine_path``'s directory, found by their
    manifests (``feature_type`` and option ``pruning = "steps"``), not by their file names;
    newest build first; with ``graph``, only builds of the graph it declares. An engine whose
    manifest is missing (or, with no ``graph``, cannot be read) is not one. With ``graph``, a
    file named as a build of its model/variant whose manifest is there but cannot be read
    stops the search (``EngineIntegrityError`` naming it and why): a damaged steps engine is
    never passed over for the full graph."""
    found: list[tuple[str, Path]] = []
    for record in EngineStore(Path(engine_path).parent).list():
        manifest = record.manifest
        if manifest is None:
            if graph is not None:
                _refuse_unreadable(record.path, graph)
            continue
        if (
            manifest.feature_type == feature_type
            and manifest.options.get(STEPS_OPTION[0]) == STEPS_OPTION[1]
            and (graph is None or manifest.other_graph(graph) is None)
        ):
            found.append((manifest.built_at, record.path))
    return [path for _, path in sorted(found, reverse=True)]


def _refuse_unreadable(path: Path, graph: EngineSpec) -> None:
    """``EngineIntegrityError`` when ``path`` is named as a build of ``graph``'s model/variant
    and its manifest is there but cannot be read."""
    try:
        name = EngineName.parse(path.name)
    except ValueError:
        return
    found = None
    if (name.model, name.variant) == (graph.model, graph.variant):
        found = _manifest_damage(path, name)
    if found is not None:
        raise found
