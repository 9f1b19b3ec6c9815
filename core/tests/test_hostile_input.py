"""Inputs that escaped the contract in the adversarial campaign."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.config import load_settings
from c3_matcher.dto import CameraCalibration, NavCameraFrame
from c3_matcher.errors import ConfigurationError, InvalidInputError
from c3_matcher.serialize import load_calibration


def _image() -> np.ndarray:
    return np.zeros((32, 32, 3), np.uint8)


def test_singular_k_is_refused_at_construction():
    k = np.array([[500.0, 0, 16], [500.0, 1e-300, 16], [0, 0, 1]])
    k[1, 1] = 1e-300  # > 0, last row fine, but not invertible
    with pytest.raises(InvalidInputError, match="calibration.K.*singular"):
        CameraCalibration(k, np.zeros(0), (32, 32))
    rank_deficient = np.array([[500.0, 500.0, 16], [500.0, 500.0, 16], [0, 0, 1]])
    with pytest.raises(InvalidInputError, match="calibration.K"):
        CameraCalibration(rank_deficient, np.zeros(0), (32, 32))


@pytest.mark.parametrize("key", ["RANSAC_THRESHOLD_PX", "RESIDUAL_WARN_THRESHOLD_PX"])
@pytest.mark.parametrize("value", ["inf", "Infinity", "nan", "-inf"])
def test_infinite_thresholds_are_refused(key, value):
    with pytest.raises(ConfigurationError, match=key.lower()):
        load_settings(env={f"C3_MATCHER_MATCHER__{key}": value})


def test_frame_image_is_a_private_read_only_copy():
    buf = _image()
    frame = NavCameraFrame(uuid.uuid4(), buf, 0)
    buf[:] = 255  # the camera driver reuses its buffer
    assert int(frame.image.max()) == 0
    assert not frame.image.flags.writeable
    with pytest.raises(ValueError):
        frame.image[0, 0, 0] = 1


@pytest.mark.parametrize("height", [1e300, 1e6])
def test_absurd_height_is_named(height):
    with pytest.raises(InvalidInputError, match="frame.height_above_ground_m.*<="):
        NavCameraFrame(uuid.uuid4(), _image(), 0, height_above_ground_m=height)


@pytest.mark.parametrize("content", ["[]", "null", "[1, 2]", '"K"', "3", '{"K": null}'])
def test_calibration_json_of_the_wrong_shape_is_named(tmp_path, content):
    path = tmp_path / "cal.json"
    path.write_text(content)
    with pytest.raises(InvalidInputError, match="--calibration"):
        load_calibration(path)


@pytest.mark.parametrize(
    ("content", "missing"),
    [('{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}', "image_size"), ('{"image_size": [4, 3]}', "K")],
)
def test_a_calibration_without_a_required_key_names_the_key_and_what_it_holds(
    tmp_path, content, missing
):
    path = tmp_path / "cal.json"
    path.write_text(content)
    with pytest.raises(InvalidInputError, match=f'missing key "{missing}" \\(.+px'):
        load_calibration(path)


def test_calibration_not_utf8_is_named(tmp_path):
    path = tmp_path / "cal.json"
    path.write_bytes(b"\xff\xfe{")
    with pytest.raises(InvalidInputError, match="--calibration"):
        load_calibration(path)


def test_an_endless_calibration_is_refused_unread():
    """``--calibration /dev/zero`` (or a disk, an image): refused, not read into memory whole."""
    with pytest.raises(InvalidInputError, match="--calibration /dev/zero.*not a calibration"):
        load_calibration(Path("/dev/zero"))


def test_non_utf8_config_is_a_configuration_error(tmp_path):
    path = tmp_path / "c3.toml"
    path.write_bytes(b'[matcher]\nstrategy = "\xff\xfe"\n')
    with pytest.raises(ConfigurationError, match="--config.*UTF-8"):
        load_settings(path, env={})


def test_config_that_is_a_directory_is_a_configuration_error(tmp_path):
    with pytest.raises(ConfigurationError, match="--config"):
        load_settings(tmp_path, env={})


def test_bad_json_in_an_env_table_names_the_variable():
    with pytest.raises(ConfigurationError, match="C3_MATCHER_MATCHER__OPTIONS"):
        load_settings(env={"C3_MATCHER_MATCHER__OPTIONS": "not json"})
    assert json.dumps  # env values that are tables or lists are JSON
