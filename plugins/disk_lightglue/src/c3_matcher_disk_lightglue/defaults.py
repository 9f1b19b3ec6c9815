"""The ``disk_lightglue`` strategy's own defaults for the settings a configuration leaves unset,
chosen by measurement (docs/precision.md, "DISK + LightGlue"). The one place they are declared:
the plugin's ``StrategySpec`` and its config builder both read ``DEFAULTS``.

- ``photometric = "clahe"`` and ``filter_threshold = 0.01``: across seasons they add correct
  fixes (naip_cross_date 11 -> 14/27) and, with the refit below, no precision on the frames the
  upstream settings also get (naip_cross_date, those 11 frames: IT-03 p95 3.20 -> 3.06 px).
- ``refit_threshold_px = 2.0``: the final refit brings the same-date control back below its
  upstream precision (naip_demo IT-03 p95 1.24 -> 1.05 px, upstream 1.13) and never takes a
  candidate below ``min_inliers_threshold``.
"""

from __future__ import annotations

from c3_matcher.plugins.types import StrategyDefaults

__all__ = ["DEFAULTS"]

DEFAULTS = StrategyDefaults(photometric="clahe", filter_threshold=0.01, refit_threshold_px=2.0)
