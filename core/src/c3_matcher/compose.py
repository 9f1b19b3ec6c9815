"""The composition root.

``compose_root(config, pre_constructed)`` wires the ``c3_matcher`` slot: it checks the required
pre-constructed shared helpers, builds what may be defaulted (clock, durable FDR recorder),
adds its logging sinks (and removes only those on ``close()``), discovers the plugins the
installed profile allows, selects the configured strategy, creates it (engines load now, at
start-up) and runs the start-up engine probe on its feature backend, whatever the plugin.
It never silently builds a required helper: ``build_default_helpers(settings)`` does that,
explicitly, for callers that do not bring their own (the CLI, tests, integrators).
"""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher import keypoint_budget as budgets
from c3_matcher import protocols, unread_settings
from c3_matcher.config import C3Settings, FdrSettings, with_strategy_defaults
from c3_matcher.errors import (
    AirborneBootstrapError,
    C3Error,
    StrategyNotLinkedError,
    StrategyStartupError,
    describe,
)
from c3_matcher.fdr import JsonlFdrRecorder
from c3_matcher.health import MonotonicClock, RollingHealthWindow, SteadyClock, clock_problem
from c3_matcher.logs import (
    MATCHER_READY,
    LoggingHandle,
    configure_logging,
    log_event,
    logging_as,
)
from c3_matcher.pipeline import PipelineMatcher
from c3_matcher.plugins.manager import PluginHost, discover
from c3_matcher.plugins.types import StrategyDefaults
from c3_matcher.probe import check_members
from c3_matcher.profiles import installed_profile
from c3_matcher.protocols import (
    Clock,
    ClosableMatcher,
    CrossDomainMatcher,
    FdrClient,
    FeatureBackend,
)
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.stages.extract import backend_budget
from c3_matcher.strategy import DEFAULT_MAX_KEYPOINTS, engine_startup_probe
from c3_matcher.strategy_options import check_options_tables, strategy_options

__all__ = [
    "AIRBORNE_REQUIRED_PRE_CONSTRUCTED_KEYS",
    "OPTIONAL_PRE_CONSTRUCTED_KEYS",
    "ComposedRoot",
    "build_default_helpers",
    "build_plugin_host",
    "check_inliers_reachable",
    "check_strategy_budget",
    "compose_root",
    "open_recorder",
    "state_default_fdr_path",
    "strategy_settings",
]

CONSUMER = "c3_matcher"
AIRBORNE_REQUIRED_PRE_CONSTRUCTED_KEYS: Mapping[str, tuple[str, ...]] = {
    CONSUMER: ("c3_lightglue_runtime", "c282_ransac_filter", "c7_inference"),
}
OPTIONAL_PRE_CONSTRUCTED_KEYS = ("clock", "c13_fdr")
_KEY_TYPES: Mapping[str, type] = {
    "c3_lightglue_runtime": protocols.LightGlueRuntime,
    "c282_ransac_filter": protocols.RansacFilter,
    "c7_inference": protocols.InferenceRuntime,
    "clock": Clock,
    "c13_fdr": FdrClient,
}


@dataclass(frozen=True)
class ComposedRoot:
    """What ``compose_root`` wired. ``close()`` closes the matcher (a frame in progress in
    another thread finishes first; a later ``match`` raises ``MatcherClosedError``), then
    releases the logging sinks and the recorder it built. Idempotent. What it logs, composing,
    matching and closing, is its own: another root's sinks take none of it
    (``c3_matcher.logs``)."""

    matcher: CrossDomainMatcher
    strategy: str
    health_window: RollingHealthWindow
    fdr: FdrClient
    clock: Clock
    plugin_host: PluginHost
    helpers: Mapping[str, Any]
    logging: LoggingHandle | None
    owned_fdr: JsonlFdrRecorder | None = None  # the recorder it built (no ``c13_fdr`` given)

    def close(self) -> None:
        with logging_as(self.logging):
            if isinstance(self.matcher, ClosableMatcher):  # a strategy's own matcher may not be
                self.matcher.close()
            if self.logging is not None:
                self.logging.close()
            if self.owned_fdr is not None:
                self.owned_fdr.close()


def build_plugin_host() -> PluginHost:
    """The plugin host of this environment: its installed profile and plugin entry points."""
    return PluginHost(installed_profile(), discover())


def build_default_helpers(
    settings: C3Settings,
    providers_available: tuple[str, ...] | None = None,
    *,
    plugin_host: PluginHost | None = None,
) -> dict[str, Any]:
    """The default shared helpers (``c3_lightglue_runtime``, ``c282_ransac_filter``,
    ``c7_inference``) built from configuration: ONNX Runtime and OpenCV USAC. The LightGlue
    runtime's filter threshold (``[lightglue] filter_threshold``) and the RANSAC filter's final
    refit (``[matcher] refit_threshold_px``, never below ``min_inliers_threshold``) are the
    configured strategy's own defaults where the configuration leaves them unset
    (``strategy_settings``: the helpers serve the one strategy ``compose_root`` wires); the
    feature types with a steps engine are those the plugins' engine specs declare
    (``steps_specs``); ``[lightglue] mode = "auto"`` is settled by the LightGlue runtime from the
    provider its sessions actually get. ``plugin_host``: the process's (default: discovered
    now)."""
    from c3_matcher.engines.lightglue import OnnxLightGlueRuntime
    from c3_matcher.engines.lightglue_specs import steps_specs
    from c3_matcher.engines.runtime import OnnxInferenceRuntime
    from c3_matcher.logs import swap_default_handler

    swap_default_handler()  # the helpers log before compose_root sets the JSON sink up
    host = plugin_host if plugin_host is not None else build_plugin_host()
    resolved = strategy_settings(settings, plugin_host=host)
    threshold = resolved.lightglue.filter_threshold
    assert threshold is not None  # resolved: the configuration's or the strategy's own
    inference = OnnxInferenceRuntime.from_settings(settings.engines, providers_available)
    return {
        "c7_inference": inference,
        "c3_lightglue_runtime": OnnxLightGlueRuntime(
            inference,
            mode=settings.lightglue.mode,  # "auto": from the provider the sessions run on
            filter_threshold=threshold,
            depth_confidence=settings.lightglue.depth_confidence,
            width_confidence=settings.lightglue.width_confidence,
            exit_matches=resolved.lightglue.exit_matches or 0,
            steps_specs=steps_specs(host.engine_specs()),
        ),
        "c282_ransac_filter": OpenCvRansacFilter(
            seed=settings.matcher.ransac_seed,
            refit_px=resolved.matcher.refit_threshold_px or 0.0,
            refit_floor=settings.matcher.min_inliers_threshold,
        ),
    }


def strategy_settings(
    settings: C3Settings, strategy: str | None = None, plugin_host: PluginHost | None = None
) -> C3Settings:
    """``settings`` for ``strategy`` (default: ``[matcher] strategy``, which is set to it): the
    settings the configuration leaves unset take that strategy's own defaults
    (``StrategySpec.defaults``); a strategy this environment does not offer gets upstream's
    (``StrategyDefaults()``), and composing it fails later with its own error."""
    name = strategy or settings.matcher.strategy
    if name != settings.matcher.strategy:
        settings = settings.model_copy(
            update={"matcher": settings.matcher.model_copy(update={"strategy": name})}
        )
    host = plugin_host if plugin_host is not None else build_plugin_host()
    try:
        defaults = host.resolve(name).defaults
    except Exception:  # not linked / not installed: compose_root raises its own error
        defaults = StrategyDefaults()
    return with_strategy_defaults(settings, defaults, name)


def open_recorder(
    fdr: FdrSettings, clock: Clock, *, path: Path | None = None, fresh: bool = False
) -> JsonlFdrRecorder:
    """The durable recorder of ``[fdr]`` at its ``path`` (or ``path``), rotating and holding
    records on a full disk within its limits; ``fresh`` starts a new log (a ground run's)."""
    return JsonlFdrRecorder(
        path or fdr.path,
        clock,
        max_bytes=fdr.max_bytes,
        max_pending_bytes=fdr.max_pending_bytes,
        fresh=fresh,
    )


def state_default_fdr_path(config: C3Settings) -> None:
    """Log (INFO ``c3.fdr.default_path``) where the recorder writes when ``[fdr] path`` was not
    set by a file, the environment or the caller: the user's data directory, which nobody
    chose explicitly."""
    if "path" not in config.fdr.model_fields_set:
        log_event(
            "INFO",
            "c3.fdr.default_path",
            f"flight data recorder writing to {config.fdr.path} (the default [fdr] path; set "
            "[fdr] path, C3_MATCHER_FDR__PATH or pass c13_fdr to change it)",
            path=str(config.fdr.path),
        )


def compose_root(
    config: C3Settings,
    pre_constructed: Mapping[str, Any] | None = None,
    *,
    plugin_host: PluginHost | None = None,
    configure_logs: bool = True,
) -> ComposedRoot:
    """Wire the ``c3_matcher`` slot; raise ``AirborneBootstrapError`` for a missing key,
    ``StrategyNotLinkedError`` for a strategy the build does not link."""
    helpers = _checked_helpers(pre_constructed)
    clock: Clock = SteadyClock.of(helpers.get("clock") or MonotonicClock())  # one for all
    with ExitStack() as opened:  # given back at once if composition fails, else by close()
        owned_fdr: JsonlFdrRecorder | None = None  # a given c13_fdr stays the caller's
        if "c13_fdr" not in helpers:
            owned_fdr = open_recorder(config.fdr, clock)
            opened.callback(owned_fdr.close)
        fdr: FdrClient = helpers["c13_fdr"] if owned_fdr is None else owned_fdr
        handle = None
        if configure_logs:
            handle = configure_logging(fdr, level=config.logging.level)
            opened.callback(handle.close)
        with logging_as(handle):  # its records, its matcher's frames' too, are its own
            if owned_fdr is not None:
                state_default_fdr_path(config)
            _log_provider_request(helpers["c7_inference"])
            host = plugin_host if plugin_host is not None else build_plugin_host()
            matcher, health = _create_strategy(config, helpers, host, fdr, clock)
        opened.pop_all()
    name = config.matcher.strategy
    return ComposedRoot(matcher, name, health, fdr, clock, host, helpers, handle, owned_fdr)


def _log_provider_request(inference: object) -> None:
    """The shared ONNX Runtime's provider request (made by ``build_default_helpers``), logged."""
    from c3_matcher.engines.runtime import OnnxInferenceRuntime

    if isinstance(inference, OnnxInferenceRuntime):
        inference.log_selection()


def _create_strategy(
    config: C3Settings,
    helpers: Mapping[str, Any],
    host: PluginHost,
    fdr: FdrClient,
    clock: Clock,
) -> tuple[CrossDomainMatcher, RollingHealthWindow]:
    """The configured strategy: its settings composed once, then created (engines load), probed."""
    for error in host.errors:
        log_event("ERROR", "c3.plugins.load_error", str(error), error=str(error))
    name = config.matcher.strategy
    spec = host.resolve(name)
    check_options_tables(config, host)
    options = strategy_options(config, name, spec.options_model)
    plugin = host.strategy_plugin(name).distribution
    try:  # what the user set, before defaults, that the strategy does not read
        unread_settings.say_unread(config, spec, options, host)
    except Exception as exc:  # its options' own method failed: the plugin's fault, named
        raise StrategyStartupError(name, plugin, describe(exc)) from exc
    config = with_strategy_defaults(config, spec.defaults, name)
    health = RollingHealthWindow(clock, config.matcher.min_inliers_threshold)
    try:
        matcher = spec.factory(
            config=config,
            options=options,
            inference_runtime=helpers["c7_inference"],
            lightglue_runtime=helpers["c3_lightglue_runtime"],
            ransac_filter=helpers["c282_ransac_filter"],
            health_window=health,
            fdr_client=fdr,
            clock=clock,
        )
    except C3Error:
        raise  # says itself what is wrong (an engine, an option)
    except Exception as exc:
        raise StrategyStartupError(name, plugin, describe(exc)) from exc
    if not isinstance(matcher, CrossDomainMatcher):
        kind = type(matcher).__name__
        raise StrategyStartupError(name, plugin, f"its factory returned {kind}, not a matcher")
    provider = helpers["c7_inference"].provider
    if isinstance(matcher, PipelineMatcher):  # every strategy on the shared pipeline
        matcher.record_as(name)  # not its backend's label: one backend may serve two strategies
        try:
            check_members(matcher.backend)
        except TypeError as exc:  # a member forgotten fails here, not on the first frame
            raise StrategyStartupError(name, plugin, str(exc)) from None
        check_inliers_reachable(config, matcher.backend)
        engine_startup_probe(matcher.backend)
        provider = str(matcher.provenance().get("provider", provider))  # never raises
    _log_ready(config, host, provider)
    return matcher, health


def check_inliers_reachable(config: C3Settings, backend: FeatureBackend) -> None:
    """``keypoint_budget.check_inliers_reachable`` against the keypoints per image the backend
    keeps (:func:`~c3_matcher.stages.extract.backend_budget`: its ``max_keypoints``, after any
    cut to its extractor engine's top-K); a backend that declares none is not checked."""
    budget = backend_budget(backend)
    if budget is not None:
        budgets.check_inliers_reachable(config, budget)


def check_strategy_budget(settings: C3Settings, host: PluginHost) -> None:
    """Start-up's keypoint-budget checks of the configured strategy, no engine loaded
    (``c3-matcher config``: ``keypoint_budget.check_declared_budget``, the same messages); a
    strategy this build does not link is passed over, one no plugin knows refused."""
    name = settings.matcher.strategy
    try:
        spec = host.resolve(name)
    except StrategyNotLinkedError:
        return
    config = with_strategy_defaults(settings, spec.defaults, name)
    options = strategy_options(config, name, spec.options_model)
    engines = host.strategy_engine_specs(name)
    budgets.check_declared_budget(config, options, engines, DEFAULT_MAX_KEYPOINTS)


def _checked_helpers(pre_constructed: Mapping[str, Any] | None) -> dict[str, Any]:
    """The pre-constructed helpers, every required key present and every known key of its
    protocol (``AirborneBootstrapError`` naming the key otherwise)."""
    helpers = dict(pre_constructed or {})
    for key in AIRBORNE_REQUIRED_PRE_CONSTRUCTED_KEYS[CONSUMER]:
        if key not in helpers:
            raise AirborneBootstrapError(CONSUMER, key)
    for key, value in helpers.items():
        expected = _KEY_TYPES.get(key)
        if expected is not None and not isinstance(value, expected):
            raise AirborneBootstrapError(
                CONSUMER, key, f"expected a {expected.__name__}, got {type(value).__name__}"
            )
    if "clock" in helpers and (problem := clock_problem(helpers["clock"])) is not None:
        raise AirborneBootstrapError(CONSUMER, "clock", problem)
    return helpers


def _log_ready(config: C3Settings, host: PluginHost, provider: str) -> None:
    """``provider`` is what runs the strategy: its backend's own (``provenance()``), as in
    every result and flight-data record, else the inference runtime's."""
    name = config.matcher.strategy
    log_event(
        "INFO",
        MATCHER_READY,
        f"C3 ready: matcher={name}",
        strategy=name,
        min_inliers_threshold=config.matcher.min_inliers_threshold,
        residual_warn_threshold_px=config.matcher.residual_warn_threshold_px,
        profile=host.profile.name,
        provider=provider,
    )
