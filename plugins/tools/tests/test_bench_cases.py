"""``c3-matcher bench``: the cases it plans (a PyTorch reference case only for a strategy whose
plugin offers one: never for the SIFT + MAGSAC baseline, which has none) and the data it reads
under ``[matcher] max_image_pixels`` (refused as ``replay`` refuses it: up front, and in the
worker that times the case). Cheapest strategy (``sift_magsac``, no engines), one run."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import pytest

import c3_matcher_tools.bench
from c3_matcher.config import C3Settings
from c3_matcher_tools.bench import BenchCase, cases_for

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
DEMO = REPO / "data" / "demo"
SMALL = 50_000
"""A ``max_image_pixels`` below the shipped frames (the demo flight's are 640x480 px)."""


def _args(*strategies: str, **flags: Any) -> argparse.Namespace:
    """``bench``'s parsed command line: ``strategies``, no optional case unless ``flags``."""
    values: dict[str, Any] = {
        "strategy": list(strategies),
        "no_reference": False,
        "no_baseline": True,
        "no_stored": True,
        "no_modes": True,
        "keypoints": None,
        "threads": None,
        "sweep": False,
    }
    return argparse.Namespace(**{**values, **flags})


@pytest.fixture()
def with_torch(monkeypatch: pytest.MonkeyPatch) -> None:
    """As where the engine-build environment (torch) is installed."""
    monkeypatch.setattr(c3_matcher_tools.bench, "_has_torch", lambda: True)


@pytest.mark.usefixtures("with_torch")
def test_a_baseline_gets_no_pytorch_reference_case() -> None:
    cases = cases_for(_args("sift_magsac"), C3Settings(), FLIGHT)
    assert cases and all(c.strategy == "sift_magsac" for c in cases)
    assert [c.kind for c in cases] == ["engine", "engine"], [c.label for c in cases]


@pytest.mark.usefixtures("with_torch")
def test_a_learned_strategy_keeps_its_pytorch_reference_case() -> None:
    cases = cases_for(_args("xfeat", "sift_magsac"), C3Settings(), FLIGHT)
    assert [(c.strategy, c.kind) for c in cases if c.kind == "pytorch"] == [("xfeat", "pytorch")]
    no_ref = cases_for(_args("xfeat", no_reference=True), C3Settings(), FLIGHT)
    assert all(c.kind == "engine" for c in no_ref)


def test_bench_of_the_baseline_runs_and_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    """Where torch is installed it planned ``sift_magsac[pytorch]``, whose worker failed (no
    reference for sift_magsac) and threw away the timed cases with exit 1."""
    from c3_matcher.cli import main

    argv = ["bench", "--runs", "1", "--strategy", "sift_magsac", "--no-baseline", "--no-stored"]
    assert main([*argv, "--data", str(FLIGHT)]) == 0, capsys.readouterr().err[-2000:]
    out = capsys.readouterr().out
    assert "sift_magsac (new tiles" in out and "sift_magsac (cached tiles" in out
    assert "[pytorch]" not in out


def _small_config(tmp_path: Path) -> Path:
    config = tmp_path / "small.toml"
    config.write_text(f"[matcher]\nmax_image_pixels = {SMALL}\n")
    return config


@pytest.mark.parametrize("data", [FLIGHT, DEMO], ids=["flight", "demo-format"])
def test_bench_refuses_frames_above_the_configured_max_image_pixels(
    data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    no_bench_case: None,
) -> None:
    """As ``replay`` refuses them: exit 2 naming the limit, before any case runs."""
    from c3_matcher.cli import main

    config = _small_config(tmp_path)
    argv = ["bench", "--runs", "1", "--strategy", "sift_magsac", "--no-reference"]
    code = main(["--config", str(config), *argv, "--no-baseline", "--data", str(data)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"exceeds the limit of {SMALL} px" in err and "max_image_pixels" in err, err


def test_the_worker_reads_frames_under_the_configured_max_image_pixels(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The case's worker reads the data under the same limit (one JSON line, exit 2, no
    answer)."""
    import io

    from c3_matcher_tools.bench_worker import _worker_main

    case = json.dumps(asdict(BenchCase("sift_magsac", "engine", 0, 1024, None)))
    config = _small_config(tmp_path)
    answers = io.StringIO()
    argv = [case, "1", str(FLIGHT), "--config", str(config)]
    assert _worker_main(argv, io.StringIO(), answers) == 2 and answers.getvalue() == ""
    refused = json.loads(capsys.readouterr().err.strip().splitlines()[-1])
    assert f"exceeds the limit of {SMALL} px" in refused["reason"], refused


def test_flight_inputs_read_under_the_given_limit() -> None:
    from c3_matcher.errors import InvalidInputError
    from c3_matcher_tools.run.inputs import flight_inputs

    for data in (FLIGHT, DEMO):
        with (
            pytest.raises(InvalidInputError, match=f"exceeds the limit of {SMALL} px"),
            flight_inputs(data, SMALL),
        ):
            pass
