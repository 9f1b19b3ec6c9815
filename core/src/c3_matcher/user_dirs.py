"""c3-matcher's user cache and data directories, by the XDG base-directory rule, with the
standard library alone (the flight computer's install carries no package for two paths).

``$XDG_CACHE_HOME/c3-matcher``, else ``~/.cache/c3-matcher``; ``$XDG_DATA_HOME/c3-matcher``,
else ``~/.local/share/c3-matcher``. An XDG variable that is unset, empty or relative is ignored
(the specification says so); the home is ``$HOME`` when it is absolute, else the account's
home in the password database. These are exactly the paths ``platformdirs`` gives on Linux.
macOS and Windows get the same XDG layout, not their own conventions: the flight computers run
Linux, and elsewhere (a developer's machine) a path under the home is as good as any.

The variables are read from the environment given (default ``os.environ``), never changed. The
settings' defaults read the process's: ``load_settings``'s mapping holds the ``C3_MATCHER_``
settings (callers and tests pass only those), while the base directories belong to the
process, and the section defaults are built when ``c3_matcher.config`` is imported."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from c3_matcher.errors import ConfigurationError

__all__ = ["APP_NAME", "user_cache_dir", "user_data_dir"]

APP_NAME = "c3-matcher"


def user_cache_dir(environ: Mapping[str, str] | None = None) -> Path:
    """``$XDG_CACHE_HOME/c3-matcher``, else ``~/.cache/c3-matcher`` (engines, TensorRT cache)."""
    return _base_dir("XDG_CACHE_HOME", ".cache", environ) / APP_NAME


def user_data_dir(environ: Mapping[str, str] | None = None) -> Path:
    """``$XDG_DATA_HOME/c3-matcher``, else ``~/.local/share/c3-matcher`` (the FDR)."""
    return _base_dir("XDG_DATA_HOME", ".local/share", environ) / APP_NAME


def _base_dir(variable: str, under_home: str, environ: Mapping[str, str] | None) -> Path:
    """The XDG base directory ``variable`` names when absolute, else ``under_home`` in the
    home (joined as text, as ``os.path.expanduser`` joins: a home of ``/`` gives ``/.cache``)."""
    env = os.environ if environ is None else environ
    given = env.get(variable, "")
    if Path(given).is_absolute():
        return Path(given)
    return Path(f"{_home(env, variable).rstrip('/')}/{under_home}")


def _home(env: Mapping[str, str], variable: str) -> str:
    """``$HOME`` when absolute, else the account's home; ``ConfigurationError`` when neither
    gives an absolute path (``variable`` is the other way to name the directory)."""
    home = env.get("HOME", "")
    if not Path(home).is_absolute():
        home = _account_home()
    if Path(home).is_absolute():
        return home
    reason = (
        "no home directory (HOME is unset or relative, and the password database gives none): "
        f"set HOME, or {variable}, to an absolute path"
    )
    raise ConfigurationError("environment", [("HOME", reason)])


def _account_home() -> str:
    """The user's home in the password database (``""`` when it has no entry); where there is
    no such database (Windows), ``Path.home()`` (``""`` when it has none)."""
    try:
        import pwd
    except ImportError:
        try:
            return str(Path.home())
        except RuntimeError:
            return ""
    try:
        return pwd.getpwuid(os.getuid()).pw_dir
    except KeyError:
        return ""
