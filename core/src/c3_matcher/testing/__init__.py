"""Test kit for c3-matcher and its plugins: the allowed test doubles and fixture makers.

``FakeInferenceRuntime``, ``FakeLightGlueRuntime``, ``FakeRansacFilter``, ``InMemoryFdr`` (the
FakeFdrClient) and ``FakeClock`` are the doubles allowed in unit tests of control flow; the
contract kit is ``c3_matcher.testing.contract``.
"""

from __future__ import annotations

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.testing.fakes import (
    FakeBackend,
    FakeClock,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    FakeRansacFilter,
    ScriptedCandidate,
    ScriptedRig,
    SequenceRansacFilter,
    make_frame,
    make_rerank,
    scripted_pipeline,
)

__all__ = [
    "FakeBackend",
    "FakeClock",
    "FakeInferenceRuntime",
    "FakeLightGlueRuntime",
    "FakeRansacFilter",
    "InMemoryFdr",
    "ScriptedCandidate",
    "ScriptedRig",
    "SequenceRansacFilter",
    "make_frame",
    "make_rerank",
    "scripted_pipeline",
]
