"""The engine-output assertion that fires at start-up: a backend run once on a deterministic
textured image (``compose_root`` runs it on every strategy's backend; the contract kit uses the
same image)."""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import EngineError, describe
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import PreparedImage
from c3_matcher.protocols import FeatureBackend

__all__ = [
    "BACKEND_MEMBERS",
    "check_members",
    "engine_startup_probe",
    "missing_members",
    "textured_probe",
]


def textured_probe(width: int, height: int, block: int = 6) -> NDArray[np.uint8]:
    """A deterministic textured RGB image (height, width, 3) uint8: ``block`` px squares of
    random colour (seed 0), the start-up probe's and the contract kit's stand-in image."""
    rng = np.random.default_rng(0)
    cells = -(-max(width, height) // block)
    noise = rng.integers(0, 256, (cells, cells, 3), dtype=np.uint8)
    blocks = np.kron(noise, np.ones((block, block, 1), np.uint8))[:height, :width]
    return np.ascontiguousarray(blocks)


def engine_startup_probe(backend: FeatureBackend, size: int = 128, block: int = 6) -> None:
    """Run the backend once on a deterministic textured probe image and assert its outputs
    (the engine-output assertion that fires at start-up, not on the first frame).

    The probe is ``block`` px squares of random colour (seed 0); 6 px blocks do not line up with
    the 8x8 cells some detectors (XFeat) score, so every cell sees texture."""
    image = textured_probe(size, size, block)
    probe = PreparedImage(
        image=image,
        valid=np.ones((size, size), bool),
        working_from_engine=np.eye(3),
        working_size=(size, size),
    )
    try:
        features = backend.extract(probe)
        _check_features(features, size)
        matches = backend.match(features, features)
        _check_matches(matches, len(features))
    except Exception as exc:
        failed = f"start-up probe failed: {describe(exc)}"
        if _runs_engines(backend):
            raise EngineError(backend.label, failed) from exc
        raise EngineError(
            backend.label,
            f"{failed}; the backend runs no engine: test its extract and match with the "
            "contract kit (c3_matcher.testing.contract.BackendContract, docs/plugins.md)",
            command=None,
        ) from exc


def _check_features(features: object, size: int) -> None:
    """The probe's features: a :class:`Features` with keypoints, all inside the image."""
    if not isinstance(features, Features):
        raise TypeError(f"extract returned {type(features).__name__}, not Features")
    if len(features) == 0:
        raise ValueError("the extractor found no keypoint on the textured probe image")
    kp = features.keypoints
    outside = int((~((kp >= -0.5) & (kp <= size - 0.5)).all(axis=1)).sum())
    if outside:
        raise ValueError(f"{outside} keypoint(s) outside the {size}x{size} px probe image")


def _check_matches(matches: object, count: int) -> None:
    """The probe matched with itself: :class:`RawMatches` of indices into its ``count``
    keypoints, some, each query keypoint in one pair at most (a pair given twice would count
    twice as an inlier)."""
    if not isinstance(matches, RawMatches):
        raise TypeError(f"match returned {type(matches).__name__}, not RawMatches")
    if len(matches) == 0:
        raise ValueError(
            "matching the probe image with itself gave no match (an engine fault, or a "
            "setting that stops every pair early: [lightglue] exit_matches)"
        )
    pairs = matches.matches
    if not bool(((pairs >= 0) & (pairs < count)).all()):
        raise ValueError(f"match gave indices outside the {count} keypoints it was given")
    query = pairs[:, 0]
    if np.unique(query).size != query.size:
        raise ValueError("match paired one query keypoint more than once")


def _runs_engines(backend: FeatureBackend) -> bool:
    """Whether the backend names engines in its provenance (then ``engines build`` is the fix
    for a failing probe); a backend whose provenance cannot be read is taken to run them."""
    try:
        return bool(backend.provenance().get("engines", True))
    except Exception:
        return True


BACKEND_MEMBERS: Final = (
    "label",
    "input_rule",
    "extract_phase",
    "match_phase",
    "extract",
    "match",
    "provenance",
)
"""What every ``FeatureBackend`` has (``c3_matcher.protocols.FeatureBackend``)."""


def missing_members(backend: object) -> list[str]:
    """The ``FeatureBackend`` members ``backend`` lacks (methods must be callable)."""
    missing = [name for name in BACKEND_MEMBERS if not hasattr(backend, name)]
    return missing + [
        name
        for name in ("extract", "match", "provenance")
        if name not in missing and not callable(getattr(backend, name))
    ]


def check_members(backend: object) -> None:
    """``TypeError`` naming every member ``backend`` lacks, and where the contract is."""
    missing = missing_members(backend)
    if missing:
        raise TypeError(
            f"{type(backend).__name__} is not a FeatureBackend: it lacks "
            f"{', '.join(missing)} (a backend has {', '.join(BACKEND_MEMBERS)}; "
            "see 'The backend's contract' in docs/plugins.md)"
        )
