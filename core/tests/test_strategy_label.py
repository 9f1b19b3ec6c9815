"""The results and flight-data records name the strategy the user selected (``matcher_label``),
not its backend's ``label``: one backend class serving two strategies, or a label copied from
the guide's example, put another strategy's name into every record. A real ORB backend on the
demo frame and its real tiles, real RANSAC."""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import cv2
import pytest

from c3_matcher import plugins as c3
from c3_matcher.compose import compose_root
from c3_matcher.config import C3Settings
from c3_matcher.demo import demo_inputs
from c3_matcher.dto import RerankResult
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.plugins.manager import PluginSource
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.strategy import backend_strategy_factory
from c3_matcher.testing.hosts import RESEARCH_PROFILE, fake_helpers

from .test_contract_kit import OpenCvBackend

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"


def _orb(_config: Any, _options: Any) -> OpenCvBackend:
    return OpenCvBackend(cv2.ORB_create(2000), cv2.NORM_HAMMING, "orb_bf")


def _host() -> c3.PluginHost:
    """One distribution offering ``orb_bf`` and ``orb_bf_fast``, one backend class (its label
    ``orb_bf``) behind both."""
    create = backend_strategy_factory(_orb)
    specs = [c3.StrategySpec("orb_bf", create), c3.StrategySpec("orb_bf_fast", create)]
    module = types.SimpleNamespace(c3_matcher_strategies=c3.hookimpl(lambda: specs))
    return c3.PluginHost(RESEARCH_PROFILE, [PluginSource("orb", "c3-orb-bf", "0.1", module=module)])


@pytest.mark.parametrize("strategy", ["orb_bf_fast", "orb_bf"])
def test_results_and_records_name_the_strategy_selected(strategy: str) -> None:
    fdr = InMemoryFdr()
    helpers = {**fake_helpers(), "c282_ransac_filter": OpenCvRansacFilter(), "c13_fdr": fdr}
    settings = C3Settings(matcher={"strategy": strategy})
    root = compose_root(settings, helpers, plugin_host=_host(), configure_logs=False)
    frame, rerank, calibration = demo_inputs(DEMO)
    try:
        result = root.matcher.match(frame, rerank, calibration)
        wrong = RerankResult(frame.frame_id, (rerank.candidates[0], rerank.candidates[2]))
        with pytest.raises(InsufficientInliersError) as no_fix:
            root.matcher.match(frame, wrong, calibration)
    finally:
        root.close()
    assert result.matcher_label == strategy and no_fix.value.matcher_label == strategy
    (done,) = fdr.of_kind("matcher.frame_done")
    (missed,) = fdr.of_kind("matcher.insufficient_inliers")
    assert done["matcher_label"] == missed["matcher_label"] == strategy
