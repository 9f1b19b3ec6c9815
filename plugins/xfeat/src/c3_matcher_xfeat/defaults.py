"""The ``xfeat`` strategy's own defaults for the settings a configuration leaves unset, chosen by
measurement on every shipped flight (docs/precision.md, "XFeat"). The one place they are
declared: the plugin's ``StrategySpec`` reads ``DEFAULTS``, and ``compose_root`` applies
them once, before the strategy's config is made from the settings.

- ``photometric = "none"``: CLAHE gained XFeat frames (naip_demo 22 -> 25/27, naip_s2015_f2020
  1 -> 2/18) but made the one cross-season fix both settings get less precise (frame 13 of
  naip_s2015_f2020: 2.31 -> 2.81 px; IT-03 p95 2.31 -> 2.79): recall bought with precision.
- ``filter_threshold = 0.1`` (upstream): only LighterGlue (``matcher = "lighterglue"``) reads
  it; 0.01 gained naip_cross_date frames and lost precision on naip_s2015_f2020 (2.94 -> 3.25).
- ``refit_threshold_px = 2.0``: the final refit lowers IT-03 or leaves it on every flight
  (naip_demo 1.92 -> 1.59) and never takes a candidate below ``min_inliers_threshold``.
"""

from __future__ import annotations

from c3_matcher.plugins.types import StrategyDefaults

__all__ = ["DEFAULTS"]

DEFAULTS = StrategyDefaults(photometric="none", filter_threshold=0.1, refit_threshold_px=2.0)
