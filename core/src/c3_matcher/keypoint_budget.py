"""The settings a strategy's keypoint budget makes unreachable, checked in one place for
start-up and ``c3-matcher config`` alike.

A candidate has no more inliers than keypoints, and a LightGlue pair no more mutual matches, so
``[matcher] min_inliers_threshold`` or ``[lightglue] exit_matches`` above the keypoints per image
the strategy keeps would fail every frame. Start-up checks them against the budget its backend
keeps (``max_keypoints``); ``config`` against the budget the strategy declares without loading
an engine (``declared_budget``): its options' ``keypoint_budget`` where they have one, else
``[matcher] max_keypoints`` or the extractor strategies' default, cut to the top-K its
extractor engine specification declares. The message is the same text either way.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from c3_matcher.config import C3Settings
from c3_matcher.errors import ConfigurationError

if TYPE_CHECKING:
    from c3_matcher.engines.spec import EngineSpec

__all__ = [
    "KeypointBudgetOptions",
    "PairMatcherOptions",
    "check_declared_budget",
    "check_exit_reachable",
    "check_inliers_reachable",
    "declared_budget",
    "reads_lightglue",
]


@runtime_checkable
class KeypointBudgetOptions(Protocol):
    """A strategy's options that set its keypoint budget themselves (XFeat's): the budget
    from the options table, else ``[matcher] max_keypoints`` (None when unset), else theirs."""

    def keypoint_budget(self, matcher_max_keypoints: int | None) -> int: ...


@runtime_checkable
class PairMatcherOptions(Protocol):
    """A strategy's options that choose its pair matcher (XFeat's mnn or LighterGlue): whether
    the choice matches with LightGlue, so that ``[lightglue]`` settings concern it at all."""

    def matches_with_lightglue(self) -> bool: ...


def reads_lightglue(options: object, engines: Sequence[EngineSpec]) -> bool | None:
    """Whether a strategy matches its pairs with LightGlue, so that ``[lightglue]`` settings
    apply to it, as its plugin declares it: where its validated ``options`` choose the pair
    matcher (``PairMatcherOptions``), that choice; else whether its declared ``engines`` hold a
    LightGlue-family matcher (a spec with a ``feature_type``). None where it declares neither
    (a plugin that reuses another's engines, as the example DISK + LightGlue plugin does): not
    known, and it may read them. The one answer the budget checks, start-up's word on
    unread settings and a run's report all take."""
    if isinstance(options, PairMatcherOptions):
        return options.matches_with_lightglue()
    if engines:
        return any(spec.feature_type is not None for spec in engines)
    return None


def check_inliers_reachable(config: C3Settings, budget: int) -> None:
    """``ConfigurationError`` naming ``[matcher] min_inliers_threshold`` and the keypoint budget
    when the threshold is above ``budget``, the keypoints per image the strategy keeps: a
    candidate has no more inliers than keypoints, so every frame would fail."""
    m = config.matcher
    if m.min_inliers_threshold <= budget:
        return
    asked = "unset: the strategy's default" if m.max_keypoints is None else m.max_keypoints
    reason = (
        f"{m.min_inliers_threshold} exceeds the {budget} keypoints per image the strategy "
        "keeps: a candidate has no more inliers than keypoints, so every frame would fail; "
        f"lower it to at most {budget}, or raise the budget ([matcher] max_keypoints = {asked}; "
        "a strategy's options table may set its own; its extractor engine's top-K caps it)"
    )
    problem = ("matcher.min_inliers_threshold", reason)
    raise ConfigurationError(f"strategy {m.strategy}", [problem])


def check_exit_reachable(required: tuple[str, int] | None, budget: int, label: str) -> None:
    """``ConfigurationError`` when a setting stops every pair with fewer matches than it asks
    (``required``: ``(setting, count)``, LightGlue's unmatchable-pair exit) and that count is
    above ``budget``: no pair has more mutual matches than keypoints."""
    if required is None or required[1] <= budget:
        return
    setting, count = required
    raise ConfigurationError(
        f"strategy {label}",
        [
            (
                setting,
                f"{count} exceeds the {budget} keypoints per image the strategy keeps: no pair "
                "has more mutual matches than keypoints, so every pair would stop with no "
                f"match; set it to at most {budget}",
            )
        ],
    )


def declared_budget(
    config: C3Settings, options: object, engines: Sequence[EngineSpec], default: int
) -> int | None:
    """The keypoints per image the strategy keeps under ``config`` (its own defaults resolved)
    and its validated ``options``, known without an engine (``default``: the budget of an
    extractor strategy whose options set none, ``strategy.config.DEFAULT_MAX_KEYPOINTS``);
    None for a strategy without an extractor engine specification that its options do not
    budget either (a backend that applies its budget itself; start-up checks what it keeps)."""
    declared = (dict(spec.options).get("top_k") for spec in engines)
    top_ks = [k for k in declared if isinstance(k, int)]
    asked = config.matcher.max_keypoints
    if isinstance(options, KeypointBudgetOptions):
        asked = options.keypoint_budget(asked)
    elif top_ks:
        asked = asked or default
    else:
        return None
    return min(asked, max(top_ks)) if top_ks else asked


def check_declared_budget(
    config: C3Settings, options: object, engines: Sequence[EngineSpec], default: int
) -> None:
    """Start-up's budget checks without an engine (``c3-matcher config``): the inlier
    threshold, and where the strategy is declared to match with LightGlue (``reads_lightglue``)
    and ``[lightglue] mode`` may run adaptive, the unmatchable-pair exit."""
    budget = declared_budget(config, options, engines, default)
    if budget is None:
        return
    check_inliers_reachable(config, budget)
    exit_matches = config.lightglue.exit_matches or 0
    lightglue = reads_lightglue(options, engines) is True  # not known: not checked, as before
    if lightglue and config.lightglue.mode != "full" and exit_matches > 0:
        required = ("lightglue.exit_matches", exit_matches)
        check_exit_reachable(required, budget, config.matcher.strategy)
