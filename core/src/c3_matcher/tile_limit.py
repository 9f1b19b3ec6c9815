"""A candidate's tile decoded under the matcher's pixel limit (``[matcher] max_image_pixels``):
by a handle that takes a limit (:class:`PixelLimitedHandle`, ``decode_within``: every handle of
c3-matcher, whose tiles above it are refused from their header, before decoding), else by its
own ``decode()`` (a handle of another's, made before this existed, or a subclass that decodes
its own way), whose pixels above it are refused once decoded: its decoder, and what that
allocates, are its own."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import TilePixelsHandle
from c3_matcher.tiles import ImageDecodeError

__all__ = ["PixelLimitedHandle", "decode_within"]


@runtime_checkable
class PixelLimitedHandle(Protocol):
    """A tile handle that decodes under a pixel limit it is given: an image above
    ``max_pixels`` (width x height) is refused, from its header where it has one."""

    def decode_within(self, max_pixels: int) -> NDArray[np.uint8]: ...


def decode_within(handle: TilePixelsHandle, max_pixels: int, what: str) -> NDArray[np.uint8]:
    """The pixels of ``handle`` (the tile ``what``) decoded within ``max_pixels`` (width x
    height): by its ``decode_within`` where that decodes as its ``decode()`` does
    (:func:`_takes_limit`), else by ``decode()`` and an ImageDecodeError naming ``what`` when
    the pixels it returned are above the limit."""
    if isinstance(handle, PixelLimitedHandle) and _takes_limit(type(handle)):
        return handle.decode_within(max_pixels)
    pixels = handle.decode()
    shape: tuple[int, ...] = tuple(getattr(pixels, "shape", ()))
    if len(shape) >= 2 and int(shape[0]) * int(shape[1]) > max_pixels:
        raise ImageDecodeError(
            what,
            f"decoded by its handle ({type(handle).__name__}) to {shape[1]}x{shape[0]} px, "
            f"above the limit of {max_pixels} px ([matcher] max_image_pixels)",
        )
    return pixels


def _takes_limit(kind: type) -> bool:
    """Whether handles of ``kind`` decode under a limit as their ``decode()`` decodes: its
    ``decode_within`` comes from the class its ``decode`` comes from, or one derived from it (a
    subclass overriding ``decode()`` alone is decoded by its own ``decode()``)."""
    within, plain = _defined_by(kind, "decode_within"), _defined_by(kind, "decode")
    return within is not None and plain is not None and issubclass(within, plain)


def _defined_by(kind: type, name: str) -> type | None:
    """The class of ``kind``'s method resolution order that defines ``name`` (None: none)."""
    return next((k for k in kind.__mro__ if name in vars(k)), None)
