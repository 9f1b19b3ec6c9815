"""The start-up probe's error says what fixes it: ``engines build`` for a backend that runs
engines, the contract kit for one that runs none (a plugin's own OpenCV detector, say)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import EngineError
from c3_matcher.features import Features
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
