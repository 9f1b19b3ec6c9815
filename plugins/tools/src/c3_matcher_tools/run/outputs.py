"""A run's report (:func:`flight_report`) and files: ``results.jsonl`` (one
:class:`FrameOutcome` a line), ``flight.geojson`` and ``report.html`` (the same for ``replay`` and
for each strategy ``eval`` runs, :func:`write_flight_outputs`), every one written through
:func:`~c3_matcher.atomic.atomic_writer`: a run that fails part-way leaves no torn file, and
no earlier run's results beside its own FDR (:func:`forget_previous_run`)."""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.atomic import (
    atomic_writer,
    held_directory,
    refuse_output_over_inputs,
    refuse_unwritable,
)
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import FlightDataset, name_problem
from c3_matcher_tools.run.records import FlightRun, FrameOutcome
from c3_matcher_tools.run.scoring import RunSummary, summarize

__all__ = [
    "EVAL_OUT",
    "REPLAY_OUT",
    "RUN_FILES",
    "RunFiles",
    "check_output_dirs",
    "exclusive_output_dir",
    "flight_report",
    "forget_previous_run",
    "output_dir_name",
    "write_flight_outputs",
    "write_html_report",
    "write_results",
]

REPLAY_OUT = Path("out") / "replay"
"""Where ``replay`` writes without ``--out``: ``<this>/<dataset>-<strategy>`` below the working
directory."""
EVAL_OUT = Path("out") / "eval"
"""Where ``eval`` writes without ``--out``: ``<this>/<dataset>`` below the working directory."""


@contextlib.contextmanager
def exclusive_output_dir(*directories: Path) -> Iterator[None]:
    """``directories`` (made if missing) for this run alone while the block runs
    (:func:`~c3_matcher.atomic.held_directory`, no lock file left behind), so that a second
    ``replay`` or ``eval`` into one of them is refused, ``InvalidInputError`` naming it, before
    it writes anything there; one that is a file or not writable is refused before any is made.
    Taken in the order given; all released when the block ends."""
    for directory in directories:  # every one, before any is made
        refuse_unwritable(directory, field="--out", directory=True)
    with contextlib.ExitStack() as held:
        for directory in directories:
            held.enter_context(held_directory(directory, when_busy=_refused(directory)))
        yield


def check_output_dirs(
    directories: Sequence[Path], datasets: Sequence[FlightDataset], *, field: str = "--out"
) -> None:
    """Refuse, before anything is made or loaded, an output directory of a run over
    ``datasets`` that is, holds or lies inside one of them: one that is or holds the dataset's
    directory, tile store, frames, calibration or frame images
    (:func:`~c3_matcher.atomic.refuse_output_over_inputs`, as ``dataset render`` and ``import``
    refuse an OUT holding an input), or that lies inside the dataset's directory, which a run
    reads and never writes; then one that is a file or not writable. ``InvalidInputError``
    naming ``field``."""
    for directory in directories:
        for dataset in datasets:
            inputs = {
                dataset.root,
                dataset.store_path,
                dataset.root / str(dataset.meta["frames"]),
                dataset.root / str(dataset.meta["calibration"]),
                *((dataset.root / f.image).parent for f in dataset.frames),
            }
            refuse_output_over_inputs(directory, sorted(inputs), field=field)
            root = dataset.root.expanduser().resolve()
            if root in directory.expanduser().resolve().parents:
                raise InvalidInputError(
                    field,
                    f"{directory} is inside the input dataset {dataset.root}, which a run reads "
                    "and never writes: choose another",
                )
        refuse_unwritable(directory, field=field, directory=True)


RUN_FILES = ("results.jsonl", "report.json", "flight.geojson", "report.html")
"""What a finished run leaves beside its FDR and log (``report.json``: replay's)."""


def forget_previous_run(out: Path, files: Sequence[str] = RUN_FILES) -> None:
    """Remove the ``files`` an earlier run left in ``out``, as a new run starts there: a run
    stopped part-way leaves its own FDR and log, never beside another run's results."""
    for name in files:
        (out / name).unlink(missing_ok=True)


def _refused(directory: Path) -> Callable[[], None]:
    def refuse() -> None:
        raise InvalidInputError(
            "--out",
            f"{directory}: another replay or eval is writing this directory; "
            "one run per output directory (wait for it, or choose another --out)",
        )

    return refuse


def output_dir_name(dataset: FlightDataset) -> str:
    """``dataset``'s name as the one path component of an output directory named after it;
    ``InvalidInputError`` naming its ``dataset.json`` when it has a
    :func:`~c3_matcher_tools.dataset.format.name_problem`."""
    why = name_problem(dataset.name)
    if why:
        raise InvalidInputError(
            "dataset", f"{dataset.root / 'dataset.json'}: name {dataset.name!r} {why}"
        )
    return dataset.name


def write_results(path: Path, outcomes: Sequence[FrameOutcome]) -> Path:
    """``path`` (JSON Lines): each outcome's ``to_json()``, in order."""
    with atomic_writer(path) as fh:
        for o in outcomes:
            fh.write(json.dumps(o.to_json()) + "\n")
    return path


def flight_report(
    dataset: FlightDataset, run: FlightRun, summary: RunSummary | None = None
) -> dict[str, Any]:
    """What every run's report starts with (``replay``'s ``report.json``, each strategy's entry
    in ``eval.json``): the dataset, the strategy, its matcher labels, the ``[matcher]`` and
    ``[lightglue]`` settings it ran with, start-up and wall time, then ``summary``
    (:func:`summarize` of the run's outcomes when None)."""
    return {
        "dataset": str(dataset.root),
        "strategy": run.strategy,
        "matcher_labels": run.matcher_labels,
        "settings": run.settings,
        "lightglue_settings": run.lightglue,
        "startup_s": run.startup_s,
        "wall_s": run.wall_s,
        **(summarize(run.outcomes) if summary is None else summary).to_json(),
    }


@dataclass(frozen=True)
class RunFiles:
    """Where a run's map and flight report were written (``html`` None: no matplotlib)."""

    geojson: str
    html: str | None


def write_flight_outputs(
    out: Path, dataset: FlightDataset, run: FlightRun, report: Mapping[str, Any]
) -> RunFiles:
    """A run's files in ``out`` (replay, and eval per strategy): ``results.jsonl``,
    ``flight.geojson`` and ``report.html``, which shows ``report`` (it needs
    :func:`flight_report`'s keys) and the map's path."""
    from c3_matcher_tools.geojson import write_geojson

    write_results(out / "results.jsonl", run.outcomes)
    outcomes = list(run.outcomes)
    geojson = str(write_geojson(out / "flight.geojson", outcomes, run.strategy))
    shown = {**report, "geojson": geojson}
    return RunFiles(geojson, write_html_report(out, dataset, outcomes, run.strategy, shown))


def write_html_report(
    out: Path,
    dataset: FlightDataset,
    outcomes: Sequence[FrameOutcome],
    strategy: str,
    report: Mapping[str, Any],
) -> str | None:
    """``out/report.html`` (None, with the reason on stderr, when matplotlib is missing: then a
    ``report.html`` an earlier run left there is removed, as it reports another run's
    results)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        (out / "report.html").unlink(missing_ok=True)
        print(
            f"c3-matcher: no report.html ({exc}): install the report extra "
            "(pip install 'c3-matcher-tools[report]')",
            file=sys.stderr,
        )
        return None
    from importlib.metadata import version

    from c3_matcher_tools.report import write_report

    summary = {k: v for k, v in report.items() if k not in ("settings", "lightglue_settings")}
    lightglue = report.get("lightglue_settings") or {}
    settings = {**report["settings"], **{f"lightglue.{k}": v for k, v in lightglue.items()}}
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
        settings=settings,
        provenance=provenance,
    )
    return str(path)
