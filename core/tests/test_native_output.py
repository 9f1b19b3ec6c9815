"""What a strategy's native library writes to the process's stdout (C's ``printf``, a write to
descriptor 1) goes to stderr while a command runs: ``match``'s stdout stays exactly its one JSON
document, as a program reading it needs. Python's ``print`` was already sent there; a native
write went past it into the result. A real ORB backend on the demo frame and its real tiles."""

from __future__ import annotations

import ctypes
import json
import os
import types
from pathlib import Path
from typing import Any

import cv2
import pytest

from c3_matcher import plugins as c3
from c3_matcher.features import Features
from c3_matcher.plugins.manager import PluginSource
from c3_matcher.prepared import PreparedImage
from c3_matcher.strategy import backend_strategy_factory
from c3_matcher.testing.hosts import RESEARCH_PROFILE

from .test_contract_kit import OpenCvBackend

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"


class NativeOrb(OpenCvBackend):
    """ORB + cross-checked brute force whose extract writes to descriptor 1, as a vendor
    library does: directly, and through C's buffered stdio."""

    def extract(self, image: PreparedImage) -> Features:
        os.write(1, b"native library: extracting\n")
        ctypes.CDLL(None).printf(b"native printf: extracting\n")
        return super().extract(image)


def _host() -> c3.PluginHost:
    create = backend_strategy_factory(
        lambda _c, _o: NativeOrb(cv2.ORB_create(2000), cv2.NORM_HAMMING, "native_orb")
    )
    hook = c3.hookimpl(lambda: [c3.StrategySpec("native_orb", create)])
    module = types.SimpleNamespace(c3_matcher_strategies=hook)
    return c3.PluginHost(
        RESEARCH_PROFILE, [PluginSource("native", "acme-native", "1", module=module)]
    )


def _demo_args() -> list[str]:
    meta = json.loads((DEMO / "demo.json").read_text())
    att = meta["attitude_deg"]
    args = ["match", "--strategy", "native_orb", "--query", str(DEMO / "frame.jpg")]
    args += ["--calibration", str(DEMO / "calibration.json"), "--height", str(meta["height_m"])]
    args += ["--attitude", f"{att['roll']},{att['pitch']},{att['yaw']}"]
    args += ["--tile-gsd", str(meta["tile_gsd_m"]), "--no-correspondences"]
    for t in meta["tiles"]:
        args += ["--tile", str(DEMO / t["file"]), "--tile-id", ",".join(map(str, t["tile_id"]))]
    return args


def test_match_stdout_is_one_json_document_though_the_strategy_writes_natively(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: Any
) -> None:
    import c3_matcher.compose
    from c3_matcher.cli import main

    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", _host)
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    assert main(_demo_args()) == 0
    said = capfd.readouterr()
    result = json.loads(said.out)  # exactly one JSON document on stdout
    assert said.out.count("\n") == 1 and result["matcher_label"] == "native_orb"
    assert result["per_candidate"][0]["tile_index"] == 1  # the demo's true tile
    assert "native library: extracting" in said.err and "native printf: extracting" in said.err
