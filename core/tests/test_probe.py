"""The start-up probe's error says what fixes it: ``engines build`` for a backend that runs
engines, the contract kit for one that runs none (a plugin's own OpenCV detector, say)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import EngineError
from c3_matcher.features import Features, RawMatches
from c3_matcher.probe import engine_startup_probe


class Blind:
    """A backend that finds no keypoint (the 0/1-mask pitfall of docs/plugins.md)."""

    label = "blind"

    def __init__(self, engines: dict[str, Any]) -> None:
        self.engines = engines

    def extract(self, image: Any) -> Features:
        return Features(
            np.zeros((0, 2), np.float32),
            np.zeros((0, 32), np.float32),
            np.zeros(0, np.float32),
            image.working_size,
        )

    def match(self, query: Features, tile: Features) -> Any:
        raise AssertionError("never reached: no keypoint")

    def provenance(self) -> dict[str, Any]:
        return {"provider": "opencv", "engines": self.engines}


def test_a_backend_without_engines_is_pointed_at_the_contract_kit_not_at_engines_build():
    with pytest.raises(EngineError) as failed:
        engine_startup_probe(Blind({}))  # type: ignore[arg-type]
    said = str(failed.value)
    assert "found no keypoint" in said and "BackendContract" in said
    assert "engines build" not in said and failed.value.command is None


def test_a_backend_that_runs_engines_is_told_to_build_them():
    with pytest.raises(EngineError) as failed:
        engine_startup_probe(Blind({"extractor": {"file_sha256": "ab" * 32}}))  # type: ignore[arg-type]
    assert str(failed.value).endswith("build it with `c3-matcher engines build`")


class Faulty:
    """A plugin's backend with one of the mistakes the probe stops at start-up, which would
    otherwise fail every frame as "no match" or inflate inlier counts."""

    label = "faulty"

    def __init__(self, mistake: str) -> None:
        self.mistake = mistake

    def extract(self, image: Any) -> Features:
        xy = np.stack(np.meshgrid(np.arange(8.0, 120, 16), np.arange(8.0, 120, 16)), -1)
        kp = xy.reshape(-1, 2).astype(np.float32)
        if self.mistake == "outside":
            kp[:5] += 5000
        n = len(kp)
        return Features(kp, np.eye(n, 32, dtype=np.float32), np.ones(n, np.float32), (128, 128))

    def match(self, query: Features, tile: Features) -> Any:
        index = np.arange(len(query), dtype=np.int64)
        pairs = np.stack([index, index], 1)
        if self.mistake == "tuple":
            return pairs, np.ones(len(pairs), np.float32)
        if self.mistake == "index":
            pairs[0, 1] = 10**6
        if self.mistake == "twice":
            pairs = np.concatenate([pairs, pairs])
        return RawMatches(pairs, np.ones(len(pairs), np.float32))

    def provenance(self) -> dict[str, Any]:
        return {"provider": "opencv", "engines": {}}


@pytest.mark.parametrize(
    ("mistake", "said"),
    [
        ("outside", "5 keypoint(s) outside the 128x128 px probe image"),
        ("tuple", "match returned tuple, not RawMatches"),
        ("index", "match gave indices outside the 49 keypoints it was given"),
        ("twice", "match paired one query keypoint more than once"),
    ],
)
def test_a_backend_that_breaks_the_contract_stops_start_up_naming_how(mistake, said):
    with pytest.raises(EngineError) as failed:
        engine_startup_probe(Faulty(mistake))  # type: ignore[arg-type]
    assert said in str(failed.value)
    engine_startup_probe(Faulty("none"))  # type: ignore[arg-type]  # the same backend, mended
