"""The stages of the per-frame loop, in the order ``PipelineMatcher.match`` runs them:

- :mod:`~c3_matcher.stages.query`: the query frame prepared once and extracted (at every quarter
  turn under rotation search);
- :mod:`~c3_matcher.stages.candidate_features`: a candidate's tile features, stored (a tile
  store's precomputed map features), cached (the tile cache) or extracted;
- :mod:`~c3_matcher.stages.verify`: matching and verification of a candidate: the geometric
  prior's translation vote, RANSAC, the prior's geometry check and its similarity fallback;
- :mod:`~c3_matcher.stages.refine`: the optional second pass through the best candidate's
  homography;
- :mod:`~c3_matcher.stages.ranking`: the deterministic ranking of the survivors;
- :mod:`~c3_matcher.stages.recorder`: the frame's health update, logs and FDR records
  (:mod:`~c3_matcher.stages.frame_records`: what the terminal record says of the candidates).

:mod:`~c3_matcher.stages.outcomes` holds the values that travel between them (a candidate kept
or dropped, what a frame's records report), :mod:`~c3_matcher.stages.failure` the typed
failure of a candidate's backbone step and :mod:`~c3_matcher.stages.extract` a backend's
features checked wherever a stage takes them.
"""
