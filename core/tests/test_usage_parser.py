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
