"""A run's report (:func:`flight_report`) and files: ``results.jsonl`` (one
:class:`FrameOutcome` a line; the frames flown kept in a partial file beside it until then,
:mod:`~c3_matcher_tools.run.results_file`), ``flight.geojson`` and ``report.html`` (the same
for ``replay`` and for each strategy ``eval`` runs, :func:`write_flight_outputs`), every one
written through :func:`~c3_matcher.atomic.atomic_writer`: a run that fails part-way leaves no
torn file, and no earlier run's results beside its own FDR (:func:`forget_previous_run`). A
run's output directory is its command's alone: marked as it is taken (:data:`RUN_MARK`,
:func:`mark_output_dirs`), and one that holds anything but an earlier run of the command is
refused before anything runs (:func:`check_output_dirs`). The summary of an eval over several
flights, beside a folder per flight, follows a later run of one of them into its folder
(:func:`summary_above`, :func:`refresh_summary`)."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.atomic import (
    held_directory,
    refuse_output_over_inputs,
    refuse_unwritable,
    write_text_atomically,
)
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import FlightDataset, name_problem
from c3_matcher_tools.run.records import FlightRun
from c3_matcher_tools.run.report_html import no_report_html, write_html_report
from c3_matcher_tools.run.results_file import RESULTS_FILE, write_results
from c3_matcher_tools.run.run_mark import RUN_MARK, RunLayout, marked_by, run_json_file, run_mark
from c3_matcher_tools.run.scoring import RunSummary, summarize

__all__ = [
    "EVAL_OUT",
    "EVAL_RUN",
    "EVAL_SUMMARY",
    "REPLAY_OUT",
    "REPLAY_RUN",
    "RUN_FILES",
    "RunFiles",
    "SummaryAbove",
    "check_output_dirs",
    "exclusive_output_dir",
    "flight_report",
    "forget_previous_run",
    "mark_output_dirs",
    "no_report_html",
    "output_dir_name",
    "refresh_summary",
    "refuse_foreign_output",
    "refuse_other_dataset",
    "summary_above",
    "write_flight_outputs",
    "write_html_report",
    "write_results",
    "write_summary",
]

REPLAY_OUT = Path("out") / "replay"
"""Where ``replay`` writes without ``--out``: ``<this>/<dataset>-<strategy>`` below the working
directory."""
EVAL_OUT = Path("out") / "eval"
"""Where ``eval`` writes without ``--out``: ``<this>/<dataset>`` below the working directory."""


REPLAY_RUN = RunLayout("replay", "report.json", frozenset({"dataset", "strategy", "fdr", "log"}))
"""``replay``'s output directory; a ``report.json`` of its own names the FDR and log."""
EVAL_SUMMARY = "summary.json"
"""What ``eval`` over several flights writes beside their directories: each strategy on each."""
EVAL_RUN = RunLayout(
    "eval", "eval.json", frozenset({"dataset", "frames", "bars", "strategies"}), EVAL_SUMMARY
)
"""``eval``'s output directory for one flight (for several, one below the root per flight)."""


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
            try:
                held.enter_context(held_directory(directory, when_busy=_refused(directory)))
            except OSError as exc:  # what no permission check foresees (/proc, a full disk)
                why = exc.strerror or str(exc)
                raise InvalidInputError("--out", f"{directory}: cannot be made: {why}") from exc
        yield


def check_output_dirs(
    directories: Sequence[Path],
    datasets: Sequence[FlightDataset],
    *,
    layout: RunLayout,
    root: Path | None = None,
    field: str = "--out",
) -> None:
    """Refuse, before anything is made or loaded, an output directory of a run over
    ``datasets`` (``directories``, each written as ``layout``, and ``root``, that of a run over
    several flights, above them) that is, holds or lies inside one of them: one that is or holds
    the dataset's directory, tile store, frames, calibration or frame images
    (:func:`~c3_matcher.atomic.refuse_output_over_inputs`, as ``dataset render`` and ``import``
    refuse an OUT holding an input), or that lies inside the dataset's directory, which a run
    reads and never writes; then one that is a file or not writable; then one that holds
    anything but an earlier run of the command (:func:`refuse_foreign_output`): a run replaces
    only what the command wrote. ``InvalidInputError`` naming ``field``."""
    _refuse_over_inputs([*([] if root is None else [root]), *directories], datasets, field)
    if root is not None:
        _refuse_foreign_root(root, layout, field)
    for directory in directories:
        refuse_foreign_output(directory, layout, field=field)


def _refuse_over_inputs(
    directories: Sequence[Path], datasets: Sequence[FlightDataset], field: str
) -> None:
    """:func:`check_output_dirs`' refusals of an output directory over an input dataset, or
    that is a file or not writable."""
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


def refuse_foreign_output(directory: Path, layout: RunLayout, *, field: str = "--out") -> None:
    """Refuse ``directory`` when it is a directory that holds something but no earlier run of
    ``layout``'s command (:meth:`RunLayout.holds_run`): a flight-data log, a user's files,
    another command's output, none of them a run's to replace. ``InvalidInputError`` naming
    ``field``, ``directory`` and what it holds; one missing or empty is taken."""
    names = _names_or_refuse(directory, field)
    if not names or layout.holds_run(directory):
        return
    whose = marked_by(directory)
    if whose is not None:  # another command's
        why = f"its {RUN_MARK} says {whose} wrote it"
    elif layout.summary is not None and all(_of_root(directory / n, layout) for n in names):
        why = f"it holds {layout.command}'s output for several flights: give a flight's folder"
    else:  # a user's files, or a run stopped before runs were marked
        why = f"no {layout.command}'s {RUN_MARK} or {layout.report} there"
    raise InvalidInputError(
        field,
        f"{directory} holds {_some(names)}, not known as an earlier {layout.command}'s output "
        f"({why}): {_only_its_own(layout)}; give an empty or new directory",
    )


def _refuse_foreign_root(root: Path, layout: RunLayout, field: str) -> None:
    """Refuse ``root``, the output directory of a run of ``layout`` over several flights, when
    it holds anything but such a run's ``summary`` and a directory per flight (each empty or
    holding an earlier run of ``layout``)."""
    foreign = [n for n in _names_or_refuse(root, field) if not _of_root(root / n, layout)]
    if foreign:
        raise InvalidInputError(
            field,
            f"{root} holds {_some(foreign)}, not known as an earlier {layout.command} of "
            f"several flights (only its {layout.summary} and a directory per flight belong "
            f"there): {_only_its_own(layout)}; give an empty or new directory",
        )


def _only_its_own(layout: RunLayout) -> str:
    """What a run of ``layout`` replaces in a directory, said as a refusal ends."""
    return f"{layout.command} replaces only an earlier {layout.command}'s output"


def _of_root(path: Path, layout: RunLayout) -> bool:
    """``path``, in the output directory of a run of ``layout`` over several flights, is that
    run's summary or one flight's directory (empty, or an earlier run of ``layout``'s)."""
    if path.name == layout.summary:
        return _summary_rows(path) is not None
    if path.is_symlink() or not path.is_dir():
        return False
    names = _names(path)
    return names == [] or (names is not None and layout.holds_run(path))


def _summary_rows(path: Path) -> list[dict[str, Any]] | None:
    """The rows of the summary of a run over several flights at ``path`` (a JSON list of
    objects, each naming a ``strategy`` and a ``flight``); None when it is no such file."""
    rows = run_json_file(path)
    ok = isinstance(rows, list) and all(
        isinstance(r, dict) and {"strategy", "flight"} <= r.keys() for r in rows
    )
    return rows if ok else None


@dataclass(frozen=True)
class SummaryAbove:
    """The summary (``path``) of an earlier run over several flights, one of which had its
    folder ``folder`` beside it, which a run of one flight now writes: the rows it held
    (``rows``), of which that folder's no longer say what the folder holds."""

    path: Path
    folder: str
    rows: tuple[dict[str, Any], ...]


def summary_above(out: Path, layout: RunLayout) -> SummaryAbove | None:
    """The summary of an earlier run of ``layout`` over several flights that names ``out``, the
    output directory of a run of one flight, as one of its flights' folders (it lies in
    ``out``'s parent and has rows of the flight ``out`` is named after); None where there is
    none."""
    if layout.summary is None:
        return None
    folder = out.expanduser().resolve()
    path = folder.parent / layout.summary
    rows = _summary_rows(path)
    if rows is None or all(r["flight"] != folder.name for r in rows):
        return None
    return SummaryAbove(path, folder.name, tuple(rows))


def refresh_summary(above: SummaryAbove, flight: str, rows: Sequence[Mapping[str, Any]]) -> str:
    """Rewrite ``above`` with its folder's rows replaced by ``rows``, those of this run of
    ``flight`` into that folder, where the first of them stood (the other flights' rows stay
    as their folders hold them); or, where the folder now holds another flight than the one
    it is named after, leave it removed (:func:`forget_previous_run`, as the run started): no
    row of the summary may say what the folder beside it does not hold. The line that says
    which, for stderr."""
    if flight != above.folder:
        return (
            f"{above.path} removed: {above.folder}'s folder beside it now holds {flight}'s "
            "results; evaluate those flights together again for a summary"
        )
    at = next(n for n, r in enumerate(above.rows) if r["flight"] == above.folder)
    kept = [r for r in above.rows if r["flight"] != above.folder]
    refreshed = [*kept[:at], *rows, *kept[at:]]
    write_text_atomically(above.path, json.dumps(refreshed, indent=2) + "\n")
    return f"{above.path}: {flight}'s rows replaced by this run's"


def write_summary(
    rows: list[Any], root: Path | None, above: SummaryAbove | None, flight: str
) -> str | None:
    """The summary's ``rows`` written: as :data:`EVAL_SUMMARY` in ``root`` (a run over several
    flights), else into the summary ``above`` the one flight's folder (its ``flight``'s rows;
    the line that says so returned), if there is one."""
    if root is not None:
        write_text_atomically(root / EVAL_SUMMARY, json.dumps(rows, indent=2) + "\n")
        return None
    return None if above is None else refresh_summary(above, flight, rows)


def mark_output_dirs(
    layout: RunLayout,
    *directories: Path,
    datasets: Sequence[FlightDataset] = (),
    strategy: str | None = None,
) -> None:
    """Mark ``directories``, which this run now holds (:func:`exclusive_output_dir`), as
    ``layout``'s output (:data:`RUN_MARK`), before the run writes anything else there: each
    checked again first (:func:`refuse_foreign_output`: something may have come since
    :func:`check_output_dirs`), then marked as a run in progress (``"running": true``, until
    :func:`mark_ended`: a run killed before it could end is told from one that ended) of
    the dataset beside it in ``datasets`` (its resolved path) and ``strategy`` where given."""
    for directory in directories:
        refuse_foreign_output(directory, layout)
    for n, directory in enumerate(directories):
        dataset = datasets[n] if n < len(datasets) else None
        mark = {**run_mark(layout, dataset, strategy), "running": True}
        write_text_atomically(directory / RUN_MARK, json.dumps(mark) + "\n")


def refuse_other_dataset(directory: Path, dataset: FlightDataset, layout: RunLayout) -> None:
    """Refuse ``directory``, named after ``dataset``'s name (the default output directory),
    when its :data:`RUN_MARK` says it holds a run of another dataset of that name: replacing
    it would lose the other's results (one of another name, written there by ``--out``, is
    replaced). ``InvalidInputError`` naming ``--out`` and both datasets."""
    mark = run_json_file(directory / RUN_MARK)
    if not isinstance(mark, dict) or marked_by(directory) != layout.mark["command"]:
        return
    earlier, ours = mark.get("dataset"), str(dataset.root.expanduser().resolve())
    if mark.get("name") == dataset.name and isinstance(earlier, str) and earlier != ours:
        raise InvalidInputError(
            "--out",
            f"{directory} holds a {layout.command} of {earlier}, another dataset named "
            f"{dataset.name!r} than this one ({ours}): give --out to keep both, or remove "
            f"{directory} to replace it",
        )


def _names_or_refuse(directory: Path, field: str) -> list[str]:
    """:func:`_names`, a directory that cannot be listed refused naming ``field``."""
    names = _names(directory)
    if names is None:
        raise InvalidInputError(
            field, f"{directory}: cannot be listed, so what it holds cannot be told"
        )
    return names


def _names(directory: Path) -> list[str] | None:
    """What ``directory`` holds, by name, sorted; [] when it is missing or no directory (a
    file there is refused as unwritable); None when it cannot be listed."""
    if not directory.is_dir():
        return []
    try:
        return sorted(p.name for p in directory.iterdir())
    except OSError:
        return None


def _some(names: Sequence[str], shown: int = 3) -> str:
    """The first ``shown`` of ``names``, and how many more."""
    more = len(names) - shown
    return ", ".join(names[:shown]) + (f" and {more} more" if more > 0 else "")


RUN_FILES = (RESULTS_FILE, REPLAY_RUN.report, "flight.geojson", "report.html")
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


def flight_report(
    dataset: FlightDataset, run: FlightRun, summary: RunSummary | None = None
) -> dict[str, Any]:
    """What every run's report starts with (``replay``'s ``report.json``, each strategy's entry
    in ``eval.json``): the dataset, the strategy, its matcher labels, the ``[matcher]`` and
    ``[lightglue]`` settings it ran with and the keypoint budget it kept, its provenance
    (:attr:`FlightRun.provenance`), start-up and wall time, then ``summary`` (:func:`summarize`
    of the run's outcomes when None)."""
    return {
        "dataset": str(dataset.root),
        "strategy": run.strategy,
        "matcher_labels": run.matcher_labels,
        "settings": run.settings,
        "keypoint_budget": run.keypoint_budget,
        "lightglue_settings": run.lightglue,
        "provenance": run.provenance,
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
    out: Path,
    dataset: FlightDataset,
    run: FlightRun,
    report: Mapping[str, Any],
    *,
    say_no_report: bool = True,
) -> RunFiles:
    """A run's files in ``out`` (replay, and eval per strategy): ``results.jsonl``,
    ``flight.geojson`` and ``report.html``, which shows ``report`` (it needs
    :func:`flight_report`'s keys) and the map's path; ``say_no_report``: say why there is no
    ``report.html`` (:func:`no_report_html`; False: the caller says it, once a run)."""
    from c3_matcher_tools.geojson import write_geojson

    write_results(out / RESULTS_FILE, run.outcomes)
    outcomes = list(run.outcomes)
    geojson = str(write_geojson(out / "flight.geojson", outcomes, run.strategy))
    shown = {**report, "geojson": geojson}
    html = write_html_report(out, dataset, outcomes, run.strategy, shown, say=say_no_report)
    return RunFiles(geojson, html)
