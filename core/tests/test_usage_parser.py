"""The command line's parser: a value that starts with a minus sign is a value when it is a
number or a list of numbers (a negative roll, a southern latitude), as argparse already takes
a single negative number."""

from __future__ import annotations

import pytest

from c3_matcher.commands import UsageParser


def _parser() -> UsageParser:
    parser = UsageParser(prog="c3-matcher match")
    parser.add_argument("--attitude")
    parser.add_argument("--height", type=float)
    parser.add_argument("-v", action="store_true")
    return parser


@pytest.mark.parametrize("value", ["-3,1,90", "-33.9,151.2", "-.5,-1e-3,2E2", "-7"])
def test_negative_numbers_and_lists_of_them_are_values(value: str) -> None:
    assert _parser().parse_args(["--attitude", value]).attitude == value


@pytest.mark.parametrize("word", ["-v", "-3,x,90", "-3,,1"])
def test_anything_else_with_a_minus_is_still_an_option(word: str) -> None:
    with pytest.raises(SystemExit) as info:
        _parser().parse_args(["--attitude", word])
    assert info.value.code == 2


@pytest.mark.parametrize(
    ("option", "value", "says"),
    [
        ("--attitude", "1,2", "expected 3 finite comma-separated numbers, got '1,2'"),
        ("--attitude", "0,95,0", "attitude.pitch_deg: must be <= 90.0, got 95.0"),  # degrees in,
        ("--attitude", "0,0,720", "attitude.yaw_deg: must be <= 360.0, got 720.0"),  # degrees out
        ("--height", "nan", "must be finite and > 0, got nan"),
        ("--tile-id", "18,1", "expected ZOOM,LAT,LON"),
        ("--tile-id", "0,14.6,121.0", "zoom 0 names no place: give the tile's zoom, 1 or more"),
        ("--tile-id", "21,90,0", "90.0 is beyond web mercator's latitude limit, +-85.0511 deg"),
        ("--tile-id", "21,-85.06,0", "is beyond web mercator's latitude limit"),
        ("--height", "-4", "must be finite and > 0, got -4.0"),
        ("--window", "8", "must be in [64, 4096], got 8"),
        ("--max-keypoints", "0", "must be in ["),
    ],
)
def test_a_bad_value_is_named_once_by_its_option(
    option: str, value: str, says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """argparse already prefixes ``argument OPTION:``; the value's own message does not repeat
    it (it read ``argument --window: --window: must be ...``)."""
    from c3_matcher.cli import main

    with pytest.raises(SystemExit) as info:
        main(["match", "--query", "q.jpg", "--tile", "t.png", option, value])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert f"argument {option}: " in err and says in err, err
    assert err.count(option) == 1, err
