"""The re-ranker's output the matcher takes in: candidate tiles, best first."""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from c3_matcher import _validate as v
from c3_matcher.dto.geo import TileId


@runtime_checkable
class TilePixelsHandle(Protocol):
    """A reference to one tile's encoded bytes (PNG/JPEG/TIFF...) that decodes on demand.

    ``encoded()`` returns a zero-copy view of the bytes (page-cache backed where the store allows);
    ``decode()`` returns uint8 RGB (H, W, 3) pixels and raises on undecodable data.
    """

    def encoded(self) -> memoryview: ...

    def decode(self) -> NDArray[np.uint8]: ...


@dataclass(frozen=True, slots=True)
class RerankCandidate:
    """One candidate tile proposed by C2.5.

    ``tile_pixels_handle`` references the tile's encoded bytes (page-cache backed) and decodes on
    demand; ``gsd_m_per_px`` is the tile's ground sample distance when known, else the
    web-mercator GSD of ``tile_id`` is assumed.
    """

    tile_id: TileId
    score: float
    tile_pixels_handle: TilePixelsHandle
    gsd_m_per_px: float | None = None

    def __post_init__(self) -> None:
        v.require(
            isinstance(self.tile_id, TileId),
            "candidate.tile_id",
            f"expected TileId, got {type(self.tile_id).__name__}",
        )
        object.__setattr__(self, "score", v.finite_float(self.score, "candidate.score"))
        missing = [
            m
            for m in ("encoded", "decode")
            if not callable(getattr(self.tile_pixels_handle, m, None))
        ]
        v.require(
            not missing,
            "candidate.tile_pixels_handle",
            "expected a TilePixelsHandle (encoded() and decode()), "
            f"{type(self.tile_pixels_handle).__name__} lacks {', '.join(missing)}()",
        )
        if self.gsd_m_per_px is not None:
            g = v.finite_float(self.gsd_m_per_px, "candidate.gsd_m_per_px")
            v.require(g > 0, "candidate.gsd_m_per_px", f"must be > 0, got {g}")

    def ground_sample_distance_m(self) -> float:
        if self.gsd_m_per_px is not None:
            return float(self.gsd_m_per_px)
        return self.tile_id.web_mercator_gsd_m()


@dataclass(frozen=True, slots=True)
class RerankResult:
    """C2.5's output: the frame's top-N candidate tiles, best first. None at all is a valid
    proposal (no tile near the estimate): ``match`` then raises ``InsufficientInliersError``."""

    frame_id: uuid.UUID
    candidates: tuple[RerankCandidate, ...]

    def __post_init__(self) -> None:
        v.require(
            isinstance(self.frame_id, uuid.UUID),
            "rerank_result.frame_id",
            f"expected uuid.UUID, got {type(self.frame_id).__name__}",
        )
        cands = v.items(
            self.candidates, "rerank_result.candidates", "a sequence of RerankCandidate"
        )
        for i, c in enumerate(cands):
            v.require(
                isinstance(c, RerankCandidate),
                f"rerank_result.candidates[{i}]",
                f"expected RerankCandidate, got {type(c).__name__}",
            )
        object.__setattr__(self, "candidates", cands)
