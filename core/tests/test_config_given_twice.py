"""``--config`` is taken before or after the command's name, once: a second one is refused
(exit 2) naming both files. The last one was read and the first dropped, silently, with every
setting it held."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.config_argument import split_config
from c3_matcher.errors import ConfigurationError


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    first, second = tmp_path / "a.toml", tmp_path / "b.toml"
    first.write_text("[matcher]\nmin_inliers_threshold = 80\n")
    second.write_text("[engines]\nintra_op_threads = 2\n")
    return first, second


@pytest.mark.parametrize(
    "argv",
    [
        ["--config", "{a}", "config", "--config", "{b}"],
        ["--config={a}", "config", "--config={b}"],
        ["config", "--config", "{a}", "--config={b}"],
        ["--conf", "{a}", "--config", "{b}", "config"],
        ["--c={a}", "config", "--config={b}"],
        ["--confi", "{a}", "--co", "{b}", "config"],
    ],
    ids=[
        "before-and-after",
        "equals-forms",
        "both-after",
        "cut-short",
        "cut-short-equals",
        "both-cut",
    ],
)
def test_a_second_config_is_refused_naming_both_files(
    clean_env: pytest.MonkeyPatch,
    files: tuple[Path, Path],
    argv: list[str],
    capsys: pytest.CaptureFixture[str],
) -> None:
    first, second = files
    assert main([arg.format(a=first, b=second) for arg in argv]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    (line,) = err.splitlines()
    assert line.startswith("c3-matcher: invalid configuration (command line): --config: ")
    assert str(first) in line and str(second) in line and "one configuration file" in line


def test_one_config_before_or_after_the_command_is_taken(
    clean_env: pytest.MonkeyPatch, files: tuple[Path, Path]
) -> None:
    first, _ = files
    for argv in (["--config", str(first), "config"], ["config", f"--config={first}"]):
        assert split_config(argv) == (["config"], first)
    assert split_config(["config", "--", "--config", "x"]) == (
        ["config", "--", "--config", "x"],
        None,
    )


def test_split_config_says_which_files_it_was_given() -> None:
    with pytest.raises(ConfigurationError) as refused:
        split_config(["--config", "a.toml", "match", "--config=b.toml"])
    ((field, reason),) = refused.value.problems
    assert field == "--config" and "'a.toml' and 'b.toml'" in reason


def test_config_cut_short_before_the_command_is_read_as_argparse_read_it(
    clean_env: pytest.MonkeyPatch, files: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """Before the command's name, ``--conf FILE`` named the file through argparse's
    abbreviations, past the check for a second one; it is still read, now by ``split_config``.
    After the name it is the command's to read (none has such an option: refused there)."""
    first, _ = files
    for argv in (["--conf", str(first), "config"], [f"--c={first}", "config"]):
        assert split_config(argv) == (["config"], first)
        assert main([*argv, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["matcher"]["min_inliers_threshold"] == 80
    assert split_config(["config", "--conf", "x"]) == (["config", "--conf", "x"], None)
    with pytest.raises(SystemExit) as stopped:
        main(["config", "--conf", str(first)])
    assert stopped.value.code == 2
    assert "unrecognized arguments: --conf" in capsys.readouterr().err


def test_config_without_a_file_is_refused_by_its_full_name(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for argv in (["--conf"], ["--config"]):
        with pytest.raises(SystemExit) as stopped:
            main(argv)
        assert stopped.value.code == 2
        assert "argument --config: expected one argument" in capsys.readouterr().err
