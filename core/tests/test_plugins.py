"""Plugin discovery through entry points, with fake installed distributions."""

from __future__ import annotations

import inspect
import json

import pytest

from c3_matcher.errors import (
    DuplicateStrategyError,
    StrategyNotLinkedError,
    UnknownStrategyError,
)
from c3_matcher.plugins import PluginHost, hookspecs
from c3_matcher.plugins.manager import discover
from c3_matcher.profiles import UNPROFILED, BuildProfile, installed_profile

from .fake_dists import BROKEN_PLUGIN, WORKING_PLUGIN, dists, make_dist

AIRBORNE_DATA = {
    "name": "airborne",
    "strict": True,
    "flags": {
        "BUILD_MATCHER_DISK_LIGHTGLUE": {
            "state": "ON",
            "strategy": "disk_lightglue",
            "distribution": "c3-matcher-disk-lightglue",
        },
        "BUILD_MATCHER_XFEAT": {
            "state": "WIRED",
            "strategy": "xfeat",
            "distribution": "c3-matcher-xfeat",
        },
    },
}
RESEARCH_DATA = {**AIRBORNE_DATA, "name": "research", "strict": False}


@pytest.fixture
def site(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def host_for(site, data=RESEARCH_DATA):  # type: ignore[no-untyped-def]
    return PluginHost(BuildProfile.from_data(data, "profile-dist"), discover(dists(site)))


def test_working_plugin_is_discovered(site):
    make_dist(
        site,
        "c3-matcher-disk-lightglue",
        "fake_disk",
        WORKING_PLUGIN.format(strategy="disk_lightglue", flag="BUILD_MATCHER_DISK_LIGHTGLUE"),
    )
    host = host_for(site)
    assert list(host.strategies()) == ["disk_lightglue"]
    assert host.resolve("disk_lightglue").build_flag == "BUILD_MATCHER_DISK_LIGHTGLUE"
    plugin = host.strategy_plugin("disk_lightglue")
    assert (plugin.distribution, plugin.version) == ("c3-matcher-disk-lightglue", "1.0")
    assert host.errors == ()


def test_broken_plugin_is_reported_naming_plugin_and_distribution(site):
    make_dist(site, "acme-broken", "acme_broken", BROKEN_PLUGIN)
    host = host_for(site)
    (error,) = host.errors
    assert 'Error importing plugin "acme_broken"' in str(error)
    assert "acme-broken" in str(error) and "module_that_does_not_exist" in str(error)
    assert host.strategies() == {}


@pytest.mark.parametrize(
    ("module", "source", "said"),
    [
        (
            "acme_wrong_module",
            "import os  # the entry point aims at the wrong module\n",
            "acme_wrong_module implements no c3_matcher hook",
        ),
        (
            "acme_unmarked",
            "def c3_matcher_strategies():  # @hookimpl forgotten\n    return []\n",
            "c3_matcher_strategies not marked as a hook",
        ),
    ],
)
def test_entry_point_implementing_no_hook_is_reported_not_loaded_silently(
    site, module, source, said
):
    make_dist(site, "acme-empty", module, source)
    host = host_for(site)
    (error,) = host.errors
    assert f'plugin "{module}"' in str(error) and said in str(error)
    assert host.loaded == ()


def test_duplicate_strategy_rejected_naming_both_distributions(site):
    for dist, mod in (("acme-one", "acme_one"), ("acme-two", "acme_two")):
        make_dist(site, dist, mod, WORKING_PLUGIN.format(strategy="acme_match", flag=None))
    host = host_for(site)
    assert "acme_match" not in host.strategies()
    with pytest.raises(DuplicateStrategyError) as info:
        host.resolve("acme_match")
    assert info.value.distributions == ("acme-one", "acme-two")
    assert any(isinstance(e, DuplicateStrategyError) for e in host.errors)


def test_strict_profile_ignores_unlinked_third_party_plugin(site):
    make_dist(
        site,
        "acme-matcher",
        "acme_matcher",
        WORKING_PLUGIN.format(strategy="acme_match", flag=None),
    )
    airborne = host_for(site, AIRBORNE_DATA)
    assert airborne.strategies() == {}
    assert [(p.distribution, "strict" in p.reason) for p in airborne.ignored] == [
        ("acme-matcher", True)
    ]
    with pytest.raises(StrategyNotLinkedError, match="acme-matcher"):
        airborne.resolve("acme_match")
    research = host_for(site, RESEARCH_DATA)
    assert list(research.strategies()) == ["acme_match"]


def test_not_linked_errors_name_strategy_flag_profile_and_fix(site):
    host = host_for(site, AIRBORNE_DATA)
    with pytest.raises(StrategyNotLinkedError) as info:
        host.resolve("xfeat")
    err = info.value
    assert (err.strategy, err.flag, err.profile) == ("xfeat", "BUILD_MATCHER_XFEAT", "airborne")
    assert "c3-matcher[research]" in err.fix
    with pytest.raises(StrategyNotLinkedError, match="install c3-matcher-disk-lightglue"):
        host.resolve("disk_lightglue")  # ON, but its plugin is not installed here
    research = host_for(site, RESEARCH_DATA)
    with pytest.raises(UnknownStrategyError, match="not recognized: no strategy is installed"):
        research.resolve("dsik_lightglue")


def test_profile_from_entry_points(site):
    assert installed_profile(dists(site)) is UNPROFILED
    make_dist(
        site,
        "c3-matcher-profile-airborne",
        "prof_air",
        f"PROFILE = {AIRBORNE_DATA!r}\n",
        group="c3_matcher.profile",
        ep_name="airborne",
        ep_value="prof_air:PROFILE",
    )
    profile = installed_profile(dists(site))
    assert profile.name == "airborne" and profile.strict
    assert profile.flag_report() == {
        "BUILD_MATCHER_DISK_LIGHTGLUE": "ON",
        "BUILD_MATCHER_XFEAT": "WIRED",
    }
    make_dist(
        site,
        "c3-matcher-profile-research",
        "prof_res",
        f"PROFILE = {RESEARCH_DATA!r}\n",
        group="c3_matcher.profile",
        ep_name="research",
        ep_value="prof_res:PROFILE",
    )
    with pytest.raises(Exception, match="more than one build profile"):
        installed_profile(dists(site))


def test_every_hookspec_is_documented_and_prefixed():
    specs = [
        obj
        for name, obj in inspect.getmembers(hookspecs, inspect.isfunction)
        if hasattr(obj, "c3_matcher_spec")
    ]
    assert {s.__name__ for s in specs} == {
        "c3_matcher_strategies",
        "c3_matcher_engine_specs",
        "c3_matcher_reference_backend",
        "c3_matcher_register_commands",
    }
    for spec in specs:
        assert spec.__name__.startswith("c3_matcher_")
        doc = inspect.getdoc(spec) or ""
        assert len(doc.split()) >= 15, f"hook {spec.__name__} is not documented"


NOISY_PLUGIN = """
from c3_matcher.plugins import hookimpl

print("a plugin printing as it is imported")

@hookimpl
def c3_matcher_register_commands(commands):
    def run(args, ctx):
        print("a plugin printing while a command runs")
        ctx.out("the result")
        return 0

    commands.add("noisy", help="prints, then says its result").set_defaults(handler=run)
"""


NATIVE_PLUGIN = """
import ctypes, os
from c3_matcher.plugins import hookimpl

os.write(1, b"a native banner as it is imported\\n")

@hookimpl
def c3_matcher_register_commands(commands):
    def run(args, ctx):
        os.write(1, b"a native library writing to descriptor 1\\n")
        ctypes.CDLL(None).printf(b"a native printf\\n")
        ctx.out('{"result": 1}')
        return 0

    commands.add("native", help="writes natively, then says its result").set_defaults(handler=run)
"""


def test_what_a_plugin_writes_natively_to_stdout_goes_to_stderr(site, monkeypatch, capfd):
    """A C library's printf (a vendor extractor) went to descriptor 1, into a JSON result; so
    did a native banner as the plugin was imported."""
    import c3_matcher.compose
    from c3_matcher.cli import main

    make_dist(site, "acme-native", "acme_native", NATIVE_PLUGIN)
    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", lambda: host_for(site))
    assert main(["native"]) == 0
    said = capfd.readouterr()
    assert json.loads(said.out) == {"result": 1} and said.out.count("\n") == 1
    assert "writing to descriptor 1" in said.err and "a native printf" in said.err
    assert "a native banner as it is imported" in said.err


def test_what_a_plugin_prints_goes_to_stderr_and_stdout_holds_the_result_alone(
    site, monkeypatch, capsys
):
    """A plugin's print would otherwise land in every command's --json output."""
    import c3_matcher.compose
    from c3_matcher.cli import main

    make_dist(site, "acme-noisy", "acme_noisy", NOISY_PLUGIN)
    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", lambda: host_for(site))
    assert main(["noisy"]) == 0
    said = capsys.readouterr()
    assert said.out == "the result\n"
    assert "printing as it is imported" in said.err and "printing while a command" in said.err
