"""Reading JSON that a user, a file or another process gave: :func:`loads_json`.

Python's decoder fails on such text in two ways that are not ``json.JSONDecodeError``: a
document nested about 1000 deep overflows its recursion (``RecursionError``), and an integer of
more than 4300 digits is a ``ValueError`` advising an interpreter setting. Both are bad input,
not internal errors, so every reader of outside JSON reads through this one function and says
the same words for them."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

__all__ = ["NESTED_TOO_DEEP", "loads_json"]

NESTED_TOO_DEEP = "nested too deep to read (arrays or objects inside about 1000 others)"
"""Why a document nested past the decoder's recursion limit is refused."""

_INTERPRETER_ADVICE = "; use sys."


def loads_json(
    text: str | bytes,
    *,
    object_pairs_hook: Callable[[list[tuple[str, Any]]], Any] | None = None,
) -> Any:
    """``json.loads(text)``, where every way ``text`` fails to be JSON is a ``ValueError``
    (``json.JSONDecodeError``, ``UnicodeDecodeError`` and a hook's own errors as they are) whose
    message says why in words: :data:`NESTED_TOO_DEEP`, or the digit limit without advice to
    change the interpreter."""
    try:
        return json.loads(text, object_pairs_hook=object_pairs_hook)
    except RecursionError:
        raise ValueError(NESTED_TOO_DEEP) from None
    except ValueError as exc:
        why, advice, _ = str(exc).partition(_INTERPRETER_ADVICE)
        if not advice:
            raise
        raise ValueError(why) from None
