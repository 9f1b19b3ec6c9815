"""``lightglue_exporters``: the two LightGlue exporters a plugin names, built from its feature
type and its reference extractor (control flow; the real exports run in ``engines build``)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from c3_matcher_disk_lightglue.engines import LIGHTGLUE_DISK_SPEC, LIGHTGLUE_DISK_STEPS_SPEC
from c3_matcher_tools.engines.export import lightglue_steps


def test_each_exporter_gets_fresh_features_and_the_spec_facts(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[tuple[str, dict[str, Any]]] = []
    monkeypatch.setattr(
        lightglue_steps, "export_lightglue", lambda _r, **kw: calls.append(("full", kw))
    )
    monkeypatch.setattr(
        lightglue_steps, "export_lightglue_steps", lambda _r, **kw: calls.append(("steps", kw))
    )
    made: list[int] = []

    def features_fn() -> Any:
        made.append(len(made))
        return f"features-{len(made)}"

    full, steps = lightglue_steps.lightglue_exporters("disk", features_fn)
    assert made == []  # the reference extractor is made when an exporter runs, not before
    full(SimpleNamespace(spec=LIGHTGLUE_DISK_SPEC))
    steps(SimpleNamespace(spec=LIGHTGLUE_DISK_STEPS_SPEC))
    assert calls == [
        ("full", {"features_fn": "features-1", "input_dim": 128, "feature_type": "disk"}),
        ("steps", {"features_fn": "features-2", "feature_type": "disk"}),
    ]
