"""What the contract kit (``c3_matcher.testing.contract``) hands a strategy's ``make_matcher``:
the test doubles of one scripted frame, and what a test inspects after it."""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from typing import Any

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.health import RollingHealthWindow
from c3_matcher.testing.fakes import (
    FakeClock,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    FakeRansacFilter,
    ScriptedCandidate,
)
from c3_matcher.testing.scripted import ScriptedBackend

__all__ = ["Doubles"]


@dataclass
class Doubles:
    """The doubles a contract test hands to ``make_matcher``, and what it inspects after."""

    script: list[ScriptedCandidate]
    inference: FakeInferenceRuntime
    lightglue: FakeLightGlueRuntime
    ransac: FakeRansacFilter
    fdr: InMemoryFdr
    health: RollingHealthWindow
    clock: FakeClock
    log_stream: io.StringIO
    backend: ScriptedBackend | None = None  # BackendContract: your backend under the script

    def logs(self, kind: str) -> list[dict[str, Any]]:
        lines = [json.loads(x) for x in self.log_stream.getvalue().splitlines() if x]
        return [r for r in lines if r["kind"] == kind]
