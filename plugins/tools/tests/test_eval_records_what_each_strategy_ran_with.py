"""``eval.json`` says what each strategy ran with, so that two evals can be told apart from it
alone: the keypoint budget it ran with (its own default when no setting names one) beside the
setting, and its provenance as its FDR records it (execution provider, engines) with the
c3-matcher version report.html names (xfeat on two frames)."""

from __future__ import annotations

import json
from importlib.metadata import version
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools.testing.cli import run_cli

from .conftest import _small_flight


@pytest.fixture(scope="module")
def evaluated(engine_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """xfeat evaluated on two frames, no keypoint setting given: its ``--out`` and the one
    strategy's ``eval.json`` entry."""
    where = tmp_path_factory.mktemp("ran_with")
    flight, out = _small_flight(where / "flight", "two_frames"), where / "ev"
    argv = (
        "eval", flight, "--strategy", "xfeat", "--no-baseline", "--determinism-frames", "1",
        "--samples", "0", "--out", out, "--json",
    )  # fmt: skip
    proc = run_cli(*argv, cwd=where, engine_dir=engine_dir, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (entry,) = json.loads(proc.stdout)["strategies"]
    return out, entry


def test_eval_json_names_the_keypoint_budget_a_strategy_ran_with(
    evaluated: tuple[Path, Any],
) -> None:
    _, entry = evaluated
    assert entry["settings"]["max_keypoints"] is None  # the setting: left unset
    assert entry["keypoint_budget"] == 4096  # what xfeat ran with (its mnn default)


def test_eval_json_names_the_provenance_a_strategy_ran_with(evaluated: tuple[Path, Any]) -> None:
    out, entry = evaluated
    records = [json.loads(line) for line in (out / "xfeat" / "fdr.jsonl").read_text().splitlines()]
    framed = [r["payload"] for r in records if "provider" in r.get("payload", {})]
    assert framed, "the FDR records no provider"
    provenance = entry["provenance"]
    assert provenance["provider"] == framed[0]["provider"]
    assert provenance["engines"] == framed[0]["engines"]
    assert provenance["c3-matcher"] == version("c3-matcher")
    assert provenance["matcher_labels"] == ["xfeat"]
    page = (out / "xfeat" / "report.html").read_text()
    assert provenance["provider"] in page  # the flight report names the same provider
