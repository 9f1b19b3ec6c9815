"""``OnnxLightGlueRuntime``: the shared LightGlue handle. No PyTorch.

One object, one engine per feature type (each feature type has its own weights). LightGlue
graph I/O: inputs ``kpts0`` float32 (1, M, 2), ``kpts1`` (1, N, 2) normalised keypoints (see
``normalize_keypoints``), ``desc0`` float32 (1, M, D), ``desc1`` (1, N, D); outputs
``matches0`` int64 (M,) index into image 1 of the mutual nearest neighbour or -1, and
``mscores0`` float32 (M,) its match confidence (0 where not mutual). The match filter threshold
is applied here, exactly as upstream ``filter_matches`` does: keep ``matches0 > -1 and mscores0 >
threshold``.

Two engine kinds per feature type, both loaded through ``load``: the single graph (``"full"``:
every layer on every point; adaptive depth/width does not survive a single-graph export) and the
steps graph (manifest option ``pruning = "steps"``, ``c3_matcher.engines.lightglue_adaptive``):
the transformer in steps with upstream's early exit and point pruning decided in numpy.
``mode="adaptive"`` (the CPU flight default, ``[lightglue] mode``, ``resolve_mode``) runs the
steps engine where one is loaded (loading a full engine also loads the steps engine beside it:
the engine in the same directory whose manifest declares the same ``feature_type`` and option
``pruning = "steps"``), otherwise the full one; ``mode="full"`` (the constructor's default) runs the
single graph where one is loaded (a steps engine alone then runs every layer on every point).
``depth_confidence`` / ``width_confidence`` ``None`` take the engine manifest's upstream
defaults; ``-1`` disables the rule. ``exit_matches`` (0: off) stops an adaptive pair with no
matches when, after its second layer, fewer than that many mutual matches are confident
(``AdaptiveLightGlue``). ``last_run`` tells what the last ``match_pair`` did (mode, layers run,
points kept per layer, the confident matches at that test, whether it stopped the pair).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final, NamedTuple

import numpy as np
from loguru import logger
from numpy.typing import NDArray

from c3_matcher.engines.lightglue_adaptive import AdaptiveLightGlue
from c3_matcher.engines.lightglue_specs import STEPS_OPTION, STEPS_SIZES, steps_size
from c3_matcher.engines.manifest import EngineIntegrityError
from c3_matcher.engines.providers import CPU_PROVIDER
from c3_matcher.engines.spec import EngineSpec
from c3_matcher.engines.store import intact_engine, steps_engines_beside, unreadable_engine
from c3_matcher.errors import EngineError
from c3_matcher.features import PairSide, RawMatches
from c3_matcher.protocols import InferenceRuntime, ManifestRuntime

__all__ = [
    "DEFAULT_FILTER_THRESHOLD",
    "LIGHTGLUE_MODES",
    "OnnxLightGlueRuntime",
    "normalize_keypoints",
    "resolve_mode",
    "steps_engines_beside",
]

DEFAULT_FILTER_THRESHOLD = 0.1
LIGHTGLUE_MODES = ("adaptive", "full")


def resolve_mode(mode: str, provider: str) -> str:
    """``[lightglue] mode`` for the session's execution ``provider``: ``"auto"`` is adaptive on
    the CPU provider (early exit and pruning save 2-4x there) and full on any other (on an H100
    with CUDA, one graph took 12.5 ms per pair against 22 ms for the steps, whose per-layer
    launches and host round trips cost more than the layers they skip: docs/decisions.md, GPU
    defaults); ``"adaptive"`` and ``"full"`` are kept as given."""
    if mode == "auto":
        return "adaptive" if provider == CPU_PROVIDER else "full"
    if mode not in LIGHTGLUE_MODES:
        raise ValueError(f"mode must be one of auto, {', '.join(LIGHTGLUE_MODES)}; got {mode!r}")
    return mode


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


class _Pair(NamedTuple):
    """One pair's normalised keypoints and descriptors, in the steps driver's argument order."""

    kpts0: NDArray[np.float32]
    kpts1: NDArray[np.float32]
    desc0: NDArray[np.float32]
    desc1: NDArray[np.float32]


class OnnxLightGlueRuntime:
    """LightGlue on ONNX Runtime through a shared ``InferenceRuntime``; satisfies
    ``c3_matcher.protocols.LoadableLightGlueRuntime``. ``filter_threshold`` is the match
    confidence a match must exceed (upstream default 0.1). ``steps_specs`` are the steps
    engines the plugins declare, by feature type (``steps_specs`` of the plugin host's engine
    specs): only a build of a declared graph is run, and a missing one is warned about in
    adaptive mode, naming the build command. ``None`` (not known): any steps engine found beside
    a full one is used, and none found is no warning. ``mode="auto"`` is ``resolve_mode`` of the
    provider the sessions ACTUALLY run on: the requested one until a LightGlue engine is loaded,
    then its session's (onnxruntime falls back to the CPU when a GPU provider cannot start:
    adaptive then, the steps engine loaded beside the full graph already loaded)."""

    def __init__(
        self,
        inference: InferenceRuntime,
        *,
        filter_threshold: float = DEFAULT_FILTER_THRESHOLD,
        mode: str = "full",
        depth_confidence: float | None = None,
        width_confidence: float | None = None,
        exit_matches: int = 0,
        steps_specs: Mapping[str, EngineSpec] | None = None,
    ) -> None:
        if not 0.0 <= filter_threshold < 1.0:
            raise ValueError(f"filter_threshold must be in [0, 1), got {filter_threshold}")
        self._inference = inference
        self._auto = mode == "auto"
        self._mode = resolve_mode(mode, inference.provider if self._auto else "")
        self.filter_threshold: Final = float(filter_threshold)
        self._depth = depth_confidence
        self._width = width_confidence
        self.exit_matches: Final = int(exit_matches)
        """The unmatchable-pair exit's count (0: off)."""
        self._declared = None if steps_specs is None else dict(steps_specs)
        self._engines: dict[str, tuple[Path, str]] = {}
        self._steps: dict[str, tuple[Path, str, AdaptiveLightGlue, AdaptiveLightGlue]] = {}
        self._served_by_steps: dict[str, Path] = {}
        """The full engine a steps engine was loaded in place of, per feature type."""
        self.last_run: dict[str, Any] = {}

    @property
    def mode(self) -> str:
        """The mode that runs: ``"adaptive"`` or ``"full"`` (``"auto"`` resolved)."""
        return self._mode

    @property
    def feature_types(self) -> tuple[str, ...]:
        """Feature types with a loaded engine."""
        return tuple(sorted(set(self._engines) | set(self._steps)))

    def load(self, feature_type: str, engine_path: Path) -> Path:
        """Load the LightGlue engine for ``feature_type`` (at strategy creation); the file that
        will match ``feature_type`` (:meth:`serving_engine`: in adaptive mode the steps engine
        loaded in place of a full one).

        Idempotent for the same path; ``EngineError`` if another engine is already loaded for
        this feature type, or if the engine's manifest declares another feature type.
        """
        self._load(feature_type, engine_path)
        served = self.serving_engine(feature_type)
        assert served is not None  # loaded now, or raised
        return served

    def serving_engine(self, feature_type: str) -> Path | None:
        """The engine file :meth:`match_pair` runs for ``feature_type`` (None: none loaded): the
        steps engine in adaptive mode or when it is the only one, else the full graph."""
        if feature_type in self._steps and (
            self.mode == "adaptive" or feature_type not in self._engines
        ):
            return self._steps[feature_type][0]
        loaded = self._engines.get(feature_type)
        return None if loaded is None else loaded[0]

    def _load(self, feature_type: str, engine_path: Path) -> None:
        path = Path(engine_path).expanduser().absolute()  # a link: its manifest is beside it
        for table in (self._engines, self._steps):
            if feature_type in table and table[feature_type][0] == path:
                return
        if self._served_by_steps.get(feature_type) == path:
            return  # its steps engine is loaded in its place (memory): not loaded now either
        self._settle_auto()  # sessions loaded already (an extractor) tell the provider
        if (
            self.mode == "adaptive"
            and feature_type not in self._steps
            and self._may_have_steps(feature_type)
            and self._load_sibling_steps(feature_type, path)
        ):
            # the steps engine serves both modes: the full graph is not loaded (memory), but it
            # is verified now, so a changed file is refused at start-up, not on a later switch
            intact_engine(path)
            self._served_by_steps[feature_type] = path
            return
        engine_id = self._inference.load_engine(path)
        options: dict[str, Any] = {}
        if isinstance(self._inference, ManifestRuntime):
            manifest = self._inference.manifest(engine_id)
            declared = manifest.feature_type
            if declared is not None and declared != feature_type:
                raise EngineError(
                    path, f"engine matches {declared!r} features, not {feature_type!r}"
                )
            options = dict(manifest.options)
        steps = options.get(STEPS_OPTION[0]) == STEPS_OPTION[1]
        table_name = "steps" if steps else "full"
        loaded = (self._steps if steps else self._engines).get(feature_type)
        if loaded is not None:
            raise EngineError(
                path,
                f"{table_name} LightGlue for {feature_type!r} is already loaded from {loaded[0]}",
            )
        if steps:
            self._steps[feature_type] = (path, engine_id, *self._drivers(path, engine_id, options))
        else:
            self._engines[feature_type] = (path, engine_id)
            if not (self._settle_auto() and self._load_sibling_steps(feature_type, path)):
                self._verify_steps_beside(feature_type, path)
        logger.bind(
            kind="c3.lightglue.engine_loaded",
            feature_type=feature_type,
            engine_id=engine_id,
            engine_kind=table_name,
        ).info("LightGlue ({}) for {} loaded", table_name, feature_type)

    def _settle_auto(self) -> bool:
        """``mode="auto"`` resolved as full from the requested provider, whose sessions run on
        the CPU (onnxruntime fell back): adaptive from now on, said as a WARNING. True when it
        switched."""
        provider = self._inference.provider
        if not self._auto or self._mode == "adaptive" or resolve_mode("auto", provider) == "full":
            return False
        self._mode = "adaptive"
        logger.bind(kind="c3.lightglue.mode_fallback", provider=provider).warning(
            "LightGlue mode auto: the sessions run on {} (onnxruntime fell back), so adaptive, "
            "as on a CPU",
            provider,
        )
        return True

    def _may_have_steps(self, feature_type: str) -> bool:
        return self._declared is None or feature_type in self._declared

    def _graph(self, feature_type: str) -> EngineSpec | None:
        """The steps graph declared for ``feature_type`` (None: any build of one)."""
        return None if self._declared is None else self._declared.get(feature_type)

    def _load_sibling_steps(self, feature_type: str, full_path: Path) -> bool:
        """Adaptive mode: load the steps engine for ``feature_type`` beside a full one (same
        directory, ``steps_engines_beside``) INSTEAD of it, so a strategy that names its full
        engine runs adaptive; False when none is there or usable (the full engine then runs,
        with a warning naming the build command when the plugin declares one). A steps engine
        changed after its build, or whose file or manifest cannot be read, stops start-up
        (``EngineIntegrityError``, from ``steps_engines_beside`` or the load)."""
        siblings = steps_engines_beside(full_path, feature_type, self._graph(feature_type))
        if full_path in siblings:
            return False  # the path given is the steps engine itself
        for candidate in siblings:
            try:
                self._load(feature_type, candidate)
            except EngineIntegrityError:
                raise  # changed after its build: refused, never replaced by the full graph
            except OSError as exc:  # its file cannot be read: as if changed
                raise unreadable_engine(candidate, exc) from exc
            except (EngineError, ValueError, KeyError) as exc:
                logger.warning("steps engine {} not usable: {}", candidate.name, exc)
                continue
            return True
        spec = None if self._declared is None else self._declared.get(feature_type)
        if spec is not None:
            logger.bind(kind="c3.lightglue.no_steps_engine", feature_type=feature_type).warning(
                "LightGlue for {}: no steps engine beside {}, running every layer on every "
                "point (build it: c3-matcher engines build --only {}/{})",
                feature_type,
                full_path.name,
                spec.model,
                spec.variant,
            )
        return False

    def _verify_steps_beside(self, feature_type: str, full_path: Path) -> None:
        """Full mode loads no steps engine; one beside the full graph (which adaptive mode
        would run) is still hashed against its manifest now: a changed file is refused at
        start-up (``EngineIntegrityError``) wherever it lies in the strategy's engines."""
        if not self._may_have_steps(feature_type):
            return
        for candidate in steps_engines_beside(full_path, feature_type, self._graph(feature_type)):
            try:
                intact_engine(candidate)
            except EngineIntegrityError:
                raise
            except EngineError:
                continue  # an unusable build, not a changed one: full mode does not run it

    def _drivers(
        self, path: Path, engine_id: str, options: dict[str, Any]
    ) -> tuple[AdaptiveLightGlue, AdaptiveLightGlue]:
        """(adaptive, every-layer) drivers of one steps engine; ``EngineError`` naming the
        option when its manifest lacks a size the drivers need."""

        def run(feeds: Any) -> Any:
            return self._inference.run(engine_id, feeds)

        depth = self._depth if self._depth is not None else options.get("depth_confidence", -1)
        width = self._width if self._width is not None else options.get("width_confidence", -1)
        common = {name: steps_size(path, options, name) for name in STEPS_SIZES}
        adaptive = AdaptiveLightGlue(
            run,
            depth_confidence=float(depth),
            width_confidence=float(width),
            exit_matches=self.exit_matches,
            **common,
        )
        every_layer = AdaptiveLightGlue(run, depth_confidence=-1, width_confidence=-1, **common)
        return adaptive, every_layer

    def _run_steps(
        self, feature_type: str, pair: _Pair
    ) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """(matches0, mscores0) of the steps engine: adaptive, or every layer in full mode."""
        _, _, adaptive, every_layer = self._steps[feature_type]
        driver = adaptive if self.mode == "adaptive" else every_layer
        result = driver.match(*pair)
        self.last_run = {
            "mode": "adaptive" if driver is adaptive else "steps-full",
            "layers": result.layers,
            "kept0": result.kept0,
            "kept1": result.kept1,
            "matched": result.matched,
            "unmatchable": result.unmatchable,
        }
        return result.matches0, result.mscores0

    def _run_full(
        self, feature_type: str, pair: _Pair
    ) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """(matches0, mscores0) of the single graph: every layer on every point."""
        _, engine_id = self._engines[feature_type]
        feeds = dict(zip(("kpts0", "kpts1", "desc0", "desc1"), pair, strict=True))
        out = self._inference.run(
            engine_id, {name: np.ascontiguousarray(x)[None] for name, x in feeds.items()}
        )
        m, n = len(pair.kpts0), len(pair.kpts1)
        self.last_run = {"mode": "full", "layers": None, "kept0": [m], "kept1": [n]}
        return (
            np.asarray(out["matches0"]).reshape(-1).astype(np.int64, copy=False),
            np.asarray(out["mscores0"]).reshape(-1).astype(np.float32, copy=False),
        )

    def match_pair(self, side0: PairSide, side1: PairSide, *, feature_type: str) -> RawMatches:
        """Match two images' keypoint sets; keypoints (x, y) px of images of ``size`` (width,
        height).

        Returns ``RawMatches``: ``matches`` int64 (M, 2) (index into set 0, index into set 1) in
        ascending order of the set-0 index, ``scores`` float32 (M,). ``KeyError`` if no engine is
        loaded for ``feature_type``.
        """
        if feature_type not in self._engines and feature_type not in self._steps:
            raise KeyError(
                f"no LightGlue engine loaded for feature type {feature_type!r} "
                f"(loaded: {list(self.feature_types)}); call load(feature_type, path) first"
            )
        kpts0, desc0, size0 = side0
        kpts1, desc1, size1 = side1
        _check_pair(kpts0, desc0, size0, 0)
        _check_pair(kpts1, desc1, size1, 1)
        if len(kpts0) == 0 or len(kpts1) == 0:
            return RawMatches(np.zeros((0, 2), np.int64), np.zeros((0,), np.float32))
        n0, n1 = normalize_keypoints(kpts0, size0), normalize_keypoints(kpts1, size1)
        steps = self._steps.get(feature_type)
        if steps is not None and self.serving_engine(feature_type) == steps[0]:
            matches0, mscores0 = self._run_steps(feature_type, _Pair(n0, n1, desc0, desc1))
        else:
            matches0, mscores0 = self._run_full(feature_type, _Pair(n0, n1, desc0, desc1))
        valid = (matches0 > -1) & (mscores0 > np.float32(self.filter_threshold))
        index0 = np.flatnonzero(valid).astype(np.int64)
        matches = np.stack([index0, matches0[valid]], axis=-1).astype(np.int64, copy=False)
        return RawMatches(
            np.ascontiguousarray(matches.reshape(-1, 2)), np.ascontiguousarray(mscores0[valid])
        )
