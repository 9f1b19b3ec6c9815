"""``c3-matcher config`` shows what a run of the configuration does: the values the configured
strategy gives the settings left unset (each a comment saying whose it is, so the TOML read back
is the same configuration), its options' defaults, the ``[lightglue]`` values it does not read
(warned on stderr, as start-up logs them), and configured execution providers this machine
lacks (warned, exit 0: a file may be written for another machine). It printed "unset, the
default applies" for every strategy alike, and passed a provider list start-up then refused."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.cli import main
from c3_matcher.config import load_settings

XFEAT = "C3_MATCHER_MATCHER__STRATEGY"
IGNORED = "lightglue.filter_threshold set, but strategy"


def _config(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[list[str], list[str]]:
    """``c3-matcher [ARGV] config``'s stdout and stderr lines (exit 0)."""
    assert main([*argv, "config"]) == 0, capsys.readouterr().err
    out, err = capsys.readouterr()
    return out.splitlines(), err.splitlines()


def test_each_strategy_shows_the_values_it_runs_with_where_the_settings_leave_them(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """DISK keeps 2048 keypoints and exits a pair under 8 matches; XFeat keeps 4096 and does not
    match with LightGlue: the two printed the same lines but ``strategy =``."""
    disk, _ = _config(capsys)
    assert "# max_keypoints = 2048  # unset: the keypoints per image disk_lightglue keeps" in disk
    assert "# exit_matches = 8  # unset: disk_lightglue's default" in disk
    assert "# filter_threshold = 0.1  # unset: disk_lightglue's default" in disk
    assert '# photometric = "none"  # unset: disk_lightglue\'s default' in disk
    assert "# refit_threshold_px = 2.0  # unset: disk_lightglue's default" in disk
    clean_env.setenv(XFEAT, "xfeat")
    xfeat, _ = _config(capsys)
    assert "# max_keypoints = 4096  # unset: the keypoints per image xfeat keeps" in xfeat
    at = xfeat.index("[lightglue]")
    assert xfeat[at + 1].startswith("# strategy xfeat does not match with LightGlue")
    assert "# exit_matches: unset, the default applies" in xfeat  # not xfeat's to resolve
    options = xfeat.index("# [matcher.options.xfeat]")  # its options' defaults, all unset
    assert xfeat[options + 1 : options + 3] == [
        '# matcher = "mnn"  # unset: xfeat\'s default',
        "# min_cossim = 0.82  # unset: xfeat's default",
    ]


def test_the_values_shown_read_back_as_the_same_configuration(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Shown as comments, they stay unset: the file then runs another strategy its own way."""
    clean_env.setenv(XFEAT, "xfeat")
    clean_env.setenv("C3_MATCHER_MATCHER__OPTIONS__XFEAT__MIN_COSSIM", "0.5")
    given = _config_json(capsys)
    lines, _ = _config(capsys)
    text = "\n".join(lines) + "\n"
    assert tomllib.loads(text)["matcher"]["options"] == {"xfeat": {"min_cossim": 0.5}}
    saved = tmp_path / "c3.toml"
    saved.write_text(text)
    clean_env.delenv(XFEAT)
    clean_env.delenv("C3_MATCHER_MATCHER__OPTIONS__XFEAT__MIN_COSSIM")
    assert _config_json(capsys, "--config", str(saved)) == given
    assert given["matcher"]["photometric"] is None and given["lightglue"]["exit_matches"] is None


def _config_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    assert main([*argv, "config", "--json"]) == 0, capsys.readouterr().err
    data: dict[str, Any] = json.loads(capsys.readouterr().out)
    return data


def test_a_strategy_not_installed_is_said_and_its_settings_printed_as_given(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.errors import StrategyNotLinkedError
    from c3_matcher.plugins.manager import PluginHost

    def not_linked(self: PluginHost, strategy: str) -> None:
        raise StrategyNotLinkedError(strategy, "BUILD_MATCHER_DISK_LIGHTGLUE", "operator", "")

    clean_env.setattr(PluginHost, "resolve", not_linked)
    lines, err = _config(capsys)
    assert lines[1].startswith("# strategy disk_lightglue is not installed here"), lines[:3]
    assert "# photometric: unset, the default applies" in lines
    assert "# exit_matches: unset, the default applies" in lines
    assert err == []


@pytest.mark.parametrize(
    ("strategy", "options", "warned"),
    [
        ("xfeat", "{}", True),  # mutual nearest neighbours: no LightGlue
        ("sift_magsac", "{}", True),
        ("xfeat", '{"xfeat": {"matcher": "lighterglue"}}', False),
        ("disk_lightglue", "{}", False),
    ],
)
def test_lightglue_values_the_strategy_does_not_read_are_warned_not_refused(
    clean_env: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    strategy: str,
    options: str,
    warned: bool,
) -> None:
    clean_env.setenv(XFEAT, strategy)
    clean_env.setenv("C3_MATCHER_MATCHER__OPTIONS", options)
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD", "0.99")
    _, err = _config(capsys)
    said = [line for line in err if IGNORED in line]
    if warned:
        assert said == [
            f"c3-matcher: warning: {IGNORED} {strategy} does not match with "
            "LightGlue and reads no [lightglue] setting: its run is the same "
            "without it (remove it, or choose a strategy or pair matcher that "
            "uses LightGlue)"
        ], err
    else:
        assert said == [], err


def test_a_file_config_wrote_for_disk_runs_xfeat_without_a_word(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """It holds ``[lightglue] mode = "auto"``, the default: nothing the user set is unread."""
    lines, _ = _config(capsys)
    saved = tmp_path / "c3.toml"
    saved.write_text("\n".join(lines) + "\n")
    clean_env.setenv(XFEAT, "xfeat")
    _, err = _config(capsys, "--config", str(saved))
    assert err == []


def test_providers_this_machine_lacks_are_warned_as_start_up_resolves_them(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """CoreML is never installed on Linux: start-up refuses it alone, and leaves it out beside
    the CPU; ``config`` exited 0 without a word either way."""
    from c3_matcher.engines.runtime import OnnxInferenceRuntime
    from c3_matcher.errors import ConfigurationError

    clean_env.setenv("C3_MATCHER_ENGINES__PROVIDERS", '["CoreML"]')
    _, err = _config(capsys)
    (line,) = err
    assert line.startswith("c3-matcher: warning: [engines] providers"), line
    assert "CoreMLExecutionProvider not installed on this machine" in line
    assert "start-up on this machine refuses it" in line
    with pytest.raises(ConfigurationError):  # as start-up does
        OnnxInferenceRuntime.from_settings(load_settings().engines)
    clean_env.setenv("C3_MATCHER_ENGINES__PROVIDERS", '["CoreML", "CPU"]')
    assert main(["config", "--json"]) == 0  # said with either output
    (line,) = capsys.readouterr().err.splitlines()
    assert "CoreMLExecutionProvider not installed" in line
    assert line.endswith("a run here leaves it out and runs on CPUExecutionProvider"), line
    clean_env.setenv("C3_MATCHER_ENGINES__PROVIDERS", '["CPU"]')
    assert _config(capsys)[1] == []


def test_an_option_the_chosen_matcher_refuses_is_not_shown(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """With ``matcher = "lighterglue"``, XFeat refuses ``min_cossim`` (the mnn matcher's
    threshold): it was shown as ``# min_cossim = 0.82  # unset: xfeat's default``, a line
    refused once uncommented. The option lines shown, uncommented, are taken."""
    clean_env.setenv(XFEAT, "xfeat")
    clean_env.setenv("C3_MATCHER_MATCHER__OPTIONS__XFEAT__MATCHER", "lighterglue")
    lines, _ = _config(capsys)
    at = lines.index("[matcher.options.xfeat]")
    table = lines[at + 1 : lines.index("", at)]
    assert table[0] == 'matcher = "lighterglue"'
    assert not any("min_cossim" in line for line in table), table
    shown = [line for line in table if "  # unset: " in line]
    assert shown == ["# upscale = 1  # unset: xfeat's default"]
    clean_env.delenv("C3_MATCHER_MATCHER__OPTIONS__XFEAT__MATCHER")
    uncommented = {line: line[2:].split("  # ")[0] for line in shown}
    saved = tmp_path / "c3.toml"
    saved.write_text("\n".join(uncommented.get(line, line) for line in lines) + "\n")
    assert _config_json(capsys, "--config", str(saved))["matcher"]["options"] == {
        "xfeat": {"matcher": "lighterglue", "upscale": 1}
    }


@pytest.mark.parametrize("strategy", ["disk_lightglue", "sift_magsac"])
def test_a_strategy_with_no_options_to_show_gets_no_options_table(
    strategy: str, clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """An empty ``[matcher.options.<strategy>]`` read back is not the configuration shown (and a
    flight install without that strategy refuses it): none is written."""
    clean_env.setenv(XFEAT, strategy)
    given = _config_json(capsys)
    lines, _ = _config(capsys)
    assert not any(line.startswith(f"[matcher.options.{strategy}]") for line in lines), lines
    saved = tmp_path / "c3.toml"
    saved.write_text("\n".join(lines) + "\n")
    clean_env.delenv(XFEAT)
    assert (
        _config_json(capsys, "--config", str(saved))["matcher"]["options"]
        == (given["matcher"]["options"])
    )


def test_a_refused_option_names_the_value_refused(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """As the core's own settings do: which value, not only which bound."""
    toml = tmp_path / "c3.toml"
    toml.write_text('[matcher]\nstrategy = "xfeat"\n[matcher.options.xfeat]\nupscale = 9\n')
    assert main(["--config", str(toml), "config"]) == 2
    said = capsys.readouterr().err
    assert "matcher.options.xfeat.upscale: Input should be less than or equal to 4, got 9" in said
