"""An XYZ tile folder: ``ROOT/{z}/{x}/{y}.png`` or ``.jpg`` / ``.jpeg`` (y grows south), 256 px.
A TMS folder (rows from the south), which holds the TMS spec's ``tilemapresource.xml`` as
gdal2tiles writes it without ``--xyz``, is refused at open: its tiles would be served mirrored
north-south.

Each tile file is read from the page cache on demand (:class:`~c3_matcher.tiles.MmapTileHandle`,
which holds no mapping: a file that shrinks while in use is that tile's error, never SIGBUS).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import MmapTileHandle
from c3_matcher.tilestore.base import TileStoreBase

__all__ = ["XyzTileStore"]

SUFFIXES = (".png", ".jpg", ".jpeg")
TMS_RESOURCE = "tilemapresource.xml"  # the TMS spec's description of a folder of TMS rows


class XyzTileStore(TileStoreBase):
    """Read tiles from an XYZ folder (see the module docstring)."""

    def __init__(self, root: str | Path) -> None:
        self._root = Path(root)
        if not self._root.is_dir():
            raise InvalidInputError("xyz", f"no such tile folder: {self._root}")
        if (self._root / TMS_RESOURCE).is_file():
            raise InvalidInputError(
                "xyz",
                f"{self._root}: holds {TMS_RESOURCE}, so it is a TMS tile folder (rows counted"
                " from the south, as gdal2tiles writes without --xyz); it reads XYZ folders (rows"
                " from the north): write the tiles with gdal2tiles --xyz",
            )

    @property
    def name(self) -> str:
        return self._root.name

    def tile_path(self, zoom: int, x: int, y: int) -> Path | None:
        for suffix in SUFFIXES:
            p = self._root / str(zoom) / str(x) / f"{y}{suffix}"
            if p.is_file():
                return p
        return None

    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | None:
        """The tile file's bytes (read-only view), or None when absent; an unreadable, empty or
        shrinking file, or one turned into a FIFO since it was looked for (never waited on),
        raises InvalidInputError naming it."""
        p = self.tile_path(zoom, x, y)
        return None if p is None else MmapTileHandle(p).encoded()

    def zooms(self) -> list[int]:
        return sorted(int(p.name) for p in self._root.iterdir() if p.is_dir() and p.name.isdigit())

    def tiles(self, zoom: int) -> Iterator[tuple[int, int]]:
        """XYZ (x, y) of every tile file at ``zoom`` (``{zoom}/{x}/{y}.png|jpg|jpeg``; other
        names are no tiles), by x then y, each once."""
        level = self._root / str(zoom)
        columns = level.iterdir() if level.is_dir() else iter(())
        for x in sorted(int(c.name) for c in columns if c.name.isdigit() and c.is_dir()):
            rows = {
                int(f.stem)
                for f in (level / str(x)).iterdir()
                if f.suffix in SUFFIXES and f.stem.isdigit() and f.is_file()
            }
            for y in sorted(rows):
                yield x, y

    def __repr__(self) -> str:
        return f"XyzTileStore({str(self._root)!r})"
