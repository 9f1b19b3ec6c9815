"""A backend's ``extract``, its answer checked wherever the core takes it (the query, each tile,
the refine pass, the start-up probe): a :class:`Features` whose keypoints lie on the image it
was given. A backend that returns anything else, or keypoints of another scale or another
image, fails that extraction, naming what was wrong, as a NaN keypoint does: keypoints off the
image would otherwise reach RANSAC as correspondences nowhere on either image, and a
consistent mistake (a scale forgotten past some image size) gives a confident, wrong fix.

An extraction with more keypoints than the backend's budget (:func:`extraction_budget`) keeps
the budget's best by score (:func:`cut_to_budget`), and a matcher says so once (a WARNING,
:class:`Extraction`), not every frame: OpenCV's detectors keep the keypoints tied with
the N-th and so give N + 1, a true tile that must not be refused for it, and a million keypoints
would take one frame tens of seconds and hundreds of MB to match."""

from __future__ import annotations

import operator
import threading
from typing import Final

import numpy as np

from c3_matcher.errors import InvalidInputError
from c3_matcher.features import Features
from c3_matcher.logs import log_event
from c3_matcher.prepared import PreparedImage
from c3_matcher.protocols import FeatureBackend, KeypointBudgetBackend

__all__ = [
    "KEYPOINTS_CUT",
    "KEYPOINT_BUDGET_UNREAD",
    "KEYPOINT_CEILING",
    "KEYPOINT_MARGIN_PX",
    "Extraction",
    "backend_budget",
    "checked_features",
    "cut_to_budget",
    "extract_checked",
    "extraction_budget",
]

KEYPOINT_MARGIN_PX = 1.0
"""How far (px) past the image's edge (pixel centres 0..w-1, the image -0.5..w-0.5) a keypoint
may lie: sub-pixel refinement at the border steps a fraction of a pixel out; further out, the
keypoint is not of this image."""

KEYPOINT_CEILING = 32768
"""The most keypoints per image the core takes from a backend that declares no keypoint budget
(no ``max_keypoints``: ``KeypointBudgetBackend``): above every budget a setting asks
(``[matcher] max_keypoints`` <= 8192; the example ORB plugin's option <= 20000), far below the
counts that make one frame take seconds and hundreds of MB."""

KEYPOINTS_CUT = "c3.matcher.keypoints_cut"
"""The WARNING a matcher logs once when an extraction held more keypoints than its budget."""
KEYPOINT_BUDGET_UNREAD = "c3.matcher.keypoint_budget_unread"
"""The WARNING a matcher logs when it is composed over a backend whose ``max_keypoints`` is no
positive integer (0, None, a float): its extractions are held to the core's ceiling instead."""


def checked_features(features: object, size: tuple[int, int], image: str = "image") -> Features:
    """``features`` as the extraction of a ``size`` (w, h) px ``image``; ``InvalidInputError``
    when it is not :class:`Features` or has keypoints off the image (more than
    :data:`KEYPOINT_MARGIN_PX` past its edge)."""
    if not isinstance(features, Features):
        raise InvalidInputError(
            "features", f"extract returned {type(features).__name__}, not Features"
        )
    w, h = size
    low = -0.5 - KEYPOINT_MARGIN_PX
    kp = features.keypoints.astype(np.float64)
    on = (kp >= low) & (kp <= np.array([w, h], np.float64) - 0.5 + KEYPOINT_MARGIN_PX)
    off = ~on.all(axis=1)
    if off.any():
        lo, hi = kp[off].min(axis=0), kp[off].max(axis=0)
        raise InvalidInputError(
            "features.keypoints",
            f"{int(off.sum())} keypoint(s) outside the {w}x{h} px {image} (x {lo[0]:.0f}.."
            f"{hi[0]:.0f}, y {lo[1]:.0f}..{hi[1]:.0f}): keypoints are in the pixels of the "
            "image extract was given",
        )
    return features


def backend_budget(backend: FeatureBackend) -> int | None:
    """The keypoints per image ``backend`` declares it keeps (``max_keypoints``,
    :class:`KeypointBudgetBackend`: a positive integer, a NumPy one too), or None where it
    declares none or no positive integer: the one reading of a backend's budget, for its
    extractions, the start-up check that its inlier threshold is reachable, the tile store's
    precomputed features and the ground tools' reports."""
    return _positive(_declared(backend))


def _declared(backend: FeatureBackend) -> object:
    """``backend``'s ``max_keypoints`` as it is, None where it declares none (no
    ``max_keypoints``, or None)."""
    return backend.max_keypoints if isinstance(backend, KeypointBudgetBackend) else None


def _positive(value: object) -> int | None:
    """``value`` as a positive int (any integer type but bool), else None."""
    if isinstance(value, bool):
        return None
    try:
        number = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        return None
    return number if number >= 1 else None


def extraction_budget(backend: FeatureBackend) -> tuple[int, str]:
    """The most keypoints one extraction of ``backend`` keeps, and that limit in words: the
    budget it declares (:func:`backend_budget`), else :data:`KEYPOINT_CEILING`."""
    return _budget_in_words(backend, backend_budget(backend))


def _budget_in_words(backend: FeatureBackend, declared: int | None) -> tuple[int, str]:
    """``extraction_budget`` of ``backend`` whose budget read is ``declared``."""
    if declared is not None:
        return declared, f"the {declared} backbone {backend.label} declares (max_keypoints)"
    return KEYPOINT_CEILING, (
        f"the core's ceiling of {KEYPOINT_CEILING} for a backbone that declares no keypoint "
        f"budget ({backend.label} declares no max_keypoints)"
    )


def cut_to_budget(features: Features, budget: int) -> Features:
    """``features`` when they hold at most ``budget`` keypoints, else their ``budget`` best by
    score (descending; a tie goes to the earlier keypoint, so one answer always gives one cut),
    in the backend's order, with their descriptors and scores."""
    if len(features) <= budget:
        return features
    best = np.argsort(-features.keypoint_scores, kind="stable")[:budget]
    keep = np.sort(best)
    return Features(
        features.keypoints[keep],
        features.descriptors[keep],
        features.keypoint_scores[keep],
        features.image_size,
    )


class Extraction:
    """One matcher's extractions from ``backend``: each answer checked (:func:`checked_features`,
    on the engine image it was given) and cut to the budget (:func:`cut_to_budget`), read once
    here, at composition (:func:`extraction_budget`: a backend's budget is part of its declared
    interface, fixed for its life). The first cut is said (a :data:`KEYPOINTS_CUT` WARNING
    naming the backbone, the count and the budget) unless ``say_cuts`` is False, the later ones
    are not: a backend over its budget is over it every frame; so is, once, a ``max_keypoints``
    that is no positive integer (:data:`KEYPOINT_BUDGET_UNREAD`). Thread-safe."""

    def __init__(self, backend: FeatureBackend, *, say_cuts: bool = True) -> None:
        self.backend: Final = backend
        declared = _declared(backend)  # read once: a backend's budget is fixed for its life
        positive = _positive(declared)
        budget, self._limit = _budget_in_words(backend, positive)
        self.budget: Final = budget
        self._lock = threading.Lock()
        self._say = say_cuts
        if say_cuts and declared is not None and positive is None:
            log_event(
                "WARNING",
                KEYPOINT_BUDGET_UNREAD,
                f"C3 keypoint budget unread; backbone={backend.label}; max_keypoints="
                f"{declared!r} is no positive integer: its extractions are held to {self._limit}",
                backbone=backend.label,
                declared=repr(declared),
            )

    def __call__(self, image: PreparedImage, name: str = "image") -> Features:
        """``backend.extract(image)``, checked (``name`` in an error) and cut to the budget."""
        features = checked_features(self.backend.extract(image), image.engine_size, name)
        if len(features) <= self.budget:
            return features
        self._said_cut(len(features), image.engine_size)
        return cut_to_budget(features, self.budget)

    def _said_cut(self, count: int, size: tuple[int, int]) -> None:
        """Say, unless said already, that an extraction on a ``size`` (w, h) px image held
        ``count`` keypoints, more than the budget, and was cut to it."""
        with self._lock:
            say, self._say = self._say, False
        if not say:
            return
        log_event(
            "WARNING",
            KEYPOINTS_CUT,
            f"C3 keypoints cut; backbone={self.backend.label}; {count} keypoints on a "
            f"{size[0]}x{size[1]} px image, more than {self._limit}: the {self.budget} of "
            "highest score kept (said once per matcher; the extractor should keep to its budget)",
            backbone=self.backend.label,
            keypoints=count,
            budget=self.budget,
        )


def extract_checked(backend: FeatureBackend, image: PreparedImage, name: str = "image") -> Features:
    """One extraction as flight takes it (:class:`Extraction`), the cut not said: for one-off
    extractions (the start-up probe's, a tile store's precomputed features)."""
    return Extraction(backend, say_cuts=False)(image, name)
