"""Run-time modules import without PyTorch (torch is build-time only)."""

from __future__ import annotations

import subprocess
import sys

RUNTIME_MODULES = [
    "c3_matcher.engines",
    "c3_matcher.engines.spec",
    "c3_matcher.engines.naming",
    "c3_matcher.engines.manifest",
    "c3_matcher.engines.store",
    "c3_matcher.engines.runtime",
    "c3_matcher.engines.lightglue",
    "c3_matcher.engines.lightglue_adaptive",
    "c3_matcher.engines.extract",
    "c3_matcher.engines.cli",
]


def test_runtime_modules_import_without_torch() -> None:
    code = (
        "import sys\n"
        "for name in ('torch', 'kornia', 'onnxscript'):\n"
        "    sys.modules[name] = None  # any import of them raises ImportError\n"
        f"for module in {RUNTIME_MODULES!r}:\n"
        "    __import__(module)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=False,
        env=None,
    )
    assert proc.returncode == 0, proc.stderr
