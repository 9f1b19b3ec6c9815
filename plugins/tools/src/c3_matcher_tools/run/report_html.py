"""A run's ``report.html`` (replay's, and each strategy's that eval runs): written where the
report extra (matplotlib) is installed (:func:`write_html_report`), and why not where it is
not (:func:`no_report_html`)."""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.extras import install_line
from c3_matcher_tools.run.records import FrameOutcome

__all__ = ["no_report_html", "write_html_report"]


def no_report_html() -> str | None:
    """Why no ``report.html`` can be written here (matplotlib, the report extra, is not
    installed), as a run says it; None where one can."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        extra = install_line("report")
        return f"c3-matcher: no report.html ({exc}): install the report extra ({extra})"
    return None


def write_html_report(
    out: Path,
    dataset: FlightDataset,
    outcomes: Sequence[FrameOutcome],
    strategy: str,
    report: Mapping[str, Any],
    *,
    say: bool = True,
) -> str | None:
    """``out/report.html`` (None when matplotlib is missing, with the reason on stderr when
    ``say``: then a ``report.html`` an earlier run left there is removed, as it reports another
    run's results)."""
    if (why := no_report_html()) is not None:
        (out / "report.html").unlink(missing_ok=True)
        if say:
            print(why, file=sys.stderr)
        return None
    from c3_matcher_tools.report.html import write_report

    shown_apart = ("settings", "lightglue_settings", "provenance")
    summary = {k: v for k, v in report.items() if k not in shown_apart}
    ran = report.get("provenance") or {}  # FlightRun.provenance, as flight_report gives it
    lightglue = report.get("lightglue_settings") or {}  # none where the strategy reads none
    settings = {**report["settings"], **{f"lightglue.{k}": v for k, v in lightglue.items()}}
    provenance = {
        "dataset": str(dataset.root),
        "dataset format": dataset.meta.get("format"),
        "tile store": str(dataset.store_path),
        "matcher labels (from the results)": ", ".join(report.get("matcher_labels", [])),
        "c3-matcher": ran.get("c3-matcher", "-"),
        "execution provider": ran.get("provider", "-"),
        "engines": json.dumps(ran.get("engines", {})),
        "made by": json.dumps(dataset.meta.get("spec", dataset.meta.get("import", {}))),
    }
    if "provenance_error" in ran:  # the backend's provenance could not be read: said so
        provenance["provenance error"] = str(ran["provenance_error"])
    path = write_report(
        out / "report.html",
        dataset,
        list(outcomes),
        strategy=strategy,
        summary=summary,
        settings=settings,
        provenance=provenance,
    )
    return str(path)
