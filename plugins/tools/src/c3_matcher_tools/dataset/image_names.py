"""Which file each image a telemetry CSV names is: a name is a path relative to IMAGES_DIR
(``./IMG_1.jpg`` is ``IMG_1.jpg``; an absolute path is taken as it is). A name outside
IMAGES_DIR (``../x.jpg``, an absolute path elsewhere) is refused, judged on the name: a
symbolic link the user placed in the folder is theirs to place. A name that is the file an
earlier name is, however spelled (a symbolic link to it among them), is refused too: one photo
would become two frames with two poses."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

__all__ = ["file_identity", "is_utf8", "place_images"]


def is_utf8(text: str) -> bool:
    """``text`` can be written as UTF-8: it holds no lone surrogate (how Python holds a file
    name's byte that is not UTF-8)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def file_identity(path: Path) -> Path:
    """Which file ``path`` is: its symbolic links followed (the path itself where they loop)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):
        return path


def place_images(
    images_dir: Path, named: Sequence[tuple[int, str]]
) -> tuple[dict[int, str], list[tuple[int, str]]]:
    """Each (CSV line, image name) of ``named``, in line order, placed in ``images_dir``:
    (line -> the name as a path relative to ``images_dir``, POSIX-style, for each accepted;
    (line, why) for each refused, as :func:`~c3_matcher_tools.dataset.telemetry.refuse_lines`
    takes them)."""
    root = Path(os.path.normpath(images_dir.absolute()))
    placed: dict[int, str] = {}
    problems: list[tuple[int, str]] = []
    first: dict[Path, tuple[int, str]] = {}  # file -> the first (line, name) naming it
    for line, name in sorted(named):
        path = Path(os.path.normpath(root / name))
        if path != root and root not in path.parents:
            why = f"line {line}: image {name!r} is outside IMAGES_DIR {images_dir}"
            problems.append((line, why))
            continue
        key = file_identity(path)
        if key in first:
            was_line, was = first[key]
            same = "" if was == name else f" as {was!r}"
            problems.append((line, f"line {line}: image {name!r} already on line {was_line}{same}"))
            continue
        first[key] = (line, name)
        placed[line] = path.relative_to(root).as_posix()
    return placed, problems
