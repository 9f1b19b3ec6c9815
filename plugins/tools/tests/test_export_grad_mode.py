"""An export runs with PyTorch's grad mode off and leaves the caller's mode as it found it: the
exporters once switched it off for the whole process, so a test, a notebook or anything run
after ``engines build`` in the same process found gradients off. The plugins' real exporters on
their real weights and references, the export and verification loop itself replaced (the
engines' bytes are checked by their build, not here)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import torch

import c3_matcher_aliked_lightglue.export as aliked_export
import c3_matcher_disk_lightglue.export as disk_export
import c3_matcher_xfeat.export as xfeat_export
from c3_matcher.engines.spec import EngineSpec
from c3_matcher_aliked_lightglue.engines import ALIKED_N16_SPEC
from c3_matcher_disk_lightglue.engines import DISK_SPEC, LIGHTGLUE_DISK_STEPS_SPEC
from c3_matcher_tools.engines.export import ExportReport, ExportRequest, lightglue, lightglue_steps
from c3_matcher_xfeat.engines import XFEAT_SPEC


@pytest.fixture(params=[True, False], ids=["grad on", "grad off"])
def grad_mode(request: pytest.FixtureRequest) -> Iterator[bool]:
    """The caller's grad mode while the test runs (the process's own restored after)."""
    with torch.set_grad_enabled(request.param):
        yield request.param


def _request(spec: EngineSpec, tmp_path: Path) -> ExportRequest:
    return ExportRequest(spec, spec.weights.resolve(), tmp_path / "engine.onnx", (), lambda _: None)


@pytest.mark.parametrize(
    ("module", "exporter", "spec"),
    [
        (disk_export, "export_disk", DISK_SPEC),
        (aliked_export, "export_aliked", ALIKED_N16_SPEC),
        (xfeat_export, "export_xfeat", XFEAT_SPEC),
    ],
)
def test_an_extractor_export_runs_without_grad_and_leaves_the_callers_mode(
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    grad_mode: bool,
    module: ModuleType,
    exporter: str,
    spec: EngineSpec,
) -> None:
    seen: list[tuple[bool, str]] = []

    def export_and_verify(_request: ExportRequest, _module: Any, **kit: Any) -> ExportReport:
        seen.append((torch.is_grad_enabled(), kit["label"]))
        return ExportReport.from_checks("none", {}, [{"input": "none"}], [])

    monkeypatch.setattr(module, "export_and_verify_extractor", export_and_verify)
    report = getattr(module, exporter)(_request(spec, tmp_path))
    assert report.passed
    (grad_inside, label), *_ = seen
    assert not grad_inside
    assert f"top-K {spec.option('top_k')}" in label  # the spec's own, read for every extractor
    assert torch.is_grad_enabled() is grad_mode


@pytest.mark.parametrize(
    ("export", "module", "options"),
    [
        (lightglue.export_lightglue, lightglue, {"input_dim": 128}),
        (lightglue_steps.export_lightglue_steps, lightglue_steps, {}),
    ],
)
def test_a_lightglue_export_that_fails_leaves_the_callers_grad_mode(
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    grad_mode: bool,
    export: Any,
    module: ModuleType,
    options: dict[str, Any],
) -> None:
    seen: list[bool] = []

    def refused(*_args: Any, **_kwargs: Any) -> Any:
        seen.append(torch.is_grad_enabled())
        raise RuntimeError("weights refused")

    monkeypatch.setattr(module, "load_lightglue_reference", refused)
    request = _request(LIGHTGLUE_DISK_STEPS_SPEC, tmp_path)
    with pytest.raises(RuntimeError, match="weights refused"):
        export(request, features_fn=lambda *_: None, feature_type="disk", **options)
    assert seen == [False]
    assert torch.is_grad_enabled() is grad_mode
