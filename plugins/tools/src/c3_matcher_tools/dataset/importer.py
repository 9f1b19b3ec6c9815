"""Import a recorded flight (images, telemetry CSV, calibration) into a ``c3-flight/1`` dataset.

The telemetry CSV is read and checked by :mod:`c3_matcher_tools.dataset.telemetry` (its columns
are listed there); each frame's candidates are proposed from the tile store by
:mod:`c3_matcher_tools.dataset.proposals`.

Rows and images: a row's image name is a path relative to IMAGES_DIR, placed there by
:mod:`c3_matcher_tools.dataset.image_names` (one outside it, or naming the file a row before
names, is refused). Every image in IMAGES_DIR without a telemetry row and every row whose image is
missing is skipped and reported (:class:`ImportReport`); a refused value names its CSV line.
TELEMETRY, CALIBRATION and the DEM must be regular files: a FIFO or a device is refused
unread (reading one would wait for a writer, or never end).
Everything is checked before anything is written; the dataset is written into a temporary
sibling directory and renamed into place. Its tile store is a hard link to the one given where
both are on one filesystem, else a copy (:func:`~c3_matcher_tools.dataset.writing.link_or_copy`);
the report says which.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher.file_kinds import special_kind
from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.atomic import atomic_directory, check_output_dir
from c3_matcher_tools.dataset.format import FrameRecord, dataset_name
from c3_matcher_tools.dataset.image_names import file_identity
from c3_matcher_tools.dataset.proposals import StoreProposals, imported_frame, propose_from_store
from c3_matcher_tools.dataset.sources.images import IMAGE_SUFFIXES
from c3_matcher_tools.dataset.sources.options import (
    ImportReport,
    ProposalOptions,
    check_ground_options,
)
from c3_matcher_tools.dataset.sources.writer import image_problem
from c3_matcher_tools.dataset.telemetry import (
    Telemetry,
    TelemetryRow,
    read_telemetry_table,
    refuse_lines,
)
from c3_matcher_tools.dataset.writing import copy_file, write_dataset

__all__ = ["ImportSpec", "import_csv_flight", "refuse_special_inputs"]


@dataclass(frozen=True)
class ImportSpec:
    """What ``c3-matcher dataset import`` was given (lengths in metres): the inputs, how
    candidates are proposed (``proposal``, the tile store included) and the ground's altitude
    when the telemetry gives altitudes above sea level."""

    images_dir: Path
    telemetry_csv: Path
    calibration_json: Path
    proposal: ProposalOptions
    ground_elevation_m: float | None = None  # the ground's altitude above sea level, m
    dem: Path | None = None  # a DEM GeoTIFF of the ground's altitude above sea level

    def __post_init__(self) -> None:
        check_ground_options(self.ground_elevation_m, self.dem)

    @property
    def inputs(self) -> tuple[Path | None, ...]:
        """The files and folders the import reads (``None``: no DEM)."""
        store = self.proposal.store
        return (self.images_dir, self.telemetry_csv, self.calibration_json, store, self.dem)


def _check_image(path: Path, calibration: CameraCalibration) -> str | None:
    """Why ``path`` cannot be a frame, as every import checks its images, or None."""
    if not path.is_file():
        return "no such file"
    return image_problem(path.read_bytes(), calibration.image_size)


def refuse_special_inputs(inputs: Iterable[tuple[str, str | Path | None]]) -> None:
    """Refuse each input given (``(field, path)``; None: not given) that is there but is a
    FIFO, a device or a socket, naming it and what it is: reading one waits for a writer
    forever, or never ends. A directory is left to its reader, which names it (a ROS 2 bag is
    one)."""
    for field, path in inputs:
        if path is None or str(path) == "-":
            continue
        kind = special_kind(Path(path))
        if kind is not None and not Path(path).is_dir():
            raise InvalidInputError(field, f"{path} is {kind}, not a file")


def _pair_images(
    images_dir: Path, rows: list[TelemetryRow]
) -> tuple[list[TelemetryRow], list[tuple[str, str]]]:
    """(rows whose image exists, skipped (name, why)): every image in ``images_dir`` that no
    row names (as the file it is: :func:`file_identity`) and every row without its image, in
    name / line order. ``rows``: placed in ``images_dir`` by the telemetry's reader."""
    on_disk = {
        file_identity(p): p.name
        for p in images_dir.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES
    }
    found = [(images_dir / r.image).is_file() for r in rows]  # one stat a row
    kept = [r for r, there in zip(rows, found, strict=True) if there]
    named = {file_identity(images_dir / r.image) for r in kept}  # only those on disk can be
    unnamed = sorted(name for file, name in on_disk.items() if file not in named)
    missing = [r for r, there in zip(rows, found, strict=True) if not there]
    skipped = [(n, "no telemetry row") for n in unnamed]
    skipped += [
        (r.image, f"line {r.line}: no such image") for r in sorted(missing, key=lambda r: r.line)
    ]
    return kept, skipped


def import_csv_flight(
    spec: ImportSpec, out: Path, *, name: str | None = None, force: bool = False
) -> ImportReport:
    """Check every input (``out`` must not be or hold one, ``force`` or not), then write the
    dataset ``out`` atomically; returns what was done (frames, every image or row skipped and
    why, where the heights came from). Raises InvalidInputError naming the input at fault
    (nothing is written then)."""
    out = Path(out)
    check_output_dir(out, force=force, inputs=spec.inputs)
    label = dataset_name(name, out)
    checked = _check_csv_inputs(spec)
    frames = _csv_frames(checked, spec, label)
    meta = _csv_meta(checked, spec, label)
    with atomic_directory(out, force=force) as tmp:
        (tmp / "frames").mkdir()
        for r, f in zip(checked.rows, frames, strict=True):
            copy_file(checked.images_dir / r.image, tmp / f.image)
        placed = write_dataset(
            tmp, meta, checked.calibration, frames, store=spec.proposal.store, link_store=True
        )
    return _csv_report(checked, spec, out, len(frames), placed)


@dataclass(frozen=True)
class _CheckedCsv:
    """A telemetry-CSV import's inputs once checked: the images folder, the calibration, the
    telemetry, the rows whose image is there (in time order) with the images and rows
    skipped, and the candidates proposed for each row."""

    images_dir: Path
    calibration: CameraCalibration
    table: Telemetry
    rows: list[TelemetryRow]
    skipped: list[tuple[str, str]]
    proposed: StoreProposals


def _check_csv_inputs(spec: ImportSpec) -> _CheckedCsv:
    """Check the images folder, store, calibration, telemetry, each image named and the
    store's coverage of every frame, in that order (a frame outside it skipped with
    ``--skip-outside``); raises InvalidInputError naming the input at fault."""
    images_dir = Path(spec.images_dir)
    refuse_special_inputs(
        (
            ("TELEMETRY", spec.telemetry_csv),
            ("CALIBRATION", spec.calibration_json),
            ("--dem", spec.dem),
        )
    )
    if not images_dir.exists():
        raise InvalidInputError("IMAGES_DIR", f"{images_dir}: no such file or folder")
    if not images_dir.is_dir():
        raise InvalidInputError("IMAGES_DIR", f"{images_dir}: not a directory")
    spec.proposal.check_store()
    calibration = load_calibration(Path(spec.calibration_json), field="CALIBRATION")
    table = read_telemetry_table(
        Path(spec.telemetry_csv),
        ground_elevation_m=spec.ground_elevation_m,
        dem=spec.dem,
        images_dir=images_dir,
    )
    rows, skipped = _pair_images(images_dir, list(table.rows))
    if not rows:
        raise InvalidInputError(
            "IMAGES_DIR",
            f"{images_dir}: no telemetry row names an image there "
            f"({len(table.rows)} row(s), e.g. {table.rows[0].image!r})",
        )
    refuse_lines(images_dir, _image_problems(images_dir, rows, calibration))
    proposed = propose_from_store(rows, calibration, spec.proposal)
    inside, proposed, outside = proposed.within(
        rows, "TELEMETRY", lambda r: f"line {r.line}", skip=spec.proposal.skip_outside
    )
    rows = [rows[i] for i in inside]
    return _CheckedCsv(images_dir, calibration, table, rows, [*skipped, *outside], proposed)


def _image_problems(
    images_dir: Path, rows: Sequence[TelemetryRow], calibration: CameraCalibration
) -> list[tuple[int, str]]:
    """(line, why) of each row whose image cannot be a frame."""
    problems = []
    for r in rows:
        why = _check_image(images_dir / r.image, calibration)
        if why:
            problems.append((r.line, f"line {r.line}: {r.image}: {why}"))
    return problems


def _csv_frames(checked: _CheckedCsv, spec: ImportSpec, name: str) -> list[FrameRecord]:
    """The dataset record of each row, its frame ids derived from the dataset's ``name``."""
    frames: list[FrameRecord] = []
    t0 = checked.rows[0].time_s
    base = uuid.uuid5(uuid.NAMESPACE_URL, f"c3-flight-import:{name}")
    for i, (r, proposal) in enumerate(zip(checked.rows, checked.proposed.looks, strict=True)):
        ext = Path(r.image).suffix.lower() or ".jpg"
        known: dict[str, Any] = {}
        if r.altitude_msl_m is not None:
            known["altitude_msl_m"] = r.altitude_msl_m
        known["height_source"] = checked.table.height_source
        frames.append(imported_frame(i, r, t0, base, ext, proposal, spec.proposal, heights=known))
    return frames


def _csv_meta(checked: _CheckedCsv, spec: ImportSpec, name: str) -> dict[str, Any]:
    """The dataset's ``dataset.json``: the store's zoom and sources, and the import's inputs
    (by file name) and options in ``spec``."""
    zoom = checked.proposed.zoom
    return {
        "name": name,
        "candidate_size_px": spec.proposal.candidate_size_px,
        "zoom": zoom,
        "tiles_source": checked.proposed.tiles_source,
        "frames_source": f"imported: {Path(spec.telemetry_csv).name}",
        "spec": {
            "kind": "import",
            "images_dir": checked.images_dir.name,
            "telemetry_csv": Path(spec.telemetry_csv).name,
            "calibration_json": Path(spec.calibration_json).name,
            **spec.proposal.spec_json(zoom),
            **(
                {}
                if spec.ground_elevation_m is None
                else {"ground_elevation_m": spec.ground_elevation_m}
            ),
            **({} if spec.dem is None else {"dem": Path(spec.dem).name}),
        },
        "attribution": checked.proposed.attribution,
    }


def _csv_report(
    checked: _CheckedCsv, spec: ImportSpec, out: Path, frames: int, placed: str
) -> ImportReport:
    """What the import of ``frames`` frames into ``out`` did (``placed``: how its tile store
    got there)."""
    heights = [r.altitude_m for r in checked.rows]
    return ImportReport(
        dataset=str(out),
        source=Path(spec.telemetry_csv).name,
        kind="telemetry CSV",
        frames=frames,
        skipped=tuple(checked.skipped),
        time_source=f"column {checked.table.columns['time_s']!r}",
        time_offset_s=0.0,
        height_sources={checked.table.height_source: frames},
        attitude_assumed=(),
        height_assumed=(),
        gnss_degraded=(),
        zoom=checked.proposed.zoom,
        notes=(
            f"heights above ground {min(heights):.1f} to {max(heights):.1f} m; "
            + _msl_note(checked.table.columns, spec),
            *checked.table.notes,
            placed,
        ),
    )


def _msl_note(columns: Mapping[str, str], spec: ImportSpec) -> str:
    """What became of an altitude above sea level: used, not used (and why), or where to put
    one."""
    msl = columns.get("altitude_msl_m")
    if msl is None:
        return (
            "altitudes above sea level go in a column altitude_msl_m, with --ground-elevation "
            "or --dem"
        )
    if spec.ground_elevation_m is None and spec.dem is None:
        return (
            f"column {msl!r} (above sea level) not used: no --ground-elevation or --dem to read "
            "it against"
        )
    return f"column {msl!r} read against {'the DEM' if spec.dem else 'the ground elevation'}"
