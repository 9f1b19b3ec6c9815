"""The ``aliked_lightglue`` strategy's own defaults for the settings a configuration leaves unset,
chosen by measurement (docs/precision.md, "ALIKED + LightGlue"). The one place they are declared:
the plugin's ``StrategySpec`` reads ``DEFAULTS``, and ``compose_root`` applies them once,
before the strategy's config is made from the settings.

- ``filter_threshold = 0.1`` (upstream): 0.01 gained cross-season frames (naip_cross_date
  9 -> 11/27) and lost precision on every flight measured (naip_demo IT-03 p95 1.13 -> 1.16 px;
  on the frames both get, naip_cross_date 3.20 -> 3.47, gorinchem_z18 1.79 -> 2.03).
- ``photometric = "none"``: CLAHE at 0.1 gained fixes on some flights (gorinchem_z18 9 -> 11/12)
  and lost them and precision where frames and map are years apart (naip_s2015_f2010, with
  the refit: 16 -> 12/18 fixes, IT-03 p95 2.89 -> 4.43 px; naip_cross_date 9 -> 8/27).
- ``refit_threshold_px = 2.0``: the final refit lowers IT-03 or leaves it on every frame
  (naip_demo 1.13 -> 0.95 px) and never takes a candidate below ``min_inliers_threshold``.
"""

from __future__ import annotations

from c3_matcher.plugins.types import StrategyDefaults

__all__ = ["DEFAULTS"]

DEFAULTS = StrategyDefaults(photometric="none", filter_threshold=0.1, refit_threshold_px=2.0)
