"""A run keeps its output when its strategy's backend misbehaves after start-up: a
``provenance()`` that raises loses no frame and no report (each frame's record and the run's
provenance say ``provenance_error``), and a ``SystemExit`` from its ``extract`` on a frame is
that frame's backbone error, the run going on. Real path: the shipped demo flight cut to two
frames, the ``sift_magsac`` baseline composed as ``replay`` composes it, its FDR on disk."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.compose import build_plugin_host
from c3_matcher.config import C3Settings
from c3_matcher.pipeline import PipelineMatcher
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run.flight import fly_prepared
from c3_matcher_tools.run.matcher import prepare_matcher
from c3_matcher_tools.run.records import FlightRun, FrameStatus

SmallFlight = Callable[..., Path]  # the fixture of conftest.py


def _fly(flight: Path, out: Path, misbehave: Callable[[Any], None]) -> FlightRun:
    """The flight replayed with ``sift_magsac``, its backend made to ``misbehave`` once
    composed."""
    host = build_plugin_host()
    with prepare_matcher(C3Settings(), "sift_magsac", plugin_host=host) as prepared:
        assert isinstance(prepared.matcher, PipelineMatcher)
        misbehave(prepared.matcher.backend)
        return fly_prepared(prepared, load_dataset(flight), out, plugin_host=host)


def _frame_records(out: Path) -> list[dict[str, Any]]:
    lines = (out / "fdr.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    return [r for r in records if r["kind"].startswith("matcher.")]


def test_a_provenance_that_raises_loses_no_frame_and_no_run_output(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def unavailable() -> Any:
        raise RuntimeError("provenance unavailable")

    said = "provenance() raised RuntimeError: provenance unavailable"
    run = _fly(
        small_flight("prov"),
        tmp_path / "out",
        lambda backend: monkeypatch.setattr(backend, "provenance", unavailable),
    )
    assert run.provenance["provenance_error"] == said and "provider" not in run.provenance
    assert [o.status for o in run.outcomes] == [FrameStatus.OK, FrameStatus.INSUFFICIENT]
    records = _frame_records(tmp_path / "out")  # the second frame has no fix whatever it does
    assert [r["kind"] for r in records] == ["matcher.frame_done", "matcher.insufficient_inliers"]
    assert [r["payload"]["provenance_error"] for r in records] == [said, said]
    assert records[0]["payload"]["best_inlier_count"] >= 60


def test_a_system_exit_from_extract_is_that_frames_backbone_error(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def gives_up(backend: Any) -> None:
        real = backend.extract
        calls: list[int] = []

        def extract(image: Any) -> Any:
            calls.append(1)
            if len(calls) == 1:  # the first frame's query
                raise SystemExit("backend gave up")
            return real(image)

        monkeypatch.setattr(backend, "extract", extract)

    run = _fly(small_flight("sysexit"), tmp_path / "out", gives_up)
    statuses = [o.status for o in run.outcomes]
    assert statuses == [FrameStatus.BACKBONE_ERROR, FrameStatus.INSUFFICIENT]
    kinds = [(r["kind"], r["payload"].get("phase")) for r in _frame_records(tmp_path / "out")]
    assert kinds == [
        ("matcher.backbone_error", "query_extract"),
        ("matcher.insufficient_inliers", None),
    ]
    assert run.provenance["provider"]  # the backend's own, read at the end
