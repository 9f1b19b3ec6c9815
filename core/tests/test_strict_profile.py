"""A strict profile offers only the strategies its BUILD_MATCHER_* rows link: shipping in a
linked distribution (or one whose name normalises to it) does not make a flagless strategy
fly. Fake installed distributions; nothing is installed."""

from __future__ import annotations

import pytest

from c3_matcher.errors import StrategyNotLinkedError
from c3_matcher.plugins import PluginHost
from c3_matcher.plugins.manager import discover
from c3_matcher.profiles import BuildProfile

from .fake_dists import WORKING_PLUGIN, dists, make_dist

_DISK = {
    "state": "ON",
    "strategy": "disk_lightglue",
    "distribution": "c3-matcher-disk-lightglue",
}
AIRBORNE = {"name": "airborne", "strict": True, "flags": {"BUILD_MATCHER_DISK_LIGHTGLUE": _DISK}}
RESEARCH = {**AIRBORNE, "name": "research", "strict": False}
TOOLING = {**AIRBORNE, "name": "operator-tooling", "tools": "c3-matcher-tools"}

TWO_STRATEGIES = """
from c3_matcher.plugins import StrategySpec, hookimpl

def create(**kwargs):
    raise AssertionError("not called in discovery tests")

@hookimpl
def c3_matcher_strategies():
    return [StrategySpec(name=name, factory=create, build_flag=flag, baseline=baseline)
            for name, flag, baseline in {specs!r}]
"""


@pytest.fixture
def site(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def host(site, data):  # type: ignore[no-untyped-def]
    return PluginHost(BuildProfile.from_data(data, "profile-dist"), discover(dists(site)))


@pytest.mark.parametrize("dist", ["C3_Matcher_Disk_LightGlue", "c3-matcher-disk-lightglue"])
def test_flagless_strategy_in_a_linked_distribution_is_refused_by_a_strict_profile(site, dist):
    make_dist(site, dist, "lookalike", WORKING_PLUGIN.format(strategy="acme_match", flag=None))
    airborne = host(site, AIRBORNE)
    assert "acme_match" not in airborne.strategies()
    with pytest.raises(StrategyNotLinkedError, match="no BUILD_MATCHER_"):
        airborne.resolve("acme_match")
    assert [p.distribution for p in airborne.ignored] == [dist]
    assert list(host(site, RESEARCH).strategies()) == ["acme_match"]  # research runs it


def test_the_linked_strategy_resolves_beside_a_refused_one(site):
    specs = [("disk_lightglue", "BUILD_MATCHER_DISK_LIGHTGLUE", False), ("extra", None, False)]
    make_dist(site, "c3-matcher-disk-lightglue", "disk_two", TWO_STRATEGIES.format(specs=specs))
    airborne = host(site, AIRBORNE)
    assert airborne.resolve("disk_lightglue").build_flag == "BUILD_MATCHER_DISK_LIGHTGLUE"
    assert list(airborne.strategies()) == ["disk_lightglue"]
    with pytest.raises(StrategyNotLinkedError):
        airborne.resolve("extra")


def test_a_linked_flag_claimed_from_another_distribution_is_refused(site):
    specs = [("disk_lightglue", "BUILD_MATCHER_DISK_LIGHTGLUE", False)]
    make_dist(site, "acme-matcher", "acme_disk", TWO_STRATEGIES.format(specs=specs))
    research_like_strict = {**AIRBORNE}  # strict: acme-matcher is not even loaded
    assert host(site, research_like_strict).strategies() == {}
    tooling = host(site, {**TOOLING, "tools": "acme-matcher"})  # linked, but not for this flag
    with pytest.raises(StrategyNotLinkedError, match="from c3-matcher-disk-lightglue"):
        tooling.resolve("disk_lightglue")


def test_the_ground_tools_baseline_is_offered_by_a_strict_tooling_profile(site):
    specs = [("sift_magsac", None, True), ("tools_extra", None, False)]
    make_dist(site, "c3-matcher-tools", "tools_fake", TWO_STRATEGIES.format(specs=specs))
    tooling = host(site, TOOLING)
    assert list(tooling.strategies()) == ["sift_magsac"]
    with pytest.raises(StrategyNotLinkedError):
        tooling.resolve("tools_extra")
