"""The command line as a user runs it, for tests of the commands: ``c3-matcher ARGS`` in a fresh
Python process, free of the caller's ``C3_MATCHER_*`` settings."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Mapping
from pathlib import Path

from c3_matcher.config_sources import ENV_PREFIX

__all__ = ["run_cli"]


def run_cli(
    *args: str | Path,
    cwd: Path,
    engine_dir: Path | None = None,
    settings: Mapping[str, str] | None = None,
    timeout: float = 900,
    limit_file_bytes: int | None = None,
) -> subprocess.CompletedProcess[str]:
    """``c3-matcher ARGS`` run in ``cwd`` (its output captured as text); ``engine_dir``: the
    engines it reads (``C3_MATCHER_ENGINES__DIRECTORY``); ``settings``: the ``C3_MATCHER_*``
    environment it is given; ``limit_file_bytes`` caps every file it writes (``ulimit -f``)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(ENV_PREFIX)}
    env.update(settings or {})
    if engine_dir is not None:
        env[f"{ENV_PREFIX}ENGINES__DIRECTORY"] = str(engine_dir)
    return subprocess.run(
        [sys.executable, "-m", "c3_matcher.cli", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=timeout,
        preexec_fn=None if limit_file_bytes is None else _file_size_limit(limit_file_bytes),
    )


def _file_size_limit(size: int) -> Callable[[], None]:
    """A ``preexec_fn`` capping every file the child writes at ``size`` bytes."""

    def limit() -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

    return limit
