"""What ``c3-matcher match`` reads: the query image and its calibration, and the candidates,
either tile image files (``--tile``) or windows of an MBTiles store centred on tile ids
(``--store``). Every input is checked here, before anything is composed: a bad one is an
``InvalidInputError`` naming it (exit 2)."""

from __future__ import annotations

import argparse
import hashlib
import math
import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto.camera import CameraCalibration
from c3_matcher.dto.candidates import RerankCandidate, RerankResult
from c3_matcher.dto.geo import Attitude, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.georef import require_mercator_latitude
from c3_matcher.logs import log_event
from c3_matcher.serialize import CALIBRATION_SIZE_FIX, load_calibration
from c3_matcher.tiles import MmapTileHandle, decode_image, read_image
from c3_matcher.tilestore.mbtiles import MBTilesStore

__all__ = [
    "MAX_PLACEHOLDER_TILES",
    "MISSING_INPUT",
    "attitude_arg",
    "file_candidates",
    "frame_id_of",
    "open_store",
    "placeholder_tile_id",
    "read_query",
    "store_candidates",
    "tile_id_arg",
    "usable_height",
    "warn_missing_inputs",
]

MISSING_INPUT = "c3.match.input_missing"
"""The kind of the WARNING ``match`` logs for each input it was not given
(``warn_missing_inputs``)."""

_FRAME_IDS = uuid.UUID("6c3d1e0a-5b7e-4f0e-9a51-3c3a7d0f2b11")  # the namespace of frame_id_of


def frame_id_of(image: NDArray[np.uint8]) -> uuid.UUID:
    """The id of a frame given as an image file: a name-based UUID (RFC 4122 version 5) of its
    pixels, so that the same inputs give the same output, ``frame_id`` included."""
    return uuid.uuid5(_FRAME_IDS, hashlib.sha256(np.ascontiguousarray(image).data).hexdigest())


def read_query(
    query: Path, calibration_path: Path | None, max_pixels: int
) -> tuple[NDArray[np.uint8], CameraCalibration]:
    """The query image and its calibration (the file, else a pinhole with the focal length =
    the image width, px); a calibration for another image size is bad input."""
    image = read_image(query, max_pixels)
    height, width = image.shape[:2]
    calibration = (
        load_calibration(calibration_path)
        if calibration_path
        else CameraCalibration.pinhole(width, height, focal_px=float(width))
    )
    if tuple(calibration.image_size) != (width, height):  # bad input (exit 2), not a backbone
        cw, ch = calibration.image_size
        raise InvalidInputError(
            f"--calibration {calibration_path}",
            f"image_size is {cw}x{ch} px but the --query image {query} is {width}x{height} px "
            f"({CALIBRATION_SIZE_FIX})",
        )
    return image, calibration


def file_candidates(
    frame_id: uuid.UUID,
    tiles: Sequence[Path],
    tile_ids: Sequence[TileId],
    tile_gsd_m: float | None,
    max_pixels: int,
) -> RerankResult:
    """The tile files as the frame's candidates, in order; ``tile_ids`` one per tile, or none
    (then :func:`placeholder_tile_id` of each position)."""
    if tile_ids and len(tile_ids) != len(tiles):
        raise InvalidInputError(
            "--tile-id",
            f"{len(tile_ids)} given for {len(tiles)} --tile; give one per tile or none",
        )
    if not tile_ids and len(tiles) > MAX_PLACEHOLDER_TILES:
        raise InvalidInputError(
            "--tile",
            f"{len(tiles)} given without --tile-id, at most {MAX_PLACEHOLDER_TILES}: "
            "give one --tile-id per tile",
        )
    candidates = []
    for i, path in enumerate(tiles):
        tile_id = tile_ids[i] if tile_ids else placeholder_tile_id(i)
        candidates.append(
            RerankCandidate(tile_id, 1.0, _readable_tile(path, max_pixels), tile_gsd_m)
        )
    return RerankResult(frame_id, tuple(candidates))


_LONGITUDES = 181  # the whole longitudes 0..180 a placeholder id counts through


MAX_PLACEHOLDER_TILES = 91 * _LONGITUDES
"""How many ``--tile`` a ``match`` without ``--tile-id`` takes: as many positions as
:func:`placeholder_tile_id` names (latitudes 0..90 by longitudes 0..180)."""


def placeholder_tile_id(index: int) -> TileId:
    """The id of the ``--tile`` at position ``index`` given without ``--tile-id``: zoom 0 (no
    place: see :func:`c3_matcher.georef.is_georeferenced`), ``0,0,INDEX`` for the first 181,
    then ``0,LAT,LON`` with ``INDEX = LAT * 181 + LON``, so that every position has its own
    id within the valid range (up to ``MAX_PLACEHOLDER_TILES``)."""
    lat, lon = divmod(index, _LONGITUDES)
    return TileId(0, float(lat), float(lon))


def open_store(path: Path) -> MBTilesStore:
    """The ``--store`` MBTiles store (``close()`` it when done); ``InvalidInputError`` naming
    ``--store`` for a missing file or one that is no MBTiles store."""
    try:
        return MBTilesStore(path)
    except InvalidInputError as exc:
        raise InvalidInputError(f"--store {path}", exc.reason) from None


def store_candidates(
    frame_id: uuid.UUID,
    store: MBTilesStore,
    tile_ids: Sequence[TileId],
    window_px: int,
    tile_gsd_m: float | None,
) -> RerankResult:
    """One candidate per tile id: the ``window_px`` square of ``store`` centred on it, at its
    zoom (a zoom the store lacks is bad input; a window over no stored tile is a candidate
    dropped, as in flight), its GSD the web-mercator one of that zoom at its latitude: the
    window's grid is the zoom's, so a ``tile_gsd_m`` given (``--tile-gsd``) is refused."""
    if tile_gsd_m is not None:
        raise InvalidInputError(
            "--tile-gsd", "is for --tile images; a --store window's is its zoom's"
        )
    if not tile_ids:
        raise InvalidInputError("--tile-id", "--store needs one --tile-id per candidate window")
    try:  # a zoom_level the check at open does not look at: the store is no MBTiles file
        zooms = store.zooms()
    except InvalidInputError as exc:
        raise InvalidInputError(f"--store {store.path}", exc.reason) from None
    for tile_id in tile_ids:
        if tile_id.zoom not in zooms:
            raise InvalidInputError(
                f"--tile-id {tile_id.zoom},{tile_id.lat},{tile_id.lon}",
                f"{store.path} has no tiles at zoom {tile_id.zoom} (it has {zooms})",
            )
    return RerankResult(frame_id, tuple(store.candidate(t, size_px=window_px) for t in tile_ids))


def _readable_tile(path: Path, max_pixels: int) -> MmapTileHandle:
    """A handle on a ``--tile`` file that exists and decodes within ``max_pixels`` (exit 2
    otherwise, naming it)."""
    p = Path(path)
    if not p.exists():
        raise InvalidInputError(f"--tile {p}", "no such image file")
    try:  # a directory, a FIFO, an empty file: said as such
        handle = MmapTileHandle(p, max_pixels=max_pixels)
    except InvalidInputError as exc:
        raise InvalidInputError(f"--tile {p}", exc.reason) from None
    decode_image(handle.encoded(), f"--tile {p}", max_pixels)
    return handle


def usable_height(args: argparse.Namespace) -> float | None:
    """The frame's height for ``match``'s parsed ``args``: none where the tiles' GSD is unknown
    (no scale to match it to: zoom 0's stood in, and the frame was refused)."""
    return None if _gsd_unknown(args) else args.height


def _gsd_unknown(args: argparse.Namespace) -> bool:
    return args.tile_gsd is None and not args.tile_id


def warn_missing_inputs(args: argparse.Namespace) -> None:
    """One WARNING (``MISSING_INPUT``, the option in ``option``) per input of ``match``'s parsed
    ``args`` that the matcher will have to do without (it fails silently otherwise): a JSON log
    record on stderr at the configured level, and in the FDR as every warning is. Called once
    the matcher's logging is configured."""
    missing = []
    if args.attitude is None:
        missing.append(("--attitude", "the query is not rotated north-up: yaw >= ~60 deg fails"))
    if args.height is None:
        missing.append(("--height", "the query's scale is not matched to the tiles'"))
    if _gsd_unknown(args):
        unused = "; --height is not used" if args.height is not None else ""
        missing.append(("--tile-gsd or --tile-id", f"the tiles' GSD is unknown{unused}"))
    for option, consequence in missing:
        log_event("WARNING", MISSING_INPUT, f"no {option} ({consequence})", option=option)


def _floats(text: str, n: int) -> tuple[float, ...]:
    """``n`` finite comma-separated numbers."""
    what = f"{n} finite comma-separated numbers"
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return values


def attitude_arg(text: str) -> Attitude:
    """``--attitude ROLL,PITCH,YAW`` (degrees)."""
    roll, pitch, yaw = _floats(text, 3)
    try:
        return Attitude.from_degrees(roll, pitch, yaw)
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def tile_id_arg(text: str) -> TileId:
    """``--tile-id Z,LAT,LON``: a place, so of zoom 1 or more (zoom 0 is the id a tile without
    ``--tile-id`` gets: no place) and within web mercator's latitudes
    (:func:`~c3_matcher.georef.require_mercator_latitude`)."""
    try:
        tile_id = TileId.parse(text)
        if tile_id.zoom < 1:
            zoom = f"zoom {tile_id.zoom} names no place: give the tile's zoom, 1 or more"
            raise argparse.ArgumentTypeError(zoom)
        require_mercator_latitude(tile_id)
        return tile_id
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
