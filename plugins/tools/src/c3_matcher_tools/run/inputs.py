"""What a run feeds the matcher: (frame, rerank, calibration) per frame, read from a flight
dataset (``dataset.json``) or from a demo-format directory (``demo.json``: one frame, its
candidate tiles, the camera's calibration; read by the core's
:func:`~c3_matcher.demo.demo_inputs`)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from c3_matcher.demo import MatchInputs, demo_inputs
from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import DEFAULT_MAX_IMAGE_PIXELS

if TYPE_CHECKING:
    from c3_matcher_tools.dataset.format import FlightDataset, FrameRecord

__all__ = ["MatchInputs", "demo_inputs", "flight_inputs", "timed_frames"]


@contextmanager
def flight_inputs(
    data_dir: Path, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS
) -> Iterator[list[MatchInputs]]:
    """One ``MatchInputs`` per frame: a flight dataset's :func:`timed_frames`, or the single
    frame of a demo-format directory, its images read within ``max_pixels`` (``[matcher]
    max_image_pixels``). A dataset's tile store, which the candidates' tile handles read from,
    stays open until the ``with`` block ends."""
    from c3_matcher_tools.dataset.format import is_flight_dataset, load_dataset

    if not is_flight_dataset(data_dir):
        yield [demo_inputs(data_dir, max_pixels)]
        return

    dataset = load_dataset(data_dir, max_pixels)
    with dataset.open_store() as store:
        yield [
            (dataset.nav_frame(f), dataset.rerank(f, store), dataset.calibration)
            for f in timed_frames(dataset)
        ]


def timed_frames(dataset: FlightDataset) -> tuple[FrameRecord, ...]:
    """The frames of ``dataset`` a run times: with ground truth, those whose true tile is among
    their candidates (each ``match`` has a right answer to find); a recorded flight without
    ground truth, every frame (as it flew). A simulated flight without such a frame (every
    frame a distractor-only one): InvalidInputError (``--data``) naming it and why."""
    if not any(f.has_truth for f in dataset.frames):
        return dataset.frames
    frames = tuple(f for f in dataset.frames if f.true_tile_present)
    if frames:
        return frames
    raise InvalidInputError(
        "--data",
        f"{dataset.root}: flight {dataset.name!r}: none of its {len(dataset.frames)} frames has "
        "its true tile among its candidates, so there is no match to time (a flight with ground "
        "truth times the frames whose true tile is present)",
    )
