"""pytest plugin shipped with c3-matcher (entry point ``pytest11``): fixtures for plugin authors.

Fixtures: ``c3_fake_clock``, ``c3_fdr`` (in-memory FDR). The contract test base class is
``c3_matcher.testing.contract.MatcherContract``.
"""

from __future__ import annotations

import pytest

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.testing.fakes import FakeClock


@pytest.fixture
def c3_fake_clock() -> FakeClock:
    """A monotonic clock that moves only when the test calls ``advance(seconds)``."""
    return FakeClock()


@pytest.fixture
def c3_fdr() -> InMemoryFdr:
    """An FDR that keeps its records in memory: ``of_kind(kind)`` lists those of a kind."""
    return InMemoryFdr()
