"""A dataset's files stay inside its folder. The names ``dataset.json`` and ``frames.jsonl`` give
(the store, the calibration, the frame records, each frame's image) are paths relative to the
dataset, and a load refuses one that is absolute or whose normalised form leaves the folder
(``../x.jpg``, ``frames/../../x.jpg``), and one that leads out of it through a symbolic link:
a dataset is what people send one another, and a name or a link that reached past it would have
replay read any file on the machine, draw it into a report that goes back to the sender, and
``features build`` write next to it.

A link that stays inside the folder is followed. The tools never write a link into a dataset
(an import copies the images and hard-links or copies the store), so a link out of one is
either hand-made or came with the dataset: a big store shared by several datasets is hard-linked
into each (the same file, no copy), as ``dataset import`` does, or copied."""

from __future__ import annotations

import os
from pathlib import Path

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.json_values import json_text

__all__ = ["META_PATHS", "check_meta_paths", "inside_name", "leads_outside", "real_root"]

META_PATHS = ("store", "frames", "calibration")
"""The keys of ``dataset.json`` that name a file of the dataset."""


def inside_name(value: object, field: str) -> str:
    """``value`` when it is a non-empty string naming a path inside the dataset (relative, and
    inside it once normalised), else InvalidInputError naming ``field``. Judged on the name
    alone: :func:`leads_outside` follows the links."""
    name = json_text(value, field)
    if Path(name).is_absolute():
        raise InvalidInputError(field, f"{name!r} is an absolute path: it must be relative")
    if "\0" in name:
        raise InvalidInputError(field, f"{name!r} holds a NUL character")
    normal = os.path.normpath(name)
    if normal == ".":
        raise InvalidInputError(field, f"{name!r} names the dataset folder, not a file in it")
    if normal == os.pardir or normal.startswith(os.pardir + os.sep):
        raise InvalidInputError(field, f"{name!r} leads outside the dataset folder")
    return name


def real_root(root: Path) -> Path:
    """The dataset folder ``root`` with its symbolic links followed: where its files must lead
    (:func:`leads_outside`)."""
    return _followed(root.absolute())


def leads_outside(real: Path, root: Path, name: str) -> str | None:
    """Why ``root / name`` (``name`` passed :func:`inside_name`) leads outside the dataset
    folder whose links followed are ``real`` (:func:`real_root`), through a symbolic link, or
    None where it stays inside (or does not exist: its read says so)."""
    target = _followed(root.absolute() / name)
    if target == real or real in target.parents:
        return None
    return (
        f"{name!r} leads outside the dataset folder, to {target}, through a symbolic link; "
        "hard-link or copy the file into the folder instead"
    )


def check_meta_paths(root: Path, meta_path: Path, meta: dict[str, object]) -> None:
    """InvalidInputError naming ``meta_path`` (the dataset's ``dataset.json``) and the key
    where a file it names (:data:`META_PATHS`, each passed :func:`inside_name`) leads outside
    the dataset folder ``root`` through a symbolic link."""
    real = real_root(root)
    for key in META_PATHS:
        why = leads_outside(real, root, str(meta[key]))
        if why:
            raise InvalidInputError("dataset", f"{meta_path}: {key}: {why}")


def _followed(path: Path) -> Path:
    """``path`` with every symbolic link followed (as far as they go; the path itself where
    they loop)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):
        return Path(os.path.normpath(path))
