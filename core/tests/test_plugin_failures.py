"""A broken installation or plugin is listed with its reason and left out, never a crash.

Fake distributions are written into the test's own directory: one with incomplete metadata
anywhere on ``sys.path`` must not take down every command, and a plugin that imports but whose
hooks fail (or that calls ``sys.exit`` as it is imported) must not take down the command line or
the other plugins' strategies.
"""

from __future__ import annotations

import email
import json
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import importlib_metadata
import pytest

from c3_matcher.commands import CommandRegistry, UsageParser
from c3_matcher.errors import PluginLoadError, ProfileError, StrategyNotLinkedError
from c3_matcher.plugins import PluginHost
from c3_matcher.plugins.manager import discover
from c3_matcher.profiles import UNPROFILED, BuildProfile, installed_profile

from .fake_dists import WORKING_PLUGIN, dists, make_dist

RESEARCH = BuildProfile.from_data({"name": "research", "strict": False, "flags": {}}, "prof")

ENGINE_PLUGIN = """
from c3_matcher.engines.spec import EngineSpec, TensorSpec, WeightsRef
from c3_matcher.plugins import StrategySpec, hookimpl

SPEC = EngineSpec(model="{model}", variant="tiny", weights=WeightsRef("none", "none"),
                  exporter="tests:none", kind="extractor",
                  inputs=(TensorSpec("x", "float32", (1, "n")),),
                  outputs=(TensorSpec("y", "float32", (1, "n")),), input_rule="any")

def create(**kwargs):
    raise AssertionError("not called")

@hookimpl
def c3_matcher_strategies():
    return [StrategySpec(name="{model}_match", factory=create, description="fake")]

@hookimpl
def c3_matcher_engine_specs():
    {engines}
"""

COMMAND_PLUGIN = """
from c3_matcher.plugins import StrategySpec, hookimpl

def create(**kwargs):
    raise AssertionError("not called")

@hookimpl
def c3_matcher_strategies():
    return [StrategySpec(name="acme_cmd_match", factory=create, description="fake")]

@hookimpl
def c3_matcher_register_commands(commands):
    {body}
"""


@pytest.fixture
def site(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The test's own directory on ``sys.path``; the fake modules imported from it are
    forgotten afterwards (another test writes other code under the same module name)."""
    monkeypatch.syspath_prepend(str(tmp_path))
    before = set(sys.modules)
    yield tmp_path
    for name in set(sys.modules) - before:
        if name.startswith("acme_"):
            del sys.modules[name]


def host_for(site: Path) -> PluginHost:
    return PluginHost(RESEARCH, discover(dists(site)))


def working(site: Path, strategy: str = "acme_ok") -> None:
    make_dist(
        site, f"{strategy}-dist", strategy, WORKING_PLUGIN.format(strategy=strategy, flag=None)
    )


def write_dist_info(site: Path, stem: str, metadata: str | None, entry_points: str = "") -> None:
    """``<stem>.dist-info`` with ``metadata`` as METADATA (None: no METADATA file)."""
    info = site / f"{stem}.dist-info"
    info.mkdir()
    if metadata is not None:
        (info / "METADATA").write_text(metadata)
    if entry_points:
        (info / "entry_points.txt").write_text(entry_points)


class OldStyleDistribution(importlib_metadata.PathDistribution):
    """importlib_metadata before 8: a missing METADATA file or field reads as None."""

    @property
    def metadata(self):  # type: ignore[override]
        return email.message_from_string(self.read_text("METADATA") or "")

    @property
    def version(self):  # type: ignore[override]
        return self.metadata["Version"]


def old_style(site: Path) -> list[importlib_metadata.Distribution]:
    return [OldStyleDistribution(p) for p in sorted(site.glob("*.dist-info"))]


BEHAVIOURS = pytest.mark.parametrize("read", [dists, old_style], ids=["raises", "returns_none"])


# -- (1) a distribution with incomplete metadata -------------------------------------------------
@BEHAVIOURS
def test_a_distribution_without_metadata_is_skipped_silently(site, read):
    working(site)
    write_dist_info(site, "foo-1.0", None)  # an empty *.dist-info left behind by an installer
    write_dist_info(site, "~umpy-1.26.0", None)  # pip's half-uninstalled leftover
    write_dist_info(site, "bar-1.0", "Metadata-Version: 2.1\nName: bar\n")  # no Version
    sources = discover(read(site))
    assert [(s.name, s.distribution) for s in sources] == [("acme_ok", "acme_ok-dist")]
    assert installed_profile(read(site)) is UNPROFILED
    host = PluginHost(RESEARCH, sources)
    assert list(host.strategies()) == ["acme_ok"] and host.errors == ()


@BEHAVIOURS
@pytest.mark.parametrize(
    ("metadata", "said"),
    [
        ("Metadata-Version: 2.1\nName: acme-nover\n", "no readable Version"),
        ("Metadata-Version: 2.1\nVersion: 1.0\n", "no readable Name"),
        (None, "no readable Name"),
    ],
    ids=["no_version", "no_name", "no_metadata"],
)
def test_a_plugin_with_incomplete_metadata_is_a_load_error_naming_it(site, read, metadata, said):
    working(site)
    (site / "acme_nover.py").write_text(WORKING_PLUGIN.format(strategy="acme_nover", flag=None))
    write_dist_info(
        site, "acme_nover-1.0", metadata, "[c3_matcher.plugins]\nacme_nover = acme_nover\n"
    )
    host = PluginHost(RESEARCH, discover(read(site)))
    (error,) = host.errors
    assert isinstance(error, PluginLoadError)
    assert 'plugin "acme_nover"' in str(error) and said in str(error)
    assert "acme_nover-1.0.dist-info" in str(error) or "acme-nover" in str(error)
    assert list(host.strategies()) == ["acme_ok"]


@BEHAVIOURS
def test_a_profile_with_unreadable_metadata_is_a_profile_error_not_a_traceback(site, read):
    write_dist_info(site, "prof-1.0", None, "[c3_matcher.profile]\nairborne = prof:PROFILE\n")
    with pytest.raises(ProfileError, match="prof-1.0.dist-info"):
        installed_profile(read(site))


def test_the_command_line_survives_broken_metadata_on_sys_path(site, capsys):
    """The reviewer's repro: an empty ``foo-1.0.dist-info`` made ``--version`` a traceback, a
    plugin without Version made ``plugins`` one."""
    from c3_matcher.cli import main

    write_dist_info(site, "foo-1.0", None)
    (site / "acme_nover.py").write_text(WORKING_PLUGIN.format(strategy="acme_nover", flag=None))
    write_dist_info(
        site,
        "acme_nover-1.0",
        "Metadata-Version: 2.1\nName: acme-nover\n",
        "[c3_matcher.plugins]\nacme_nover = acme_nover\n",
    )
    with pytest.raises(SystemExit) as exited:
        main(["--version"])
    assert exited.value.code == 0
    assert capsys.readouterr().out.startswith("c3-matcher ")
    assert main(["plugins", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert any('plugin "acme_nover"' in e and "Version" in e for e in report["errors"])


# -- (2) a plugin that loads but whose hooks fail ------------------------------------------------
def test_a_plugin_calling_sys_exit_on_import_is_a_load_error(site):
    working(site)
    make_dist(site, "acme-exit", "acme_exit", "import sys\nsys.exit('acme_exit: no gpu sdk')\n")
    host = host_for(site)
    (error,) = host.errors
    assert 'plugin "acme_exit"' in str(error) and "SystemExit: acme_exit: no gpu sdk" in str(error)
    assert list(host.strategies()) == ["acme_ok"]


def test_ctrl_c_while_a_plugin_imports_is_not_swallowed(site):
    make_dist(site, "acme-slow", "acme_slow", "raise KeyboardInterrupt\n")
    with pytest.raises(KeyboardInterrupt):
        host_for(site)


@pytest.mark.parametrize(
    ("engines", "said"),
    [
        ("from acme_missing.engines import SPECS  # noqa: F401", "ModuleNotFoundError"),
        ("return SPEC", "c3_matcher_engine_specs returned EngineSpec, expected a list"),
        ("return ['not a spec']", "c3_matcher_engine_specs returned str"),
    ],
)
def test_a_failing_engine_specs_hook_leaves_out_its_plugin_only(site, engines, said):
    """It failed ``match`` of every strategy (the helpers read every plugin's engines) while
    ``plugins`` listed no error."""
    make_dist(
        site, "acme-good", "acme_good", ENGINE_PLUGIN.format(model="good", engines="return [SPEC]")
    )
    make_dist(site, "acme-bad", "acme_bad", ENGINE_PLUGIN.format(model="bad", engines=engines))
    host = host_for(site)
    (error,) = host.errors
    assert 'plugin "acme_bad"' in str(error) and said in str(error)
    assert [s.model for s in host.engine_specs()] == ["good"]
    assert list(host.strategies()) == ["good_match"]
    with pytest.raises(StrategyNotLinkedError, match=f"acme-bad.*{said}"):
        host.resolve("bad_match")


def registry() -> tuple[UsageParser, CommandRegistry]:
    parser = UsageParser(prog="c3-matcher")
    commands = CommandRegistry(parser.add_subparsers(dest="command", required=True))
    commands.add("match", help="the built-in one").set_defaults(handler=lambda a, c: 0)
    return parser, commands


@pytest.mark.parametrize(
    ("body", "said"),
    [
        ('commands.add("match", help="mine")', "command 'match' is registered twice"),
        ("import acme_optional_dependency  # noqa: F401", "ModuleNotFoundError"),
        ("raise SystemExit(3)", "SystemExit: 3"),
    ],
)
def test_a_failing_command_hook_leaves_out_its_plugin_only(site, body, said):
    working(site)
    make_dist(site, "acme-cmd", "acme_cmd", COMMAND_PLUGIN.format(body=body))
    host = host_for(site)
    assert host.errors == () and "acme_cmd_match" in host.strategies()
    parser, commands = registry()
    host.register_commands(commands)
    (error,) = host.errors
    assert 'plugin "acme_cmd"' in str(error) and said in str(error)
    assert list(host.strategies()) == ["acme_ok"]
    assert [p.name for p in host.loaded] == ["acme_ok"]
    with pytest.raises(StrategyNotLinkedError, match=said):
        host.resolve("acme_cmd_match")
    assert parser.parse_args(["match"]).handler(None, None) == 0  # the built-in one


def test_a_command_added_before_its_hook_failed_refuses_with_the_reason(site):
    body = textwrap.indent(
        'commands.add("acme-run", help="x").set_defaults(handler=lambda a, c: 0)\n'
        "raise RuntimeError('half registered')",
        "    ",
    ).lstrip()
    make_dist(site, "acme-cmd", "acme_cmd", COMMAND_PLUGIN.format(body=body))
    host = host_for(site)
    parser, commands = registry()
    host.register_commands(commands)
    handler = parser.parse_args(["acme-run"]).handler
    with pytest.raises(PluginLoadError, match="half registered"):
        handler(None, None)


@pytest.mark.parametrize(
    "body",
    ['commands.add("match", help="mine")', "import acme_optional_dependency  # noqa: F401"],
)
def test_the_command_line_survives_a_failing_command_hook(site, monkeypatch, capsys, body):
    import c3_matcher.compose
    from c3_matcher.cli import main

    working(site)
    make_dist(site, "acme-cmd", "acme_cmd", COMMAND_PLUGIN.format(body=body))
    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", lambda: host_for(site))
    assert main(["plugins", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [s["name"] for s in report["strategies"]] == ["acme_ok"]
    assert len(report["errors"]) == 1 and 'plugin "acme_cmd"' in report["errors"][0]


def test_a_plugin_printing_as_it_adds_its_commands_prints_to_stderr(site, monkeypatch, capsys):
    import c3_matcher.compose
    from c3_matcher.cli import main

    make_dist(site, "acme-cmd", "acme_cmd", COMMAND_PLUGIN.format(body='print("adding mine")'))
    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", lambda: host_for(site))
    assert main(["plugins", "--json"]) == 0
    said = capsys.readouterr()
    assert json.loads(said.out)["errors"] == [] and "adding mine" in said.err


def test_a_bug_while_the_plugins_load_is_one_line_not_a_traceback(monkeypatch, capsys):
    import c3_matcher.compose
    from c3_matcher.cli import main

    def broken() -> PluginHost:
        raise RuntimeError("a bug of the host")

    monkeypatch.delenv("C3_MATCHER_TRACEBACK", raising=False)
    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", broken)
    assert main(["plugins"]) == 1
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "c3-matcher: internal error: RuntimeError: a bug of the host"
    )
