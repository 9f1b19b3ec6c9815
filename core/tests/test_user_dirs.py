"""The default directories outside a checkout (engine cache, TensorRT cache, flight data
recorder) follow the XDG base-directory rule with the standard library alone: the flight
computer's install depends on the design card's run-time dependencies only."""

from __future__ import annotations

import json
import os
import pwd
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from c3_matcher.config import EngineSettings, FdrSettings
from c3_matcher.engines import store
from c3_matcher.errors import ConfigurationError
from c3_matcher.user_dirs import user_cache_dir, user_data_dir

REPO = Path(__file__).resolve().parents[2]
CARD_DEPENDENCIES = {
    "pluggy",
    "numpy",
    "opencv-python-headless",
    "onnxruntime",
    "pydantic-settings",
    "loguru",
    "importlib-metadata",
}


def _name(requirement: str) -> str:
    """The distribution name of a requirement such as ``numpy>=1.26``."""
    for mark in "<>=!~[; ":
        requirement = requirement.split(mark, 1)[0]
    return requirement.strip().lower()


def test_core_depends_on_the_design_cards_run_time_dependencies_only() -> None:
    project = tomllib.loads((REPO / "core" / "pyproject.toml").read_text())["project"]
    assert {_name(r) for r in project["dependencies"]} == CARD_DEPENDENCIES


def test_settings_and_their_default_directories_load_without_platformdirs(tmp_path: Path) -> None:
    code = (
        "import sys, json; sys.modules['platformdirs'] = None\n"
        "from c3_matcher.config import load_settings\n"
        "s = load_settings(env={})\n"
        "print(json.dumps([str(s.engines.tensorrt_cache_dir), str(s.fdr.path)]))\n"
    )
    env = {"HOME": str(tmp_path / "home"), "XDG_DATA_HOME": str(tmp_path / "data")}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == [
        str(tmp_path / "home" / ".cache" / "c3-matcher" / "tensorrt"),
        str(tmp_path / "data" / "c3-matcher" / "fdr" / "c3_fdr.jsonl"),
    ]


ACCOUNT_HOME = pwd.getpwuid(os.getuid()).pw_dir.rstrip("/")
XDG = ("XDG_CACHE_HOME", "XDG_DATA_HOME")

# HOME, (XDG_CACHE_HOME, XDG_DATA_HOME) or unset, and the cache and data directories expected,
# "{t}" standing for the test's directory. Each expectation is what platformdirs 4 gives on
# Linux in that environment (user_cache_dir / user_data_dir of "c3-matcher").
CASES = {
    "default": ("{t}/home", None, ("{t}/home/.cache", "{t}/home/.local/share")),
    "xdg absolute": ("{t}/home", ("{t}/xc", "{t}/xd"), ("{t}/xc", "{t}/xd")),
    "xdg relative ignored": (
        "{t}/home",
        ("xc", "./xd"),
        ("{t}/home/.cache", "{t}/home/.local/share"),
    ),
    "xdg empty ignored": ("{t}/home", ("", ""), ("{t}/home/.cache", "{t}/home/.local/share")),
    "home changed": ("{t}/other", None, ("{t}/other/.cache", "{t}/other/.local/share")),
    "home is the root": ("/", None, ("/.cache", "/.local/share")),
    "home relative: the account's": (
        "relative/home",
        None,
        (f"{ACCOUNT_HOME}/.cache", f"{ACCOUNT_HOME}/.local/share"),
    ),
}


@pytest.mark.parametrize(("home", "xdg", "bases"), CASES.values(), ids=CASES.keys())
def test_directories_follow_the_xdg_rule(
    home: str, xdg: tuple[str, str] | None, bases: tuple[str, str], tmp_path: Path, monkeypatch
) -> None:
    env = {"HOME": home, **dict(zip(XDG, xdg or (), strict=False))}
    env = {name: value.replace("{t}", str(tmp_path)) for name, value in env.items()}
    want = tuple(Path(base.replace("{t}", str(tmp_path))) / "c3-matcher" for base in bases)
    assert (user_cache_dir(env), user_data_dir(env)) == want  # a given environment
    for name in XDG:
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert (user_cache_dir(), user_data_dir()) == want  # the process's


def test_settings_defaults_and_the_installed_engine_dir_use_them(
    tmp_path: Path, monkeypatch
) -> None:
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("XDG_DATA_HOME", raising=False)
    assert EngineSettings().tensorrt_cache_dir == tmp_path / "cache" / "c3-matcher" / "tensorrt"
    assert FdrSettings().path == tmp_path / "home/.local/share/c3-matcher/fdr/c3_fdr.jsonl"
    monkeypatch.setattr(store, "checkout_root", lambda: None)  # as installed from a wheel
    assert store.default_engine_dir() == tmp_path / "cache" / "c3-matcher" / "engines"


def test_no_home_at_all_is_refused_naming_home(monkeypatch) -> None:
    def no_entry(uid: int) -> pwd.struct_passwd:
        raise KeyError(uid)

    monkeypatch.setattr(pwd, "getpwuid", no_entry)
    with pytest.raises(ConfigurationError) as err:
        user_cache_dir({"HOME": "relative"})
    assert err.value.problems[0][0] == "HOME"
    assert "XDG_CACHE_HOME" in str(err.value)
