"""The ``aliked_lightglue`` strategy's own defaults for the settings a configuration leaves unset
(``[matcher] photometric``, ``[lightglue] filter_threshold``), chosen by measurement on every
shipped flight (docs/precision.md). The one place they are declared: the plugin's
``StrategySpec`` and its config builder both read ``DEFAULTS``."""

from __future__ import annotations

from c3_matcher.plugins.types import StrategyDefaults

__all__ = ["DEFAULTS"]

DEFAULTS = StrategyDefaults(photometric="clahe", filter_threshold=0.01)
