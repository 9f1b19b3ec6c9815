"""The command line as a user runs it, for the tools' tests: the core's :func:`run_cli`
(``c3_matcher.testing.cli``), ``c3-matcher ARGS`` in a fresh Python process."""

from __future__ import annotations

from c3_matcher.testing.cli import run_cli

__all__ = ["run_cli"]
