"""Build profiles: which BUILD_MATCHER_* flags the installed build has.

A profile is a build-time fact. Each profile is a tiny distribution generated from
``buildflags/matrix.toml`` (``c3-matcher-profile-<name>``) that depends on the plugin
distributions its row links and publishes its row as data through the entry-point group
``c3_matcher.profile``. The core's extras (``c3-matcher[airborne]`` ...) each pull one of them.
Two profiles installed at once is an error; no profile means nothing is linked.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import importlib_metadata

from c3_matcher.errors import ProfileError
from c3_matcher.plugins.distributions import entry_points_in, field_of, location_of

__all__ = [
    "PROFILE_GROUP",
    "UNPROFILED",
    "BuildProfile",
    "FlagRow",
    "FlagState",
    "installed_profile",
]

PROFILE_GROUP = "c3_matcher.profile"


class FlagState(StrEnum):
    ON = "ON"  # strategy linked
    WIRED = "WIRED"  # flag wired, strategy not linked (airborne xfeat)
    OFF = "OFF"


@dataclass(frozen=True, slots=True)
class FlagRow:
    """One BUILD_MATCHER_* flag in one profile."""

    flag: str
    state: FlagState
    strategy: str
    distribution: str


@dataclass(frozen=True, slots=True)
class BuildProfile:
    """The installed profile: its name, its flags, and whether it loads only what it links.

    ``strict`` profiles (airborne, operator-tooling) load only the plugin distributions their
    flags link: a stray third-party entry point cannot change flight software.
    """

    name: str
    flags: tuple[FlagRow, ...]
    strict: bool
    distribution: str | None
    tools: str | None = None

    @classmethod
    def from_data(cls, data: Mapping[str, Any], distribution: str | None) -> BuildProfile:
        try:
            rows = tuple(
                FlagRow(flag, FlagState(row["state"]), row["strategy"], row["distribution"])
                for flag, row in data["flags"].items()
            )
            tools = data.get("tools")
            return cls(
                str(data["name"]),
                rows,
                bool(data["strict"]),
                distribution,
                None if tools is None else str(tools),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ProfileError(
                f"profile data of {distribution} is malformed: {exc!r}; reinstall the profile"
            ) from exc

    def flag_for_strategy(self, strategy: str) -> FlagRow | None:
        return next((row for row in self.flags if row.strategy == strategy), None)

    def linked_distributions(self) -> frozenset[str]:
        """The plugin distributions this build links, the ground tools included if it has them."""
        linked = {r.distribution for r in self.flags if r.state is FlagState.ON}
        return frozenset(linked | ({self.tools} if self.tools else set()))

    def allows_distribution(self, distribution: str) -> bool:
        return not self.strict or _norm(distribution) in {
            _norm(d) for d in self.linked_distributions()
        }

    def refuses_strategy(
        self, strategy: str, build_flag: str | None, distribution: str, *, baseline: bool = False
    ) -> str | None:
        """Why this build must not offer ``strategy`` from ``distribution`` (None: it may).

        Only a strict profile refuses. There a strategy is offered when a BUILD_MATCHER_* row
        of the profile names it, its plugin declares that row's flag and ships in that row's
        distribution, or when it is a baseline of the profile's ground tools. Being shipped in
        a linked distribution (or one whose name normalises to it) is not enough: a strategy
        without a flag never flies.
        """
        if not self.strict:
            return None
        row = self.flag_for_strategy(strategy)
        if row is None:
            if baseline and self.tools is not None and _norm(distribution) == _norm(self.tools):
                return None
            return (
                f"strategy {strategy!r} has no BUILD_MATCHER_* flag in the {self.name} build "
                "(a strict profile runs only the strategies its flags link)"
            )
        if _norm(row.distribution) != _norm(distribution) or build_flag != row.flag:
            return (
                f"strategy {strategy!r} (flag {build_flag}) is linked as {row.flag} from "
                f"{row.distribution}, not from {distribution}"
            )
        return None

    def flag_report(self) -> dict[str, str]:
        return {row.flag: row.state.value for row in self.flags}


UNPROFILED = BuildProfile(name="none", flags=(), strict=False, distribution=None)


def _norm(name: str) -> str:
    return name.lower().replace("_", "-")


def installed_profile(
    distributions: Iterable[importlib_metadata.Distribution] | None = None,
) -> BuildProfile:
    """The profile of this environment, from the ``c3_matcher.profile`` entry points."""
    dists = list(importlib_metadata.distributions() if distributions is None else distributions)
    found: list[tuple[str, importlib_metadata.EntryPoint]] = []
    seen: set[str] = set()
    for dist in dists:
        name = field_of(dist, "Name")  # None: incomplete metadata, skipped unless a profile's
        if name is None and entry_points_in(dist, PROFILE_GROUP):
            raise ProfileError(
                f"the build profile at {location_of(dist)} has no readable Name in its "
                "metadata; reinstall it (pip install --force-reinstall c3-matcher-profile-...)"
            )
        if name is None or _norm(name) in seen:
            continue
        seen.add(_norm(name))
        found.extend((name, ep) for ep in entry_points_in(dist, PROFILE_GROUP))
    if not found:
        return UNPROFILED
    if len(found) > 1:
        names = ", ".join(sorted(f"{ep.name} ({dist})" for dist, ep in found))
        raise ProfileError(
            f"more than one build profile is installed: {names}; a build has exactly one "
            "(uninstall all but one c3-matcher-profile-* distribution)"
        )
    dist_name, entry_point = found[0]
    try:
        data = entry_point.load()
    except (KeyboardInterrupt, GeneratorExit):
        raise
    except BaseException as exc:  # SystemExit too: a broken profile is one line, not an exit
        raise ProfileError(
            f"profile {entry_point.name} ({dist_name}) failed to load: {exc}"
        ) from exc
    return BuildProfile.from_data(data, dist_name)
