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
    describe,
)
from c3_matcher.plugins import hookspecs
from c3_matcher.plugins.distributions import entry_points_in, field_of, location_of
from c3_matcher.plugins.isolation import CommandRecorder, call_one, checked_list, is_failure
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
    """An entry point and the distribution that ships it; ``problem``: why it cannot be loaded
    (its distribution's metadata is incomplete), listed as its load error."""

    name: str
    distribution: str
    version: str
    entry_point: importlib_metadata.EntryPoint | None = None
    module: types.ModuleType | object | None = None  # pre-imported (tests, in-tree registration)
    problem: str | None = None


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
    engines: dict[str, list[EngineSpec]] = field(default_factory=dict)  # by plugin, load order
    left_out: dict[str, PluginLoadError] = field(default_factory=dict)  # strategy -> why


def discover(
    distributions: Iterable[importlib_metadata.Distribution] | None = None,
) -> list[PluginSource]:
    """Entry points of the plugin group, one per (distribution, name), in a stable order. A
    distribution whose metadata lacks its Name or Version is passed over if it declares no
    plugin, else its plugins come with that ``problem`` (its folder names it when its Name is
    missing)."""
    dists = importlib_metadata.distributions() if distributions is None else distributions
    sources: dict[tuple[str, str], PluginSource] = {}
    for dist in dists:
        entry_points = entry_points_in(dist, ENTRY_POINT_GROUP)
        if not entry_points:
            continue
        name, version = field_of(dist, "Name"), field_of(dist, "Version")
        problem = None
        if name is None or version is None:
            missing = "Name" if name is None else "Version"
            problem = f"its metadata ({location_of(dist)}) has no readable {missing}; reinstall it"
        label = name or location_of(dist)
        for ep in entry_points:
            source = PluginSource(ep.name, label, version or "?", ep, problem=problem)
            sources.setdefault((label.lower(), ep.name), source)
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
        if source.problem is not None:
            self._errors.append(PluginLoadError(source.name, source.distribution, source.problem))
            return
        if not self._profile.allows_distribution(source.distribution):
            self._ignored.append(
                IgnoredPlugin(
                    source.name,
                    source.distribution,
                    f"not linked by profile {self._profile.name!r} (strict profile)",
                )
            )
            return
        plugin_name = f"{source.distribution}:{source.name}"
        specs: list[StrategySpec] = []
        hook = None  # the hook being asked, once the module is in
        try:  # SystemExit too (a module calling sys.exit as it is imported), not Ctrl-C
            module = source.module if source.module is not None else _load_entry_point(source)
            self._pm.register(module, name=plugin_name)
            self._pm.check_pending()
            _check_implements_a_hook(self._pm, module)
            specs = self._strategies_of(module)
            hook = "c3_matcher_engine_specs"  # asked now: its failure is listed as it loads
            self._registry.engines[plugin_name] = self._engine_specs_of(plugin_name)
        except BaseException as exc:
            if not is_failure(exc):
                raise
            self._unregister(plugin_name)
            cause = exc if hook is None else f"{hook}: {describe(exc)}"
            error = PluginLoadError(source.name, source.distribution, cause)
            self._errors.append(error)
            self._registry.left_out.update(dict.fromkeys((s.name for s in specs), error))
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
        return checked_list(returned, "c3_matcher_strategies", StrategySpec)

    def _engine_specs_of(self, plugin_name: str) -> list[EngineSpec]:
        """The engines the plugin declares, asked once as it loads: a hook that fails is its
        load error, not a failure of every strategy's start-up later."""
        from c3_matcher.engines.spec import EngineSpec

        hook = "c3_matcher_engine_specs"
        batches = reversed(call_one(self._pm, plugin_name, hook))
        return [spec for batch in batches for spec in checked_list(batch, hook, EngineSpec)]

    def _unregister(self, plugin_name: str) -> None:
        if self._pm.has_plugin(plugin_name):
            self._pm.unregister(name=plugin_name)

    def _leave_out(self, plugin_name: str, exc: BaseException, hook: str) -> PluginLoadError:
        """Unregister a loaded plugin whose ``hook`` failed: its strategies and engines go, and
        selecting one of its strategies is refused with the returned error (listed too)."""
        plugin = next(p for p in self._loaded if f"{p.distribution}:{p.name}" == plugin_name)
        error = PluginLoadError(plugin.name, plugin.distribution, f"{hook}: {describe(exc)}")
        self._unregister(plugin_name)
        self._loaded.remove(plugin)
        self._errors.append(error)
        self._registry.engines.pop(plugin_name, None)
        for name in plugin.strategies:
            self._registry.left_out[name] = error
            owned = self._registry.strategies.get(name)
            if owned is not None and owned[1] is plugin:
                del self._registry.strategies[name]
        return error

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
        return [spec for specs in self._registry.engines.values() for spec in specs]

    def strategy_engine_specs(self, name: str) -> list[EngineSpec]:
        """The engines the plugin of strategy ``name`` declares (its keypoint budget's top-K)."""
        plugin = self.strategy_plugin(name)
        return list(self._registry.engines.get(f"{plugin.distribution}:{plugin.name}", ()))

    def register_commands(self, commands: CommandRegistry) -> None:
        """Let every loaded plugin add its commands, one plugin at a time: one whose hook fails
        is left out (``_leave_out``), the commands it added refuse with the reason."""
        hook = "c3_matcher_register_commands"
        impls = self._pm.hook.c3_matcher_register_commands.get_hookimpls()
        for plugin_name in dict.fromkeys(impl.plugin_name for impl in reversed(impls)):
            recorder = CommandRecorder(commands)
            try:
                call_one(self._pm, plugin_name, hook, commands=recorder)
            except BaseException as exc:
                if not is_failure(exc):
                    raise
                recorder.refuse(self._leave_out(plugin_name, exc, hook))

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
        if strategy in self._registry.left_out and row is None:
            error = self._registry.left_out[strategy]
            fix = f"its plugin was left out, fix or uninstall {error.distribution}: {error}"
            raise StrategyNotLinkedError(strategy, None, profile, fix)
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
