"""Configuration values that used to pass silently or crash later, and ``c3-matcher config``
output that used to be invalid TOML or an internal error: each now refused naming the key, or
printed so that it reads back as it was."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from c3_matcher.config import load_settings
from c3_matcher.config_sources import MAX_TOML_BYTES
from c3_matcher.errors import ConfigurationError


def _fields(exc: ConfigurationError) -> list[str]:
    return [field for field, _ in exc.problems]


def test_a_ransac_seed_beyond_opencvs_c_int_is_refused_at_load() -> None:
    """It used to pass and fail at ``match`` as ``internal error: ValueError: integer won't fit
    into a C int`` (OpenCV's USAC generator state)."""
    assert load_settings(env={"C3_MATCHER_MATCHER__RANSAC_SEED": "2147483647"}).matcher
    with pytest.raises(ConfigurationError) as info:
        load_settings(env={"C3_MATCHER_MATCHER__RANSAC_SEED": "2147483648"})
    assert _fields(info.value) == ["matcher.ransac_seed"]


@pytest.mark.parametrize(
    ("key", "largest"),
    [
        ("MATCHER__MIN_INLIERS_THRESHOLD", 8192),
        ("LIGHTGLUE__EXIT_MATCHES", 8192),
    ],
)
def test_a_count_no_frame_can_reach_is_refused_at_load(key: str, largest: int) -> None:
    """Inliers and mutual matches never exceed the largest keypoint budget: a threshold above
    it used to load and then fail every frame (or the start-up probe, blaming the engine)."""
    section, name = key.lower().split("__")
    assert getattr(getattr(load_settings(env={f"C3_MATCHER_{key}": str(largest)}), section), name)
    with pytest.raises(ConfigurationError) as info:
        load_settings(env={f"C3_MATCHER_{key}": str(largest + 1)})
    assert _fields(info.value) == [f"{section}.{name}"]


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("[matcher]\ntile_cache_size = true\n", "matcher.tile_cache_size"),
        ("[matcher]\nransac_seed = true\n", "matcher.ransac_seed"),
        ("[matcher]\nmax_keypoints = true\n", "matcher.max_keypoints"),
        ("[lightglue]\nfilter_threshold = false\n", "lightglue.filter_threshold"),
        ("[lightglue]\nexit_matches = true\n", "lightglue.exit_matches"),
        ("[engines]\ndevice_id = true\n", "engines.device_id"),
    ],
)
def test_a_boolean_is_not_a_number(tmp_path: Path, text: str, field: str) -> None:
    """``true`` used to be taken as 1 and ``false`` as 0.0."""
    toml = tmp_path / "c3.toml"
    toml.write_text(text)
    with pytest.raises(ConfigurationError) as info:
        load_settings(toml, env={})
    ((named, reason),) = info.value.problems
    assert named == field and "got the boolean" in reason


def test_booleans_still_set_switches(tmp_path: Path) -> None:
    toml = tmp_path / "c3.toml"
    toml.write_text("[matcher]\nrefine = true\nstored_features = false\n")
    settings = load_settings(toml, env={"C3_MATCHER_ENGINES__TENSORRT_FP16": "1"})
    assert (settings.matcher.refine, settings.matcher.stored_features) == (True, False)
    assert settings.engines.tensorrt_fp16 is True


@pytest.mark.parametrize(
    ("variable", "field"),
    [
        ("C3_MATCHER_ENGINES__DIRECTORY", "engines.directory"),
        ("C3_MATCHER_ENGINES__TENSORRT_CACHE_DIR", "engines.tensorrt_cache_dir"),
        ("C3_MATCHER_FDR__PATH", "fdr.path"),
    ],
)
def test_an_empty_path_is_refused_not_taken_as_the_working_directory(
    tmp_path: Path, variable: str, field: str
) -> None:
    """``C3_MATCHER_FDR__PATH=$UNSET`` used to become ``.``."""
    with pytest.raises(ConfigurationError) as info:
        load_settings(env={variable: ""})
    assert [(f, "is empty" in r) for f, r in info.value.problems] == [(field, True)]
    section, key = field.split(".")
    toml = tmp_path / "c3.toml"
    toml.write_text(f'[{section}]\n{key} = ""\n')
    with pytest.raises(ConfigurationError) as info:
        load_settings(toml, env={})
    assert [(f, "is empty" in r) for f, r in info.value.problems] == [(field, True)]


def test_a_config_file_too_large_to_be_one_is_refused_unread(tmp_path: Path) -> None:
    """``--config`` naming a disk image or ``/dev/zero`` used to be read whole (MemoryError)."""
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * MAX_TOML_BYTES + b"\n")
    with pytest.raises(ConfigurationError) as info:
        load_settings(big, env={})
    ((named, reason),) = info.value.problems
    assert named == "--config" and reason.startswith(f"larger than {MAX_TOML_BYTES} bytes")


def test_bad_json_for_a_whole_section_names_its_variable() -> None:
    """``C3_MATCHER_MATCHER=nan`` used to be blamed on "environment"."""
    with pytest.raises(ConfigurationError) as info:
        load_settings(env={"C3_MATCHER_MATCHER": "nan"})
    assert _fields(info.value) == ["C3_MATCHER_MATCHER"]


ODD_OPTIONS = {
    "xfeat": {
        "a b": 1,
        "a.b": 2,
        "": {"inner key": "x"},
        "tables": [{"b": 1, "c d": [1.5, "y"]}],
        "text": 'tab\tline\nquote" backslash\\ del\x7f emoji \U0001f600 e-acute \u00e9',
    },
    "my strategy": {"k": True},
}


def test_config_toml_reads_back_whatever_the_option_keys(
    clean_env: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Keys with spaces, dots or nothing, tables inside lists and characters beyond the BMP
    used to give invalid TOML (or another value: ``a.b = 2`` reads back as a table), or an
    internal error (a table in a list). (``config`` itself refuses these tables: no strategy
    takes such keys; a third party's options model may.)"""
    from c3_matcher.cli import to_toml

    clean_env.setenv("C3_MATCHER_MATCHER__OPTIONS", json.dumps(ODD_OPTIONS))
    text = to_toml(load_settings().model_dump(mode="json"))
    assert text.isascii()
    assert tomllib.loads(text)["matcher"]["options"] == ODD_OPTIONS
    saved = tmp_path / "c3.toml"
    saved.write_text(text)
    clean_env.delenv("C3_MATCHER_MATCHER__OPTIONS")
    assert load_settings(saved).matcher.options == ODD_OPTIONS


def test_config_names_a_value_toml_cannot_express() -> None:
    """A null inside a list (JSON from the environment) used to be ``internal error:
    TypeError: no TOML form for NoneType``; ``--json`` prints it."""
    from c3_matcher.cli import to_toml
    from c3_matcher.errors import InvalidInputError

    with pytest.raises(InvalidInputError) as info:
        to_toml({"matcher": {"options": {"mine": {"a": [1, None]}}}})
    assert "matcher.options.mine.a[1]" in str(info.value) and "--json" in str(info.value)


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ({"xfaet": {"matcher": "lighterglue"}}, "matcher.options.xfaet"),
        ({"xfeat": {"matchr": "lighterglue"}}, "matcher.options.xfeat.matchr"),
    ],
)
def test_config_refuses_options_start_up_would_refuse(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], options: dict, named: str
) -> None:
    """``config`` said a misspelt strategy table or option was good, and printed it; the
    first ``match`` or ``replay`` then refused it."""
    from c3_matcher.cli import main

    clean_env.setenv("C3_MATCHER_MATCHER__OPTIONS", json.dumps(options))
    assert main(["config"]) == 2
    err = capsys.readouterr().err
    assert named in err and "internal error" not in err


def test_config_refuses_a_strategy_this_install_does_not_link(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``config`` says whether a configuration is good: a strategy no installed plugin offers
    is refused there (exit 2, naming the strategies there are), as ``match`` refuses it; it
    was printed as the effective configuration, exit 0."""
    from c3_matcher.cli import main

    clean_env.setenv("C3_MATCHER_MATCHER__STRATEGY", "nope")
    assert main(["config"]) == 2
    err = capsys.readouterr().err
    assert "'nope'" in err and "disk_lightglue" in err and "internal error" not in err


def test_a_word_where_a_list_belongs_is_told_the_form_a_list_takes(
    clean_env: pytest.MonkeyPatch,
) -> None:
    """``C3_MATCHER_ENGINES__PROVIDERS=cpu`` said only 'Input should be a valid tuple'."""
    clean_env.setenv("C3_MATCHER_ENGINES__PROVIDERS", "cpu")
    with pytest.raises(ConfigurationError) as info:
        load_settings()
    assert "engines.providers" in str(info.value) and "got 'cpu': give a list" in str(info.value)
    assert "(in the environment, as JSON)" in str(info.value)


def test_config_prints_a_strategy_this_build_knows_but_does_not_link(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An operator-tooling install links no DISK, the default: its configuration is still good
    and ``config`` prints it (``match`` says what to install)."""
    from c3_matcher.cli import main
    from c3_matcher.errors import StrategyNotLinkedError
    from c3_matcher.plugins.manager import PluginHost

    def not_linked(self: PluginHost, strategy: str) -> None:
        raise StrategyNotLinkedError(
            strategy, "BUILD_MATCHER_DISK_LIGHTGLUE", "operator-tooling", ""
        )

    clean_env.setattr(PluginHost, "resolve", not_linked)
    assert main(["config", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["matcher"]["strategy"] == "disk_lightglue"


def test_an_options_table_no_installed_strategy_has_is_refused_at_start_up(
    clean_env: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A misspelt ``[matcher.options.xfet]`` left the strategy on its defaults, silently; a
    table of another installed strategy is held to that strategy's options."""
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.config import C3Settings
    from c3_matcher.fdr import InMemoryFdr

    for options, field in (
        ({"xfet": {"matcher": "lighterglue"}}, "matcher.options.xfet"),
        ({"xfeat": {"matcher": "bogus"}}, "matcher.options.xfeat.matcher"),
    ):
        settings = C3Settings(
            matcher={"strategy": "disk_lightglue", "options": options},
            engines={"directory": tmp_path},
        )
        helpers = {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()}
        with pytest.raises(ConfigurationError) as refused:
            compose_root(settings, helpers, configure_logs=False)
        assert _fields(refused.value) == [field]


@pytest.mark.parametrize("nested", ["[" * 5000 + "]" * 5000, "{ a = " * 3000 + "1" + " }" * 3000])
def test_a_config_nested_too_deep_is_refused_naming_the_file(tmp_path: Path, nested: str) -> None:
    """Arrays or inline tables nested thousands deep used to escape as RecursionError."""
    toml = tmp_path / "c3.toml"
    toml.write_text(f"[matcher]\nx = {nested}\n")
    with pytest.raises(ConfigurationError) as info:
        load_settings(toml, env={})
    assert list(info.value.problems) == [
        (
            "--config",
            "unreadable TOML: nested too deep to read (arrays or objects inside about 1000 others)",
        )
    ]


def test_json_nested_too_deep_in_the_environment_is_a_configuration_error() -> None:
    deep = '{"x": {"y": ' + "[" * 5000 + "]" * 5000 + "}}"
    with pytest.raises(ConfigurationError, match="not valid JSON"):
        load_settings(env={"C3_MATCHER_MATCHER__OPTIONS": deep})


@pytest.mark.parametrize(
    ("variable", "field"),
    [
        ("C3_MATCHER_ENGINES__DIRECTORY", "engines.directory"),
        ("C3_MATCHER_ENGINES__TENSORRT_CACHE_DIR", "engines.tensorrt_cache_dir"),
        ("C3_MATCHER_FDR__PATH", "fdr.path"),
    ],
)
def test_a_path_beginning_with_a_tilde_is_under_the_users_home(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, variable: str, field: str
) -> None:
    """``[engines] directory = "~/engines"`` used to name a folder ``~`` in the working
    directory (the FDR's recorder alone expanded its own path)."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    section, key = field.split(".")
    toml = tmp_path / "c3.toml"
    toml.write_text(f'[{section}]\n{key} = "~/from-toml"\n')
    from_toml = getattr(getattr(load_settings(toml, env={}), section), key)
    from_env = getattr(getattr(load_settings(env={variable: "~/from-env"}), section), key)
    assert (from_toml, from_env) == (tmp_path / "home/from-toml", tmp_path / "home/from-env")
