"""A plugin's real ``FeatureBackend`` under the contract kit's script (``BackendContract``).

``ScriptedBackend`` wraps your backend: the script decides which candidate's ``extract`` or
``match`` raises, your code does the rest on the probe texture, the query's shown a known
offset further right in every tile, and each match is checked against that offset;
``MarkedRansac`` is the scripted RANSAC double for the candidate it matched last.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import RansacResult
from c3_matcher.features import Features, RawMatches
from c3_matcher.pipeline import FeatureBackend
from c3_matcher.prepared import PreparedImage
from c3_matcher.probe import (
    check_members,
    check_shifted_matches,
    probe_shift,
    probe_side,
    textured_probe,
)
from c3_matcher.testing.fakes import QUERY_MARK, FakeRansacFilter, ScriptedCandidate

__all__ = ["MarkedRansac", "ScriptedBackend"]

_QUERY = QUERY_MARK - 1  # the mark ``extract`` reads from the query frame


class ScriptedBackend:
    """Your ``FeatureBackend`` under a script: it reads which candidate an image is (the kit's
    tile ``i`` is the constant value ``i + 1``), raises where the script says
    (``fail_extract``, ``fail_match``), and otherwise runs YOUR ``extract`` on a deterministic
    textured stand-in of the same size and mask (a tile's shows the query's ``shift`` px
    further right; by default ``probe_shift`` of your ``input_rule``), and YOUR ``match``;
    ``last_mark`` tells the scripted RANSAC which candidate it is verifying. A match of the
    query with a tile that does not follow the offset (``check_shifted_matches``) is kept in
    ``breaches``; ``assert_no_breach`` fails the test naming it."""

    def __init__(
        self, backend: FeatureBackend, script: list[ScriptedCandidate], shift: int | None = None
    ) -> None:
        check_members(backend)
        self.inner = backend
        self.label: Final = backend.label
        self.input_rule: Final = backend.input_rule
        self.extract_phase: Final = backend.extract_phase
        self.match_phase: Final = backend.match_phase
        self.script = script
        rule = backend.input_rule
        self.shift: Final = probe_shift(rule, probe_side(rule)) if shift is None else shift
        self.last_mark = -1
        self.breaches: list[str] = []
        self._marks: dict[int, tuple[Features, int]] = {}

    def _scripted(self, mark: int) -> ScriptedCandidate | None:
        return self.script[mark] if 0 <= mark < len(self.script) else None

    def extract(self, image: PreparedImage) -> Features:
        pixels = image.image[image.valid] if image.valid.any() else image.image.reshape(-1, 3)
        mark = int(np.bincount(pixels.reshape(-1)).argmax()) - 1
        scripted = self._scripted(mark)
        if scripted is not None and scripted.fail_extract:
            raise RuntimeError(f"scripted extractor failure on candidate {mark}")
        h, w = image.image.shape[:2]
        x0 = self.shift if mark == _QUERY else 0  # the query's texture, shift px into a tile's
        textured = textured_probe(w, h, x0=x0)
        features = self.inner.extract(dataclasses.replace(image, image=textured))
        self._marks[id(features)] = (features, mark)
        return features

    def match(self, query: Features, tile: Features) -> RawMatches:
        _, mark = self._marks.get(id(tile), (tile, -1))
        scripted = self._scripted(mark)
        if scripted is not None and scripted.fail_match:
            raise RuntimeError(f"scripted matcher failure on candidate {mark}")
        raw = self.inner.match(query, tile)
        self.last_mark = mark
        if self._marks.get(id(query), (query, -1))[1] == _QUERY and mark != _QUERY:
            try:
                check_shifted_matches(query, tile, raw, self.shift)
            except (TypeError, ValueError) as exc:
                self.breaches.append(f"match(query, tile {mark}): {exc}")
        return raw

    def provenance(self) -> Any:
        return self.inner.provenance()

    def assert_no_breach(self) -> None:
        """``AssertionError`` naming the first match that broke the (query, tile) contract."""
        assert not self.breaches, self.breaches[0]


class MarkedRansac(FakeRansacFilter):
    """The scripted RANSAC double for the candidate ``ScriptedBackend`` matched last."""

    def __init__(self, script: list[ScriptedCandidate], backend: ScriptedBackend) -> None:
        super().__init__(script)
        self._backend = backend

    def filter(self, correspondences: NDArray[np.float32], threshold_px: float) -> RansacResult:
        marked = np.array([[0.0, 0.0, 0.0, self._backend.last_mark + 1]], np.float32)
        return super().filter(marked, threshold_px)
