"""Property-based tests (hypothesis): bad values of every type reach a contract error
(``InvalidInputError`` / ``ConfigurationError``) or exit 2, never another exception."""

from __future__ import annotations

import contextlib
import json
import math
import tempfile
import uuid
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from c3_matcher.config import C3Settings, load_settings
from c3_matcher.dto import Attitude, CameraCalibration, NavCameraFrame, TileId
from c3_matcher.errors import ConfigurationError, InvalidInputError
from c3_matcher.fdr import read_fdr
from c3_matcher.serialize import load_calibration

FAST = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))

anything = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.binary(max_size=8),
    st.lists(st.integers(), max_size=3),
    st.just(np.float32(np.nan)),
    st.just(np.int64(-1)),
)


@FAST
@given(zoom=anything, lat=anything, lon=anything)
def test_tile_id_accepts_or_names_the_field(zoom, lat, lon):
    try:
        t = TileId(zoom, lat, lon)
    except InvalidInputError as exc:
        assert exc.field.startswith("tile_id.")
    else:
        assert 0 <= t.zoom <= 30 and math.isfinite(t.lat) and math.isfinite(t.lon)


@FAST
@given(roll=anything, pitch=anything, yaw=anything)
def test_attitude_accepts_or_names_the_field(roll, pitch, yaw):
    try:
        Attitude(roll, pitch, yaw)
    except InvalidInputError as exc:
        assert exc.field.startswith("attitude.")


arrays = st.builds(
    lambda shape, dtype, fill: np.full(shape, fill).astype(dtype, casting="unsafe"),
    st.lists(st.integers(0, 40), min_size=0, max_size=4).map(tuple),
    st.sampled_from([np.uint8, np.float32, np.float64, np.int64, np.bool_]),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
)


@FAST
@given(
    image=st.one_of(arrays, anything),
    stamp=anything,
    height=st.one_of(st.none(), anything),
    frame_id=st.one_of(st.just(uuid.UUID(int=1)), anything),
)
def test_nav_camera_frame_accepts_or_names_the_field(image, stamp, height, frame_id):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            NavCameraFrame(frame_id, image, stamp, height_above_ground_m=height)
        except InvalidInputError as exc:
            assert exc.field.startswith("frame.")


@FAST
@given(
    k=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=9, max_size=9),
    dist=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=6),
    size=st.tuples(anything, anything),
)
def test_calibration_accepts_or_names_the_field(k, dist, size):
    try:
        cal = CameraCalibration(
            np.array(k, dtype=np.float64).reshape(3, 3), np.array(dist, dtype=np.float64), size
        )
    except InvalidInputError as exc:
        assert exc.field.startswith("calibration.")
    else:
        np.linalg.inv(cal.K)  # whatever is accepted is usable


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=5)),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=12), inner, max_size=4)
    ),
    max_leaves=12,
)
calibration_like = st.fixed_dictionaries(
    {},
    optional={
        "K": json_values,
        "distortion": json_values,
        "image_size": json_values,
        "camera_to_body": json_values,
    },
)


@FAST
@given(value=st.one_of(json_values, calibration_like))
def test_calibration_files_load_or_are_named(value):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "cal.json"
        path.write_text(json.dumps(value))
        try:
            load_calibration(path)
        except InvalidInputError as exc:
            assert "--calibration" in exc.field


def _env_keys() -> list[str]:
    keys = []
    for section, field in C3Settings.model_fields.items():
        for name in getattr(field.annotation, "model_fields", {}):
            keys.append(f"C3_MATCHER_{section.upper()}__{name.upper()}")
    return keys


@FAST
@given(
    key=st.sampled_from(_env_keys()),
    value=st.one_of(
        st.text(max_size=20).filter(lambda s: "\0" not in s),
        st.sampled_from(["inf", "-1", "nan", "1e400", "[]", "{}", "null", "true", "[1,", '"x"']),
    ),
)
def test_any_environment_value_loads_or_is_a_configuration_error(key, value):
    try:
        load_settings(env={key: value})
    except ConfigurationError as exc:
        assert exc.problems


@FAST
@given(content=st.binary(max_size=200))
def test_any_config_file_loads_or_is_a_configuration_error(content):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "c3.toml"
        path.write_bytes(content)
        with contextlib.suppress(ConfigurationError):
            load_settings(path, env={})


toml_scalars = st.one_of(
    st.integers(min_value=-(2**40), max_value=2**40).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(
        lambda f: "nan" if math.isnan(f) else ("inf" if f == math.inf else repr(f))
    ),
    st.text(max_size=6).map(json.dumps),
    st.sampled_from(["true", "[]", "[1, 2]", "{}", '["CUDA"]', '"CPU"']),
)


@FAST
@given(
    section=st.sampled_from(["matcher", "engines", "fdr", "logging"]),
    key=st.sampled_from(
        [
            "strategy",
            "min_inliers_threshold",
            "ransac_threshold_px",
            "residual_warn_threshold_px",
            "max_long_side",
            "max_keypoints",
            "tile_cache_size",
            "max_image_pixels",
            "providers",
            "device_id",
            "intra_op_threads",
            "max_bytes",
            "level",
            "nonsense",
        ]
    ),
    value=toml_scalars,
)
def test_any_toml_value_loads_or_names_the_field(section, key, value):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "c3.toml"
        path.write_text(f"[{section}]\n{key} = {value}\n")
        try:
            s = load_settings(path, env={})
        except ConfigurationError as exc:
            assert exc.problems
        else:
            m = s.matcher
            assert math.isfinite(m.ransac_threshold_px)
            assert math.isfinite(m.residual_warn_threshold_px)


@FAST
@given(content=st.binary(max_size=300))
def test_read_fdr_never_raises_and_accounts_for_every_line(content):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "x.jsonl"
        path.write_bytes(content)
        result = read_fdr(path)
        lines = content.split(b"\n")
        complete = len(lines) - 1
        torn = 1 if lines[-1] else 0
        assert len(result) + len(result.corrupt) == complete + torn


@pytest.fixture(scope="module")
def cli_main():
    from c3_matcher.cli import main

    return main


def _exit_code(main, argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


cli_text = st.one_of(
    st.text(max_size=12).filter(lambda s: "\0" not in s and not s.startswith("-")),
    st.sampled_from(["-5", "-28", "nan", "inf", "1e400", "0", "1,2", "1,2,3", "a,b,c", ""]),
)


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(
    flag=st.sampled_from(["--attitude", "--tile-id", "--height", "--tile-gsd", "--strategy"]),
    value=cli_text,
)
def test_match_arguments_exit_2_never_a_traceback(cli_main, capsys, flag, value):
    code = _exit_code(
        cli_main,
        ["match", "--query", "/nonexistent/q.jpg", "--tile", "/nonexistent/t.png", flag, value],
    )
    assert code == 2
    capsys.readouterr()


@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
@given(flag=st.sampled_from(["--limit", "--max-keypoints"]), value=cli_text)
def test_replay_arguments_exit_2_never_a_traceback(cli_main, capsys, flag, value):
    code = _exit_code(cli_main, ["replay", "/nonexistent/flight", flag, value])
    assert code == 2
    capsys.readouterr()
