"""A real writer killed outright in a second process (fault tests: what the out-of-memory
killer, SIGKILL or a power cut leaves behind, with no cleanup run)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

__all__ = ["killed_while_writing"]


def killed_while_writing(body: str) -> None:
    """Run ``body`` in a new Python process, its last statement indented inside a writer's
    block, then SIGKILL that process there (an ``AssertionError`` when it ended otherwise)."""
    script = (
        f"import os, signal\n{textwrap.dedent(body)}\n    os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == -9, f"the writer ended with {done.returncode}: {done.stderr}"
