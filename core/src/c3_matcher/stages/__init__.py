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
  (:mod:`~c3_matcher.stages.frame_records`: the terminal record's fields, declared once, and
  what it says of the candidates; :mod:`~c3_matcher.stages.provenance`: the backend's
  provenance in it; :mod:`~c3_matcher.stages.no_fix`: a frame without a fix;
  :mod:`~c3_matcher.stages.interrupts`: whether a stopped frame can still be recorded).

:mod:`~c3_matcher.stages.outcomes` holds the values that travel between them (a candidate kept
or dropped, what a frame's records report), :mod:`~c3_matcher.stages.failure` the typed
failure of a candidate's backbone step, :mod:`~c3_matcher.stages.extract` a backend's
features checked wherever a stage takes them and :mod:`~c3_matcher.stages.matching` what its
``match`` is given and returns, checked; :mod:`~c3_matcher.stages.frame_inputs` the
arguments ``match`` refuses before a frame is matched.
"""
