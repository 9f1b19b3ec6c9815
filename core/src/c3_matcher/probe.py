"""The engine-output assertion that fires at start-up: a backend run on a deterministic textured
image and on a wider view of the same texture that holds it at a known offset, the two matched
once (``compose_root`` runs it on every strategy's backend; the contract kit uses the same
images).

Both images follow the backend's own ``input_rule`` (``probe_side``), and the offset is a multiple
of the rule's ``multiple`` (``probe_shift``), so a network with that stride sees the same texture
at the same phase in both. A backend that matches correctly pairs each query point (x, y) with
the tile point (x + shift, y), in (query, tile) order, each keypoint once; the tile has
texture the query lacks, and so more keypoints.

A backend may say why a match gave no pair: ``early_stop()`` returns ``(setting, why)`` when a
configured rule stopped the last pair before matching it (LightGlue's unmatchable-pair exit), not
a fault. The probe then tries a larger pair (``PROBE_GROWTH``), with more matches to pass such a
rule, and checks the contract on the first that is matched; a rule that stops even the largest
is a configuration error naming the setting.
"""

from __future__ import annotations

from functools import cache
from typing import Final

import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import ConfigurationError, EngineError, describe
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import InputRule, PreparedImage, check_pairs
from c3_matcher.protocols import EarlyStopping, FeatureBackend
from c3_matcher.stages.extract import extract_checked
from c3_matcher.stages.interrupts import is_stop
from c3_matcher.stages.provenance import read_provenance

__all__ = [
    "BACKEND_MEMBERS",
    "PROBE_BLOCK_PX",
    "PROBE_GROWTH",
    "PROBE_SIDE",
    "check_members",
    "check_shifted_matches",
    "engine_startup_probe",
    "missing_members",
    "probe_image",
    "probe_pair",
    "probe_shift",
    "probe_side",
    "textured_probe",
]

PROBE_SIDE: Final = 128
"""px: the probe image's side before the backend's input rule rounds it."""
MIN_SHIFT: Final = 16
"""px: the query sits at least this far into the tile (then up to the rule's next multiple)."""
ON_OFFSET_PX: Final = 2.0
"""px: a pair follows the known offset when its tile point is this close to where it should be."""
PROBE_GROWTH: Final = (1, 2, 4)
"""The probe's sizes, in multiples of :data:`PROBE_SIDE`, tried in turn while the backend says a
setting stopped the pair early (``early_stop``); a larger one is never tried otherwise."""
PROBE_BLOCK_PX: Final = 6
"""The probe texture's squares (px): 6 px do not line up with the 8x8 cells some detectors
(XFeat) score, so every cell sees texture."""
_FIELD_CELLS: Final = 512  # the texture field: 512 x 512 blocks (3072 px at 6 px), then repeated


@cache
def _field() -> NDArray[np.uint8]:
    """The random block colours (seed 0) every probe image is cut from (read-only)."""
    field = np.random.default_rng(0).integers(0, 256, (_FIELD_CELLS, _FIELD_CELLS, 3), np.uint8)
    field.setflags(write=False)
    return field


def textured_probe(width: int, height: int, *, x0: int = 0) -> NDArray[np.uint8]:
    """A deterministic textured RGB image (height, width, 3) uint8: :data:`PROBE_BLOCK_PX` px
    squares of random colour (seed 0), the start-up probe's and the contract kit's stand-in.

    Every image is a window on one texture: ``x0`` moves the window right, so the pixel
    (x, y) of ``textured_probe(w, h, x0=s)`` is the pixel (x + s, y) of ``textured_probe(w + s,
    h)``."""
    block = PROBE_BLOCK_PX
    cx0, cx1 = x0 // block, -(-(x0 + width) // block)
    cy1 = -(-height // block)
    field = _field()
    reps = (-(-cy1 // _FIELD_CELLS), -(-cx1 // _FIELD_CELLS), 1)
    cells = np.tile(field, reps)[:cy1, cx0:cx1] if reps != (1, 1, 1) else field[:cy1, cx0:cx1]
    blocks = np.kron(cells, np.ones((block, block, 1), np.uint8))
    start = x0 - cx0 * block
    return np.ascontiguousarray(blocks[:height, start : start + width])


def probe_side(rule: InputRule | None, at_least: int = PROBE_SIDE) -> int:
    """The side (px) of a square image that follows ``rule``: the smallest multiple of its
    ``multiple`` that is at least ``at_least``, else (past ``max_long_side``) the largest that
    fits; ``at_least`` without a rule."""
    if rule is None:
        return at_least
    m = rule.multiple
    up = -(-at_least // m) * m
    return up if up <= rule.max_long_side else (rule.max_long_side // m) * m


def probe_shift(rule: InputRule | None, side: int) -> int:
    """How far (px) into the tile the ``side`` px query sits: the smallest multiple of the
    rule's ``multiple`` that is at least ``MIN_SHIFT``; 0 (the image itself) when that is more
    than half the side."""
    m = 1 if rule is None else rule.multiple
    shift = -(-MIN_SHIFT // m) * m
    return shift if 2 * shift <= side else 0


def probe_image(width: int, height: int, x0: int = 0) -> PreparedImage:
    """A :class:`PreparedImage` of the probe texture (``textured_probe``, its window moved
    ``x0`` px right), every pixel valid."""
    return PreparedImage(
        image=textured_probe(width, height, x0=x0),
        valid=np.ones((height, width), bool),
        working_from_engine=np.eye(3),
        working_size=(width, height),
    )


def probe_pair(
    rule: InputRule | None, at_least: int = PROBE_SIDE
) -> tuple[PreparedImage, PreparedImage, int]:
    """(query, tile, shift): the ``probe_side`` px square query is the texture from x =
    ``shift``; the tile, from x = 0, is ``shift`` px wider, so the query point (x, y) is the
    tile point (x + shift, y). Where that tile would pass the rule's ``max_long_side``, the tile
    is the square and the query ``shift`` px narrower."""
    side = probe_side(rule, at_least)
    shift = probe_shift(rule, side)
    query_width, tile_width = side, side + shift
    if rule is not None and tile_width > rule.max_long_side:
        query_width, tile_width = side - shift, side
    query = probe_image(query_width, side, shift)
    return query, probe_image(tile_width, side, 0), shift


def engine_startup_probe(backend: FeatureBackend) -> None:
    """Extract the probe pair (``probe_pair``), match it once and assert the outputs (the
    engine-output assertion that fires at start-up, not on the first frame): features inside
    their image (cut to the keypoint budget, as in flight), pairs in (query, tile) order that
    follow the known offset, each query keypoint once (``check_shifted_matches``).

    The images are :data:`PROBE_SIDE` px rounded by the backend's ``input_rule``, squares of
    random colour (:func:`textured_probe`). A pair a setting of the backend stops early
    (``early_stop``) is tried again larger (``PROBE_GROWTH``); ``ConfigurationError`` naming the
    setting when it stops the largest too: it would stop every pair of real images."""
    rule = backend.input_rule
    stopped: tuple[str, str] | None = None
    for side in dict.fromkeys(probe_side(rule, PROBE_SIDE * grow) for grow in PROBE_GROWTH):
        stopped = _probe_once(backend, rule, side)
        if stopped is None:
            return
    assert stopped is not None
    setting, why = stopped
    raise ConfigurationError(
        "start-up probe",
        [
            (
                setting,
                f"{why} on the start-up probe's largest pair too "
                f"({_images(*probe_pair(rule, side))}): "
                "an image matched with a view holding it, clearer than real pairs, so every "
                "pair would stop with no match; set it lower",
            )
        ],
    )


def _probe_once(
    backend: FeatureBackend, rule: InputRule | None, side: int
) -> tuple[str, str] | None:
    """One probe on the ``side`` px pair: None when it passes, ``(setting, why)`` when a
    setting of the backend stopped its match early (``early_stop``); ``EngineError``
    otherwise."""
    query_image, tile_image, shift = probe_pair(rule, side)
    try:
        query = _extracted(backend, query_image)
        tile = _extracted(backend, tile_image)
        matches = backend.match(query, tile)
        if isinstance(matches, RawMatches) and len(matches) == 0:
            stopped = _early_stop(backend)
            if stopped is not None:
                return stopped
        check_shifted_matches(query, tile, matches, shift)
    except BaseException as exc:  # a plugin's own sys.exit too: its failure, named
        if is_stop(exc):  # Ctrl-C, a signal handler's exit: they go on
            raise
        failed = (
            f"start-up probe failed ({_images(query_image, tile_image, shift)}): {describe(exc)}"
        )
        if _runs_engines(backend):
            raise EngineError(backend.label, failed) from exc
        raise EngineError(
            backend.label,
            f"{failed}; the backend runs no engine: test its extract and match with the "
            "contract kit (c3_matcher.testing.contract.BackendContract, docs/plugins.md)",
            command=None,
        ) from exc
    return None


def _images(query: PreparedImage, tile: PreparedImage, shift: int) -> str:
    """A probe pair (``probe_pair``), in words."""
    (w, h), (tw, _) = query.engine_size, tile.engine_size
    return f"a {w}x{h} px image in a {tw}x{h} px one, {shift} px in"


def _early_stop(backend: FeatureBackend) -> tuple[str, str] | None:
    """The backend's ``early_stop()`` (``EarlyStopping``): ``(setting, why)`` when a rule
    stopped its last match before matching, else None (a backend without it, or one that fails,
    says nothing)."""
    if not isinstance(backend, EarlyStopping):
        return None
    try:
        found = backend.early_stop()
    except Exception:
        return None
    if isinstance(found, tuple) and len(found) == 2 and all(isinstance(x, str) for x in found):
        return found[0], found[1]
    return None


def _extracted(backend: FeatureBackend, image: PreparedImage) -> Features:
    """``backend``'s features of the probe ``image`` as flight takes them
    (:func:`~c3_matcher.stages.extract.extract_checked`: on the image, cut to the backend's
    keypoint budget), and some: ``ValueError`` when it found no keypoint."""
    features = extract_checked(backend, image, name="probe image")
    if len(features) == 0:
        raise ValueError("the extractor found no keypoint on the textured probe image")
    return features


def check_shifted_matches(
    query: Features, tile: Features, matches: object, shift: int, min_on_offset: float = 0.5
) -> None:
    """``ValueError`` unless ``matches`` are the matches of ``query`` with ``tile``, whose
    texture holds the query's ``shift`` px to the right: :class:`RawMatches`, some, pairs of
    their keypoints as flight checks them (:func:`~c3_matcher.prepared.check_pairs`), and at
    least ``min_on_offset`` of them pairing a query point (x, y) with a tile point within
    ``ON_OFFSET_PX`` of (x + shift, y)."""
    if not isinstance(matches, RawMatches):
        raise TypeError(f"match returned {type(matches).__name__}, not RawMatches")
    if len(matches) == 0:
        raise ValueError(
            "matching the probe image with a view that holds it gave no match (an engine "
            "fault, or a setting that stops every pair early)"
        )
    check_pairs(matches, len(query), len(tile))
    q, t = matches.matches[:, 0], matches.matches[:, 1]
    expected = query.keypoints[q] + np.array([shift, 0], np.float32)
    on = float(np.mean(np.linalg.norm(tile.keypoints[t] - expected, axis=1) <= ON_OFFSET_PX))
    if on < min_on_offset:
        raise ValueError(
            f"only {on:.0%} of the {len(matches)} pairs join a query point (x, y) to the tile "
            f"point (x + {shift}, y) that shows it (at least {min_on_offset:.0%} expected): "
            "are the pairs (query index, tile index), each from the matching of those two "
            "images?"
        )


def _runs_engines(backend: FeatureBackend) -> bool:
    """Whether the backend names engines in its provenance (then ``engines build`` is the fix
    for a failing probe); a backend whose provenance cannot be read is taken to run them."""
    return bool(read_provenance(backend).get("engines", True))


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
    """The ``FeatureBackend`` members ``backend`` lacks (methods must be callable, the input
    rule an ``InputRule``)."""
    missing = [name for name in BACKEND_MEMBERS if not hasattr(backend, name)]
    wrong = [
        name
        for name in ("extract", "match", "provenance")
        if name not in missing and not callable(getattr(backend, name))
    ]
    rule = getattr(backend, "input_rule", None)
    if "input_rule" not in missing and not isinstance(rule, InputRule):
        wrong.append(f"input_rule as an InputRule (it is a {type(rule).__name__})")
    return missing + wrong


def check_members(backend: object) -> None:
    """``TypeError`` naming every member ``backend`` lacks, and where the contract is."""
    missing = missing_members(backend)
    if missing:
        raise TypeError(
            f"{type(backend).__name__} is not a FeatureBackend: it lacks "
            f"{', '.join(missing)} (a backend has {', '.join(BACKEND_MEMBERS)}; "
            "see 'The backend's contract' in docs/plugins.md)"
        )
