"""What an installed distribution says about itself, read without trusting it to be complete.

Any ``*.dist-info`` anywhere on ``sys.path`` is a distribution to ``importlib_metadata``: an empty
one an installer left behind, pip's half-uninstalled ``~name`` copy, one whose METADATA lacks a
field. Before 8.0 ``importlib_metadata`` read a missing METADATA file or field as None; later
versions raise (``MetadataNotFound``, ``KeyError``). Both read here as None: a caller skips such
a distribution, or names it when it declares an entry point it needs.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Protocol

import importlib_metadata

__all__ = ["InstalledDistribution", "entry_points_in", "field_of", "location_of"]


class InstalledDistribution(Protocol):
    """What is read of a distribution here (``importlib_metadata.Distribution`` is one; its
    typing differs between versions)."""

    @property
    def metadata(self) -> Any: ...

    @property
    def entry_points(self) -> Iterable[importlib_metadata.EntryPoint]: ...


def field_of(dist: InstalledDistribution, field: str) -> str | None:
    """``field`` (``Name``, ``Version``) of ``dist``'s metadata; None when the metadata or the
    field is missing, empty or unreadable."""
    try:
        value = dist.metadata[field]
    except Exception:  # MetadataNotFound, KeyError, an undecodable or unreadable file
        return None
    return value.strip() if isinstance(value, str) and value.strip() else None


def entry_points_in(dist: InstalledDistribution, group: str) -> list[importlib_metadata.EntryPoint]:
    """The entry points of ``group`` that ``dist`` declares; none when its ``entry_points.txt``
    cannot be read or parsed."""
    try:
        return [ep for ep in dist.entry_points if ep.group == group]
    except Exception:
        return []


def location_of(dist: InstalledDistribution) -> str:
    """Where ``dist``'s metadata is (its ``*.dist-info`` folder), to name one without a name."""
    path = getattr(dist, "_path", None)  # PathDistribution's; other finders may lack it
    return str(path) if path is not None else repr(dist)
