"""A run's report records the ``[lightglue]`` settings only for a strategy that reads them: the
SIFT baseline (and XFeat with mutual nearest neighbours) matches without LightGlue, so its
``lightglue_settings`` is empty, and a value the user set there is said once in the run's
``matcher.log``. The report recorded them as if they had applied, ``filter_threshold`` 0.99
included, while the run was the same without them."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from c3_matcher.cli import main

from .conftest import SmallFlight


def test_the_baselines_report_records_no_lightglue_settings(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    small_flight: SmallFlight,
) -> None:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD", "0.99")
    flight, out = small_flight("naip_demo"), tmp_path / "run"
    argv = ["replay", str(flight), "--limit", "1", "--strategy", "sift_magsac", "--out", str(out)]
    assert main(argv) == 0, capsys.readouterr().err[-2000:]
    report = json.loads((out / "report.json").read_text())
    assert report["lightglue_settings"] == {}
    assert report["settings"]["strategy"] == "sift_magsac"
    logged = [json.loads(line) for line in (out / "matcher.log").read_text().splitlines()]
    (ignored,) = [r for r in logged if r["kind"] == "c3.config.ignored"]
    assert ignored["settings"] == ["lightglue.filter_threshold"]
