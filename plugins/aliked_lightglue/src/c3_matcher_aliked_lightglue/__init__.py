"""ALIKED + LightGlue strategy for c3-matcher.

Only what is ALIKED-specific lives here: its engines (``engines.py``, run time), its build time
(``export.py``: the export rewrite, with the deformable convolution as GridSample + MatMul in
``deform_conv.py``, and the PyTorch reference), its input rule (H and W multiples of 32), its
options (``variant`` n16 or n16rot) and its ``create``; the per-frame work is the core's
shared pipeline.
"""

from __future__ import annotations

from c3_matcher_aliked_lightglue.matcher import (
    ALIKED_SIZE_MULTIPLE,
    AlikedLightGlueConfig,
    AlikedLightGlueMatcher,
    AlikedLightGlueOptions,
    create,
)

__all__ = [
    "ALIKED_SIZE_MULTIPLE",
    "AlikedLightGlueConfig",
    "AlikedLightGlueMatcher",
    "AlikedLightGlueOptions",
    "create",
]
