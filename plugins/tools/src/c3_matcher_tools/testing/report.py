"""The flight report drawn for a test: its page's text and the matplotlib figures it embeds,
without the gallery's pictures (which run the matcher's drawing on every frame)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.report import charts as report_charts
from c3_matcher_tools.report import html as report_html
from c3_matcher_tools.run import FrameOutcome, summarize, write_html_report

__all__ = ["drawn_report"]


def drawn_report(
    out: Path, dataset: FlightDataset, outcomes: Sequence[FrameOutcome], strategy: str = "xfeat"
) -> tuple[str, list[Any]]:
    """``report.html``'s text as :func:`write_html_report` writes it into ``out`` (threshold
    60 inliers), and its figures in the order the page embeds them (each drawn)."""
    figures: list[Any] = []

    def keep(fig: Any) -> str:
        fig.canvas.draw()
        figures.append(fig)
        return "data:,"

    report = {
        "settings": {"min_inliers_threshold": 60},
        "matcher_labels": [],
        **summarize(outcomes).to_json(),
    }
    mp = pytest.MonkeyPatch()
    mp.setattr(report_charts, "_png_uri", keep)
    mp.setattr(report_html, "gallery_pictures", lambda *a, **k: [])
    try:
        written = write_html_report(out, dataset, list(outcomes), strategy, report)
    finally:
        mp.undo()
    assert written == str(out / "report.html")
    return (out / "report.html").read_text(), figures
