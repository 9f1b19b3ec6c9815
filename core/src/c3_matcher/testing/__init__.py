"""Test kit for c3-matcher and its plugins: the allowed test doubles and fixture makers.

``FakeInferenceRuntime``, ``FakeLightGlueRuntime``, ``FakeRansacFilter``, ``InMemoryFdr`` (the
FakeFdrClient) and ``FakeClock`` are the doubles allowed in unit tests of control flow; the
contract kit is ``c3_matcher.testing.contract``.
"""

from __future__ import annotations

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.testing import fakes, hosts
from c3_matcher.testing.fakes import *  # noqa: F403 (the doubles: fakes.__all__)
from c3_matcher.testing.hosts import *  # noqa: F403 (a one-strategy host: hosts.__all__)

__all__ = ["InMemoryFdr", *fakes.__all__, *hosts.__all__]
