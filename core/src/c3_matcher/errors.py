"""The matcher's errors: one base class, each error carrying the facts a caller needs to act.

``MatcherBackboneError`` and ``InsufficientInliersError`` are the two errors of the
``CrossDomainMatcher.match`` contract. ``InvalidInputError`` (an argument of the wrong type) and
``MatcherClosedError`` (``match`` after ``close()``) are a caller's programming errors. The
others are start-up and configuration errors raised before the first frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = [
    "AirborneBootstrapError",
    "AmbiguousMatchError",
    "C3Error",
    "ConfigurationError",
    "DuplicateStrategyError",
    "EngineError",
    "InsufficientInliersError",
    "InvalidInputError",
    "MatcherBackboneError",
    "MatcherClosedError",
    "OutputStreamError",
    "PluginLoadError",
    "ProfileError",
    "StrategyNotLinkedError",
    "StrategyStartupError",
    "UnknownStrategyError",
    "describe",
    "refused_words",
]


def describe(exc: BaseException) -> str:
    """``"TypeName: message"`` of an exception, also of one whose message cannot be read (a
    plugin's or a tile handle's ``__str__`` that raises): telling of a failure must never be
    what fails."""
    try:
        message = str(exc)
    except Exception as failure:
        message = f"<its message could not be read: {type(failure).__name__}>"
    return f"{type(exc).__name__}: {message}"


class C3Error(Exception):
    """Base class of every error raised by c3-matcher."""


class InvalidInputError(C3Error, ValueError):
    """A DTO or argument failed validation; ``field`` names it, ``reason`` says why."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}")


class MatcherBackboneError(C3Error):
    """A backbone stage (decode, preprocess, extract, match) failed.

    Per candidate it is caught by the pipeline (drop-and-continue); for the query frame
    itself (``phase="query_extract"``) it propagates to the caller.
    """

    def __init__(self, phase: str, tile_id: object | None, cause: BaseException | str) -> None:
        self.phase = phase
        self.tile_id = tile_id
        self.cause = cause
        where = "query frame" if tile_id is None else f"tile {tile_id}"
        detail = cause if isinstance(cause, str) else describe(cause)
        super().__init__(f"backbone failure in phase {phase!r} on {where}: {detail}")


class InsufficientInliersError(C3Error):
    """No candidate reached ``min_inliers_threshold`` RANSAC inliers (or every one was dropped).

    The caller (C5) falls back to VIO-only with provenance ``visual_propagated``.
    ``geometry_refused``: (RANSAC inliers, reason) of each candidate the geometric prior refused
    whatever its inliers (its attitude disagreed: a heading error past ``[matcher]
    prior_rotation_tol_deg`` refuses the true tile too), most inliers first; the message names
    the first, so that "best inlier count 0" is not read as "nothing matched".
    """

    def __init__(
        self,
        frame_id: object,
        best_inlier_count: int,
        threshold: int,
        candidates_input: int,
        candidates_dropped: int,
        matcher_label: str,
        geometry_refused: tuple[tuple[int, str], ...] = (),
    ) -> None:
        self.frame_id = frame_id
        self.best_inlier_count = best_inlier_count
        self.threshold = threshold
        self.candidates_input = candidates_input
        self.candidates_dropped = candidates_dropped
        self.matcher_label = matcher_label
        self.geometry_refused = tuple(sorted(geometry_refused, key=lambda r: -r[0]))
        super().__init__(
            f"frame {frame_id}: best inlier count {best_inlier_count} < threshold {threshold} "
            f"({candidates_dropped} of {candidates_input} candidates dropped"
            f"{refused_words(self.geometry_refused)}; backbone={matcher_label})"
        )


class AmbiguousMatchError(InsufficientInliersError):
    """Candidates with enough inliers that place the frame in different places
    (:mod:`c3_matcher.stages.ambiguity`): texture repeating at one orientation and scale
    matches a tile of another place as well as the true one, so no fix is given.
    ``ambiguity`` says which candidates and how far apart. An ``InsufficientInliersError``: the
    caller (C5) falls back to VIO-only as for any frame without a fix."""

    def __init__(self, *facts: Any, ambiguity: str) -> None:
        """``facts``: :class:`InsufficientInliersError`'s, without ``geometry_refused``."""
        super().__init__(*facts)
        self.ambiguity = ambiguity
        self.args = (
            f"frame {self.frame_id}: ambiguous: {ambiguity} (backbone={self.matcher_label})",
        )


def refused_words(refused: tuple[tuple[int, str], ...]) -> str:
    """``geometry_refused`` (most inliers first) in words for a message; empty when none."""
    if not refused:
        return ""
    inliers, reason = refused[0]
    return (
        f", {len(refused)} of them refused on geometry whatever their inliers, the most "
        f"{inliers} inliers: {reason}"
    )


class MatcherClosedError(C3Error, RuntimeError):
    """``match`` was called on a matcher after ``close()`` (``ComposedRoot.close()`` closes it):
    its flight data recorder and log sinks are released, so a frame matched now would leave no
    record; or (``reason`` given) on a copy of one in a forked child process, whose recorder is
    its parent's. A caller's lifecycle error: the call's one health update (no fix) is its only
    trace."""

    def __init__(self, matcher_label: str, reason: str | None = None) -> None:
        self.matcher_label = matcher_label
        super().__init__(
            f"matcher {matcher_label!r} cannot match here: {reason}"
            if reason is not None
            else f"matcher {matcher_label!r} is closed: match() was called after close() (the "
            "recorder and log sinks it wrote to are released); compose a new root to match again"
        )


class StrategyNotLinkedError(C3Error):
    """The selected strategy is not linked into the running build (profile)."""

    def __init__(self, strategy: str, flag: str | None, profile: str, fix: str) -> None:
        self.strategy = strategy
        self.flag = flag
        self.profile = profile
        self.fix = fix
        flag_text = f"{flag} is OFF" if flag else "it has no BUILD_MATCHER_* flag"
        super().__init__(
            f"strategy {strategy!r} is not linked in profile {profile!r} ({flag_text} or its "
            f"plugin is not installed); fix: {fix}"
        )


class UnknownStrategyError(C3Error):
    """A strategy name matches no flag and no installed plugin; ``failed`` names the plugins
    that failed to load (the strategy may be theirs)."""

    def __init__(self, strategy: str, known: Sequence[str], failed: Sequence[str] = ()) -> None:
        self.strategy = strategy
        self.known = tuple(known)
        choose = f", choose one of: {', '.join(self.known)}" if self.known else ""
        none = "" if self.known else ": no strategy is installed"
        more = ""
        if failed:
            more = (
                " (a plugin failed to load, fix it and check with `c3-matcher plugins`: "
                + "; ".join(" ".join(f.split()) for f in failed)
                + ")"
            )
        super().__init__(f"strategy {strategy!r} is not recognized{choose}{none}{more}")


class StrategyStartupError(C3Error):
    """A strategy's plugin failed to create its matcher at start-up (its factory raised, or
    returned something else than a matcher): the plugin's fault, named with its distribution."""

    def __init__(self, strategy: str, distribution: str, detail: str) -> None:
        self.strategy = strategy
        self.distribution = distribution
        super().__init__(
            f"strategy {strategy!r} (distribution {distribution}) failed to start: {detail}"
        )


class AirborneBootstrapError(C3Error):
    """``compose_root`` is missing a required pre-constructed key for a consumer slot."""

    def __init__(self, consumer: str, key: str, detail: str = "") -> None:
        self.consumer = consumer
        self.key = key
        extra = f": {detail}" if detail else ""
        super().__init__(
            f"consumer {consumer!r} requires pre-constructed key {key!r}{extra} "
            "(build the defaults with c3_matcher.build_default_helpers(settings))"
        )


class PluginLoadError(C3Error):
    """A plugin entry point failed to import or to register."""

    def __init__(self, plugin: str, distribution: str, cause: BaseException | str) -> None:
        self.plugin = plugin
        self.distribution = distribution
        self.cause = cause
        detail = cause if isinstance(cause, str) else describe(cause)
        super().__init__(
            f'Error importing plugin "{plugin}" (distribution {distribution}): {detail}'
        )


class DuplicateStrategyError(C3Error):
    """Two plugins claim one strategy name."""

    def __init__(self, strategy: str, distributions: Sequence[str]) -> None:
        self.strategy = strategy
        self.distributions = tuple(distributions)
        super().__init__(
            f"strategy {strategy!r} is claimed by more than one distribution: "
            f"{', '.join(self.distributions)}"
        )


class OutputStreamError(C3Error):
    """A command's result could not be written to its stream (``stdout``): a full disk, a
    closed file. A reader that stopped (``BrokenPipeError``) is not this error."""

    def __init__(self, stream: str, cause: OSError) -> None:
        self.stream = stream
        self.cause = cause
        super().__init__(f"cannot write the result to {stream}: {cause.strerror or cause}")


class ProfileError(C3Error):
    """The installed build profile is missing, ambiguous or inconsistent."""


class ConfigurationError(C3Error):
    """The configuration was refused; ``problems`` lists (field, reason) pairs."""

    def __init__(self, source: str, problems: Sequence[tuple[str, str]]) -> None:
        self.source = source
        self.problems = tuple(problems)
        lines = "; ".join(f"{field}: {reason}" for field, reason in self.problems)
        super().__init__(f"invalid configuration ({source}): {lines}")


class EngineError(C3Error):
    """An engine is missing, unreadable or does not match its manifest (a start-up error)."""

    def __init__(
        self, path: object, reason: str, command: str | None = "c3-matcher engines build"
    ) -> None:
        self.path = path
        self.reason = reason
        self.command = command  # None: no build fixes it (a backend that runs no engine)
        fix = f"; build it with `{command}`" if command else ""
        super().__init__(f"engine {path}: {reason}{fix}")
