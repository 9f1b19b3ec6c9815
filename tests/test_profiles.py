"""The profile matrix: buildflags/matrix.toml, the core's extras, the generated profile
distributions and what the installed environment reports all agree."""

from __future__ import annotations

import importlib.util
import json
import tomllib
from pathlib import Path

import pytest

from c3_matcher.profiles import installed_profile
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]


def _generator():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("generate", REPO / "buildflags" / "generate.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


GEN = _generator()
MATRIX = GEN.load_matrix()
ROWS = GEN.profile_rows(MATRIX)


def test_matrix_is_the_design_table():
    table = {p: {f: r["flags"][f]["state"] for f in r["flags"]} for p, r in ROWS.items()}
    assert table == {
        "airborne": {
            "BUILD_MATCHER_DISK_LIGHTGLUE": "ON",
            "BUILD_MATCHER_ALIKED_LIGHTGLUE": "ON",
            "BUILD_MATCHER_XFEAT": "WIRED",
        },
        "research": {
            "BUILD_MATCHER_DISK_LIGHTGLUE": "ON",
            "BUILD_MATCHER_ALIKED_LIGHTGLUE": "ON",
            "BUILD_MATCHER_XFEAT": "ON",
        },
        "replay-cli": {
            "BUILD_MATCHER_DISK_LIGHTGLUE": "ON",
            "BUILD_MATCHER_ALIKED_LIGHTGLUE": "ON",
            "BUILD_MATCHER_XFEAT": "ON",
        },
        "operator-tooling": {
            "BUILD_MATCHER_DISK_LIGHTGLUE": "OFF",
            "BUILD_MATCHER_ALIKED_LIGHTGLUE": "OFF",
            "BUILD_MATCHER_XFEAT": "OFF",
        },
    }
    assert ROWS["airborne"]["strict"] and ROWS["operator-tooling"]["strict"]
    assert not ROWS["research"]["strict"]
    # the flight computer never gets the ground tools; every ground profile does
    assert {p: r["tools"] for p, r in ROWS.items()} == {
        "airborne": None,
        "research": "c3-matcher-tools",
        "replay-cli": "c3-matcher-tools",
        "operator-tooling": "c3-matcher-tools",
    }


def test_generated_profile_distributions_are_current():
    for profile, data in ROWS.items():
        for path, text in GEN.render(profile, data).items():
            assert path.read_text(encoding="utf-8") == text, f"{path} is stale: run generate.py"


def test_one_version_for_every_member():
    """The matrix's version is every member's version and every pin between members."""
    for path in GEN.member_pyprojects():
        text = path.read_text(encoding="utf-8")
        assert GEN.with_version(text) == text, f"{path}: run buildflags/generate.py"
        project = tomllib.loads(text)["project"]
        assert project["version"] == GEN.VERSION


def test_core_extras_pull_exactly_one_profile_each():
    core = tomllib.loads((REPO / "core" / "pyproject.toml").read_text())
    extras = core["project"]["optional-dependencies"]
    for profile in ROWS:
        assert extras[profile] == [f"{GEN.distribution_name(profile)}=={GEN.VERSION}"]


@pytest.mark.parametrize("profile", sorted(ROWS))
def test_profile_dependencies_are_the_linked_plugins(profile):
    pyproject = tomllib.loads((REPO / "buildflags" / profile / "pyproject.toml").read_text())
    deps = sorted(d.split("==")[0] for d in pyproject["project"]["dependencies"])
    linked = [f["distribution"] for f in ROWS[profile]["flags"].values() if f["state"] == "ON"]
    tools = [ROWS[profile]["tools"]] if ROWS[profile]["tools"] else []
    assert deps == sorted(linked + tools)
    for flag in MATRIX["flags"].values():  # every flag's plugin is a real distribution here
        plugin = REPO / flag["plugin_dir"] / "pyproject.toml"
        assert tomllib.loads(plugin.read_text())["project"]["name"] == flag["distribution"]


def test_runtime_reports_the_installed_profile():
    """The development environment installs the research profile (scripts/setup)."""
    profile = installed_profile()
    assert profile.name == "research"
    want = {f: r["state"] for f, r in ROWS["research"]["flags"].items()}
    assert profile.flag_report() == want
    proc = run_cli("plugins", "--json", cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["profile"] == "research" and report["flags"] == want
    linked_here = {f["strategy"] for f in ROWS["research"]["flags"].values() if f["state"] == "ON"}
    assert {s["name"] for s in report["strategies"]} >= linked_here
