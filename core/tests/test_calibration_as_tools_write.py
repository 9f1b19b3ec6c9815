"""Calibrations as real calibration tools write them: a lens model named (OpenCV's by ROS's and
Kalibr's names; a fisheye one refused by name, never read as k1, k2, p1, p2), a mount printed
to 4 decimals (taken as its nearest rotation), a ROS or Kalibr YAML given for the JSON (how its
fields map), and a focal length in mm (refused, not matched to "no inliers")."""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher import camera as cam
from c3_matcher.cli import main
from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration

from .demo_match import DEMO, DEMO_MATCH

SHIPPED = json.loads((DEMO / "calibration.json").read_text())
FISHEYE_4 = [-0.0079, 0.0437, -0.0418, 0.0079]  # a T265-like Kannala-Brandt lens


def _written(tmp_path: Path, **values: Any) -> Path:
    """The demo's calibration with ``values`` replaced."""
    path = tmp_path / "cal.json"
    path.write_text(json.dumps({**SHIPPED, **values}))
    return path


def _refusal(path: Path) -> str:
    with pytest.raises(InvalidInputError) as refused:
        load_calibration(path)
    assert "\n" not in str(refused.value)
    return refused.value.reason


# --- distortion_model ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("model", "distortion"),
    [
        ("opencv", SHIPPED["distortion"]),
        ("opencv", []),
        ("plumb_bob", SHIPPED["distortion"]),
        ("rational_polynomial", [-0.12, 0.03, 0.0005, -0.0004, 0.0, 0.01, 0.0, 0.0]),
        ("radtan", SHIPPED["distortion"][:4]),
        ("none", []),
        ("plumb_bob", []),  # a rectified or simulated camera, as ROS drivers publish it
        ("rational_polynomial", []),
    ],
)
def test_opencv_models_named_as_opencv_ros_or_kalibr_name_them_load(
    tmp_path: Path, model: str, distortion: list[float]
) -> None:
    """The key was refused as unknown; now each name of OpenCV's model is read as that model."""
    path = _written(tmp_path, distortion_model=model, distortion=distortion)
    assert load_calibration(path).distortion.tolist() == distortion


@pytest.mark.parametrize("model", ["equidistant", "fisheye", "Kannala-Brandt", "kb4", "omni"])
def test_a_fisheye_model_is_refused_by_name_saying_what_to_do(tmp_path: Path, model: str) -> None:
    """Kalibr's ``equidistant`` 4 numbers were read as k1, k2, p1, p2 (footprint off by up to
    31 m at 30 m height): naming the model now refuses them as a lens model not supported."""
    reason = _refusal(_written(tmp_path, distortion_model=model, distortion=FISHEYE_4))
    assert reason.startswith(f"distortion_model: {model!r} is a fisheye or omnidirectional lens")
    assert "not supported" in reason and "undistort the frames first" in reason
    assert "calibrate the camera with OpenCV's model" in reason


@pytest.mark.parametrize(
    ("values", "said"),
    [
        (
            {"distortion_model": "plumb_bob", "distortion": FISHEYE_4},
            "distortion: distortion_model 'plumb_bob' takes 0 or 5 coefficients, got 4",
        ),
        (
            {"distortion_model": "rational_polynomial"},
            "distortion: distortion_model 'rational_polynomial' takes 0 or 8 or 12 or 14"
            " coefficients, got 5",
        ),
        ({"distortion_model": "pinhole-ish"}, "distortion_model: unknown model 'pinhole-ish'"),
        ({"distortion_model": 4}, 'distortion_model: expected one of "opencv", "plumb_bob"'),
    ],
)
def test_a_model_and_coefficients_that_disagree_are_refused(
    tmp_path: Path, values: dict[str, Any], said: str
) -> None:
    assert _refusal(_written(tmp_path, **values)).startswith(said)


# --- camera_to_body ------------------------------------------------------------------------


def _mount_4dp(degrees: float) -> np.ndarray:
    """The default mount tilted ``degrees`` about the body's x axis, printed to 4 decimals."""
    return np.round(cam.rot_x(math.radians(degrees)) @ cam.DEFAULT_BODY_FROM_CAMERA, 4)


def test_a_mount_printed_to_4_decimals_is_taken_as_its_nearest_rotation() -> None:
    """A 45 deg mount written as 0.7071 was refused as "must be a rotation matrix"."""
    k = CameraCalibration.pinhole(640, 480, 560.0).K
    printed = _mount_4dp(45.0)
    first = CameraCalibration(k, np.zeros(0), (640, 480), camera_to_body=printed)
    again = CameraCalibration(k, np.zeros(0), (640, 480), camera_to_body=printed)
    r = first.camera_to_body
    assert r is not None and again.camera_to_body is not None
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-14)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-14)
    exact = cam.rot_x(math.radians(45.0)) @ cam.DEFAULT_BODY_FROM_CAMERA
    np.testing.assert_allclose(r, exact, atol=1e-4)
    assert np.array_equal(r, again.camera_to_body)  # deterministic
    assert not r.flags.writeable


@pytest.mark.parametrize(
    ("mount", "said"),
    [
        (np.diag([1.0, 1.0, 1.01]), "must be a rotation matrix: max |R^T R - I| is 0.0201, more "
         "than 0.001"),
        (np.round(np.eye(3) * 0.7071, 4), "must be a rotation matrix: max |R^T R - I| is 0.5"),
        (np.diag([1.0, 1.0, -1.0]), "is a reflection (determinant -1), not a rotation"),
        (np.round(np.diag([-1.0, 1.0, 1.0]) @ _mount_4dp(30.0), 4), "is a reflection"),
    ],
)  # fmt: skip
def test_a_mount_that_is_no_rotation_is_refused_naming_why(mount: np.ndarray, said: str) -> None:
    k = CameraCalibration.pinhole(640, 480, 560.0).K
    with pytest.raises(InvalidInputError) as refused:
        CameraCalibration(k, np.zeros(0), (640, 480), camera_to_body=mount)
    assert refused.value.field == "calibration.camera_to_body"
    assert refused.value.reason.startswith(said), refused.value.reason


def test_the_demo_matches_alike_with_its_roll_in_a_mount_printed_to_4_decimals(
    tmp_path: Path,
) -> None:
    """The real path: the demo frame (roll 18 deg, default mount) given level with the roll in
    its mount, written to 4 decimals, is matched to the same place (was refused, exit 2)."""
    demo = json.loads((DEMO / "demo.json").read_text())
    ids = [x for t in demo["tiles"] for x in ("--tile-id", ",".join(map(str, t["tile_id"])))]
    path = _written(tmp_path, camera_to_body=_mount_4dp(18.0).tolist())
    rolled = [*DEMO_MATCH, *ids, "--fdr", str(tmp_path / "fdr.jsonl")]
    level = [*rolled]
    level[level.index("--calibration") + 1] = str(path)
    level[level.index("--attitude") + 1] = "0,0,120"
    results = []
    for argv in (rolled, level):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            assert main(argv) == 0
        results.append(json.loads(out.getvalue()))
    given, printed = results
    assert printed["best_candidate_idx"] == given["best_candidate_idx"]
    assert printed["centre_lat"] == pytest.approx(given["centre_lat"], abs=1e-7)  # ~1 cm
    assert printed["centre_lon"] == pytest.approx(given["centre_lon"], abs=1e-7)


# --- a calibration file that is not JSON ---------------------------------------------------

ROS_CAMERA_INFO = """image_width: 640
image_height: 480
camera_name: nav
camera_matrix:
  rows: 3
  cols: 3
  data: [560.0, 0.0, 323.0, 0.0, 560.0, 237.5, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.12, 0.03, 0.0005, -0.0004, 0.0]
"""
KALIBR_CAMCHAIN = """cam0:
  camera_model: pinhole
  distortion_coeffs: [0.1, 0.01, -0.002, 0.0003]
  distortion_model: radtan
  intrinsics: [560.0, 560.0, 323.0, 237.5]
  resolution: [640, 480]
  rostopic: /cam0/image_raw
"""


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            ROS_CAMERA_INFO,
            "it looks like a ROS camera_info YAML: write it as JSON, K the rows of "
            "camera_matrix.data, distortion its distortion_coefficients.data",
        ),
        (
            KALIBR_CAMCHAIN,
            "it looks like a Kalibr camchain YAML: write the camera as JSON, K [[fu, 0, pu], "
            "[0, fv, pv], [0, 0, 1]] from intrinsics [fu, fv, pu, pv]",
        ),
        ("K = 560\n", ""),
    ],
    ids=["ros-camera-info", "kalibr-camchain", "other-text"],
)
def test_a_file_that_is_not_json_is_said_so_with_how_its_fields_map(
    tmp_path: Path, text: str, said: str
) -> None:
    """A ROS or Kalibr YAML was "unreadable: Expecting value: line 1 column 1 (char 0)"."""
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    reason = _refusal(path)
    assert reason.startswith("not JSON (Expecting value: line 1 column 1 (char 0))"), reason
    assert said in reason
    assert ("image_size" in reason) == bool(said)


# --- a focal length in mm ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("k", "said"),
    [
        ([[4.5, 0, 323.0], [0, 4.5, 237.5], [0, 0, 1]], "fx = 4.5 px is below 28 px"),
        ([[560.0, 0, 323.0], [0, 20.0, 237.5], [0, 0, 1]], "fy = 20 px is below 21 px"),
    ],
)
def test_a_focal_length_in_mm_is_refused(tmp_path: Path, k: list[list[float]], said: str) -> None:
    """fx = 4.5 on a 640 px image (a 178 deg field of view) was taken and ended in "no
    inliers"; below width / (2 tan 85 deg) K is refused."""
    reason = _refusal(_written(tmp_path, K=k))
    assert reason.startswith(f"calibration.K: {said}"), reason
    assert reason.endswith("(a focal length in mm?)")


def test_no_shipped_calibration_comes_near_the_focal_bound() -> None:
    """Every shipped calibration has fx, fy at least 10 times the bound (a 170 deg view)."""
    bound = 1.0 / (2.0 * math.tan(math.radians(85.0)))
    shipped = sorted((DEMO.parent).glob("**/calibration*.json"))
    assert len(shipped) > 1
    for path in shipped:
        calibration = load_calibration(path)
        width, height = calibration.image_size
        assert calibration.K[0, 0] > 10 * bound * width, path
        assert calibration.K[1, 1] > 10 * bound * height, path


def test_a_mount_that_is_a_rotation_to_float_precision_is_used_as_given() -> None:
    """Only a mount written to a few decimals is moved to its nearest rotation: an exact one
    keeps its bits (results stay those of earlier versions)."""
    c, s = np.cos(0.3), np.sin(0.3)
    mount = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    )
    cal = CameraCalibration(
        np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]]), np.zeros(5), (320, 240), mount
    )
    assert cal.camera_to_body is not None and cal.camera_to_body.tobytes() == mount.tobytes()
