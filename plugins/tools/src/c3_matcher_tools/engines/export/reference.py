"""What the strategies' PyTorch reference backends share (build time: imports torch and kornia).

A reference backend (hook ``c3_matcher_reference_backend``, used by ``c3-matcher bench``) does
the work the way a user of the upstream models would: the upstream extractor on every image
(tiles re-extracted every frame) and kornia's LightGlue with its upstream adaptive depth and
width ON, the same weights as the engines. It is a ``FeatureBackend`` plugged into the core's
pipeline, so preprocessing and RANSAC are identical to the engines'. This module imports torch
and kornia only when a reference is built, so a plugin's ``export`` module may subclass
``PyTorchReference`` and still import without them.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.engines.lightglue_specs import (
    UPSTREAM_DEPTH_CONFIDENCE,
    UPSTREAM_WIDTH_CONFIDENCE,
)
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import InputRule

__all__ = [
    "PyTorchReference",
    "load_upstream_lightglue",
]


def load_upstream_lightglue(
    weights_path: Path,
    *,
    depth_confidence: float | None = UPSTREAM_DEPTH_CONFIDENCE,
    width_confidence: float | None = UPSTREAM_WIDTH_CONFIDENCE,
    **architecture: int,
) -> Any:
    """``load_lightglue_reference`` with upstream's adaptive depth / width settings switched back
    on (None leaves one off)."""
    from c3_matcher_tools.engines.export.lightglue import load_lightglue_reference

    model = load_lightglue_reference(weights_path, **architecture)
    if depth_confidence is not None:
        model.conf.depth_confidence = depth_confidence
    if width_confidence is not None:
        model.conf.width_confidence = width_confidence
    return model


class PyTorchReference:
    """Base of a strategy's PyTorch reference ``FeatureBackend`` (CPU): the input rule, kornia
    LightGlue matching (``lightglue``, None for a strategy that matches otherwise) and the
    provenance. A subclass sets ``label``, ``extract_phase`` and implements ``extract``."""

    label: str
    extract_phase: str
    match_phase = "lightglue_match"

    def __init__(self, settings: C3Settings, size_multiple: int, lightglue: Any = None) -> None:
        import torch

        self._torch = torch
        self.input_rule = InputRule(settings.matcher.max_long_side, size_multiple)
        self._lightglue = lightglue

    def match(self, query: Features, tile: Features) -> RawMatches:
        from c3_matcher_tools.engines.export.lightglue import reference_inputs

        inputs = reference_inputs(query.pair_side, tile.pair_side)
        with self._torch.no_grad():
            out = self._lightglue(inputs)
        return RawMatches(
            out["matches"][0].numpy().astype(np.int64), out["scores"][0].numpy().astype(np.float32)
        )

    def provenance(self) -> Mapping[str, Any]:
        return {"provider": f"pytorch {self._torch.__version__} (CPU)", "engines": {}}
