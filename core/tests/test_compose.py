"""compose_root: required keys, defaults, the ready log, helper identity (with test doubles)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from c3_matcher.compose import compose_root
from c3_matcher.config import C3Settings
from c3_matcher.errors import AirborneBootstrapError, StrategyNotLinkedError
from c3_matcher.fdr import FdrWriteError, JsonlFdrRecorder
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.plugins import PluginHost
from c3_matcher.profiles import BuildProfile
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing import (
    FakeBackend,
    FakeClock,
    fake_helpers,
    one_strategy_host,
)

PROFILE = BuildProfile.from_data(
    {
        "name": "research",
        "strict": False,
        "flags": {
            "BUILD_MATCHER_XFEAT": {
                "state": "OFF",
                "strategy": "xfeat",
                "distribution": "c3-matcher-xfeat",
            }
        },
    },
    "test",
)


class FakeStrategy(PipelineMatcher):
    def __init__(self, **kw):  # type: ignore[no-untyped-def]
        self.kwargs = kw
        self._lightglue_runtime = kw["lightglue_runtime"]
        super().__init__(
            FakeBackend(kw["inference_runtime"], kw["lightglue_runtime"]),
            kw["ransac_filter"],
            kw["fdr_client"],
            kw["health_window"],
            kw["clock"],
            PipelineSettings(),
        )


def fake_plugin_host() -> PluginHost:
    return one_strategy_host("fake_match", FakeStrategy, PROFILE)


def helpers():  # type: ignore[no-untyped-def]
    return fake_helpers()


def settings(tmp_path, strategy: str = "fake_match") -> C3Settings:
    return C3Settings(matcher={"strategy": strategy}, fdr={"path": tmp_path / "fdr.jsonl"})


@pytest.mark.parametrize("missing", ["c3_lightglue_runtime", "c282_ransac_filter", "c7_inference"])
def test_missing_required_key_names_consumer_and_key(tmp_path, missing):
    pre = helpers()
    del pre[missing]
    with pytest.raises(AirborneBootstrapError) as info:
        compose_root(settings(tmp_path), pre, plugin_host=fake_plugin_host(), configure_logs=False)
    assert (info.value.consumer, info.value.key) == ("c3_matcher", missing)


def test_wrong_helper_type_is_refused(tmp_path):
    pre = helpers()
    pre["c282_ransac_filter"] = object()
    with pytest.raises(AirborneBootstrapError, match="expected a RansacFilter"):
        compose_root(settings(tmp_path), pre, plugin_host=fake_plugin_host(), configure_logs=False)


class _Clock:
    def __init__(self, read):  # type: ignore[no-untyped-def]
        self.monotonic_ns = read


def _fail() -> int:
    raise OSError("no time source")


@pytest.mark.parametrize(
    ("read", "said"),
    [
        (lambda: 1.5e9, "monotonic_ns() gave 1500000000.0 (float), not an int of nanoseconds"),
        (  # numpy's repr of the value: np.int64(7) from numpy 2, 7 before
            lambda: np.int64(7),
            f"monotonic_ns() gave {np.int64(7)!r} (int64), not an int of nanoseconds",
        ),
        (lambda: -5, "monotonic_ns() gave -5, not nanoseconds >= 0"),
        (_fail, "monotonic_ns() raised OSError: no time source"),
    ],
    ids=["float", "numpy", "negative", "raises"],
)
def test_a_clock_that_cannot_time_frames_is_refused_at_start_up(tmp_path, read, said):
    """It passed (it has a ``monotonic_ns``), then every frame's success was recorded, health
    counted it, and the frame failed as an internal error: two contradictory FDR records (a
    numpy integer: no FDR record could be written, not being JSON)."""
    pre = {**helpers(), "clock": _Clock(read)}
    with pytest.raises(AirborneBootstrapError) as info:
        compose_root(settings(tmp_path), pre, plugin_host=fake_plugin_host(), configure_logs=False)
    assert info.value.key == "clock" and said in str(info.value)


def test_wires_strategy_shares_helpers_and_logs_ready(tmp_path, fdr, logs):
    pre = {**helpers(), "c13_fdr": fdr, "clock": FakeClock()}
    root = compose_root(
        settings(tmp_path), pre, plugin_host=fake_plugin_host(), configure_logs=False
    )
    assert isinstance(root.matcher, CrossDomainMatcher)
    assert root.matcher._lightglue_runtime is pre["c3_lightglue_runtime"]  # type: ignore[attr-defined]
    assert root.matcher.kwargs["fdr_client"] is fdr  # type: ignore[attr-defined]
    ready = logs.of_kind("c3.matcher.ready")
    assert len(ready) == 1
    assert (
        ready[0]["strategy"],
        ready[0]["min_inliers_threshold"],
        ready[0]["residual_warn_threshold_px"],
    ) == ("fake_match", 60, 2.5)


def test_builds_the_durable_recorder_when_no_fdr_is_given(tmp_path):
    root = compose_root(
        settings(tmp_path), helpers(), plugin_host=fake_plugin_host(), configure_logs=False
    )
    try:
        assert isinstance(root.fdr, JsonlFdrRecorder)
        assert root.fdr.path == tmp_path / "fdr.jsonl"
    finally:
        root.close()


def test_the_recorder_it_builds_holds_at_most_fdr_max_pending_bytes_on_a_full_disk(
    tmp_path, monkeypatch
):
    bounded = C3Settings(
        matcher={"strategy": "fake_match"},
        fdr={"path": tmp_path / "fdr.jsonl", "max_pending_bytes": 2048},
    )
    root = compose_root(bounded, helpers(), plugin_host=fake_plugin_host(), configure_logs=False)
    monkeypatch.setattr(os, "write", lambda fd, data: (_ for _ in ()).throw(OSError(28, "full")))
    for i in range(40):
        with pytest.raises(FdrWriteError):
            root.fdr.record("k", {"i": i, "pad": "x" * 100})
    assert isinstance(root.fdr, JsonlFdrRecorder)
    assert 0 < root.fdr.pending < 20 and root.fdr.pending + root.fdr.dropped == 40
    monkeypatch.undo()
    root.close()


def test_strategy_not_linked(tmp_path):
    with pytest.raises(StrategyNotLinkedError, match="xfeat.*research"):
        compose_root(
            settings(tmp_path, "xfeat"),
            helpers(),
            plugin_host=fake_plugin_host(),
            configure_logs=False,
        )
    # the recorder it built for the failed composition was closed (one writer per path)
    JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock()).close()


def test_closes_the_recorder_it_built_and_never_a_given_one(tmp_path):
    root = compose_root(
        settings(tmp_path), helpers(), plugin_host=fake_plugin_host(), configure_logs=False
    )
    root.close()
    given = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())  # the path is free again
    try:
        root = compose_root(
            settings(tmp_path),
            {**helpers(), "c13_fdr": given},
            plugin_host=fake_plugin_host(),
            configure_logs=False,
        )
        root.close()
        given.record("after.close", {})  # still open: the caller's to close
    finally:
        given.close()
    assert "after.close" in (tmp_path / "fdr.jsonl").read_text()


def test_a_failed_composition_takes_its_log_sinks_away_again(tmp_path):
    from c3_matcher.fdr import InMemoryFdr
    from c3_matcher.logs import log_event

    fdr = InMemoryFdr()
    with pytest.raises(StrategyNotLinkedError):
        compose_root(
            settings(tmp_path, "xfeat"),
            {**helpers(), "c13_fdr": fdr},
            plugin_host=fake_plugin_host(),
        )
    log_event("WARNING", "c3.test.after", "after the failed composition")
    assert fdr.of_kind("log.warning") == []  # its sink forwarded nothing more
