"""How the commands write what they make: never over their own inputs
(:func:`refuse_output_over_inputs`), one writer of a directory at a time
(:func:`held_directory`), and replaced whole or not at all: a writer gets a temporary
file of its own beside the target, fsynced and renamed over it (the rename then fsynced in the
directory) when the block ends; on any exception (a full disk, a file size limit, Ctrl-C) the
temporary file is removed and the target keeps what it held before. Results, reports and
pictures are written this way; the ground tools' tile stores and datasets take their temporary
names from :func:`temporary_sibling` too, so what a killed writer left is removed by the next."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import glob
import os
import secrets
import shutil
import socket
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, Any, TextIO, cast

from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr.files import fsync_dir

__all__ = [
    "atomic_writer",
    "held_directory",
    "refuse_output_over_inputs",
    "refuse_unwritable",
    "replace_directory",
    "restore_aside",
    "temporary_sibling",
    "write_bytes_atomically",
    "write_text_atomically",
]

_NO_FILE = "-"  # what a command takes in place of an input file it does not need


def refuse_output_over_inputs(
    out: Path, inputs: Iterable[str | Path | None], *, field: str = "OUT"
) -> None:
    """Refuse an ``out`` that is one of ``inputs`` (the same path once links are followed, or a
    hard link to the same file) or a folder above one: writing it, ``--force`` or not, would
    replace or delete that input (``InvalidInputError`` naming ``field``). ``None`` and ``-``
    stand for no file and are skipped."""
    target = Path(out).expanduser().resolve()
    for given in inputs:
        if given is None or str(given) == _NO_FILE:
            continue
        source = Path(given).expanduser().resolve()
        if source == target or _one_file(source, target):
            raise InvalidInputError(
                field, f"{out} is the input {given}, which writing it would replace: choose another"
            )
        if target in source.parents:
            raise InvalidInputError(
                field,
                f"{out} holds the input {given}, which replacing it would delete: choose another",
            )


def refuse_unwritable(out: Path, *, field: str = "OUT", directory: bool = False) -> None:
    """Refuse (``InvalidInputError`` naming ``field``) an ``out`` this process cannot write, a
    file or, with ``directory``, a directory: the nearest existing folder it goes in (``out``
    itself for an existing directory; missing folders are made on writing) must be a
    directory, and writable. Nothing is created."""
    target = Path(out).expanduser().absolute()
    place = target if directory else target.parent
    while not place.exists() and place != place.parent:
        place = place.parent
    if not place.is_dir():
        raise InvalidInputError(field, f"{out}: {place} is not a directory")
    if not os.access(place, os.W_OK):
        raise InvalidInputError(field, f"{out}: {place} is not writable")


@contextlib.contextmanager
def held_directory(directory: Path, *, when_busy: Callable[[], None]) -> Iterator[None]:
    """``directory`` (made if missing) held by this process while the block runs: ``flock`` on
    the directory itself, so nothing is left in it and the kernel lets go when the process
    dies. When another process holds it, ``when_busy`` is called: it raises to refuse, or
    returns to wait until the holder is done."""
    directory.mkdir(parents=True, exist_ok=True)
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            when_busy()
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _one_file(a: Path, b: Path) -> bool:
    """Both exist and are one file (a hard link)."""
    try:
        return a.samefile(b)
    except OSError:
        return False


def temporary_sibling(path: Path) -> Path:
    """A new hidden name beside ``path`` for its writer to fill and then rename onto it:
    ``.NAME.tmp-HOST-PID-XXXXXXXX`` (``HOST`` a tag of this machine's name; a long ``NAME``
    shortened so that it fits a file name, :func:`_stem`). First removes what
    earlier writers of ``path`` on this machine left there when they were killed before they
    could clean up (out of memory, SIGKILL, power lost): those whose process is gone, but for a
    directory set aside to replace a ``path`` now missing, which is put back
    (:func:`restore_aside`). A live writer's, another machine's (a shared disk) and anything
    else are left alone."""
    prefix = _prefix(path)
    dead = _left_by_the_dead(path)
    put_back = _put_back(path, dead)
    for left in dead:
        if left == put_back:
            continue
        with contextlib.suppress(OSError):
            if left.is_dir() and not left.is_symlink():
                shutil.rmtree(left)
            else:
                left.unlink()
    return path.with_name(f"{prefix}{os.getpid()}-{secrets.token_hex(4)}")


_ASIDE = ".aside"
"""The ending of the name :func:`replace_directory` gives a directory it is replacing, where it
cannot swap the two in one step."""


_NAME_MAX = 255
"""The most bytes a file name may take (Linux's and most file systems' ``NAME_MAX``)."""

_LONGEST_STEM = _NAME_MAX - 42
"""The most bytes of a name a temporary name holds: ``.`` and ``.tmp-HOST-`` (15), ``PID-`` (at
most 11) and ``XXXXXXXX`` (8) around it, and room for what is added to a temporary name after
it (``.aside``, SQLite's ``-journal``: 8)."""


def _prefix(path: Path) -> str:
    """What the temporary names of ``path`` written on this machine begin with: the same for
    every writer of ``path``, so the next one finds what a killed one left."""
    return f".{_stem(path.name)}.tmp-{zlib.crc32(socket.gethostname().encode()):08x}-"


def _stem(name: str) -> str:
    """``name``, or where a temporary name holding it whole would not fit ``_NAME_MAX`` bytes,
    its beginning and ``~`` and a tag of the whole name: a name the file system takes keeps a
    temporary name it takes too, and two long names that begin alike keep apart."""
    if len(os.fsencode(name)) <= _LONGEST_STEM:
        return name
    tag = f"~{zlib.crc32(os.fsencode(name)):08x}"
    room = _LONGEST_STEM - len(tag)
    head = name
    while len(os.fsencode(head)) > room:  # by characters: a UTF-8 one is never cut in two
        head = head[: -max(1, (len(os.fsencode(head)) - room) // 4)]
    return head + tag


def _left_by_the_dead(path: Path) -> list[Path]:
    """The temporary names beside ``path`` whose writer (a process on this machine) is gone."""
    prefix = _prefix(path)
    return sorted(
        left
        for left in path.parent.glob(f"{glob.escape(prefix)}*")
        if (pid := left.name[len(prefix) :].split("-", 1)[0]).isdigit() and not _running(int(pid))
    )


def restore_aside(path: Path) -> None:
    """Put back the directory :func:`replace_directory` set aside to replace ``path`` when its
    writer died before the new one took its place (``path`` is missing): replacing loses
    nothing, even killed between its two renames."""
    _put_back(path, _left_by_the_dead(path))


def _put_back(path: Path, dead: list[Path]) -> Path | None:
    """The set-aside directory among ``dead`` (:func:`_left_by_the_dead`) renamed back onto a
    missing ``path``, or None when ``path`` is there or none was set aside."""
    if path.exists() or path.is_symlink():
        return None
    for left in dead:
        if left.name.endswith(_ASIDE) and left.is_dir():
            with contextlib.suppress(OSError):
                left.rename(path)
                fsync_dir(path.parent)
            return left
    return None


def replace_directory(new: Path, path: Path) -> None:
    """Rename the directory ``new`` (a :func:`temporary_sibling`) onto ``path``, removing the
    directory ``path`` held. Where the kernel swaps two names in one step (Linux ``renameat2``
    ``RENAME_EXCHANGE``), ``path`` is always either the old or the new; elsewhere the old is
    renamed aside first, and a writer killed between the two renames leaves it for the next
    writer of ``path`` to put back (:func:`restore_aside`)."""
    if not path.exists():
        new.rename(path)
    elif _exchange(new, path):
        shutil.rmtree(new, ignore_errors=True)
    else:
        aside = new.with_name(new.name + _ASIDE)
        path.rename(aside)
        new.rename(path)
        shutil.rmtree(aside, ignore_errors=True)
    fsync_dir(path.parent)


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names ``a`` and ``b`` in one step; False where this system cannot."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):  # not Linux, or a C library without renameat2
        return False
    renameat2.argtypes = [
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_uint,
    ]
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):  # a file system that cannot
        return False
    raise OSError(code, os.strerror(code), str(b))


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def _running(pid: int) -> bool:
    """A process ``pid`` runs on this machine (one of another user's included)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def _replacing(path: Path, mode: str) -> Iterator[IO[Any]]:
    with _naming(path):
        tmp = temporary_sibling(path)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            with _open(fd, mode) as fh:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    fsync_dir(path.parent)


def _open(fd: int, mode: str) -> IO[Any]:
    """``fd`` as a file of ``mode``; a text one UTF-8, where what UTF-8 cannot hold (a lone
    surrogate: a file name's byte that is no UTF-8, shown in a page or a log) is written as
    Python's escape (``\\udce9``, inside a JSON string the same character): a name in it
    costs no file."""
    if "b" in mode:
        return os.fdopen(fd, mode)
    return os.fdopen(fd, mode, encoding="utf-8", errors="backslashreplace")


@contextlib.contextmanager
def _naming(path: Path) -> Iterator[None]:
    """An ``OSError`` of writing ``path`` names ``path``, not the temporary file beside it
    (``[Errno 21] Is a directory: 'out.png'``); its class (``IsADirectoryError``, ...) kept."""
    try:
        yield
    except OSError as exc:
        if exc.errno is None or exc.filename == str(path):
            raise
        raise OSError(exc.errno, exc.strerror, str(path)) from exc


@contextlib.contextmanager
def atomic_writer(path: Path) -> Iterator[TextIO]:
    """A UTF-8 text file to write ``path`` through (module docstring; what UTF-8 cannot hold
    escaped, :func:`_open`)."""
    with _replacing(path, "w") as fh:
        yield cast(TextIO, fh)


def write_text_atomically(path: Path, text: str) -> Path:
    """``path`` holding ``text`` (UTF-8), replaced whole (module docstring)."""
    with atomic_writer(path) as fh:
        fh.write(text)
    return path


def write_bytes_atomically(path: Path, data: bytes) -> Path:
    """``path`` holding ``data``, replaced whole (module docstring)."""
    with _replacing(path, "wb") as fh:
        fh.write(data)
    return path
