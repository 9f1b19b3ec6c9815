"""A run's files: ``results.jsonl`` (one :class:`FrameOutcome` a line), ``flight.geojson`` and
``report.html`` (the same for ``replay`` and for each strategy ``eval`` runs)."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.run.records import FrameOutcome

__all__ = ["write_flight_outputs", "write_html_report", "write_results"]


def write_results(path: Path, outcomes: Sequence[FrameOutcome]) -> Path:
    """``path`` (JSON Lines): each outcome's ``to_json()``, in order."""
    with path.open("w", encoding="utf-8") as fh:
        for o in outcomes:
            fh.write(json.dumps(o.to_json()) + "\n")
    return path


def write_flight_outputs(
    out: Path,
    dataset: FlightDataset,
    outcomes: Sequence[FrameOutcome],
    strategy: str,
    report: dict[str, Any],
) -> None:
    """``out/flight.geojson`` and ``out/report.html`` of one run (replay, and eval per
    strategy); their paths go into ``report["geojson"]`` / ``report["html"]`` (None: no
    matplotlib). ``report`` needs ``settings`` and :func:`~c3_matcher_tools.run.summarize`'s
    keys."""
    from c3_matcher_tools.geojson import write_geojson

    report["geojson"] = str(write_geojson(out / "flight.geojson", list(outcomes), strategy))
    report["html"] = write_html_report(out, dataset, outcomes, strategy, report)


def write_html_report(
    out: Path,
    dataset: FlightDataset,
    outcomes: Sequence[FrameOutcome],
    strategy: str,
    report: dict[str, Any],
) -> str | None:
    """``out/report.html`` (None, with the reason on stderr, when matplotlib is missing)."""
    try:
        from c3_matcher_tools.report import write_report
    except ImportError as exc:
        print(f"c3-matcher: no report.html ({exc})", file=sys.stderr)
        return None
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print(
            "c3-matcher: no report.html: install the report extra "
            "(pip install 'c3-matcher-tools[report]')",
            file=sys.stderr,
        )
        return None
    from importlib.metadata import version

    summary = {k: v for k, v in report.items() if k not in ("settings",)}
    provenance = {
        "dataset": str(dataset.root),
        "dataset format": dataset.meta.get("format"),
        "tile store": str(dataset.store_path),
        "matcher labels (from the results)": ", ".join(report.get("matcher_labels", [])),
        "c3-matcher": version("c3-matcher"),
        "made by": json.dumps(dataset.meta.get("spec", dataset.meta.get("import", {}))),
    }
    path = write_report(
        out / "report.html",
        dataset,
        list(outcomes),
        strategy=strategy,
        summary=summary,
        settings=report["settings"],
        provenance=provenance,
    )
    return str(path)
