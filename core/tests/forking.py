"""Running a piece of a test in a forked child: what it said, or that it hung."""

from __future__ import annotations

import os
import select
import signal
from collections.abc import Callable

import pytest

from c3_matcher.errors import describe

DEADLINE_S = 20.0
"""A child that has said nothing by then never will: it hung."""


def in_forked_child(work: Callable[[], str]) -> tuple[int, str]:
    """Run ``work`` in a forked child: its pid and what ``work`` returned (or the error it
    raised, as ``Type: message``); a child that says nothing within ``DEADLINE_S`` is killed and
    the test fails: it hung."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never back into the test runner
        try:
            os.close(read_end)
            try:
                said = work()
            except BaseException as exc:
                said = describe(exc)
            os.write(write_end, said.encode())
        finally:
            os._exit(0)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as pipe:
        if not select.select([pipe], [], [], DEADLINE_S)[0]:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail(f"the forked child hung: it said nothing within {DEADLINE_S} s")
        said = pipe.read().decode()
    assert os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0
    return pid, said
