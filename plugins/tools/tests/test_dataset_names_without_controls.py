"""A dataset's name holds no control character (C0, DEL, C1: ESC, CR, LF, BEL among them): the
name becomes an output folder's name and is printed in progress lines, where such a character
would move the cursor, clear the screen or end the line. ``name_problem`` refuses it naming the
characters, as a ``dataset.json`` name, a ``--name`` and an OUT named so; other text is a name."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import dataset_name, load_dataset, name_problem

from .conftest import C3, SmallFlight
from .test_import_names_not_utf8 import _inputs


@pytest.mark.parametrize(
    ("name", "named"),
    [
        ("run\x1b[2J", "U+001B"),
        ("a\rb", "U+000D"),
        ("a\nb", "U+000A"),
        ("bell\x07", "U+0007"),
        ("tab\there", "U+0009"),
        ("del\x7f", "U+007F"),
        ("next\x85line", "U+0085"),
        ("csi\x9b2J", "U+009B"),
        ("\x1b\r\x1b", "U+000D, U+001B"),
    ],
)
def test_a_name_with_control_characters_is_refused_naming_them(name: str, named: str) -> None:
    why = name_problem(name)
    assert why is not None and f"holds control characters ({named})" in why, why


@pytest.mark.parametrize("name", ["naip_demo", "vol é 北京", "a b-c.d", "demo $^^$ x"])
def test_other_text_names_a_dataset(name: str) -> None:
    assert name_problem(name) is None


def test_a_dataset_json_name_with_escape_is_refused(small_flight: SmallFlight) -> None:
    flight = small_flight("flight\x1b]0;owned\x07")
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(flight)
    said = refused.value.reason
    assert "dataset.json: name: 'flight\\x1b]0;owned\\x07': holds control characters" in said
    assert "(U+0007, U+001B)" in said, said


def test_an_out_named_with_a_line_feed_needs_a_name(tmp_path: Path) -> None:
    out = tmp_path / "two\nlines"
    with pytest.raises(InvalidInputError) as refused:
        dataset_name(None, out)
    said = str(refused.value)
    assert said.startswith("OUT: '") and "two\\nlines': its name holds control" in said, said
    assert "\n" not in said and "--name" in said, said
    assert dataset_name("two lines", out) == "two lines"


def test_a_name_given_with_a_carriage_return_is_refused(tmp_path: Path, c3: C3) -> None:
    out = tmp_path / "ds"
    done = c3("dataset", "import", *_inputs(tmp_path), out, "--name", "over\rwrite")
    assert done.returncode == 2, done.stderr
    assert "--name" in done.stderr, done.stderr
    assert "holds control characters (U+000D)" in done.stderr, done.stderr
    assert not out.exists()
