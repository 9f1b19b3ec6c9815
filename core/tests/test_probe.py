"""The start-up probe's error says what fixes it: ``engines build`` for a backend that runs
engines, the contract kit for one that runs none (a plugin's own OpenCV detector, say)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import ConfigurationError, EngineError
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import InputRule
from c3_matcher.probe import engine_startup_probe
from c3_matcher.testing.fakes import equal_descriptor_pairs, texture_features


class Blind:
    """A backend that finds no keypoint (the 0/1-mask pitfall of docs/plugins.md)."""

    label = "blind"
    input_rule = InputRule(max_long_side=1024, multiple=1)

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
    otherwise fail every frame as "no match" or inflate inlier counts; without a mistake it
    finds the probe texture's block corners and pairs equal descriptors, as a correct backend
    would."""

    label = "faulty"
    input_rule = InputRule(max_long_side=1024, multiple=1)

    def __init__(self, mistake: str) -> None:
        self.mistake = mistake

    def extract(self, image: Any) -> Features:
        out = texture_features(image.image, image.valid)
        kp = out["keypoints"]
        if self.mistake == "outside":
            kp[:5] += 5000
        size = (image.image.shape[1], image.image.shape[0])
        return Features(kp, out["descriptors"], out["keypoint_scores"], size)

    def match(self, query: Features, tile: Features) -> Any:
        pairs = equal_descriptor_pairs(query.descriptors, tile.descriptors).matches
        if self.mistake == "tuple":
            return pairs, np.ones(len(pairs), np.float32)
        if self.mistake == "index":
            pairs[0, 1] = 10**6
        if self.mistake == "twice":
            pairs = np.concatenate([pairs, pairs])
        if self.mistake == "tile_twice":  # a second query keypoint onto the first's tile keypoint
            pairs[1, 1] = pairs[0, 1]
        if self.mistake == "swapped":  # (tile, query): the matcher called the other way round
            pairs = equal_descriptor_pairs(tile.descriptors, query.descriptors).matches
        if self.mistake == "ignores_tile":  # keypoint i with keypoint i, whatever they show
            index = np.arange(min(len(query), len(tile)), dtype=np.int64)
            pairs = np.stack([index, index], 1)
        return RawMatches(pairs, np.ones(len(pairs), np.float32))

    def provenance(self) -> dict[str, Any]:
        return {"provider": "opencv", "engines": {}}


@pytest.mark.parametrize(
    ("mistake", "said"),
    [
        ("outside", "5 keypoint(s) outside the 128x128 px probe image"),
        ("tuple", "match returned tuple, not RawMatches"),
        ("index", "the matcher's output pairs tile keypoint 1000000, but the tile has"),
        ("twice", "(each query keypoint may be in one pair at most)"),
        ("tile_twice", "(each tile keypoint may be in one pair at most)"),
        ("swapped", "the matcher's output pairs query keypoint"),
        ("ignores_tile", "pairs join a query point (x, y) to the tile point (x + 16, y)"),
    ],
)
def test_a_backend_that_breaks_the_contract_stops_start_up_naming_how(mistake, said):
    with pytest.raises(EngineError) as failed:
        engine_startup_probe(Faulty(mistake))  # type: ignore[arg-type]
    assert said in str(failed.value)
    engine_startup_probe(Faulty("none"))  # type: ignore[arg-type]  # the same backend, mended


class ExitsEarly(Faulty):
    """A correct backend whose matcher stops a pair with fewer than ``needs`` pairs before
    matching it, as a setting tells it (LightGlue's unmatchable-pair exit), and says so through
    ``early_stop``."""

    def __init__(self, needs: int) -> None:
        super().__init__("none")
        self.needs = needs
        self.sides: list[int] = []
        self.stopped = False

    def match(self, query: Features, tile: Features) -> Any:
        self.sides.append(query.image_size[1])
        found = super().match(query, tile)
        self.stopped = len(found) < self.needs
        return (
            RawMatches(np.zeros((0, 2), np.int64), np.zeros(0, np.float32))
            if self.stopped
            else found
        )

    def required_matches(self) -> tuple[str, int] | None:
        return ("lightglue.exit_matches", self.needs)

    def early_stop(self) -> tuple[str, str] | None:
        return (
            ("lightglue.exit_matches", f"{self.needs} stopped the pair") if self.stopped else None
        )


def test_a_pair_a_setting_stops_early_is_probed_again_larger_not_called_an_engine_fault():
    """``[lightglue] exit_matches = 200`` (documented 0..8192) failed start-up as an engine
    fault with build advice: the 128 px probe pair has too few matches to pass the exit, though
    real frames do. A larger pair passes it, and the contract is checked on that one."""
    backend = ExitsEarly(needs=1000)  # the 128 px pair has ~440 corners, the 256 px ~1800
    engine_startup_probe(backend)  # type: ignore[arg-type]
    assert backend.sides == [128, 256]
    engine_startup_probe(ExitsEarly(needs=1))  # type: ignore[arg-type]  # passes at once


def test_a_setting_that_stops_even_the_largest_probe_pair_is_a_configuration_error():
    backend = ExitsEarly(needs=10**6)
    with pytest.raises(ConfigurationError) as refused:
        engine_startup_probe(backend)  # type: ignore[arg-type]
    assert backend.sides == [128, 256, 512]
    ((field, reason),) = refused.value.problems
    assert field == "lightglue.exit_matches" and "1000000 stopped the pair" in reason
    assert "512x512 px" in reason and "engines build" not in str(refused.value)


def test_an_empty_match_no_setting_explains_is_still_an_engine_fault():
    class Silent(ExitsEarly):
        def early_stop(self) -> None:
            return None

    backend = Silent(needs=10**6)
    with pytest.raises(EngineError, match="gave no match"):
        engine_startup_probe(backend)  # type: ignore[arg-type]
    assert backend.sides == [128]  # not tried larger


class ExitsOnExtract(Blind):
    """A backend whose extractor calls ``sys.exit()`` (or a library it calls does)."""

    def extract(self, image: Any) -> Features:
        raise SystemExit("licence check failed")


def test_a_plugins_sys_exit_in_the_probe_is_its_start_up_failure_not_the_processs_exit():
    """Raised outside every signal handler, it is the plugin's failure, as in flight."""
    with pytest.raises(EngineError) as failed:
        engine_startup_probe(ExitsOnExtract({}))  # type: ignore[arg-type]
    assert "start-up probe failed" in str(failed.value)
    assert "SystemExit: licence check failed" in str(failed.value)


class ExitsOnProvenance(ExitsOnExtract):
    """A failing backend whose ``provenance()`` calls ``sys.exit()`` too."""

    def provenance(self) -> dict[str, Any]:
        raise SystemExit("licence server gone")


def test_a_plugins_sys_exit_reading_its_provenance_after_a_failed_probe_is_contained():
    """The probe reads the provenance to advise on its failure as flight reads it: the plugin's
    exit there is no exit of the process; the advice is the engines' (it cannot tell)."""
    with pytest.raises(EngineError) as failed:
        engine_startup_probe(ExitsOnProvenance({}))  # type: ignore[arg-type]
    assert "SystemExit: licence check failed" in str(failed.value)
    assert "runs no engine" not in str(failed.value)
