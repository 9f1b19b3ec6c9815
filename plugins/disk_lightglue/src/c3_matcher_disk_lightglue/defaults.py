"""The ``disk_lightglue`` strategy's own defaults for the settings a configuration leaves unset,
chosen by measurement (docs/precision.md, "DISK + LightGlue"). The one place they are declared:
the plugin's ``StrategySpec`` reads ``DEFAULTS``, and ``compose_root`` applies them once,
before the strategy's config is made from the settings.

- ``photometric = "none"`` and ``filter_threshold = 0.1`` (upstream): CLAHE with threshold 0.01
  added cross-season fixes (naip_cross_date 11 -> 14/27, naip_s2010_f2020 9 -> 13/18) and lost
  precision where frames and map are years apart (naip_s2015_f2010: same 17/18 fixes, IT-03 p95
  2.82 -> 4.04 px; naip_s2010_f2015: same 16/18, 3.27 -> 3.60 px; naip_s2010_f2020, the 9
  frames both get: 2.37 -> 2.66 px), refit or not.
  Threshold 0.01 without CLAHE gained one fix (gorinchem_z18) and lost a little precision on the
  same-date flights (naip_s2020_f2015 1.81 -> 1.86 px, worse on 16 of 18 frames).
- ``refit_threshold_px = 2.0``: the final refit lowers IT-03 or leaves it on every flight, worse
  on no frame (naip_demo 1.13 -> 1.02 px, naip_s2010_f2020 2.37 -> 1.87 px), and never takes a
  candidate below ``min_inliers_threshold``.
- ``exit_matches = 8``: after its second layer a pair with fewer than 8 mutual matches of
  confidence above 0.3 stops with no matches. Replayed exactly on every pair of the 15 shipped
  flights (792 pairs, ``scripts/early_exit_sweep.py``): it stops 476 pairs, saves 861 of 3539
  LightGlue layers and stops no pair whose candidate was accepted, so no pick and no refusal
  changes; the fewest such matches on an accepted pair was 17, twice the count
  (docs/decisions.md, "Pairs that cannot match stop early").
"""

from __future__ import annotations

from c3_matcher.plugins.types import StrategyDefaults

__all__ = ["DEFAULTS"]

DEFAULTS = StrategyDefaults(
    photometric="none", filter_threshold=0.1, refit_threshold_px=2.0, exit_matches=8
)
