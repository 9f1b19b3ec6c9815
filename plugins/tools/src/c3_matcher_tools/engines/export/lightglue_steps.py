"""Adaptive (stepped) LightGlue export and verification (build time: imports torch).

Writes ONE ONNX file with the three disjoint sub-graphs that
``c3_matcher.engines.lightglue_adaptive`` drives (input projection; one transformer layer chosen
by a ``layer`` index, with its token confidence and matchability; the match-assignment head of a
chosen layer before the threshold). The per-layer weights are stacked ``(L, ...)`` and gathered
by the index, so the file holds each weight once and every layer runs the same nodes.

Verification (a failed check keeps no engine): on real pairs of the verification imagery, an
overlapping pair (``verification_pairs``) and a distractor pair (two crops that share no ground),
at 1024 and 2048 keypoints per side, the run time (numpy decisions between ONNX Runtime steps)
is compared with kornia's ``LightGlue`` (upstream's adaptive forward) with the same weights and
the same ``depth_confidence`` / ``width_confidence``: the share of identical matches, the layers
run, the points kept, and the RANSAC inlier counts of both match sets (homography, 3 px).
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np
import onnxruntime as ort
import torch
from numpy.typing import NDArray
from torch import nn
from torch.func import functional_call
from torch.nn import functional as nnf

from c3_matcher.engines.lightglue import DEFAULT_FILTER_THRESHOLD, normalize_keypoints
from c3_matcher.engines.lightglue_adaptive import AdaptiveLightGlue, AdaptiveResult
from c3_matcher_tools.engines.export import ExportReport, ExportRequest
from c3_matcher_tools.engines.export.attention import ONNX_TRANSLATIONS, fused_attention_copy
from c3_matcher_tools.engines.export.lightglue import (
    FeaturePair,
    FeaturesFn,
    assignment_matches,
    export_lightglue,
    feature_pairs,
    load_lightglue_reference,
    verification_pairs,
    verify_feature_pairs,
)
from c3_matcher_tools.engines.export.onnx_export import export_requested, verification_session

__all__ = [
    "STEPS_TOLERANCES",
    "LightGlueStepsForExport",
    "export_lightglue_steps",
    "lightglue_exporters",
]

Exporter = Callable[[ExportRequest], ExportReport]

STEPS_TOLERANCES: Mapping[str, float] = {
    "min_identical_share": 0.98,  # |ours & ref| / |ours | ref| on every pair with >= 20 matches
    "max_mismatch_distractor": 4,  # matches differing on pairs with < 20 reference matches
    "layers_differ": 0,  # layers run, ours vs upstream
    "inliers_rel_diff": 0.03,  # |inliers ours - ref| / max(ref, 1)
}


def _stack(modules: Any, names: list[str]) -> list[torch.Tensor]:
    params = [dict(m.named_parameters()) for m in modules]
    return [torch.stack([p[n].detach() for p in params]).contiguous() for n in names]


class LightGlueStepsForExport(nn.Module):
    """The steps graph of ``reference`` (kornia ``LightGlue``); I/O in
    ``c3_matcher.engines.lightglue_adaptive``."""

    def __init__(self, reference: Any) -> None:
        super().__init__()
        self.lg = reference
        layers = list(reference.transformers)
        self.n_layers = len(layers)
        self.layer_names = [n for n, _ in layers[0].named_parameters()]
        for j, tensor in enumerate(_stack(layers, self.layer_names)):
            self.register_buffer(f"layer_p{j}", tensor)
        heads = list(reference.log_assignment)
        tokens = list(reference.token_confidence)
        tokens = tokens + [tokens[-1]] * (self.n_layers - len(tokens))  # last layer: unused
        self.register_buffer("ma_w", torch.stack([h.matchability.weight.detach() for h in heads]))
        self.register_buffer("ma_b", torch.stack([h.matchability.bias.detach() for h in heads]))
        self.register_buffer("fp_w", torch.stack([h.final_proj.weight.detach() for h in heads]))
        self.register_buffer("fp_b", torch.stack([h.final_proj.bias.detach() for h in heads]))
        self.register_buffer("tc_w", torch.stack([t.token[0].weight.detach() for t in tokens]))
        self.register_buffer("tc_b", torch.stack([t.token[0].bias.detach() for t in tokens]))

    @staticmethod
    def _pick(stacked: Any, index: torch.Tensor) -> torch.Tensor:
        return stacked.index_select(0, index).squeeze(0)

    def forward(
        self,
        desc0: torch.Tensor,
        desc1: torch.Tensor,
        kpts0: torch.Tensor,
        kpts1: torch.Tensor,
        state0: torch.Tensor,
        state1: torch.Tensor,
        layer: torch.Tensor,
        final0: torch.Tensor,
        final1: torch.Tensor,
        final_layer: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        lg: Any = self.lg
        proj0, proj1 = lg.input_proj(desc0), lg.input_proj(desc1)
        enc0, enc1 = lg.posenc(kpts0), lg.posenc(kpts1)
        params = {
            name: self._pick(getattr(self, f"layer_p{j}"), layer)
            for j, name in enumerate(self.layer_names)
        }
        out0, out1 = functional_call(lg.transformers[0], params, (state0, state1, enc0, enc1))
        tc_w, tc_b = self._pick(self.tc_w, layer), self._pick(self.tc_b, layer)
        ma_w, ma_b = self._pick(self.ma_w, layer), self._pick(self.ma_b, layer)
        conf0 = torch.sigmoid(nnf.linear(out0, tc_w, tc_b))[0, :, 0]
        conf1 = torch.sigmoid(nnf.linear(out1, tc_w, tc_b))[0, :, 0]
        match0 = torch.sigmoid(nnf.linear(out0, ma_w, ma_b))[0, :, 0]
        match1 = torch.sigmoid(nnf.linear(out1, ma_w, ma_b))[0, :, 0]
        # head: log_assignment[final_layer] + filter_matches before the threshold
        fp_w, fp_b = self._pick(self.fp_w, final_layer), self._pick(self.fp_b, final_layer)
        fa_w, fa_b = self._pick(self.ma_w, final_layer), self._pick(self.ma_b, final_layer)
        md0, md1 = nnf.linear(final0, fp_w, fp_b), nnf.linear(final1, fp_w, fp_b)
        z0, z1 = nnf.linear(final0, fa_w, fa_b), nnf.linear(final1, fa_w, fa_b)
        matches0, mscores0 = assignment_matches(md0, md1, z0, z1)
        return (proj0, proj1, out0, out1, conf0, conf1, match0, match1, matches0, mscores0)


def _session_run(session: ort.InferenceSession) -> Callable[[Mapping[str, Any]], dict[str, Any]]:
    names = [o.name for o in session.get_outputs()]

    def run(feeds: Mapping[str, Any]) -> dict[str, Any]:
        return dict(zip(names, session.run(names, dict(feeds)), strict=True))

    return run


def _inliers(k0: NDArray[np.float32], k1: NDArray[np.float32], matches: NDArray[np.int64]) -> int:
    if len(matches) < 4:
        return 0
    cv2.setRNGSeed(0)
    _, mask = cv2.findHomography(
        k0[matches[:, 0]].astype(np.float64),
        k1[matches[:, 1]].astype(np.float64),
        cv2.RANSAC,
        3.0,
        maxIters=2000,
        confidence=0.999,
    )
    return 0 if mask is None else int(mask.sum())


def _distractor_pair(
    rgb: NDArray[np.uint8],
) -> tuple[str, NDArray[np.uint8], NDArray[np.uint8]] | None:
    """Two crops of one image that share no ground (640x480 top-left, 512x512 bottom-right)."""
    height, width = rgb.shape[:2]
    if height < 480 + 512 or width < 640:
        return None
    a = np.ascontiguousarray(rgb[0:480, 0:640])
    b = np.ascontiguousarray(rgb[height - 512 : height, width - 512 : width])
    return ("distractor 640x480|512x512", a, b)


def _pairs_and_distractor(
    rgb: NDArray[np.uint8],
) -> list[tuple[str, NDArray[np.uint8], NDArray[np.uint8]]]:
    distractor = _distractor_pair(rgb)
    return [*verification_pairs(rgb), *([distractor] if distractor is not None else [])]


@torch.no_grad()  # off while it runs, the caller's grad mode after
def export_lightglue_steps(
    request: ExportRequest,
    *,
    features_fn: FeaturesFn,
    feature_type: str,
    keypoint_counts: tuple[int, ...] = (1024, 2048),
) -> ExportReport:
    """Export the steps graph of kornia ``LightGlue`` (``load_lightglue_reference`` of the
    request's weights with the spec's ``input_dim``; its depth/width settings are overridden by
    the spec's ``depth_confidence`` / ``width_confidence`` options for the check) and verify it
    against upstream's adaptive forward on ``features_fn``'s real features (see the module
    docstring). The plugin that declares a steps engine names a one-line exporter calling this
    with its features."""
    spec = request.spec
    reference = load_lightglue_reference(
        request.weights_path, input_dim=int(spec.option("input_dim"))
    )
    depth = float(spec.option("depth_confidence"))
    width = float(spec.option("width_confidence"))
    n_layers = int(reference.conf.n_layers)
    request.log(
        f"exporting stepped LightGlue for {feature_type} ({n_layers} layers, opset {spec.opset})"
    )
    _export_steps_graph(request, reference)
    request.log(
        f"verifying stepped LightGlue against upstream adaptive LightGlue "
        f"(depth {depth}, width {width}) on real pairs"
    )
    adaptive = _adaptive_runtime(request, reference.conf, depth, width)
    _set_upstream_adaptive(reference, depth, width)
    checks, failures = verify_feature_pairs(
        request,
        feature_pairs(request.images, features_fn, keypoint_counts, _pairs_and_distractor),
        lambda fp: _steps_pair_check(fp, reference, adaptive),
    )
    return ExportReport.from_checks(
        f"kornia {importlib.metadata.version('kornia')} LightGlue adaptive forward "
        f"(depth_confidence {depth}, width_confidence {width}) on {feature_type} features",
        STEPS_TOLERANCES,
        checks,
        failures,
        notes={"depth_confidence": depth, "width_confidence": width, "n_layers": n_layers},
        nothing_run="no verification pair was run",
    )


def _export_steps_graph(request: ExportRequest, reference: Any) -> None:
    """Trace the steps graph of ``reference`` (fused attention) and write it to the request."""
    conf: Any = reference.conf
    module = LightGlueStepsForExport(fused_attention_copy(reference)).eval()
    dynamic_shapes = _steps_dynamic_shapes()
    export_requested(
        request,
        module,
        _steps_example(int(conf.input_dim), int(conf.descriptor_dim)),
        dynamic_shapes=dynamic_shapes,
        translations=ONNX_TRANSLATIONS,
    )


def _steps_dynamic_shapes() -> dict[str, Any]:
    """The steps graph's dynamic axes: each side's descriptor, state and final-state counts."""
    dims = [
        torch.export.Dim(name, min=1, max=65536)
        for name in (
            "num_desc0",
            "num_desc1",
            "num_state0",
            "num_state1",
            "num_final0",
            "num_final1",
        )
    ]
    return {
        "desc0": {1: dims[0]},
        "desc1": {1: dims[1]},
        "kpts0": {1: dims[2]},
        "kpts1": {1: dims[3]},
        "state0": {1: dims[2]},
        "state1": {1: dims[3]},
        "layer": None,
        "final0": {1: dims[4]},
        "final1": {1: dims[5]},
        "final_layer": None,
    }


def _steps_example(input_dim: int, descriptor_dim: int) -> tuple[torch.Tensor, ...]:
    """Seeded random example inputs of the steps graph, a different size on every dynamic axis."""
    sizes = (300, 280, 260, 240, 220, 200)
    generator = torch.Generator().manual_seed(0)

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=generator)

    return (
        nnf.normalize(rand(1, sizes[0], input_dim), dim=-1),
        nnf.normalize(rand(1, sizes[1], input_dim), dim=-1),
        rand(1, sizes[2], 2) * 2 - 1,
        rand(1, sizes[3], 2) * 2 - 1,
        rand(1, sizes[2], descriptor_dim),
        rand(1, sizes[3], descriptor_dim),
        torch.tensor([1], dtype=torch.int64),
        rand(1, sizes[4], descriptor_dim),
        rand(1, sizes[5], descriptor_dim),
        torch.tensor([2], dtype=torch.int64),
    )


def _adaptive_runtime(
    request: ExportRequest, conf: Any, depth: float, width: float
) -> AdaptiveLightGlue:
    """The run time's adaptive driver over the exported graph (ONNX Runtime, CPU)."""
    session = verification_session(request.output_path)
    return AdaptiveLightGlue(
        _session_run(session),
        n_layers=int(conf.n_layers),
        input_dim=int(conf.input_dim),
        descriptor_dim=int(conf.descriptor_dim),
        depth_confidence=depth,
        width_confidence=width,
    )


def _set_upstream_adaptive(reference: Any, depth: float, width: float) -> None:
    """Set upstream's adaptive forward to the check's confidences and the run time's threshold."""
    reference.conf.depth_confidence = depth
    reference.conf.width_confidence = width
    reference.conf.filter_threshold = DEFAULT_FILTER_THRESHOLD


def _steps_matches(
    fp: FeaturePair, adaptive: AdaptiveLightGlue
) -> tuple[AdaptiveResult, NDArray[np.int64]]:
    """The steps run time's result on one pair and its matches above the filter threshold."""
    s0, s1 = fp.side0, fp.side1
    got = adaptive.match(
        normalize_keypoints(s0.keypoints, s0.size),
        normalize_keypoints(s1.keypoints, s1.size),
        s0.descriptors,
        s1.descriptors,
    )
    valid = (got.matches0 > -1) & (got.mscores0 > np.float32(DEFAULT_FILTER_THRESHOLD))
    index0 = np.flatnonzero(valid)
    return got, np.stack([index0, got.matches0[valid]], -1).astype(np.int64)


def _steps_pair_check(
    fp: FeaturePair, reference: Any, adaptive: AdaptiveLightGlue
) -> tuple[dict[str, Any], list[str]]:
    """Compare the steps run time with upstream's adaptive forward on one pair."""
    ref = fp.run_reference(reference)
    ref_matches = ref["matches"][0].numpy().astype(np.int64).reshape(-1, 2)
    got, matches = _steps_matches(fp, adaptive)
    s0, s1 = fp.side0, fp.side1
    mine = set(map(tuple, matches.tolist()))
    theirs = set(map(tuple, ref_matches.tolist()))
    union = len(mine | theirs)
    share = len(mine & theirs) / union if union else 1.0
    check: dict[str, Any] = {
        "pair": fp.pair,
        "keypoints": [len(s0.keypoints), len(s1.keypoints)],
        "matches": len(mine),
        "reference_matches": len(theirs),
        "identical_share": round(share, 5),
        "matches_mismatch": len(mine ^ theirs),
        "layers": got.layers,
        "reference_layers": int(ref["stop"]),
        "kept_last": [got.kept0[-1], got.kept1[-1]],
        "reference_kept_last": [
            int((ref["prune0"][0] == ref["prune0"][0].max()).sum()),
            int((ref["prune1"][0] == ref["prune1"][0].max()).sum()),
        ],
        "inliers": _inliers(s0.keypoints, s1.keypoints, matches),
        "reference_inliers": _inliers(s0.keypoints, s1.keypoints, ref_matches),
    }
    return check, _steps_failures(fp.where, check, share)


def _steps_failures(where: str, check: Mapping[str, Any], share: float) -> list[str]:
    """What of one pair's check (``share`` unrounded) is out of ``STEPS_TOLERANCES``."""
    failures: list[str] = []
    theirs, differ = check["reference_matches"], check["matches_mismatch"]
    layers, ref_layers = check["layers"], check["reference_layers"]
    inl, ref_inl = check["inliers"], check["reference_inliers"]
    if theirs >= 20 and share < STEPS_TOLERANCES["min_identical_share"]:
        failures.append(f"{where}: identical share {share:.4f}")
    if theirs < 20 and differ > STEPS_TOLERANCES["max_mismatch_distractor"]:
        failures.append(f"{where}: {differ} matches differ")
    if abs(layers - ref_layers) > STEPS_TOLERANCES["layers_differ"]:
        failures.append(f"{where}: {layers} layers vs upstream {ref_layers}")
    if abs(inl - ref_inl) > STEPS_TOLERANCES["inliers_rel_diff"] * max(ref_inl, 1):
        failures.append(f"{where}: {inl} inliers vs upstream {ref_inl}")
    return failures


def lightglue_exporters(
    feature_type: str, features_fn: Callable[[], FeaturesFn]
) -> tuple[Exporter, Exporter]:
    """The two exporters of upstream LightGlue for ``feature_type`` that a plugin's engine specs
    name (``lightglue_engine_specs``): the single graph (``export_lightglue``, ``input_dim`` from
    the spec) and the steps graph (``export_lightglue_steps``), each verified on real features of
    the reference extractor ``features_fn()`` makes when the exporter runs."""

    def export_full(request: ExportRequest) -> ExportReport:
        return export_lightglue(
            request,
            features_fn=features_fn(),
            input_dim=int(request.spec.option("input_dim")),
            feature_type=feature_type,
        )

    def export_steps(request: ExportRequest) -> ExportReport:
        return export_lightglue_steps(request, features_fn=features_fn(), feature_type=feature_type)

    return export_full, export_steps
