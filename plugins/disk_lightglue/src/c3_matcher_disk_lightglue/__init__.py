"""DISK + LightGlue, the default c3-matcher strategy.

Only what is DISK-specific lives here: its engines (``engines.py``), its input rule (H and W
multiples of ``DISK_SIZE_MULTIPLE``) and its ``create``; the per-frame work is the core's
shared pipeline.
"""

from __future__ import annotations

from c3_matcher_disk_lightglue.matcher import (
    DISK_SIZE_MULTIPLE,
    DiskLightGlueConfig,
    DiskLightGlueMatcher,
    create,
)

__all__ = ["DISK_SIZE_MULTIPLE", "DiskLightGlueConfig", "DiskLightGlueMatcher", "create"]
