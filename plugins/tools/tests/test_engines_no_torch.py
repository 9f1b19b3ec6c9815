"""The ground tools' engine commands and every installed plugin's engine declarations import
without PyTorch (torch is build time only: the exporters import it, nothing else)."""

from __future__ import annotations

import subprocess
import sys

TOOLS_MODULES = [
    "c3_matcher_tools.engines.compiler",
    "c3_matcher_tools.engines.bench",
    "c3_matcher_tools.engines.export",
]


def test_tools_engine_modules_and_plugin_specs_import_without_torch() -> None:
    code = (
        "import sys\n"
        "for name in ('torch', 'kornia', 'onnxscript'):\n"
        "    sys.modules[name] = None  # any import of them raises ImportError\n"
        f"for module in {TOOLS_MODULES!r}:\n"
        "    __import__(module)\n"
        "from c3_matcher.compose import build_plugin_host\n"
        "from c3_matcher.engines.lightglue_specs import steps_specs\n"
        "specs = build_plugin_host().engine_specs()\n"
        "keys = {s.key for s in specs}\n"
        "assert {'disk/depth', 'lightglue/disk', 'lightglue/disk-steps'} <= keys, keys\n"
        "assert {'lightglue/aliked-steps', 'lighterglue/xfeat'} <= keys, keys\n"
        "assert set(steps_specs(specs)) == {'disk', 'aliked'}\n"
        "assert all(not s.exporter.startswith('c3_matcher_tools') for s in specs)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
