"""``dataset import`` and ``dataset render`` refuse a bad option while parsing, before any input
is read: a usage error (exit 2) naming the option and its bounds, never an internal error or a
message about something else later. The inputs named are placeholders."""

from __future__ import annotations

import argparse

import pytest

from c3_matcher.cli import main
from c3_matcher.commands import bounded_float
from c3_matcher_tools.args import SEED_RANGE

IMPORT_CSV = ["dataset", "import", "images", "tele.csv", "calib.json", "tiles.mbtiles", "out"]
IMPORT_ULOG = ["dataset", "import", "images", "flight.ulg", "calib.json", "tiles.mbtiles", "out"]
RENDER = ["dataset", "render", "ortho.tif", "tiles.mbtiles", "out"]


def _usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one line a usage error prints (exit 2)."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "internal error" not in err
    return err


@pytest.mark.parametrize(
    "command", [IMPORT_CSV, IMPORT_ULOG, RENDER], ids=["csv", "ulog", "render"]
)
def test_a_negative_seed_is_a_usage_error(
    command: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    err = _usage_error([*command, "--seed", "-1"], capsys)
    assert f"--seed: must be in [{SEED_RANGE[0]}, {SEED_RANGE[1]}], got -1" in err


@pytest.mark.parametrize(
    ("option", "value", "bound"),
    [
        ("--interval", "nan", "finite and > 0"),
        ("--interval", "0", "finite and > 0"),
        ("--speed", "nan", "finite and >= 0"),
        ("--min-distractor-distance", "nan", "finite and >= 0"),
        ("--max-distractor-nodata", "nan", "finite and in [0, 1]"),
        ("--absent-share", "2", "finite and in [0, 1]"),
        ("--height", "inf", "finite and in (0, 100000]"),
        ("--height", "-10", "finite and in (0, 100000]"),
        ("--radius", "inf", "finite and > 0"),
        ("--focal", "0", "finite and > 0"),
        ("--heading", "nan", "finite"),
        ("--frames", "0", ">= 1"),
    ],
)
def test_render_refuses_a_value_outside_an_options_bounds(
    option: str, value: str, bound: str, capsys: pytest.CaptureFixture[str]
) -> None:
    err = _usage_error([*RENDER, option, value], capsys)
    assert f"argument {option}: must be {bound}, got" in err, err
    assert f"{option}: {option}" not in err, err


@pytest.mark.parametrize(
    ("command", "option", "value", "bound"),
    [
        (IMPORT_CSV, "--uncertainty-m", "nan", "finite and >= 0"),
        (IMPORT_CSV, "--uncertainty-m", "inf", "finite and >= 0"),
        (IMPORT_CSV, "--uncertainty-m", "-5", "finite and >= 0"),
        (IMPORT_CSV, "--ground-elevation", "nan", "finite"),
        (IMPORT_ULOG, "--time-offset", "inf", "finite and in [-4e+09, 4e+09]"),
        (IMPORT_ULOG, "--time-offset", "1e308", "finite and in [-4e+09, 4e+09]"),
        (IMPORT_ULOG, "--time-offset", "-4.1e9", "finite and in [-4e+09, 4e+09]"),
        (IMPORT_ULOG, "--interval", "nan", "finite and > 0"),
        (IMPORT_ULOG, "--max-gap", "0", "finite and > 0"),
        (IMPORT_ULOG, "--gnss-degraded-m", "nan", "finite and > 0"),
    ],
)
def test_import_refuses_a_value_outside_an_options_bounds(
    command: list[str], option: str, value: str, bound: str, capsys: pytest.CaptureFixture[str]
) -> None:
    err = _usage_error([*command, option, value], capsys)
    assert f"argument {option}: must be {bound}, got" in err, err
    assert f"{option}: {option}" not in err, err


def test_bounded_float_reads_finite_numbers_within_its_bounds() -> None:
    share = bounded_float(0.0, 1.0)
    assert share("0") == 0.0 and share("1") == 1.0 and share("0.25") == 0.25
    for text, why in [("x", "expected a number"), ("nan", r"must be finite and in \[0, 1\]")]:
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            share(text)
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be finite and > 0, got 0.0"):
        bounded_float(0.0, above=True)("0")


@pytest.mark.parametrize("name", ["a/b", "..", ".", "", "a\\b"])
@pytest.mark.parametrize("command", [IMPORT_CSV, IMPORT_ULOG], ids=["csv", "ulog"])
def test_a_name_replay_could_not_name_a_directory_after_is_a_usage_error(
    command: list[str], name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Accepted, it would make a dataset that ``replay`` and ``eval`` then refuse."""
    err = _usage_error([*command, "--name", name], capsys)
    assert f"argument --name: {name!r} cannot name an output directory" in err


@pytest.mark.parametrize(
    ("images", "telemetry", "kind"),
    [
        ("images", "flight.ulg", "ulog"),
        ("images", "flight.bin", "ardupilot"),
        ("photos", "-", "exif"),
    ],
)
def test_recorded_intrinsics_are_refused_at_once_for_a_source_that_records_none(
    images: str, telemetry: str, kind: str, tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    """CALIBRATION '-' takes a bag's CameraInfo: for any other source it is refused before the
    log or the photos are read (it was refused after reading them all, naming a bag). The
    inputs do not exist: reading one would fail with another message."""
    (tmp_path / "photos").mkdir()
    argv = ["dataset", "import", str(tmp_path / images), telemetry, "-", "t.mbtiles", "out"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"CALIBRATION: '-' takes the intrinsics a ROS bag records (CameraInfo); a {kind}" in err
