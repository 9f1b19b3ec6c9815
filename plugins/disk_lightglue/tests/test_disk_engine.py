"""The DISK engine on real imagery: agreement with kornia, determinism, masking, the helper."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from numpy.typing import NDArray

from c3_matcher.engines.extract import image_to_feeds, run_extractor
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.testing.strategy_kit import assert_features_identical


def _kornia(reference: Any, rgb: NDArray[np.uint8], n: int) -> Any:
    feeds = image_to_feeds(rgb, np.ones(rgb.shape[:2], dtype=bool))
    with torch.no_grad():
        return reference(torch.from_numpy(feeds["image"]), n=n)[0]


@pytest.mark.parametrize(
    ("image", "box"),
    [
        ("open_orthophotos/swissimage_zurich_1091-322_00_0p5m.tif", (0, 0, 320, 256)),
        ("naip_timeseries/m_4709963_se_14_1_20100629.tif", (100, 50, 768, 512)),
    ],
)
def test_keypoints_identical_to_kornia_on_unseen_imagery(
    runtime: OnnxInferenceRuntime,
    disk_engine: Path,
    disk_reference: Any,
    read_image: Callable[[str], NDArray[np.uint8]],
    image: str,
    box: tuple[int, int, int, int],
) -> None:
    x, y, w, h = box
    rgb = np.ascontiguousarray(read_image(image)[y : y + h, x : x + w])
    engine_id = runtime.load_engine(disk_engine)
    got = run_extractor(runtime, engine_id, rgb, np.ones((h, w), dtype=bool), 1024)
    ref = _kornia(disk_reference, rgb, 1024)
    assert len(got) == ref.keypoints.shape[0] > 100
    mine = np.lexsort((got.keypoints[:, 0], got.keypoints[:, 1]))
    theirs = np.lexsort((ref.keypoints[:, 0].numpy(), ref.keypoints[:, 1].numpy()))
    np.testing.assert_array_equal(got.keypoints[mine], ref.keypoints.numpy()[theirs])
    np.testing.assert_allclose(
        got.keypoint_scores[mine], ref.detection_scores.numpy()[theirs], atol=5e-3, rtol=0
    )
    np.testing.assert_allclose(
        got.descriptors[mine], ref.descriptors.numpy()[theirs], atol=1e-4, rtol=0
    )
    assert got.image_size == (w, h)


def test_same_input_twice_is_bit_identical(
    runtime: OnnxInferenceRuntime, disk_engine: Path, gorinchem: NDArray[np.uint8]
) -> None:
    engine_id = runtime.load_engine(disk_engine)
    rgb = np.ascontiguousarray(gorinchem[:512, :512])
    mask = np.ones((512, 512), dtype=bool)
    a = run_extractor(runtime, engine_id, rgb, mask, 2048)
    b = run_extractor(runtime, engine_id, rgb, mask, 2048)
    assert_features_identical(a, b)


def test_masked_pixels_yield_no_keypoints(
    runtime: OnnxInferenceRuntime, disk_engine: Path, gorinchem: NDArray[np.uint8]
) -> None:
    engine_id = runtime.load_engine(disk_engine)
    rgb = np.ascontiguousarray(gorinchem[:512, :512])
    mask = np.ones((512, 512), dtype=bool)
    mask[:, :200] = False  # a left strip (e.g. a warp border)
    mask[300:400, 300:400] = False  # a nodata hole
    feats = run_extractor(runtime, engine_id, rgb, mask, 2048)
    assert len(feats) > 500
    cols = feats.keypoints[:, 0].astype(int)
    rows = feats.keypoints[:, 1].astype(int)
    assert mask[rows, cols].all()
    unmasked = run_extractor(runtime, engine_id, rgb, np.ones_like(mask), 2048)
    u_cols = unmasked.keypoints[:, 0].astype(int)
    u_rows = unmasked.keypoints[:, 1].astype(int)
    assert (~mask[u_rows, u_cols]).sum() > 100  # the masked areas do have keypoints otherwise


def test_helper_budget_order_and_padding(
    runtime: OnnxInferenceRuntime, disk_engine: Path, gorinchem: NDArray[np.uint8]
) -> None:
    engine_id = runtime.load_engine(disk_engine)
    rgb = np.ascontiguousarray(gorinchem[:256, :256])
    full = run_extractor(runtime, engine_id, rgb, np.ones((256, 256), dtype=bool), 2048)
    assert 0 < len(full) < 2048  # padding rows (score <= 0) were dropped
    assert (full.keypoint_scores > 0).all()
    assert (np.diff(full.keypoint_scores) <= 0).all()
    top = run_extractor(runtime, engine_id, rgb, np.ones((256, 256), dtype=bool), 100)
    assert len(top) == 100
    np.testing.assert_array_equal(top.keypoints, full.keypoints[:100])
    np.testing.assert_array_equal(
        np.linalg.norm(top.descriptors, axis=1).round(4), np.ones(100, np.float32)
    )


@pytest.mark.parametrize(
    ("shape", "dtype", "mask_shape", "max_keypoints", "message"),
    [
        ((100, 128, 3), np.uint8, (100, 128), 10, "multiples of 16"),
        ((64, 64, 3), np.float32, (64, 64), 10, "uint8"),
        ((64, 64, 3), np.uint8, (64, 32), 10, "mask"),
        ((64, 64, 3), np.uint8, (64, 64), 0, "max_keypoints"),
    ],
)
def test_helper_rejects_bad_inputs(
    runtime: OnnxInferenceRuntime,
    disk_engine: Path,
    shape: tuple[int, ...],
    dtype: Any,
    mask_shape: tuple[int, int],
    max_keypoints: int,
    message: str,
) -> None:
    engine_id = runtime.load_engine(disk_engine)
    with pytest.raises(ValueError, match=message):
        run_extractor(
            runtime, engine_id, np.zeros(shape, dtype), np.ones(mask_shape, bool), max_keypoints
        )
