"""A plugin's real ``FeatureBackend`` under the contract kit's script (``BackendContract``).

``ScriptedBackend`` wraps your backend: the script decides which candidate's ``extract`` or
``match`` raises, your code does the rest; ``MarkedRansac`` is the scripted RANSAC double for
the candidate it matched last.
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
from c3_matcher.probe import check_members
from c3_matcher.strategy import textured_probe
from c3_matcher.testing.fakes import FakeRansacFilter, ScriptedCandidate

__all__ = ["MarkedRansac", "ScriptedBackend"]


class ScriptedBackend:
    """Your ``FeatureBackend`` under a script: it reads which candidate an image is (the kit's
    tile ``i`` is the constant value ``i + 1``), raises where the script says
    (``fail_extract``, ``fail_match``), and otherwise runs YOUR ``extract`` on a deterministic
    textured stand-in of the same size and mask, and YOUR ``match``; ``last_mark`` tells the
    scripted RANSAC which candidate it is verifying."""

    def __init__(self, backend: FeatureBackend, script: list[ScriptedCandidate]) -> None:
        check_members(backend)
        self.inner = backend
        self.label: Final = backend.label
        self.input_rule: Final = backend.input_rule
        self.extract_phase: Final = backend.extract_phase
        self.match_phase: Final = backend.match_phase
        self.script = script
        self.last_mark = -1
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
        features = self.inner.extract(dataclasses.replace(image, image=textured_probe(w, h)))
        self._marks[id(features)] = (features, mark)
        return features

    def match(self, query: Features, tile: Features) -> RawMatches:
        _, mark = self._marks.get(id(tile), (tile, -1))
        scripted = self._scripted(mark)
        if scripted is not None and scripted.fail_match:
            raise RuntimeError(f"scripted matcher failure on candidate {mark}")
        raw = self.inner.match(query, tile)
        self.last_mark = mark
        return raw

    def provenance(self) -> Any:
        return self.inner.provenance()


class MarkedRansac(FakeRansacFilter):
    """The scripted RANSAC double for the candidate ``ScriptedBackend`` matched last."""

    def __init__(self, script: list[ScriptedCandidate], backend: ScriptedBackend) -> None:
        super().__init__(script)
        self._backend = backend

    def filter(self, correspondences: NDArray[np.float32], threshold_px: float) -> RansacResult:
        marked = np.array([[0.0, 0.0, 0.0, self._backend.last_mark + 1]], np.float32)
        return super().filter(marked, threshold_px)
