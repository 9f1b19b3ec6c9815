"""Write a dataset directory atomically: build it in a hidden sibling, rename it into place."""

from __future__ import annotations

import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from c3_matcher.atomic import (
    refuse_output_over_inputs,
    refuse_unwritable,
    replace_directory,
    restore_aside,
    temporary_sibling,
)
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import is_flight_dataset
from c3_matcher_tools.dataset.lock import replacing_dataset

__all__ = ["atomic_directory", "check_output_dir"]


def check_output_dir(
    out: Path,
    *,
    force: bool = False,
    field: str = "OUT",
    inputs: Iterable[str | Path | None] = (),
) -> None:
    """Refuse an ``out`` that is or holds one of ``inputs``
    (:func:`~c3_matcher.atomic.refuse_output_over_inputs`), that exists (unless ``force`` and it
    is a dataset directory, one holding ``dataset.json``, or an empty one) or whose nearest
    existing ancestor is not a writable directory (missing parents are created on writing, as
    ``replay`` does), or a dataset a run is reading (:func:`replacing_dataset`); nothing is
    created here (a dataset a killed ``--force`` set aside is put back first,
    :func:`~c3_matcher.atomic.restore_aside`)."""
    out = Path(out)
    refuse_output_over_inputs(out, inputs, field=field)
    restore_aside(out)  # what a replacing writer killed mid-way set aside is OUT again
    if out.exists():
        _refuse_existing(out, force=force, field=field)
        with replacing_dataset(out):  # refused now, before the work, while a run reads it
            pass
    refuse_unwritable(out, field=field)


def _refuse_existing(out: Path, *, force: bool, field: str) -> None:
    """Refuse the existing ``out`` unless ``force`` may replace it: ``--force`` replaces a
    dataset directory (or an empty one), never a file or a directory of other things."""
    if not force:
        hint = "" if out.is_dir() else " (and is not a directory)"
        raise InvalidInputError(field, f"{out} already exists{hint}: choose another or --force")
    if not out.is_dir():
        raise InvalidInputError(
            field,
            f"{out} already exists and is not a directory: --force replaces only a dataset "
            "directory, not a file; choose another OUT or remove the file",
        )
    if not is_flight_dataset(out) and not _empty(out):
        raise InvalidInputError(
            field,
            f"{out} is a directory but not a dataset (no dataset.json): --force replaces only "
            "a dataset directory; choose another OUT or empty it",
        )


@contextmanager
def atomic_directory(out: Path, *, force: bool = False) -> Iterator[Path]:
    """Yield a temporary directory beside ``out``; on success rename it to ``out`` (replacing an
    existing ``out`` only when ``force``), on any error remove it and leave ``out`` untouched.
    An existing ``out`` is held alone from the check to the swap (:func:`replacing_dataset`):
    no ``replay`` or ``eval`` starts reading it meanwhile, and one reading it refuses this."""
    out = Path(out)
    check_output_dir(out, force=force)
    with replacing_dataset(out):
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            tmp = temporary_sibling(out)
            tmp.mkdir()
        except OSError as exc:  # said of OUT, not of the temporary folder beside it
            why = exc.strerror or exc
            raise InvalidInputError("OUT", f"{out}: cannot be written ({why})") from None
        try:
            yield tmp
            replace_directory(tmp, out)
        except OSError as exc:  # a file of it that could not be written is said of OUT's
            shutil.rmtree(tmp, ignore_errors=True)
            exc.filename = _under(out, tmp, exc.filename)
            raise
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise


def _under(out: Path, tmp: Path, name: object) -> object:
    """``name`` (an error's file), when it is in ``tmp``, as the file it was to be in ``out``."""
    if isinstance(name, str | Path) and Path(name).is_relative_to(tmp):
        return str(out / Path(name).relative_to(tmp))
    return name


def _empty(directory: Path) -> bool:
    """``directory`` holds nothing (False as well when it cannot be listed)."""
    try:
        return not any(directory.iterdir())
    except OSError:
        return False
