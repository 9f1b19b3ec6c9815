"""Flight datasets (``c3-flight/1``): simulated flights over real orthophotos with exact ground
truth (:mod:`.flight`), the on-disk format (:mod:`.format`) and scoring (:mod:`.truth`)."""

from __future__ import annotations

from c3_matcher_tools.dataset.flight import render_flight
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.format import (
    FORMAT,
    CandidateTruth,
    FlightDataset,
    FrameRecord,
    load_dataset,
)
from c3_matcher_tools.dataset.truth import inlier_errors_px
from c3_matcher_tools.dataset.writing import write_dataset

__all__ = [
    "FORMAT",
    "CandidateTruth",
    "FlightDataset",
    "FlightSpec",
    "FrameRecord",
    "inlier_errors_px",
    "load_dataset",
    "render_flight",
    "write_dataset",
]
