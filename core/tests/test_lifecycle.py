"""The matcher's life as an integrator sees it: ``close()`` ends it (a later ``match`` is refused
with ``MatcherClosedError``, a frame in progress in another thread finishes first with its
records), calls from two threads are serialised, and an internal check that fails inside
``match`` is the contract's ``MatcherBackboneError`` (phase ``internal``), never the caller's
``InvalidInputError``. Scripted doubles, composed through ``compose_root`` with the durable
recorder it builds."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.compose import ComposedRoot, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.errors import (
    InsufficientInliersError,
    InvalidInputError,
    MatcherBackboneError,
    MatcherClosedError,
)
from c3_matcher.fdr import read_fdr
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.testing import (
    FakeBackend,
    ScriptedCandidate,
    ScriptedRig,
    fake_helpers,
    make_frame,
    make_rerank,
    one_strategy_host,
    pipeline_strategy,
)

S = ScriptedCandidate
SCRIPT = [S(100), S(90)]
WAIT_S = 10.0


class GatedBackend(FakeBackend):
    """Extraction waits at ``gate`` (when set up) after saying so on ``entered``, and counts how
    many extractions run at once."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.entered = threading.Event()
        self.gate: threading.Event | None = None
        self.active = 0
        self.most_active = 0
        self._count = threading.Lock()

    def extract(self, image: PreparedImage) -> Features:
        with self._count:
            self.active += 1
            self.most_active = max(self.most_active, self.active)
        try:
            self.entered.set()
            if self.gate is not None:
                assert self.gate.wait(WAIT_S)
            return super().extract(image)
        finally:
            with self._count:
                self.active -= 1


def _root(tmp_path: Path) -> ComposedRoot:
    host = one_strategy_host("gated", pipeline_strategy(GatedBackend))
    settings = C3Settings(matcher={"strategy": "gated"}, fdr={"path": tmp_path / "fdr.jsonl"})
    return compose_root(settings, fake_helpers(SCRIPT), plugin_host=host, configure_logs=False)


def _inputs() -> tuple[Any, Any, Any]:
    frame, calibration = make_frame()
    return frame, make_rerank(frame.frame_id, SCRIPT), calibration


def _kinds(tmp_path: Path) -> list[str]:
    return [r["kind"] for r in read_fdr(tmp_path / "fdr.jsonl")]


def test_match_after_close_is_refused_with_its_one_health_update_and_no_record(tmp_path):
    root = _root(tmp_path)
    frame, rerank, calibration = _inputs()
    assert root.matcher.match(frame, rerank, calibration).per_candidate[0].inlier_count == 100
    root.close()
    root.close()  # twice: nothing more happens
    with pytest.raises(MatcherClosedError, match="closed.*after close"):
        root.matcher.match(frame, rerank, calibration)
    assert _kinds(tmp_path) == ["matcher.frame_done"]  # the refused call left no half record
    assert root.health_window.update_count == 2  # once per call, whatever the outcome: no fix
    assert root.health_window.last_update.best_inlier_count == 0
    assert not root.health_window.last_update.had_backbone_error


def test_close_waits_for_the_frame_in_progress_and_keeps_its_record(tmp_path):
    root = _root(tmp_path)
    backend = root.matcher.backend  # type: ignore[attr-defined]
    backend.gate = threading.Event()
    frame, rerank, calibration = _inputs()
    outcome: dict[str, Any] = {}

    def match() -> None:
        outcome["result"] = root.matcher.match(frame, rerank, calibration)

    matching = threading.Thread(target=match)
    matching.start()
    assert backend.entered.wait(WAIT_S)
    closing = threading.Thread(target=root.close)
    closing.start()
    closing.join(0.3)
    assert closing.is_alive()  # close() waits for the frame in progress
    backend.gate.set()
    matching.join(WAIT_S)
    closing.join(WAIT_S)
    assert not closing.is_alive() and outcome["result"].per_candidate[0].inlier_count == 100
    assert _kinds(tmp_path) == ["matcher.frame_done"]  # written before the recorder closed
    with pytest.raises(MatcherClosedError):
        root.matcher.match(frame, rerank, calibration)


def test_calls_from_two_threads_are_serialised(tmp_path):
    root = _root(tmp_path)
    backend = root.matcher.backend  # type: ignore[attr-defined]
    backend.gate = threading.Event()
    frame, rerank, calibration = _inputs()
    results: list[Any] = []
    threads = [
        threading.Thread(
            target=lambda: results.append(root.matcher.match(frame, rerank, calibration))
        )
        for _ in range(2)
    ]
    for t in threads:
        t.start()
    assert backend.entered.wait(WAIT_S)
    threading.Event().wait(0.3)  # the second caller has had time to enter, were it let in
    backend.gate.set()
    for t in threads:
        t.join(WAIT_S)
    root.close()
    assert backend.most_active == 1
    first, second = (r.per_candidate[0] for r in results)
    assert first.same_content(second)
    assert root.health_window.update_count == 2
    assert _kinds(tmp_path) == ["matcher.frame_done", "matcher.frame_done"]


def test_an_internal_check_failing_is_a_backbone_error_not_the_callers(fdr, logs, monkeypatch):
    rig = ScriptedRig(SCRIPT, fdr)

    def broken(*args: Any) -> Any:
        raise InvalidInputError("match_result.per_candidate", "an internal invariant broke")

    monkeypatch.setattr("c3_matcher.pipeline.ranked", broken)
    with pytest.raises(MatcherBackboneError) as info:
        rig.match()
    assert info.value.phase == "internal"
    assert fdr.of_kind("matcher.invalid_input") == []
    (record,) = fdr.of_kind("matcher.backbone_error")
    assert record["phase"] == "internal" and "an internal invariant broke" in record["error"]
    assert rig.health.update_count == 1 and rig.health.last_update.had_backbone_error


def test_non_finite_original_px_drops_the_candidate(fdr, logs, monkeypatch):
    """A correspondence that cannot be mapped back to the frame's pixels (a lens model that
    diverges there) drops its candidate in phase ``ransac``; it is no refused input."""
    rig = ScriptedRig(SCRIPT, fdr)

    def diverging(self: PreparedImage, rows: Any) -> Any:
        out = np.array(rows, dtype=np.float32)
        out[:, 0] = np.inf
        return out

    monkeypatch.setattr(PreparedImage, "in_original_px", diverging)
    with pytest.raises(InsufficientInliersError) as info:
        rig.match()
    assert (info.value.candidates_input, info.value.candidates_dropped) == (2, 2)
    records = fdr.of_kind("matcher.backbone_error")
    assert [r["phase"] for r in records] == ["ransac", "ransac"]
    assert "inlier_correspondences" in records[0]["error"]
    assert fdr.of_kind("matcher.invalid_input") == []
    assert rig.health.update_count == 1 and rig.health.last_update.had_backbone_error
