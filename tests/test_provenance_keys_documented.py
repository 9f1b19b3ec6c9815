"""The plugin guide names every record field a backend's provenance may not use: the core's own
fields of a frame's terminal record, as declared once in the core."""

from __future__ import annotations

from pathlib import Path

from c3_matcher.stages.frame_records import TERMINAL_RECORD_FIELDS

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "plugins.md"


def test_the_guide_lists_the_reserved_provenance_keys() -> None:
    text = GUIDE.read_text(encoding="utf-8")
    start = text.index("`provenance()` is read for each frame's record")
    section = text[start : text.index("\n\n", start)]
    named = {part for part in section.split("`")[1::2] if part.isidentifier()}
    assert named >= TERMINAL_RECORD_FIELDS, sorted(TERMINAL_RECORD_FIELDS - named)
