"""What a command prints through its ``CommandContext`` and the stream's encoding cannot hold
(a file name's byte that is no UTF-8, CJK under an ASCII or Latin-1 locale) is printed as
Python's escape, on stdout and stderr both, never an error; the rest as it is."""

from __future__ import annotations

import io
import json
from typing import Any, cast

import pytest

from c3_matcher.context import CommandContext


def _context(encoding: str) -> tuple[CommandContext, io.BytesIO, io.BytesIO]:
    """A context whose streams encode ``encoding`` strictly, and the bytes under each."""
    out, err = io.BytesIO(), io.BytesIO()
    stdout = io.TextIOWrapper(out, encoding=encoding, errors="strict", write_through=True)
    stderr = io.TextIOWrapper(err, encoding=encoding, errors="strict", write_through=True)
    return CommandContext(cast(Any, None), cast(Any, None), stdout, stderr), out, err


@pytest.mark.parametrize(
    ("encoding", "text", "printed"),
    [
        ("utf-8", "rep\udce9/results.jsonl", b"rep\\udce9/results.jsonl\n"),
        ("latin-1", "東京 flight é", b"\\u6771\\u4eac flight \xe9\n"),
        ("ascii", "plain", b"plain\n"),
    ],
)
def test_what_a_stream_cannot_encode_is_printed_escaped(
    encoding: str, text: str, printed: bytes
) -> None:
    context, out, err = _context(encoding)
    context.out(text)
    context.err(text)
    assert out.getvalue() == printed
    assert err.getvalue() == printed


def test_a_json_line_stays_json_on_an_ascii_stream() -> None:
    context, out, _ = _context("ascii")
    context.out(json.dumps({"out": "rep\udce9", "name": "東京"}))
    assert json.loads(out.getvalue()) == {"out": "rep\udce9", "name": "東京"}


def test_a_surrogate_escaping_stream_writes_the_names_own_byte() -> None:
    out = io.BytesIO()
    stdout = io.TextIOWrapper(out, encoding="utf-8", errors="surrogateescape", write_through=True)
    CommandContext(cast(Any, None), cast(Any, None), stdout, stdout).out("vol\udce9")
    assert out.getvalue() == b"vol\xe9\n"
