"""LightGlue export and verification, shared by every feature type (build time: imports torch).

The reference is kornia's ``LightGlue`` loaded with the same state dict, adaptive depth and
width pruning off (``depth_confidence = width_confidence = -1``: the pruning does not survive a
single-graph export). The exported graph runs the same layers, then the last layer's assignment
and upstream's ``filter_matches`` up to the threshold, which ``OnnxLightGlueRuntime`` applies:

    inputs  kpts0 (1, M, 2), kpts1 (1, N, 2)  float32, normalised (``normalize_keypoints``)
            desc0 (1, M, D), desc1 (1, N, D)  float32
    outputs matches0 (M,) int64 (mutual nearest neighbour in image 1, or -1)
            mscores0 (M,) float32 (its confidence, 0 where not mutual)

Only the inner (M, N) block of the log-assignment matters for ``filter_matches``, so the dustbin
row/column are not built. Index grids come from ``cumsum`` of ones (the dynamo exporter cannot
export arithmetic on symbolic sizes).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from kornia.feature import LightGlue
from numpy.typing import NDArray
from torch import nn
from torch.nn import functional as nnf

from c3_matcher.engines.lightglue import DEFAULT_FILTER_THRESHOLD, OnnxLightGlueRuntime
from c3_matcher.engines.providers import CPU_PROVIDER
from c3_matcher.features import PairSide
from c3_matcher_tools.engines.export import (
    ExportReport,
    ExportRequest,
    VerificationImage,
    tolerance_failures,
)
from c3_matcher_tools.engines.export.attention import ONNX_TRANSLATIONS, fused_attention_copy
from c3_matcher_tools.engines.export.onnx_export import export_requested, verification_session

__all__ = [
    "LIGHTGLUE_TOLERANCES",
    "FeaturePair",
    "FeaturesFn",
    "LightGlueForExport",
    "PairCheckFn",
    "assignment_matches",
    "export_lightglue",
    "feature_pairs",
    "load_lightglue_reference",
    "reference_inputs",
    "verification_pairs",
    "verify_feature_pairs",
]

_UNUSED_KEY = re.compile(r"^log_assignment\.\d+\.r$")

FeaturesFn = Callable[[NDArray[np.uint8], int], tuple[NDArray[np.float32], NDArray[np.float32]]]
"""``(rgb uint8 (H, W, 3), max keypoints) -> (keypoints float32 (K, 2) px, descriptors (K, D))``
from the feature type's PyTorch reference extractor."""

LIGHTGLUE_TOLERANCES: Mapping[str, float] = {
    "matches_mismatch": 0.0,  # identical (index0, index1) pairs
    "match_score_max_abs": 5e-4,  # confidences of the kept matches
    "mscores0_max_abs": 5e-4,  # every keypoint's mutual-NN confidence
}
"""The matches must be the same pairs; their confidences (in [0, 1]) within 5e-4. The PyTorch
reference's own confidences move with its thread count: LighterGlue's by 1.5e-4 on one thread
(8.4e-5 on two or more), which failed the build of a one-core machine at the 1e-4 of before."""


def load_lightglue_reference(
    weights_path: Path,
    *,
    input_dim: int,
    descriptor_dim: int = 256,
    n_layers: int = 9,
    num_heads: int = 4,
) -> LightGlue:
    """kornia ``LightGlue`` of the given architecture with ``weights_path`` loaded (upstream key
    renames applied; a checkpoint's ``extractor.*`` entries, a copy of the extractor's weights as
    in LighterGlue's, dropped), pruning off, flash off, eval mode. ``RuntimeError`` if a learned
    parameter is missing or an unknown one is present."""
    model = LightGlue(
        features=None,  # type: ignore[arg-type]
        input_dim=input_dim,
        descriptor_dim=descriptor_dim,
        n_layers=n_layers,
        num_heads=num_heads,
        depth_confidence=-1,
        width_confidence=-1,
        flash=False,
        filter_threshold=DEFAULT_FILTER_THRESHOLD,
    )
    state = torch.load(str(weights_path), map_location="cpu", weights_only=True)
    state = {
        k.removeprefix("matcher."): v for k, v in state.items() if not k.startswith("extractor.")
    }
    for i in range(n_layers):
        state = {
            k.replace(f"self_attn.{i}.", f"transformers.{i}.self_attn.").replace(
                f"cross_attn.{i}.", f"transformers.{i}.cross_attn."
            ): v
            for k, v in state.items()
        }
    incompatible = model.load_state_dict(state, strict=False)
    params = dict(model.named_parameters())
    missing = [k for k in incompatible.missing_keys if k in params]
    # Upstream checkpoints carry an unused ``log_assignment.<i>.r`` entry per layer.
    unexpected = [k for k in incompatible.unexpected_keys if not _UNUSED_KEY.match(k)]
    if missing or unexpected:
        raise RuntimeError(
            f"LightGlue weights {weights_path}: missing {missing}, unexpected {unexpected}"
        )
    return model.eval()


class LightGlueForExport(nn.Module):
    """The reference's layers without pruning, ending in ``filter_matches`` before the
    threshold (see the module docstring for I/O)."""

    def __init__(self, reference: LightGlue) -> None:
        super().__init__()
        self.lg = reference

    def forward(
        self, kpts0: torch.Tensor, kpts1: torch.Tensor, desc0: torch.Tensor, desc1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        lg: Any = self.lg
        d0, d1 = lg.input_proj(desc0), lg.input_proj(desc1)
        enc0, enc1 = lg.posenc(kpts0), lg.posenc(kpts1)
        for layer in lg.transformers:
            d0, d1 = layer(d0, d1, enc0, enc1)
        assignment = lg.log_assignment[-1]
        md0, md1 = assignment.final_proj(d0), assignment.final_proj(d1)
        z0, z1 = assignment.matchability(d0), assignment.matchability(d1)
        return assignment_matches(md0, md1, z0, z1)


def assignment_matches(
    md0: torch.Tensor, md1: torch.Tensor, z0: torch.Tensor, z1: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Upstream's match assignment (inner (M, N) block) and ``filter_matches`` before the
    threshold, from the projected descriptors ``md0``/``md1`` (1, M|N, D) and the matchability
    logits ``z0``/``z1`` (1, M|N, 1): ``(matches0 (M,), mscores0 (M,))``."""
    dim = md0.shape[-1]
    md0, md1 = md0 / dim**0.25, md1 / dim**0.25
    sim = torch.einsum("bmd,bnd->bmn", md0, md1)
    scores = (
        nnf.log_softmax(sim, 2)
        + nnf.log_softmax(sim, 1)
        + nnf.logsigmoid(z0)
        + nnf.logsigmoid(z1).transpose(1, 2)
    )
    max0, max1 = scores.max(2), scores.max(1)
    m0, m1 = max0.indices, max1.indices
    index0 = torch.cumsum(torch.ones_like(m0), 1) - 1
    mutual0 = index0 == m1.gather(1, m0)
    mscores0 = torch.where(mutual0, max0.values.exp(), torch.zeros_like(max0.values))
    matches0 = torch.where(mutual0, m0, torch.full_like(m0, -1))
    return matches0[0], mscores0[0]


def reference_inputs(side0: PairSide, side1: PairSide) -> dict[str, dict[str, torch.Tensor]]:
    """kornia ``LightGlue``'s input for one pair (``Features.pair_side`` of each image)."""

    def side(s: PairSide) -> Any:
        return {
            "keypoints": torch.from_numpy(s.keypoints)[None],
            "descriptors": torch.from_numpy(s.descriptors)[None],
            "image_size": torch.tensor([s.size], dtype=torch.float32),
        }

    return {"image0": side(side0), "image1": side(side1)}


def verification_pairs(
    rgb: NDArray[np.uint8],
) -> list[tuple[str, NDArray[np.uint8], NDArray[np.uint8]]]:
    """Overlapping crops of one real image at two sizes (640x480 vs 512x512 px): the keypoint
    normalisation of non-square images is exercised. Needs an image of at least 712x762."""
    a = np.ascontiguousarray(rgb[0:480, 0:640])
    b = np.ascontiguousarray(rgb[200:712, 250:762])
    return [("640x480|512x512", a, b)]


PairsFn = Callable[[NDArray[np.uint8]], list[tuple[str, NDArray[np.uint8], NDArray[np.uint8]]]]
"""``rgb -> [(label, rgb0, rgb1)]``: the image pairs cut from one verification image."""


@dataclass(frozen=True, slots=True)
class FeaturePair:
    """The real features of one verification pair at one keypoint budget, a side each image."""

    pair: str
    count: int
    side0: PairSide
    side1: PairSide

    @property
    def where(self) -> str:
        return f"{self.pair} @ {self.count}"

    def run_reference(self, reference: Any) -> Any:
        """kornia ``LightGlue``'s output on this pair."""
        return reference(reference_inputs(self.side0, self.side1))


def feature_pairs(
    images: Sequence[VerificationImage],
    features_fn: FeaturesFn,
    keypoint_counts: Sequence[int],
    pairs: PairsFn = verification_pairs,
) -> Iterator[FeaturePair]:
    """Every pair of every image (``pairs``) at every keypoint budget, with its features from
    ``features_fn``: the loop every LightGlue verification runs."""
    for image in images:
        for label, rgb0, rgb1 in pairs(image.rgb):
            for count in keypoint_counts:
                side0, side1 = (_side(features_fn, rgb, count) for rgb in (rgb0, rgb1))
                yield FeaturePair(f"{image.name}:{label}", count, side0, side1)


def _side(features_fn: FeaturesFn, rgb: NDArray[np.uint8], count: int) -> PairSide:
    keypoints, descriptors = features_fn(rgb, count)
    return PairSide(keypoints, descriptors, (rgb.shape[1], rgb.shape[0]))


class _SessionRuntime:
    """A minimal ``InferenceRuntime`` over a raw session (the manifest does not exist yet)."""

    def __init__(self, path: Path) -> None:
        self._session = verification_session(path)

    @property
    def provider(self) -> str:
        return CPU_PROVIDER

    def load_engine(self, path: Any) -> str:
        return "candidate"

    def run(self, engine_id: str, feeds: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[Any]]:
        names = [o.name for o in self._session.get_outputs()]
        return dict(zip(names, self._session.run(names, dict(feeds)), strict=True))


PairCheckFn = Callable[[FeaturePair], tuple[dict[str, Any], list[str]]]
"""``feature pair -> (check figures, failures)``: one pair's verification."""


def verify_feature_pairs(
    request: ExportRequest,
    pairs: Iterator[FeaturePair],
    check_pair: PairCheckFn,
) -> tuple[list[dict[str, Any]], list[str]]:
    """Run ``check_pair`` on every pair, logging each check: (checks, failures)."""
    checks: list[dict[str, Any]] = []
    failures: list[str] = []
    for fp in pairs:
        check, failed = check_pair(fp)
        checks.append(check)
        request.log(f"  {check}")
        failures.extend(failed)
    return checks, failures


@torch.no_grad()  # off while it runs, the caller's grad mode after
def export_lightglue(
    request: ExportRequest,
    *,
    features_fn: FeaturesFn,
    feature_type: str,
    input_dim: int | None = None,
    architecture: Mapping[str, int] | None = None,
    reference_name: str = "LightGlue",
    keypoint_counts: tuple[int, ...] = (512, 1024),
) -> ExportReport:
    """Export a LightGlue-family matcher for ``feature_type`` and verify it on real features of
    every ``verification_pairs`` pair at each of ``keypoint_counts``: identical matches, scores
    within ``LIGHTGLUE_TOLERANCES``.

    The reference is ``load_lightglue_reference(request.weights_path, **architecture)``;
    ``architecture`` holds ``input_dim`` and optionally ``descriptor_dim``, ``n_layers`` and
    ``num_heads`` (LighterGlue: 64, 96, 6, 1); ``input_dim`` alone means LightGlue's default
    width, depth and heads (256, 9, 4)."""
    arch = _architecture(input_dim, architecture)
    reference = load_lightglue_reference(request.weights_path, **arch)
    request.log(f"exporting {reference_name} for {feature_type} (opset {request.spec.opset})")
    _export_graph(request, reference, arch["input_dim"])
    request.log(f"verifying {reference_name} against kornia LightGlue on real features")
    session = _SessionRuntime(request.output_path)
    runtime = OnnxLightGlueRuntime(session)
    runtime.load(feature_type, request.output_path)

    def check_pair(fp: FeaturePair) -> tuple[dict[str, Any], list[str]]:
        check = _pair_check(fp, reference, session, runtime, feature_type)
        return check, _pair_failures(fp.where, check)

    checks, failures = verify_feature_pairs(
        request, feature_pairs(request.images, features_fn, keypoint_counts), check_pair
    )
    return ExportReport.from_checks(
        f"kornia {_version('kornia')} LightGlue (pruning off) with {reference_name} "
        f"weights on {feature_type} features",
        LIGHTGLUE_TOLERANCES,
        checks,
        failures,
        nothing_run="no verification pair was run",
    )


def _architecture(input_dim: int | None, architecture: Mapping[str, int] | None) -> dict[str, int]:
    """``architecture`` with ``input_dim`` set when given; ``ValueError`` if it has none."""
    arch = dict(architecture or {})
    if input_dim is not None:
        arch["input_dim"] = input_dim
    if "input_dim" not in arch:
        raise ValueError("export_lightglue needs input_dim (or architecture['input_dim'])")
    return arch


def _export_graph(request: ExportRequest, reference: LightGlue, input_dim: int) -> None:
    """Trace ``reference`` (no pruning, fused attention) and write it to the request's path."""
    num0 = torch.export.Dim("num_keypoints0", min=1, max=65536)
    num1 = torch.export.Dim("num_keypoints1", min=1, max=65536)
    generator = torch.Generator().manual_seed(0)
    example = (
        torch.rand(1, 300, 2, generator=generator) * 2 - 1,
        torch.rand(1, 280, 2, generator=generator) * 2 - 1,
        nnf.normalize(torch.rand(1, 300, input_dim, generator=generator), dim=-1),
        nnf.normalize(torch.rand(1, 280, input_dim, generator=generator), dim=-1),
    )
    export_requested(
        request,
        LightGlueForExport(fused_attention_copy(reference)),
        example,
        dynamic_shapes={
            "kpts0": {1: num0},
            "kpts1": {1: num1},
            "desc0": {1: num0},
            "desc1": {1: num1},
        },
        translations=ONNX_TRANSLATIONS,
    )


def _pair_check(
    fp: FeaturePair,
    reference: LightGlue,
    session: _SessionRuntime,
    runtime: OnnxLightGlueRuntime,
    feature_type: str,
) -> dict[str, Any]:
    """The figures comparing the graph's matches and scores on one pair with kornia's."""
    ref = fp.run_reference(reference)
    ref_matches = ref["matches"][0].numpy().astype(np.int64)
    ref_scores = ref["scores"][0].numpy()
    ref_ms0 = ref["matching_scores0"][0].numpy()
    got = runtime.match_pair(fp.side0, fp.side1, feature_type=feature_type)
    same = got.matches.shape == ref_matches.shape and bool(np.array_equal(got.matches, ref_matches))
    mismatch = len(set(map(tuple, got.matches.tolist())) ^ set(map(tuple, ref_matches.tolist())))
    score_err = 0.0
    if same and len(ref_scores):
        score_err = float(np.abs(got.scores - ref_scores).max())
    return {
        "pair": fp.pair,
        "keypoints": [len(fp.side0.keypoints), len(fp.side1.keypoints)],
        "matches": len(got),
        "reference_matches": len(ref_matches),
        "matches_identical": same,
        "matches_mismatch": mismatch,
        "match_score_max_abs": score_err,
        "mscores0_max_abs": _mscores_error(session, fp, ref_ms0),
    }


def _pair_failures(where: str, check: Mapping[str, Any]) -> list[str]:
    """What of one pair's check is out of ``LIGHTGLUE_TOLERANCES``."""
    failures: list[str] = []
    if not check["matches_identical"]:
        failures.append(f"{where}: {check['matches_mismatch']} matches differ")
    keys = ("match_score_max_abs", "mscores0_max_abs")
    return failures + tolerance_failures(where, check, LIGHTGLUE_TOLERANCES, keys)


def _mscores_error(
    session: _SessionRuntime, fp: FeaturePair, ref_ms0: NDArray[np.float32]
) -> float:
    from c3_matcher.engines.lightglue import normalize_keypoints

    out = session.run(
        "candidate",
        {
            "kpts0": normalize_keypoints(fp.side0.keypoints, fp.side0.size)[None],
            "kpts1": normalize_keypoints(fp.side1.keypoints, fp.side1.size)[None],
            "desc0": fp.side0.descriptors[None],
            "desc1": fp.side1.descriptors[None],
        },
    )
    return float(np.abs(out["mscores0"] - ref_ms0).max())


def _version(distribution: str) -> str:
    import importlib.metadata

    return importlib.metadata.version(distribution)
