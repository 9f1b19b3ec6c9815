"""Engine export (build time): the request/report types every exporter shares.

This module imports without PyTorch; the exporter implementations (``export.onnx_export``,
``export.lightglue`` and the plugins' ``engines`` modules) import torch and run only inside
``c3-matcher engines build`` (extra ``c3-matcher-tools[engine-build]``).

An exporter is a callable ``exporter(request: ExportRequest) -> ExportReport``: it loads the
weights at ``request.weights_path``, writes one self-contained ONNX file (no external data) to
``request.output_path``, checks it with ONNX Runtime against an independent PyTorch reference on
the real images of ``request.images``, and reports the figures. The compiler refuses the engine
unless ``report.passed``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.engines.spec import EngineSpec

__all__ = [
    "ExportReport",
    "ExportRequest",
    "VerificationImage",
    "default_verification_imagery",
    "load_verification_images",
    "tolerance_failures",
]


@dataclass(frozen=True, slots=True)
class VerificationImage:
    """A real image for verification: ``name`` (file name) and ``rgb`` uint8 (H, W, 3)."""

    name: str
    rgb: NDArray[np.uint8]


@dataclass(frozen=True, slots=True)
class ExportRequest:
    """What the compiler hands an exporter. ``log`` prints one progress line (stderr)."""

    spec: EngineSpec
    weights_path: Path
    output_path: Path
    images: tuple[VerificationImage, ...]
    log: Callable[[str], None]


@dataclass(frozen=True, slots=True)
class ExportReport:
    """The exporter's verification: ``checks`` holds one dict of figures per compared input
    (sizes, counts, max abs errors...); ``failures`` says what failed (empty when passed)."""

    passed: bool
    reference: str
    tolerances: Mapping[str, float]
    checks: Sequence[Mapping[str, Any]]
    failures: tuple[str, ...] = ()
    notes: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_checks(
        cls,
        reference: str,
        tolerances: Mapping[str, float],
        checks: Sequence[Mapping[str, Any]],
        failures: Sequence[str],
        *,
        notes: Mapping[str, Any] | None = None,
        nothing_run: str = "no verification input was run",
    ) -> ExportReport:
        """The report of a verification: passed when something was checked and nothing failed
        (``nothing_run`` is the failure when ``checks`` is empty)."""
        return cls(
            passed=not failures and bool(checks),
            reference=reference,
            tolerances=tolerances,
            checks=checks,
            failures=tuple(failures) if checks else (nothing_run,),
            notes=dict(notes or {}),
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "reference": self.reference,
            "tolerances": dict(self.tolerances),
            "checks": [dict(c) for c in self.checks],
            "failures": list(self.failures),
            "notes": dict(self.notes),
        }


def tolerance_failures(
    where: str, figures: Mapping[str, Any], tolerances: Mapping[str, float], keys: Iterable[str]
) -> list[str]:
    """What of one input's ``figures`` (``where`` names the input) is out of ``tolerances``: for
    each of ``keys``, a figure above its tolerance, or one that is not a finite number. A NaN
    figure (a graph whose descriptors or scores came out NaN) is above no tolerance, so a plain
    comparison would pass it; so would it pass infinity against an infinite tolerance."""
    failures: list[str] = []
    for key in keys:
        figure, tolerance = float(figures[key]), float(tolerances[key])
        if not math.isfinite(figure):
            failures.append(f"{where}: {key} is {figure} (not a finite number)")
        elif figure > tolerance:
            failures.append(f"{where}: {key} {figure:.3g} > {tolerance:.3g}")
    return failures


def default_verification_imagery() -> tuple[Path, ...]:
    """The real image shipped with the package for verification (Gorinchem orthophoto, 1000x1000
    px, CC BY 4.0 Beeldmateriaal Nederland; see ``data/ATTRIBUTION.md``)."""
    root = resources.files("c3_matcher_tools.engines.export") / "data" / "gorinchem_test_tiled.tif"
    return (Path(str(root)),)


def load_verification_images(paths: Sequence[Path]) -> tuple[VerificationImage, ...]:
    """Read images as RGB uint8 with OpenCV; ``FileNotFoundError`` for an unreadable path."""
    import cv2  # opencv-python-headless is a run-time dependency already

    images: list[VerificationImage] = []
    for path in paths:
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FileNotFoundError(f"verification image {path} is missing or unreadable")
        rgb: NDArray[np.uint8] = np.ascontiguousarray(
            cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8
        )
        images.append(VerificationImage(Path(path).name, rgb))
    return tuple(images)
