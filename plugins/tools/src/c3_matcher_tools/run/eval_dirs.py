"""Where ``eval`` writes each dataset's results (:func:`eval_output_dirs`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.run.outputs import EVAL_OUT, output_dir_name

__all__ = ["eval_output_dirs"]


def eval_output_dirs(out: Path | None, datasets: Sequence[FlightDataset]) -> list[Path]:
    """Each dataset's output directory: ``--out`` itself for a single dataset, else
    ``<--out or out/eval>/<dataset name>``; a name that is not one plain path component, or
    two datasets of one name (one would overwrite the other), are refused."""
    if len(datasets) == 1 and out is not None:
        return [out]
    names = [output_dir_name(d) for d in datasets]
    for n, name in enumerate(names):
        if name in names[:n]:
            first = datasets[names.index(name)].root
            raise InvalidInputError(
                "dataset",
                f"{first} and {datasets[n].root} are both named {name!r} (dataset.json "
                '"name"); their outputs would share one directory: give each its own name',
            )
    return [(out or EVAL_OUT) / name for name in names]
