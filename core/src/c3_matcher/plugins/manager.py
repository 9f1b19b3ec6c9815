"""``PluginHost``: owns the pluggy PluginManager; nothing else calls ``pm.hook.*``.

Built by the composition root (no module-level manager) from the installed profile and the
entry points of the group ``c3_matcher.plugins``.
"""

from __future__ import annotations

import types
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import importlib_metadata
import pluggy

from c3_matcher.errors import (
    DuplicateStrategyError,
    PluginLoadError,
    StrategyNotLinkedError,
    UnknownStrategyError,
)
from c3_matcher.plugins import hookspecs
from c3_matcher.plugins.types import StrategySpec
from c3_matcher.profiles import BuildProfile, FlagState

if TYPE_CHECKING:
    from c3_matcher.commands import CommandRegistry
    from c3_matcher.config import C3Settings
    from c3_matcher.engines.spec import EngineSpec
    from c3_matcher.pipeline import FeatureBackend

__all__ = ["ENTRY_POINT_GROUP", "IgnoredPlugin", "LoadedPlugin", "PluginHost", "PluginSource"]

ENTRY_POINT_GROUP = "c3_matcher.plugins"


@dataclass(frozen=True, slots=True)
class PluginSource:
    """An entry point and the distribution that ships it."""

    name: str
    distribution: str
    version: str
    entry_point: importlib_metadata.EntryPoint | None = None
    module: types.ModuleType | object | None = None  # pre-imported (tests, in-tree registration)


@dataclass(frozen=True, slots=True)
class LoadedPlugin:
    name: str
    distribution: str
    version: str
    strategies: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class IgnoredPlugin:
    name: str
    distribution: str
    reason: str


@dataclass
class _Registry:
    strategies: dict[str, tuple[StrategySpec, LoadedPlugin]] = field(default_factory=dict)
    duplicates: dict[str, DuplicateStrategyError] = field(default_factory=dict)


def discover(
    distributions: Iterable[importlib_metadata.Distribution] | None = None,
) -> list[PluginSource]:
    """Entry points of the plugin group, one per (distribution, name), in a stable order."""
    dists = importlib_metadata.distributions() if distributions is None else distributions
    sources: dict[tuple[str, str], PluginSource] = {}
    for dist in dists:
        dist_name = dist.metadata["Name"]
        if dist_name is None:
            continue
        for ep in dist.entry_points:
            if ep.group == ENTRY_POINT_GROUP:
                sources.setdefault(
                    (dist_name.lower(), ep.name),
                    PluginSource(ep.name, dist_name, dist.version or "?", ep),
                )
    return [sources[key] for key in sorted(sources)]


class PluginHost:
    """Loads the plugins the profile allows and offers typed access to their hooks."""

    def __init__(self, profile: BuildProfile, sources: Sequence[PluginSource]) -> None:
        self._profile = profile
        self._pm = pluggy.PluginManager(hookspecs.PROJECT_NAME)
        self._pm.add_hookspecs(hookspecs)
        self._loaded: list[LoadedPlugin] = []
        self._ignored: list[IgnoredPlugin] = []
        self._errors: list[PluginLoadError] = []
        self._refused: dict[str, str] = {}  # strategy -> why the strict profile refuses it
        self._registry = _Registry()
        for source in sources:
            self._load(source)

    # -- loading ------------------------------------------------------------------------------
    def _load(self, source: PluginSource) -> None:
        if not self._profile.allows_distribution(source.distribution):
            self._ignored.append(
                IgnoredPlugin(
                    source.name,
                    source.distribution,
                    f"not linked by profile {self._profile.name!r} (strict profile)",
                )
            )
            return
        try:
            module = source.module if source.module is not None else _load_entry_point(source)
            self._pm.register(module, name=f"{source.distribution}:{source.name}")
            self._pm.check_pending()
            _check_implements_a_hook(self._pm, module)
            specs = self._strategies_of(module)
        except Exception as exc:
            plugin_name = f"{source.distribution}:{source.name}"
            if self._pm.has_plugin(plugin_name):
                self._pm.unregister(name=plugin_name)
            self._errors.append(PluginLoadError(source.name, source.distribution, exc))
            return
        specs = [spec for spec in specs if self._offered(spec, source)]
        loaded = LoadedPlugin(
            source.name, source.distribution, source.version, tuple(spec.name for spec in specs)
        )
        self._loaded.append(loaded)
        for spec in specs:
            self._add_strategy(spec, loaded)

    def _offered(self, spec: StrategySpec, source: PluginSource) -> bool:
        """Whether the profile offers ``spec`` from ``source``; a refusal is kept for
        ``resolve`` and listed with the ignored plugins."""
        refusal = self._profile.refuses_strategy(
            spec.name, spec.build_flag, source.distribution, baseline=spec.baseline
        )
        if refusal is None:
            return True
        self._refused[spec.name] = refusal
        self._ignored.append(
            IgnoredPlugin(f"{source.name}:{spec.name}", source.distribution, refusal)
        )
        return False

    def _strategies_of(self, module: object) -> list[StrategySpec]:
        impl = getattr(module, "c3_matcher_strategies", None)
        returned = impl() if callable(impl) else []
        if not isinstance(returned, list | tuple):
            raise TypeError(
                f"c3_matcher_strategies returned {type(returned).__name__}, expected a list "
                "of StrategySpec (return [StrategySpec(...)])"
            )
        for spec in returned:
            if not isinstance(spec, StrategySpec):
                raise TypeError(
                    f"c3_matcher_strategies returned {type(spec).__name__}, expected StrategySpec"
                )
        return list(returned)

    def _add_strategy(self, spec: StrategySpec, plugin: LoadedPlugin) -> None:
        if spec.name in self._registry.duplicates:
            dup = self._registry.duplicates[spec.name]
            self._registry.duplicates[spec.name] = DuplicateStrategyError(
                spec.name, [*dup.distributions, plugin.distribution]
            )
            return
        if spec.name in self._registry.strategies:
            _, first = self._registry.strategies.pop(spec.name)
            self._registry.duplicates[spec.name] = DuplicateStrategyError(
                spec.name, [first.distribution, plugin.distribution]
            )
            return
        self._registry.strategies[spec.name] = (spec, plugin)

    # -- typed access -------------------------------------------------------------------------
    @property
    def profile(self) -> BuildProfile:
        return self._profile

    @property
    def loaded(self) -> tuple[LoadedPlugin, ...]:
        return tuple(self._loaded)

    @property
    def ignored(self) -> tuple[IgnoredPlugin, ...]:
        return tuple(self._ignored)

    @property
    def errors(self) -> tuple[PluginLoadError | DuplicateStrategyError, ...]:
        return (*self._errors, *self._registry.duplicates.values())

    def strategies(self) -> dict[str, StrategySpec]:
        """Selectable strategies (loaded, not duplicated), by name, sorted."""
        return {
            name: self._registry.strategies[name][0] for name in sorted(self._registry.strategies)
        }

    def strategy_plugin(self, name: str) -> LoadedPlugin:
        return self._registry.strategies[name][1]

    def engine_specs(self) -> list[EngineSpec]:
        """Every engine the loaded plugins declare (plugin registration order)."""
        specs: list[EngineSpec] = []
        for batch in reversed(self._pm.hook.c3_matcher_engine_specs()):
            specs.extend(batch)
        return specs

    def register_commands(self, commands: CommandRegistry) -> None:
        """Let every loaded plugin add its commands (registration order)."""
        for impl in reversed(self._pm.hook.c3_matcher_register_commands.get_hookimpls()):
            impl.function(commands=commands)

    def reference_backend(self, strategy: str, settings: C3Settings) -> FeatureBackend | None:
        """The PyTorch reference of ``strategy`` from its plugin (build environment only)."""
        result: FeatureBackend | None = self._pm.hook.c3_matcher_reference_backend(
            strategy=strategy, settings=settings
        )
        return result

    def resolve(self, strategy: str) -> StrategySpec:
        """The spec of ``strategy``, or the error that says why it cannot be used here."""
        if strategy in self._registry.duplicates:
            raise self._registry.duplicates[strategy]
        row = self._profile.flag_for_strategy(strategy)
        found = self._registry.strategies.get(strategy)
        profile = self._profile.name
        if row is not None and row.state is not FlagState.ON:
            if row.state is FlagState.WIRED:
                fix = (
                    f"{strategy} has its flag wired but is not linked in the {profile} build "
                    "(Tier-2 follow-up); use a research or replay-cli build: "
                    "pip install 'c3-matcher[research]'"
                )
            else:
                fix = (
                    "install a profile that links it: pip install 'c3-matcher[research]' "
                    "(or [replay-cli])"
                )
            raise StrategyNotLinkedError(strategy, row.flag, profile, fix)
        if found is not None:
            return found[0]
        if strategy in self._refused:
            fix = f"{self._refused[strategy]}; it runs in a research or replay-cli build"
            raise StrategyNotLinkedError(strategy, row.flag if row else None, profile, fix)
        if row is not None:  # ON in the profile but its plugin is missing or failed to load
            failed = [e for e in self._errors if _norm(e.distribution) == _norm(row.distribution)]
            detail = f" (it failed to load: {failed[0]})" if failed else ""
            raise StrategyNotLinkedError(
                strategy,
                row.flag,
                profile,
                f"install {row.distribution}{detail}, or reinstall 'c3-matcher[{profile}]'",
            )
        if self._ignored:
            ignored = ", ".join(sorted({p.distribution for p in self._ignored}))
            raise StrategyNotLinkedError(
                strategy,
                None,
                profile,
                f"profile {profile!r} loads only the plugins it links (ignored: {ignored}); "
                "a third-party strategy runs in a research or replay-cli build",
            )
        broken = [str(e) for e in self._errors]  # the strategy may be a plugin's that failed
        raise UnknownStrategyError(strategy, sorted(self._registry.strategies), broken)


def _check_implements_a_hook(pm: pluggy.PluginManager, module: object) -> None:
    """``TypeError`` when ``module`` implements no hook, or defines one without ``@hookimpl``:
    an entry point aimed at the wrong module would otherwise load nothing, and an unmarked hook
    be passed over, silently."""
    unmarked = sorted(
        name
        for name in vars(pm.hook)
        if callable(getattr(module, name, None)) and pm.parse_hookimpl_opts(module, name) is None
    )
    if unmarked:
        raise TypeError(
            f"{', '.join(unmarked)} not marked as a hook: decorate each with "
            "@c3_matcher.plugins.hookimpl"
        )
    if not pm.get_hookcallers(module):
        name = getattr(module, "__name__", type(module).__name__)
        raise TypeError(
            f"{name} implements no c3_matcher hook (is the entry point aimed at the module "
            "holding the @hookimpl functions?)"
        )


def _norm(name: str) -> str:
    return name.lower().replace("_", "-")


def _load_entry_point(source: PluginSource) -> object:
    if source.entry_point is None:
        raise ValueError("no entry point and no module")
    return source.entry_point.load()
