"""Outside JSON is read through one function: a document too deep or a number too long is a
``ValueError`` in the same words everywhere, never a ``RecursionError`` escaping a reader."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from c3_matcher.engines.manifest import read_manifest
from c3_matcher.engines.naming import manifest_path_for
from c3_matcher.errors import EngineError
from c3_matcher.json_text import NESTED_TOO_DEEP, loads_json

DEEP = "[" * 100_000 + "]" * 100_000


def test_json_reads_as_json() -> None:
    assert loads_json(b'{"a": [1, 2.5, null]}') == {"a": [1, 2.5, None]}


def test_a_document_too_deep_is_a_value_error_in_words() -> None:
    with pytest.raises(ValueError, match=r"^nested too deep to read \(") as info:
        loads_json(DEEP)
    assert str(info.value) == NESTED_TOO_DEEP


def test_a_number_too_long_says_so_without_advice_on_the_interpreter() -> None:
    with pytest.raises(ValueError, match="5001 digits") as info:
        loads_json("[" + "9" * 5001 + "]")
    assert "sys." not in str(info.value)


def test_malformed_json_and_a_hook_error_are_raised_as_they_are() -> None:
    with pytest.raises(json.JSONDecodeError):
        loads_json("{")

    class RefusedError(ValueError):
        pass

    def hook(pairs: list[tuple[str, object]]) -> object:
        raise RefusedError("no")

    with pytest.raises(RefusedError):
        loads_json('{"a": 1}', object_pairs_hook=hook)


def test_an_engine_manifest_too_deep_is_an_engine_error_naming_it(tmp_path: Path) -> None:
    engine = tmp_path / "disk-depth-fp32-hw16-k2048-op18-0123456789ab.onnx"
    engine.write_bytes(b"")
    manifest_path_for(engine).write_text(DEEP)
    with pytest.raises(EngineError, match="is unreadable") as info:
        read_manifest(engine)
    assert NESTED_TOO_DEEP in str(info.value)
