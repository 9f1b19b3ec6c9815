from __future__ import annotations

import pytest

from c3_matcher.engines.naming import EngineName, manifest_path_for


def test_round_trip() -> None:
    name = EngineName.from_build_key("disk", "depth", "fp32", "hw16-k2048", 18, "0123456789abcdef")
    assert name.filename == "disk_depth_fp32_hw16-k2048_op18_0123456789.onnx"
    assert EngineName.parse(name.filename) == name
    assert name.manifest_filename == "disk_depth_fp32_hw16-k2048_op18_0123456789.manifest.json"


@pytest.mark.parametrize(
    "bad",
    [
        "disk.onnx",
        "disk_depth_fp32_hw16_op18_0123456789.onx",
        "disk_depth_fp32_hw16_op18_012345678.onnx",  # short hash
        "Disk_depth_fp32_hw16_op18_0123456789.onnx",  # upper case
        "disk_depth_fp32_hw16_opXX_0123456789.onnx",
    ],
)
def test_parse_rejects_names_off_schema(bad: str) -> None:
    with pytest.raises(ValueError, match="engine name schema"):
        EngineName.parse(bad)


def test_tokens_are_validated() -> None:
    with pytest.raises(ValueError):
        EngineName.from_build_key("disk_x", "depth", "fp32", "hw16", 18, "0" * 64)


def test_manifest_path(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "disk_depth_fp32_hw16_op18_0123456789.onnx"
    assert manifest_path_for(path).name == "disk_depth_fp32_hw16_op18_0123456789.manifest.json"
