"""The start-up probe on images its backend takes, matched with a moved copy of themselves.

Its images follow the backend's ``input_rule`` (a network that takes multiples of 14 or 48 is not
refused for an image the probe made the wrong size, nor told to rebuild its engines), and the
tile is the query's texture moved a known offset: a backend whose pairs are (tile, query), that
ignores what it matches, or pairs one query keypoint twice stops the start-up; the shipped way
of matching (cross-checked brute force, a real extractor engine with LightGlue) passes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher.compose import build_default_helpers
from c3_matcher.config import C3Settings
from c3_matcher.engines.manifest import EngineManifest
from c3_matcher.engines.store import EngineStore
from c3_matcher.errors import EngineError
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.probe import engine_startup_probe, probe_pair, probe_shift
from c3_matcher.strategy import ExtractorLightGlueConfig, ExtractorMatcher
from c3_matcher.testing.strategy_kit import matcher_over_helpers


class Orb:
    """ORB + cross-checked brute-force Hamming (the plugin guide's backend) on a network-like
    input rule: ``extract`` refuses sides that are not multiples of ``multiple``."""

    label, extract_phase, match_phase = "orb", "orb_detect", "bf_hamming"

    def __init__(self, multiple: int = 1, max_long_side: int = 1024) -> None:
        self.input_rule = InputRule(max_long_side=max_long_side, multiple=multiple)
        self.seen: list[tuple[int, int]] = []
        self._orb = cv2.ORB_create(2000)
        self._bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)

    def extract(self, image: PreparedImage) -> Features:
        h, w = image.image.shape[:2]
        self.seen.append((w, h))
        m = self.input_rule.multiple
        if h % m or w % m or max(h, w) > self.input_rule.max_long_side:
            raise ValueError(f"{w}x{h} px breaks this backend's input_rule")
        grey = cv2.cvtColor(image.image, cv2.COLOR_RGB2GRAY)
        kps, desc = self._orb.detectAndCompute(grey, image.valid.astype(np.uint8) * 255)
        desc = np.zeros((0, 32), np.uint8) if desc is None else desc
        xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        return Features(xy, desc, np.array([k.response for k in kps], np.float32), (w, h))

    def pairs(self, query: Features, tile: Features) -> list[tuple[int, int]]:
        found = self._bf.match(query.descriptors, tile.descriptors) if len(query) else []
        return [(m.queryIdx, m.trainIdx) for m in found]

    def match(self, query: Features, tile: Features) -> RawMatches:
        pairs = np.array(self.pairs(query, tile), np.int64).reshape(-1, 2)
        return RawMatches(pairs, np.ones(len(pairs), np.float32))

    def provenance(self) -> dict[str, Any]:
        return {"provider": "opencv", "engines": {}}


class SwappedOrb(Orb):
    """The matcher called (tile, query): each pair is (tile index, query index)."""

    def pairs(self, query: Features, tile: Features) -> list[tuple[int, int]]:
        return [
            (m.queryIdx, m.trainIdx) for m in self._bf.match(tile.descriptors, query.descriptors)
        ]


class IgnoresTile(Orb):
    """Pairs keypoint i with keypoint i, whatever the two images show."""

    def pairs(self, query: Features, tile: Features) -> list[tuple[int, int]]:
        return [(i, i) for i in range(min(len(query), len(tile)))]


class TileSideNearest(Orb):
    """Each tile keypoint takes its nearest query keypoint, no cross-check: a query keypoint
    the tile's new texture also lands on is paired twice."""

    def pairs(self, query: Features, tile: Features) -> list[tuple[int, int]]:
        nearest = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=False)
        return [
            (m.trainIdx, m.queryIdx) for m in nearest.match(tile.descriptors, query.descriptors)
        ]


@pytest.mark.parametrize(
    ("multiple", "max_long_side", "side"),
    [(14, 1022, 140), (48, 1024, 144), (32, 1024, 128), (64, 1024, 128), (1, 1024, 128)],
)
def test_the_probe_images_follow_the_backends_input_rule(multiple, max_long_side, side):
    """A correct backend whose network takes multiples of 14 (a ViT patch) or 48 was refused:
    the probe gave it 128x128 px whatever its rule said."""
    backend = Orb(multiple, max_long_side)
    engine_startup_probe(backend)  # type: ignore[arg-type]
    shift = probe_shift(backend.input_rule, side)
    assert shift % multiple == 0 and 16 <= shift <= side // 2
    assert backend.seen == [(side, side), (side + shift, side)]  # query, the tile holding it


@pytest.mark.parametrize(
    ("backend", "said"),
    [
        (SwappedOrb(), "(query index, tile index)"),
        (IgnoresTile(), "(query index, tile index)"),
        (TileSideNearest(), "(each query keypoint may be in one pair at most)"),
    ],
)
def test_a_match_that_breaks_the_query_tile_contract_stops_the_start_up(backend, said):
    """Each passed the probe that matched an image with itself (every pair (i, i))."""
    with pytest.raises(EngineError) as failed:
        engine_startup_probe(backend)
    message = str(failed.value)
    assert said in message or "but the tile has" in message, message
    assert "16 px in" in message and failed.value.command is None


def _disk_engines(engine_dir: Path, tmp_path: Path, multiple: int) -> tuple[Path, Path]:
    """The installed DISK extractor engine, copied with a manifest (and its build key) that
    says it takes sides that are multiples of ``multiple`` (the graph takes any multiple of
    16), and LightGlue."""
    store = EngineStore(engine_dir)
    disk = store.require("disk", "depth")
    manifest = json.loads(disk.with_name(disk.stem + ".manifest.json").read_text())
    rule = manifest["input_rule"]
    manifest.update(size_multiple=multiple, input_rule=rule.replace("hw16", f"hw{multiple}"))
    key = EngineManifest.from_json(manifest).recomputed_key()
    name = disk.name.replace(rule, manifest["input_rule"])
    name = name.replace(manifest["build_key"][:10], key[:10])
    manifest.update(file=name, build_key=key)
    shutil.copyfile(disk, tmp_path / name)
    (tmp_path / name).with_suffix(".manifest.json").write_text(json.dumps(manifest))
    return tmp_path / name, store.require("lightglue", "disk")


def _disk_matcher(engine_dir: Path, tmp_path: Path, engine: int, rule: int) -> ExtractorMatcher:
    settings = C3Settings(engines={"directory": engine_dir}, fdr={"path": tmp_path / "f.jsonl"})
    extractor, lightglue = _disk_engines(engine_dir, tmp_path, engine)
    config = ExtractorLightGlueConfig.from_settings(
        settings,
        label="disk48",
        feature_type="disk",
        extract_phase="disk_forward",
        extractor_engine_path=extractor,
        lightglue_engine_path=lightglue,
        size_multiple=rule,
    )
    return matcher_over_helpers(ExtractorMatcher, config, build_default_helpers(settings))


def test_a_real_engine_that_takes_multiples_of_48_passes_the_probe(engine_dir, tmp_path):
    """It matched the demo frame in flight, and start-up refused it ("needs H and W multiples
    of 48, got 128x128; build it with c3-matcher engines build")."""
    matcher = _disk_matcher(engine_dir, tmp_path, engine=48, rule=48)
    engine_startup_probe(matcher.backend)


def test_a_rule_the_engine_refuses_is_refused_at_start_up_without_build_advice(
    engine_dir, tmp_path
):
    """Sides that are multiples of 24 are not all multiples of the engine's 16: every frame
    would fail; rebuilding the engine would not help."""
    with pytest.raises(EngineError) as refused:
        _disk_matcher(engine_dir, tmp_path, engine=16, rule=24)
    said = str(refused.value)
    assert "multiples of 16" in said and "multiples of 24" in said and "disk48" in said
    assert refused.value.command is None and "engines build" not in said


@pytest.mark.parametrize(
    ("rule", "query", "tile", "shift"),
    [
        (InputRule(1024, 16), (128, 128), (144, 128), 16),
        (InputRule(1024, 48), (144, 144), (192, 144), 48),
        (InputRule(180, 48), (96, 144), (144, 144), 48),  # a 192 px tile would pass 180
        (InputRule(100, 16), (80, 96), (96, 96), 16),
        (InputRule(40, 32), (32, 32), (32, 32), 0),  # no room to move: the image itself
    ],
)
def test_the_probe_pair_keeps_to_the_rules_long_side(rule, query, tile, shift):
    q, t, s = probe_pair(rule)
    assert (q.engine_size, t.engine_size, s) == (query, tile, shift)
    assert np.array_equal(q.image, t.image[:, s : s + query[0]])  # the tile holds the query
    for size in (q.engine_size, t.engine_size):
        assert max(size) <= rule.max_long_side and size[0] % rule.multiple == 0
