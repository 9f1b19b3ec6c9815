"""``OnnxLightGlueRuntime``: the shared LightGlue handle (AZ-278, DECISIONS 9). No PyTorch.

One object, one engine per feature type (DISK and ALIKED weights differ). LightGlue graph I/O:
inputs ``kpts0`` float32 (1, M, 2), ``kpts1`` (1, N, 2) normalised keypoints (see
``normalize_keypoints``), ``desc0`` float32 (1, M, D), ``desc1`` (1, N, D); outputs
``matches0`` int64 (M,) index into image 1 of the mutual nearest neighbour or -1, and
``mscores0`` float32 (M,) its match confidence (0 where not mutual). Adaptive depth/width pruning
is off (it does not survive a single-graph export); the match filter threshold is applied here,
exactly as upstream ``filter_matches`` does: keep ``matches0 > -1 and mscores0 > threshold``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from loguru import logger
from numpy.typing import NDArray

from c3_matcher.errors import EngineError
from c3_matcher.features import RawMatches
from c3_matcher.protocols import InferenceRuntime

__all__ = ["DEFAULT_FILTER_THRESHOLD", "OnnxLightGlueRuntime", "normalize_keypoints"]

DEFAULT_FILTER_THRESHOLD = 0.1


def normalize_keypoints(kpts: NDArray[np.float32], size: tuple[int, int]) -> NDArray[np.float32]:
    """LightGlue's normalisation: ``(k - size / 2) / (max(size) / 2)`` in float32.

    ``kpts`` (K, 2) (x, y) px; ``size`` (width, height) px. The long side maps to [-1, 1], the
    short side keeps the aspect ratio (the PyTorch model's ``normalize_keypoints``, bit for bit).
    """
    wh = np.asarray(size, dtype=np.float32)
    shift = wh / np.float32(2.0)
    scale = wh.max() / np.float32(2.0)
    return ((kpts.astype(np.float32, copy=False) - shift) / scale).astype(np.float32, copy=False)


def _check_pair(
    kpts: NDArray[np.float32], desc: NDArray[np.float32], size: tuple[int, int], side: int
) -> None:
    if not (
        isinstance(kpts, np.ndarray)
        and kpts.dtype == np.float32
        and kpts.ndim == 2
        and kpts.shape[1] == 2
    ):
        raise ValueError(f"kpts{side} must be float32 (K, 2), got {getattr(kpts, 'shape', kpts)}")
    if not (
        isinstance(desc, np.ndarray)
        and desc.dtype == np.float32
        and desc.ndim == 2
        and desc.shape[0] == kpts.shape[0]
    ):
        raise ValueError(
            f"desc{side} must be float32 ({kpts.shape[0]}, D), got {getattr(desc, 'shape', desc)}"
        )
    width, height = size
    if width <= 0 or height <= 0:
        raise ValueError(f"size{side} must be (width, height) > 0, got {size}")


class OnnxLightGlueRuntime:
    """LightGlue on ONNX Runtime through a shared ``InferenceRuntime``; satisfies
    ``c3_matcher.protocols.LightGlueRuntime``. ``filter_threshold`` is the match confidence a
    match must exceed (upstream default 0.1)."""

    def __init__(
        self, inference: InferenceRuntime, *, filter_threshold: float = DEFAULT_FILTER_THRESHOLD
    ) -> None:
        if not 0.0 <= filter_threshold < 1.0:
            raise ValueError(f"filter_threshold must be in [0, 1), got {filter_threshold}")
        self._inference = inference
        self._threshold = float(filter_threshold)
        self._engines: dict[str, tuple[Path, str]] = {}

    @property
    def filter_threshold(self) -> float:
        return self._threshold

    @property
    def feature_types(self) -> tuple[str, ...]:
        """Feature types with a loaded engine."""
        return tuple(sorted(self._engines))

    def load(self, feature_type: str, engine_path: Path) -> None:
        """Load the LightGlue engine for ``feature_type`` (at strategy creation).

        Idempotent for the same path; ``EngineError`` if another engine is already loaded for
        this feature type, or if the engine's manifest declares another feature type.
        """
        path = Path(engine_path).expanduser().resolve()
        if feature_type in self._engines:
            loaded_path, _ = self._engines[feature_type]
            if loaded_path == path:
                return
            raise EngineError(
                path, f"LightGlue for {feature_type!r} is already loaded from {loaded_path}"
            )
        engine_id = self._inference.load_engine(path)
        manifest_of = getattr(self._inference, "manifest", None)
        if callable(manifest_of):
            declared = getattr(manifest_of(engine_id), "feature_type", None)
            if declared is not None and declared != feature_type:
                raise EngineError(
                    path, f"engine matches {declared!r} features, not {feature_type!r}"
                )
        self._engines[feature_type] = (path, engine_id)
        logger.bind(
            kind="c3.lightglue.engine_loaded", feature_type=feature_type, engine_id=engine_id
        ).info("LightGlue for {} loaded", feature_type)

    def match_pair(
        self,
        kpts0: NDArray[np.float32],
        desc0: NDArray[np.float32],
        size0: tuple[int, int],
        kpts1: NDArray[np.float32],
        desc1: NDArray[np.float32],
        size1: tuple[int, int],
        *,
        feature_type: str,
    ) -> RawMatches:
        """Match two keypoint sets; keypoints (x, y) px of images of ``size`` (width, height).

        Returns ``RawMatches``: ``matches`` int64 (M, 2) (index into set 0, index into set 1) in
        ascending order of the set-0 index, ``scores`` float32 (M,). ``KeyError`` if no engine is
        loaded for ``feature_type``.
        """
        if feature_type not in self._engines:
            raise KeyError(
                f"no LightGlue engine loaded for feature type {feature_type!r} "
                f"(loaded: {list(self.feature_types)}); call load(feature_type, path) first"
            )
        _check_pair(kpts0, desc0, size0, 0)
        _check_pair(kpts1, desc1, size1, 1)
        if len(kpts0) == 0 or len(kpts1) == 0:
            return RawMatches(np.zeros((0, 2), np.int64), np.zeros((0,), np.float32))
        _, engine_id = self._engines[feature_type]
        out = self._inference.run(
            engine_id,
            {
                "kpts0": normalize_keypoints(kpts0, size0)[None],
                "kpts1": normalize_keypoints(kpts1, size1)[None],
                "desc0": np.ascontiguousarray(desc0)[None],
                "desc1": np.ascontiguousarray(desc1)[None],
            },
        )
        matches0 = np.asarray(out["matches0"]).reshape(-1).astype(np.int64, copy=False)
        mscores0 = np.asarray(out["mscores0"]).reshape(-1).astype(np.float32, copy=False)
        valid = (matches0 > -1) & (mscores0 > np.float32(self._threshold))
        index0 = np.flatnonzero(valid).astype(np.int64)
        matches = np.stack([index0, matches0[valid]], axis=-1).astype(np.int64, copy=False)
        return RawMatches(
            np.ascontiguousarray(matches.reshape(-1, 2)), np.ascontiguousarray(mscores0[valid])
        )
