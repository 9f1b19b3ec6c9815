"""The DISK+LightGlue plugin's build time: exporters and PyTorch references (imports torch and
kornia inside its functions, at ``c3-matcher engines build`` and in the reference backend only).
The graphs it writes are described in ``c3_matcher_disk_lightglue.engines``.

``DiskLightGlueReference`` is the bench's PyTorch reference (hook
``c3_matcher_reference_backend``): kornia's DISK on every image and kornia's LightGlue with its
upstream adaptive depth and width ON (depth_confidence 0.95, width_confidence 0.99), the same
weights as the engines."""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.config import C3Settings
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.strategy import DEFAULT_MAX_KEYPOINTS
from c3_matcher_disk_lightglue.engines import (
    DISK_DESCRIPTOR_DIM,
    DISK_SIZE_MULTIPLE,
    DISK_SPEC,
    DISK_TOLERANCES,
    DISK_TOP_K,
    DISK_VERIFICATION_SIZES,
    LIGHTGLUE_DISK_SPEC,
)
from c3_matcher_tools.engines.export import ExportReport, ExportRequest
from c3_matcher_tools.engines.export.extractor import (
    KeypointSet,
    export_and_verify_extractor,
    extractor_exporter,
)
from c3_matcher_tools.engines.export.lightglue_steps import lightglue_exporters
from c3_matcher_tools.engines.export.reference import PyTorchReference, load_upstream_lightglue

__all__ = [
    "DiskLightGlueReference",
    "build_disk_export_module",
    "disk_features_fn",
    "disk_reference_features",
    "export_disk",
    "export_lightglue_disk",
    "export_lightglue_disk_steps",
    "load_disk_reference",
]


def load_disk_reference(weights_path: Any) -> Any:
    """kornia ``DISK`` with the ``extractor`` state dict of ``weights_path`` (eval mode)."""
    import torch
    from kornia.feature import DISK

    state = torch.load(str(weights_path), map_location="cpu", weights_only=True)
    model = DISK(desc_dim=DISK_DESCRIPTOR_DIM)
    model.load_state_dict(state.get("extractor", state))
    return model.eval()


def build_disk_export_module(reference: Any, top_k: int = DISK_TOP_K) -> Any:
    """The export rewrite of a kornia ``DISK``; shares no state with ``reference`` (its U-Net is
    deep-copied before the instance norms are swapped).

    Sparse descriptor head: DISK's last convolution (5x5, ``C -> 128 + 1`` channels at full
    resolution) is most of its cost, yet only the top-K keypoints' descriptors are read. The
    rewrite runs that convolution densely for the heat-map channel only, picks the keypoints
    (strict 5x5 maxima, top-K), then computes the 128 descriptor channels at those K pixels
    alone: each keypoint's 5x5 x C input patch (zero padding, as the convolution's "same"
    padding) times the descriptor rows of the same weights. The same sums as the dense
    convolution, so keypoints and scores are those of upstream and descriptors agree to float
    rounding (checked at build time against kornia)."""
    import copy

    from c3_matcher_disk_lightglue.export_rewrite import DiskForExport, swap_norms

    unet = copy.deepcopy(reference.unet)
    swap_norms(unet)
    return DiskForExport(unet, top_k, reference.desc_dim).eval()


@extractor_exporter
def export_disk(request: ExportRequest, top_k: int) -> ExportReport:
    """Export DISK and verify it against kornia's DISK (same weights) on real imagery at every
    ``DISK_VERIFICATION_SIZES``: identical keypoint sets, scores and descriptors within
    ``DISK_TOLERANCES``."""
    import torch

    reference = load_disk_reference(request.weights_path)

    def reference_set(feeds: Mapping[str, Any], _case: Any) -> KeypointSet:
        ref = reference(torch.from_numpy(feeds["image"]), n=top_k)[0]
        return (ref.keypoints.numpy(), ref.detection_scores.numpy(), ref.descriptors.numpy())

    return export_and_verify_extractor(
        request,
        build_disk_export_module(reference, top_k),
        label=f"DISK (top-K {top_k})",
        max_blocks=1024,
        reference=reference_set,
        reference_name=f"kornia {importlib.metadata.version('kornia')} DISK (same state dict)",
        tolerances=DISK_TOLERANCES,
        sizes=DISK_VERIFICATION_SIZES,
        relative_scores=True,
    )


def disk_reference_features(
    reference: Any, rgb: NDArray[np.uint8], max_keypoints: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Keypoints (K, 2) px and descriptors (K, 128) of kornia's DISK (``n=max_keypoints``)."""
    import torch

    from c3_matcher.engines.extract import image_to_feeds

    feeds = image_to_feeds(rgb, np.ones(rgb.shape[:2], dtype=bool))
    with torch.no_grad():
        feats = reference(torch.from_numpy(feeds["image"]), n=max_keypoints)[0]
    return (
        np.ascontiguousarray(feats.keypoints.numpy(), dtype=np.float32),
        np.ascontiguousarray(feats.descriptors.numpy(), dtype=np.float32),
    )


def disk_features_fn() -> Callable[
    [NDArray[np.uint8], int], tuple[NDArray[np.float32], NDArray[np.float32]]
]:
    """The LightGlue exporters' ``features_fn``: kornia DISK (the engines' weights)."""
    disk = load_disk_reference(DISK_SPEC.weights.resolve())
    return lambda rgb, n: disk_reference_features(disk, rgb, n)


export_lightglue_disk, export_lightglue_disk_steps = lightglue_exporters("disk", disk_features_fn)
"""The exporters of ``lightglue/disk`` and ``lightglue/disk-steps`` (the kit's, verified on real
kornia-DISK features)."""


class DiskLightGlueReference(PyTorchReference):
    """FeatureBackend over kornia's DISK and LightGlue (PyTorch, CPU)."""

    label = "disk_lightglue[pytorch]"
    extract_phase = "disk_forward"

    def __init__(self, settings: C3Settings) -> None:
        super().__init__(
            settings,
            DISK_SIZE_MULTIPLE,
            load_upstream_lightglue(LIGHTGLUE_DISK_SPEC.weights.resolve(), input_dim=128),
        )
        self._max_keypoints = settings.matcher.max_keypoints or DEFAULT_MAX_KEYPOINTS
        self._disk = load_disk_reference(DISK_SPEC.weights.resolve())

    def extract(self, image: PreparedImage) -> Features:
        from c3_matcher.engines.extract import image_to_feeds

        feeds = image_to_feeds(image.image, image.valid)
        with self._torch.no_grad():
            out = self._disk(self._torch.from_numpy(feeds["image"]), n=self._max_keypoints)[0]
        return Features(
            np.ascontiguousarray(out.keypoints.numpy(), np.float32),
            np.ascontiguousarray(out.descriptors.numpy(), np.float32),
            np.ascontiguousarray(out.detection_scores.numpy(), np.float32),
            image.engine_size,
        )
