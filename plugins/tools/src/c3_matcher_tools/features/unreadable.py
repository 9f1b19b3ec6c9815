"""Why ``features info`` cannot read a tile store's features sidecar (or finds something else in
its place), and what to do about it: one line for stderr, the command in it (``--json`` carries
it) and the exit status."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from c3_matcher.commands import EXIT_FAILURE, EXIT_USAGE
from c3_matcher_tools.features.command import build_command

if TYPE_CHECKING:
    from c3_matcher.tilestore.features import FeatureStoreUnavailableError
    from c3_matcher.tilestore.sidecar import SidecarDamagedError

__all__ = ["Unreadable", "not_a_sidecar", "unreadable_sidecar"]


@dataclass(frozen=True)
class Unreadable:
    """Why a sidecar cannot be opened or read and what to do about it (``problem``: the line
    said after ``c3-matcher:``), the command in it a script can run as it is (None: none, such
    as a damaged sidecar's, whose sets' strategy, window and stride are unknown) and
    the exit status (1: damaged, as damaged windows; 2: locked, not permitted, read-only)."""

    problem: str
    command: str | None = None
    status: int = EXIT_USAGE


def unreadable_sidecar(
    exc: FeatureStoreUnavailableError | SidecarDamagedError, given: Path, store: Path, path: Path
) -> Unreadable:
    """Why the sidecar ``path`` of ``store`` (as the user named it: ``given``) cannot be opened
    (locked, in WAL journal mode where it cannot be read, not permitted) or read (damaged)."""
    import sqlite3

    from c3_matcher.tilestore.files import open_failure, wal_blocked
    from c3_matcher.tilestore.sidecar import SidecarDamagedError
    from c3_matcher.tilestore.sidecar_file import sqlite_code

    rebuild = _build_its_sets(given, path)  # no command a script can run: NAME, W, S unknown
    if isinstance(exc, SidecarDamagedError):
        said = f"{exc}; the flight extracts instead where it is. {rebuild}."
        return Unreadable(said, None, EXIT_FAILURE)
    cause = exc.__cause__ or exc
    code, so = sqlite_code(cause), "the flight extracts every candidate instead while it is so"
    if code in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED):
        why = f"locked by another process ({cause})"
        return Unreadable(f"{path}: {why}; {so}. Try again when it is released.")
    if wal_blocked(path, cause) is not None:  # exc.why says it, and the way out
        command = f"c3-matcher features build {store}"
        then = "Make it one file on a writable copy of its folder, keeping its features"
        return Unreadable(
            f"{path}: {exc.why}; {so}. {then} (then copy it back): {command}.", command
        )
    if code == sqlite3.SQLITE_CANTOPEN and (failed := open_failure(path, "a features sidecar")):
        then = "Let the user who runs c3-matcher read it and search its folder"
        return Unreadable(f"{path}: {failed}; {so}. {then}.")
    why = f"unreadable ({' '.join(str(cause).split())})"
    return Unreadable(f"{path}: {why}; {so}. {rebuild}.", None, EXIT_FAILURE)


def not_a_sidecar(path: Path) -> Unreadable:
    """The sidecar's place ``path`` holds a directory (or another thing that is not a file): the
    flight ignores it and ``features build`` cannot write there, so it is moved away by hand (no
    command: what it holds is the user's); exit 2, as a sidecar it may not open."""
    what = "a directory" if path.is_dir() else "a special file (a pipe, socket or device)"
    return Unreadable(
        f"{path}: {what}, not a features sidecar; the flight ignores it and extracts every "
        "candidate instead. Move it away; features build then makes the sidecar there."
    )


def _build_its_sets(given: Path, path: Path) -> str:
    """What builds the sets of the damaged sidecar ``path`` again, in words: they cannot be read
    from it, so each is named by the user (``features build`` keeps the file aside)."""
    command = build_command(given, "NAME", "W", "S", None)
    return (
        f"Its sets cannot be read from it: build each again with the strategy, window and stride "
        f"it was built with (the build keeps this file as {path.name}.damaged): {command}"
    )
