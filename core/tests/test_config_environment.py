"""The environment as a configuration source: a variable that names no setting and no process
switch is refused wherever the settings are read (``load_settings`` and ``C3Settings()``), with
the variable meant when it reads as one; a table the environment sets replaces the file's whole;
``[logging] level`` in any case, as its description says."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from c3_matcher.config import C3Settings, LoggingSettings, load_settings
from c3_matcher.errors import ConfigurationError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.logs import configure_logging, log_event


@pytest.mark.parametrize(
    ("variable", "meant"),
    [
        ("C3_MATCHER_STRATEGY", "C3_MATCHER_MATCHER__STRATEGY"),  # its section left out
        ("C3_MATCHER_ENGINES_PROVIDERS", "C3_MATCHER_ENGINES__PROVIDERS"),  # one underscore
        ("C3_MATCHER_MATCHER_MIN_INLIERS_THRESHOLD", "C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD"),
        ("c3_matcher_logging_level", "C3_MATCHER_LOGGING__LEVEL"),
    ],
)
def test_a_setting_spelt_with_one_underscore_is_refused_naming_the_variable_meant(
    variable: str, meant: str
) -> None:
    """Each was taken for a process switch and ignored: exit 0, the setting unchanged."""
    with pytest.raises(ConfigurationError) as refused:
        load_settings(env={variable: '["CUDA"]' if "PROVIDERS" in variable else "500"})
    ((field, reason),) = refused.value.problems
    assert field == variable and f"did you mean {meant}?" in reason


def test_a_one_word_variable_that_is_no_switch_is_refused_naming_the_switches() -> None:
    with pytest.raises(ConfigurationError) as refused:
        load_settings(env={"C3_MATCHER_TRACEBAK": "1"})
    ((field, reason),) = refused.value.problems
    assert field == "C3_MATCHER_TRACEBAK" and "C3_MATCHER_TRACEBACK" in reason
    assert "<SECTION>__<KEY>" in reason


def test_every_process_switch_the_tree_reads_is_still_no_setting() -> None:
    """Those read with ``os.environ`` (the command's traceback, the tools' fallbacks), and only
    those."""
    switches = ["TRACEBACK", "TOOLS_NO_PYPROJ", "TOOLS_NO_RASTERIO"]
    env = {f"C3_MATCHER_{name}": "1" for name in switches}
    assert load_settings(env=env).matcher.strategy == "disk_lightglue"
    from c3_matcher.config_sources import PROCESS_SWITCHES

    assert sorted(PROCESS_SWITCHES) == sorted(switches)


def test_c3settings_refuses_a_misspelt_section_as_load_settings_does(
    clean_env: pytest.MonkeyPatch,
) -> None:
    """The README's ``C3Settings()`` (the process environment applies) ignored it silently."""
    clean_env.setenv("C3_MATCHER_LIGTHGLUE__FILTER_THRESHOLD", "0.5")
    with pytest.raises(ConfigurationError, match="C3_MATCHER_LIGTHGLUE__FILTER_THRESHOLD"):
        C3Settings()
    clean_env.delenv("C3_MATCHER_LIGTHGLUE__FILTER_THRESHOLD")
    clean_env.setenv("C3_MATCHER_ENGINES_PROVIDERS", '["CPU"]')
    with pytest.raises(ConfigurationError, match="C3_MATCHER_ENGINES__PROVIDERS"):
        C3Settings()
    clean_env.delenv("C3_MATCHER_ENGINES_PROVIDERS")
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD", "0.5")
    clean_env.setenv("C3_MATCHER_TRACEBACK", "1")
    assert C3Settings().lightglue.filter_threshold == 0.5  # a known one still applies


XFEAT_MNN = '[matcher]\nmin_inliers_threshold = 80\n[matcher.options.xfeat]\nmatcher = "mnn"\n'


@pytest.mark.parametrize(
    ("variable", "value", "options"),
    [
        (
            "C3_MATCHER_MATCHER__OPTIONS__XFEAT",
            {"matcher": "lighterglue"},
            {"xfeat": {"matcher": "lighterglue"}, "other": {"a": 1}},
        ),
        (
            "C3_MATCHER_MATCHER__OPTIONS",
            {"xfeat": {"matcher": "lighterglue"}},
            {"xfeat": {"matcher": "lighterglue"}},
        ),
        (
            "C3_MATCHER_MATCHER",
            {"options": {"xfeat": {"matcher": "lighterglue"}}},
            {"xfeat": {"matcher": "lighterglue"}},
        ),
    ],
)
def test_a_table_set_in_the_environment_replaces_the_files_whole(
    tmp_path: Path, variable: str, value: dict[str, object], options: dict[str, object]
) -> None:
    """The file's ``min_cossim`` was merged into the environment's XFeat table, which then
    failed as "remove min_cossim" and could not be mended from the environment."""
    toml = tmp_path / "c3.toml"
    toml.write_text(f"{XFEAT_MNN}min_cossim = 0.5\n[matcher.options.other]\na = 1\n")
    settings = load_settings(toml, env={variable: json.dumps(value)})
    assert settings.matcher.options == options
    assert settings.matcher.min_inliers_threshold == 80  # the section's other settings: the file's


def test_provider_options_set_in_the_environment_replace_the_files(tmp_path: Path) -> None:
    toml = tmp_path / "c3.toml"
    toml.write_text('[engines.provider_options.CUDA]\narena_extend_strategy = "kSameAsRequested"\n')
    given = json.dumps({"CUDAExecutionProvider": {"cudnn_conv_algo_search": "DEFAULT"}})
    env = {"C3_MATCHER_ENGINES__PROVIDER_OPTIONS": given}
    got = load_settings(toml, env=env).engines.provider_options
    assert got == {"CUDAExecutionProvider": {"cudnn_conv_algo_search": "DEFAULT"}}
    assert load_settings(toml, env={}).engines.provider_options == {
        "CUDAExecutionProvider": {"arena_extend_strategy": "kSameAsRequested"}
    }


@pytest.mark.parametrize("given", ["debug", "Warning", "trace", "ERROR"])
def test_the_logging_level_is_read_in_any_case(given: str) -> None:
    settings = load_settings(env={"C3_MATCHER_LOGGING__LEVEL": given})
    assert settings.logging.level == given.upper()


def test_the_logging_level_says_what_it_governs_and_that_is_what_it_does() -> None:
    """It had no description in ``c3-matcher config``."""
    said = LoggingSettings.model_fields["level"].description or ""
    for word in ("TRACE", "DEBUG", "INFO", "WARNING", "ERROR", "stderr", "matcher.log"):
        assert word in said
    assert "recorder takes the WARNING and ERROR records whatever it is" in said
    fdr, stream = InMemoryFdr(), io.StringIO()
    handle = configure_logging(fdr, level=LoggingSettings(level="error").level, stream=stream)
    try:
        log_event("WARNING", "c3.matcher.test_warning", "below the level")
        log_event("INFO", "c3.matcher.test_info", "below it too")
    finally:
        handle.close()
    assert stream.getvalue() == ""  # nothing on stderr below ERROR
    assert [kind for kind, _ in fdr.records] == ["log.warning"]  # the FDR keeps the WARNING
