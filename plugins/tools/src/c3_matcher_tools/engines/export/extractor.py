"""Export and verification every keypoint-extractor exporter shares (build time: imports torch).
Extractors declare the same I/O (``extractor_spec``): inputs ``image`` (1, 3, H, W) and ``mask``
(1, 1, H, W), H and W multiples of the spec's ``size_multiple``; outputs ``keypoints``,
``keypoint_scores``, ``descriptors`` (top-K rows, score 0 on padding rows).

``export_and_verify_extractor`` is the whole exporter loop a plugin calls with its export module
and its PyTorch reference: export, then on every verification case (by default each real image
at each size, full mask) run the graph, drop the padding rows, compare with the reference, and
report. ``extractor_exporter`` makes the exporter a spec names from the plugin's function: what
every extractor's export starts with (grad mode off, the spec's ``top_k``) is written there."""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import onnxruntime as ort
import torch
from numpy.typing import NDArray
from torch import nn
from torch.nn import functional as nnf

from c3_matcher_tools.engines.export import (
    ExportReport,
    ExportRequest,
    VerificationImage,
    tolerance_failures,
)
from c3_matcher_tools.engines.export.onnx_export import export_requested, verification_session

__all__ = [
    "ExtractorCase",
    "KeypointSet",
    "TwoStageInstanceNorm",
    "compare_keypoint_sets",
    "export_and_verify_extractor",
    "export_extractor",
    "extractor_exporter",
    "strict_maxima_candidates",
    "verification_inputs",
]


class TwoStageInstanceNorm(nn.Module):
    """InstanceNorm2d (no affine) with the mean and variance reduced over W, then H (one
    reduction over the flattened H*W axis loses float32 precision in ONNX Runtime)."""

    def __init__(self, eps: float) -> None:
        super().__init__()
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean = x.mean(dim=3, keepdim=True).mean(dim=2, keepdim=True)
        centred = x - mean
        var = (centred * centred).mean(dim=3, keepdim=True).mean(dim=2, keepdim=True)
        return centred / torch.sqrt(var + self.eps)


def strict_maxima_candidates(heat: torch.Tensor) -> torch.Tensor:
    """``heat`` (1, H, W) where it is a strict 5x5 local maximum scoring > 0 and at least 2 px
    from the border, else 0: 24 shifted comparisons (no symbolic-size arithmetic)."""
    centre = heat[:, 2:-2, 2:-2]
    shifts = [slice(0, -4), slice(1, -3), slice(2, -2), slice(3, -1), slice(4, None)]
    strict: torch.Tensor | None = None
    for i, rows in enumerate(shifts):
        for j, cols in enumerate(shifts):
            if i == 2 and j == 2:
                continue
            greater = centre > heat[:, rows, cols]
            strict = greater if strict is None else strict & greater
    assert strict is not None
    is_max = nnf.pad(strict.to(heat.dtype), (2, 2, 2, 2)) > 0.5  # border never a maximum
    return torch.where(is_max & (heat > 0), heat, torch.zeros_like(heat))


def verification_inputs(
    rgb: NDArray[np.uint8], sizes: Sequence[tuple[int, int]]
) -> list[tuple[str, NDArray[np.uint8]]]:
    """Real inputs at every (width, height) of ``sizes``: centre crops where the image is large
    enough, otherwise a bilinear resize."""
    import cv2

    inputs: list[tuple[str, NDArray[np.uint8]]] = []
    height, width = rgb.shape[:2]
    for w, h in sizes:
        if w <= width and h <= height:
            top, left = (height - h) // 2, (width - w) // 2
            crop = rgb[top : top + h, left : left + w]
            inputs.append((f"crop {w}x{h}", np.ascontiguousarray(crop)))
        else:
            resized = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR)
            inputs.append((f"resize {w}x{h}", np.ascontiguousarray(resized)))
    return inputs


def export_extractor(
    request: ExportRequest, module: nn.Module, *, multiple: int, max_blocks: int, label: str
) -> ort.InferenceSession:
    """Export ``module`` with the extractor I/O (H and W ``multiple`` x 2..``max_blocks``) to
    ``request.output_path`` and open it on the CPU for verification."""
    rows = torch.export.Dim(f"height{multiple}", min=2, max=max_blocks)
    cols = torch.export.Dim(f"width{multiple}", min=2, max=max_blocks)
    request.log(f"exporting {label} (opset {request.spec.opset})")
    export_requested(
        request,
        module,
        (torch.rand(1, 3, 256, 320), torch.ones(1, 1, 256, 320)),
        dynamic_shapes={
            "image": {2: multiple * rows, 3: multiple * cols},
            "mask": {2: multiple * rows, 3: multiple * cols},
        },
    )
    return verification_session(request.output_path)


def compare_keypoint_sets(
    name: str,
    got: tuple[NDArray[Any], NDArray[Any], NDArray[Any]],
    reference: tuple[NDArray[Any], NDArray[Any], NDArray[Any]],
    tolerances: Mapping[str, float],
    failures: list[str],
    *,
    relative_scores: bool = False,
) -> dict[str, Any]:
    """Figures comparing (keypoints (N, 2), scores (N,), descriptors (N, D)) with a reference
    whose keypoints sit on whole pixels: the (x, y) sets must be identical, then scores and
    descriptors (paired in raster order) within ``tolerances``; appends to ``failures``."""
    kp, sc, de = got
    rk, rs, rd = reference
    mine = {(float(x), float(y)) for x, y in kp}
    theirs = {(float(x), float(y)) for x, y in rk}
    mismatch = len(mine ^ theirs)
    check: dict[str, Any] = {
        "input": name,
        "keypoints": len(kp),
        "reference_keypoints": len(rk),
        "keypoints_mismatch": mismatch,
    }
    if mismatch == 0 and len(kp) == len(rk):
        order = np.lexsort((kp[:, 0], kp[:, 1]))
        ref_order = np.lexsort((rk[:, 0], rk[:, 1]))
        score_err = np.abs(sc[order] - rs[ref_order])
        check["scores_max_abs"] = float(score_err.max(initial=0.0))
        if relative_scores:
            check["scores_max_rel"] = float((score_err / np.abs(rs[ref_order])).max(initial=0.0))
        check["descriptors_max_abs"] = float(np.abs(de[order] - rd[ref_order]).max(initial=0.0))
        keys = ("scores_max_abs", "descriptors_max_abs")
        failures.extend(tolerance_failures(name, check, tolerances, keys))
    else:
        failures.append(f"{name}: {mismatch} keypoints differ ({len(kp)} vs reference {len(rk)})")
    return check


KeypointSet = tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]
"""(keypoints (N, 2) (x, y) px, scores (N,), descriptors (N, D))."""


@dataclass(frozen=True, slots=True)
class ExtractorCase:
    """One verification input: ``rgb`` uint8 (H, W, 3) and its valid ``mask`` bool (H, W)
    (``None``: every pixel valid); ``label`` names it in the report."""

    label: str
    rgb: NDArray[np.uint8]
    mask: NDArray[np.bool_] | None = None

    @property
    def valid(self) -> NDArray[np.bool_]:
        return np.ones(self.rgb.shape[:2], dtype=bool) if self.mask is None else self.mask


ReferenceFn = Callable[[Mapping[str, NDArray[Any]], ExtractorCase], KeypointSet]
"""``(feeds, case) -> KeypointSet`` of the PyTorch reference on one case; ``feeds`` are the
graph's (``image`` float32 (1, 3, H, W), ``mask`` (1, 1, H, W), ``image_to_feeds``)."""

CompareFn = Callable[[str, KeypointSet, KeypointSet, list[str]], dict[str, Any]]
"""``(input name, graph's set, reference's set, failures) -> check figures``; appends to
``failures`` what is out of tolerance."""

ImageCheckFn = Callable[[ort.InferenceSession, VerificationImage, list[str]], dict[str, Any]]
"""One further check per verification image on the exported session (e.g. a masked half)."""


ExtractorExport = Callable[[ExportRequest, int], ExportReport]
"""``(request, top_k) -> report``: one extractor's export and verification (typically a call of
``export_and_verify_extractor``), ``top_k`` the keypoints its graph keeps."""


def extractor_exporter(export: ExtractorExport) -> Callable[[ExportRequest], ExportReport]:
    """The exporter an extractor's spec names, ``exporter(request)``: ``export`` given the spec's
    ``top_k`` option, run with PyTorch's grad mode off (nothing is trained) and the caller's mode
    restored after, so that a build inside a test, a notebook or any longer process leaves
    gradients as it found them."""

    @functools.wraps(export)
    def exporter(request: ExportRequest) -> ExportReport:
        with torch.no_grad():
            return export(request, int(request.spec.option("top_k")))

    return exporter


def export_and_verify_extractor(
    request: ExportRequest,
    module: nn.Module,
    *,
    label: str,
    max_blocks: int,
    reference: ReferenceFn,
    reference_name: str,
    tolerances: Mapping[str, float],
    sizes: Sequence[tuple[int, int]],
    compare: CompareFn | None = None,
    relative_scores: bool = False,
    cases: Callable[[VerificationImage], list[ExtractorCase]] | None = None,
    image_check: ImageCheckFn | None = None,
    notes: Mapping[str, Any] | None = None,
) -> ExportReport:
    """Export ``module`` (``export_extractor``, H and W multiples of the spec's
    ``size_multiple``) and verify it against ``reference`` on every case of every real image of
    ``request.images``: ``cases(image)``, by default the image at each (width, height) of
    ``sizes`` (``verification_inputs``) with a full mask. ``compare`` defaults to
    ``compare_keypoint_sets`` (identical whole-pixel sets) with ``tolerances`` (and
    ``relative_scores``). A masked case reports ``masked_keypoints``, the graph's keypoints on
    invalid pixels."""
    multiple = request.spec.size_multiple
    if multiple is None:
        raise ValueError(f"engine spec {request.spec.key} declares no size_multiple")
    session = export_extractor(
        request, module, multiple=multiple, max_blocks=max_blocks, label=label
    )
    request.log(f"verifying {label} against {reference_name} on real imagery")

    def full_mask_cases(image: VerificationImage) -> list[ExtractorCase]:
        return [ExtractorCase(name, rgb) for name, rgb in verification_inputs(image.rgb, sizes)]

    def keypoint_sets(
        name: str, got: KeypointSet, ref: KeypointSet, failures: list[str]
    ) -> dict[str, Any]:
        return compare_keypoint_sets(
            name, got, ref, tolerances, failures, relative_scores=relative_scores
        )

    checks: list[dict[str, Any]] = []
    failures: list[str] = []
    for image in request.images:
        for case in (cases or full_mask_cases)(image):
            name = f"{image.name}:{case.label}"
            check = _check_case(session, name, case, reference, compare or keypoint_sets, failures)
            _record(request, checks, check)
        if image_check is not None:
            _record(request, checks, image_check(session, image, failures))
    return ExportReport.from_checks(reference_name, tolerances, checks, failures, notes=notes)


def _check_case(
    session: ort.InferenceSession,
    name: str,
    case: ExtractorCase,
    reference: ReferenceFn,
    compare: CompareFn,
    failures: list[str],
) -> dict[str, Any]:
    """Run the graph on one case, drop its padding rows and compare them with the reference."""
    from c3_matcher.engines.extract import image_to_feeds

    valid = case.valid
    feeds = image_to_feeds(case.rgb, valid)
    kp, sc, de = session.run(None, feeds)
    keep = sc > 0
    got = (kp[keep], sc[keep], de[keep])
    check = compare(name, got, reference(feeds, case), failures)
    if case.mask is not None:
        rows = got[0][:, 1].round().astype(int)
        cols = got[0][:, 0].round().astype(int)
        check["masked_keypoints"] = int((~valid[rows, cols]).sum())
    return check


def _record(request: ExportRequest, checks: list[dict[str, Any]], check: dict[str, Any]) -> None:
    """Keep one check for the report and log it."""
    checks.append(check)
    request.log(f"  {check}")
