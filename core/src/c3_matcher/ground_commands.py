"""The ground tools' commands as a build without them knows them (a flight computer's): named
on the command line, they are refused in one line saying where they come from, not with
argparse's bare "invalid choice" (README: ground commands come with the tools, never in
flight)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

__all__ = ["GROUND_COMMANDS", "ground_refusal"]

GROUND_COMMANDS = (
    "tiles",
    "dataset",
    "replay",
    "eval",
    "bench",
    "features",
    "engines build",
    "engines bench",
)
"""The commands the ground tools add, a group's subcommand after its group's name."""


def ground_refusal(parser: argparse.ArgumentParser, profile: str, argv: Sequence[str]) -> str:
    """Why the ground command ``argv`` names cannot run: ``parser`` (the build's command line,
    of profile ``profile``) has not got it, as the ground tools are not in this build; "" for
    any other command line (a command it has, or a name argparse refuses itself)."""
    from c3_matcher.engines.store import TOOLS_DISTRIBUTION as TOOLS

    words, choices = [w for w in argv if not w.startswith("-")][:2], _subcommands(parser)
    for depth, word in enumerate(words, start=1):
        if (name := " ".join(words[:depth])) in GROUND_COMMANDS and word not in choices:
            return (
                f"`c3-matcher {name}` comes with the ground tools ({TOOLS}), not in this build "
                f"(profile {profile}): run it on a ground machine that has them (pip install "
                f"{TOOLS}); a flight computer takes what they make, the engines copied into its "
                "[engines] directory"
            )
        choices = _subcommands(choices.get(word))
    return ""


def _subcommands(parser: argparse.ArgumentParser | None) -> dict[str, argparse.ArgumentParser]:
    """The subcommands of ``parser`` by name (none for a leaf command or no parser)."""
    actions = parser._actions if parser is not None else []
    subs = [a for a in actions if isinstance(a, argparse._SubParsersAction)]
    return dict(subs[0].choices) if subs else {}
