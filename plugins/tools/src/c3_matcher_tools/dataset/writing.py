"""Writing a ``c3-flight/1`` dataset, the files :mod:`c3_matcher_tools.dataset.format` reads,
under the names it gives them: every writer (``dataset render``, ``dataset import`` from a CSV
or from a log) ends here."""

from __future__ import annotations

import errno
import json
import os
import shutil
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher import dto
from c3_matcher_tools.dataset.format import (
    CALIBRATION_FILE,
    FORMAT,
    FRAMES_FILE,
    META_FILE,
    STORE_FILE,
    FrameRecord,
)
from c3_matcher_tools.dataset.provenance import made_by

__all__ = [
    "calibration_to_json",
    "copy_file",
    "link_or_copy",
    "place_store",
    "write_dataset",
    "write_file",
]


def calibration_to_json(calibration: dto.CameraCalibration) -> dict[str, Any]:
    out: dict[str, Any] = {
        "K": calibration.K.tolist(),
        "distortion": calibration.distortion.tolist(),
        "image_size": list(calibration.image_size),
    }
    if calibration.camera_to_body is not None:
        out["camera_to_body"] = np.asarray(calibration.camera_to_body).tolist()
    return out


def write_dataset(
    root: Path,
    meta: dict[str, Any],
    calibration: dto.CameraCalibration,
    frames: Sequence[FrameRecord],
    *,
    store: Path | None,
    link_store: bool = False,
) -> str:
    """Write a dataset under ``root``, its frame images already there: the tile store ``store``
    put there by :func:`place_store` (None: the caller placed it first), the calibration, the
    frames and the description (the format and the files, then ``meta``: its ``name`` first,
    then how the dataset was made, its ``spec`` naming the c3-matcher and the revision of the
    writer that made it: :func:`~c3_matcher_tools.dataset.provenance.made_by`). Returns how the
    store was put there, in words ("" when the caller placed it)."""
    root.mkdir(parents=True, exist_ok=True)
    placed = "" if store is None else place_store(root, store, link=link_store)
    described = {
        "format": FORMAT,
        "calibration": CALIBRATION_FILE,
        "frames": FRAMES_FILE,
        "name": meta["name"],
        "store": STORE_FILE,
        **meta,
        **({"spec": made_by(meta["spec"])} if "spec" in meta else {}),
    }
    with _naming(root / CALIBRATION_FILE):
        (root / CALIBRATION_FILE).write_text(json.dumps(calibration_to_json(calibration), indent=1))
    with _naming(root / FRAMES_FILE), (root / FRAMES_FILE).open("w", encoding="utf-8") as fh:
        for f in frames:
            fh.write(json.dumps(f.to_json()) + "\n")
    with _naming(root / META_FILE):
        (root / META_FILE).write_text(json.dumps(described, indent=2) + "\n")
    return placed


def place_store(root: Path, store: Path, *, link: bool) -> str:
    """Put the tile store ``store`` in the dataset folder ``root``: copied, or with ``link``
    hard-linked where it can be (:func:`link_or_copy`); returns which, in words."""
    root.mkdir(parents=True, exist_ok=True)
    if link:
        return link_or_copy(store, root / STORE_FILE)
    copy_file(store, root / STORE_FILE)
    return f"{STORE_FILE}: a copy of {store}"


def link_or_copy(store: Path, target: Path) -> str:
    """Put the tile store ``store`` at ``target``: a hard link (the same file, no copy) where
    the filesystem makes one, else a copy (another filesystem, links refused or not supported);
    returns which, in words. A link is safe to share: ``tiles build`` replaces a store by a
    rename, which leaves the link with the old file, a deleted store leaves it too, and nothing
    else the tools do changes a store's tiles in place (``tiles digest`` adds missing sha256s)."""
    try:
        os.link(store, target)
    except OSError as exc:
        copy_file(store, target)
        return f"{target.name}: a copy of {store} (no hard link: {exc.strerror or exc})"
    return (
        f"{target.name}: a hard link to {store} (the same file, not a copy; rebuilding or "
        "deleting that store leaves the dataset's as it is)"
    )


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path``; a failure names ``path`` (a write that fails names none)."""
    with _naming(path):
        path.write_bytes(data)


def copy_file(source: Path, copy: Path) -> None:
    """Copy ``source`` to ``copy``. A failure only the destination can cause (a full disk, a
    file-size limit, a quota, a read-only file system) names the copy: ``shutil.copyfile``
    names the source, the user's input, for any failure of its copy."""
    try:
        shutil.copyfile(source, copy)
    except OSError as exc:
        if exc.errno in _WRITE_ERRNOS:
            raise OSError(exc.errno, exc.strerror, str(copy)) from exc
        raise


_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EROFS})


@contextmanager
def _naming(path: Path) -> Iterator[None]:
    """An ``OSError`` that names no file names ``path`` (a write or a flush that fails names
    none); one that names a file is left as it is."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None:
            exc.filename = str(path)
        raise
