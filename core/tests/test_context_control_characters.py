"""What a command prints cannot drive the terminal: C0 and C1 control characters but newline and
tab (ESC, CR, BEL, CSI), as a hostile file's name or metadata may hold them, are printed as
their escapes (``\\x1b``) by ``CommandContext.out`` and ``err``, the one place commands print
through; JSON output, whose control characters ``json.dumps`` escapes, is printed as it is."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any, cast

import pytest

from c3_matcher.cli import main
from c3_matcher.context import CommandContext
from c3_matcher.fdr import JsonlFdrRecorder
from c3_matcher.testing import FakeClock

HOSTILE = "tiles\x1b[1A\x1b[2K\rfake: intact\x07\x9b2J\x00"
ESCAPED = "tiles\\x1b[1A\\x1b[2K\\x0dfake: intact\\x07\\x9b2J\\x00"


def _context() -> tuple[CommandContext, io.BytesIO, io.BytesIO]:
    out, err = io.BytesIO(), io.BytesIO()
    stdout = io.TextIOWrapper(out, encoding="utf-8", write_through=True)
    stderr = io.TextIOWrapper(err, encoding="utf-8", write_through=True)
    return CommandContext(cast(Any, None), cast(Any, None), stdout, stderr), out, err


@pytest.mark.parametrize("stream", ["bytes", "text"])
def test_control_characters_are_printed_escaped_newline_and_tab_as_they_are(stream: str) -> None:
    if stream == "bytes":
        context, out, err = _context()
        context.out(f"name:\t{HOSTILE}\nnext")
        context.err(HOSTILE)
        printed = out.getvalue().decode(), err.getvalue().decode()
    else:  # a stream of text (io.StringIO): no encoding, escaped all the same
        text_out, text_err = io.StringIO(), io.StringIO()
        context = CommandContext(cast(Any, None), cast(Any, None), text_out, text_err)
        context.out(f"name:\t{HOSTILE}\nnext")
        context.err(HOSTILE)
        printed = text_out.getvalue(), text_err.getvalue()
    assert printed == (f"name:\t{ESCAPED}\nnext\n", f"{ESCAPED}\n")


def test_json_output_is_printed_as_it_is() -> None:
    context, out, _ = _context()
    document = json.dumps({"name": HOSTILE, "more": "\x85\x1b"}, indent=2)
    context.out(document)
    assert out.getvalue().decode() == document + "\n"
    assert json.loads(out.getvalue())["name"] == HOSTILE


def test_a_log_whose_record_kind_holds_escapes_is_described_without_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record(HOSTILE, {})
    rec.close()
    main(["fdr", str(path)])
    out = capsys.readouterr().out
    assert f"kinds: {ESCAPED} 1" in out
    assert not any(char in out for char in "\x1b\r\x07\x9b\x00")


def test_delete_and_bidirectional_controls_are_printed_escaped() -> None:
    """A name holding U+202E reads reversed from there on (``photo\\u202egpj.exe`` shows as
    ``photoexe.jpg``); DEL erases on some terminals: each is printed as its escape."""
    context, out, _ = _context()
    context.out("photo\u202egpj.exe \u2066x\u2069 \u200f\x7f")
    assert out.getvalue().decode() == "photo\\u202egpj.exe \\u2066x\\u2069 \\u200f\\x7f\n"
