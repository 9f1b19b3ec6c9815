"""Map features computed once on the ground (``c3-matcher features build|info``); see
:mod:`c3_matcher.tilestore.features` for the sidecar format and the flight read path."""

from c3_matcher_tools.features.build import BuildReport, build_features
from c3_matcher_tools.features.worker import extract_window_features

__all__ = ["BuildReport", "build_features", "extract_window_features"]
