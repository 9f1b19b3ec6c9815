"""One ``features build`` of a store at a time.

A build holds ``flock`` on ``<sidecar>.lock`` (its process id written in it) while it runs, taken
without waiting: a second build of the same store is refused at once (:class:`BuildRunningError`)
instead of computing every window again beside the first. The kernel lets go of the lock when
the holder's process ends, however it ends, so a killed build never leaves a stale lock; the
file is removed when the build ends. Readers of the sidecar (the flight, ``features info``)
never take it.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

__all__ = ["BuildRunningError", "build_lock", "lock_path"]


class BuildRunningError(ValueError):
    """Another process is building the features of this store."""


def lock_path(sidecar: Path) -> Path:
    """``<sidecar>.lock``, held by the build of ``sidecar``'s store."""
    return sidecar.with_name(sidecar.name + ".lock")


@contextmanager
def build_lock(store: Path, sidecar: Path) -> Iterator[None]:
    """Hold ``store``'s build lock while the block runs (see the module docstring):
    :class:`BuildRunningError` naming the store when another process holds it, a ValueError
    naming the lock file when it cannot be made."""
    path = lock_path(sidecar)
    fd = _held(store, path)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        with suppress(OSError):
            path.unlink()  # still held: a build that opened it meanwhile takes the next one
        os.close(fd)


def _held(store: Path, path: Path) -> int:
    """A descriptor of ``path`` holding its lock; the lock file a holder removed as it let go
    (opened before, locked after) is left for the one made next."""
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise ValueError(f"{path}: cannot be created: {exc.strerror or exc}") from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise BuildRunningError(
                f"{store}: another build of its features is running{holder}; "
                "run this one again when it has finished (it builds only what is left)"
            ) from None
        try:
            if os.path.samestat(os.fstat(fd), path.stat()):
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)


def _holder(fd: int) -> str:
    """`` (process N)`` as the holder wrote it in the lock file, or nothing."""
    with suppress(OSError, ValueError):
        return f" (process {int(os.pread(fd, 32, 0).decode())})"
    return ""
