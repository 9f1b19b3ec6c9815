"""A tile store's ``c3_georeference`` metadata is outside JSON: one nested too deep to read is
refused naming the store, as any other unreadable value is."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.flight_scene import store_reference


def test_georeference_metadata_too_deep_is_refused_naming_the_store() -> None:
    deep = "[" * 100_000 + "]" * 100_000
    with pytest.raises(InvalidInputError, match=r"unreadable c3_georeference.*nested too deep"):
        store_reference({"c3_georeference": deep}, Path("area.mbtiles"))
